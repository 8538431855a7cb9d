"""Every ```python block of README.md and docs/**/*.md runs.

Each file's blocks run in order in one namespace (a later block may use an earlier one's
names), in a fresh temporary working directory holding copies of ``examples/data`` (so a page
can read ``downlight.ies``), with ``PYDYNRAD_DOCS_SMALL=1`` set. A block that should be shown
but not run is fenced as ```text, or as ```python with ``# docs: skip`` on its first line.
A failure names the file and the line its block starts on.
"""

import re
import shutil
import traceback
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: Generated or build output, not pages a reader edits.
EXCLUDED = ("docs/_build", "docs/api/_generated", "docs/auto_examples")
SKIP_MARK = "# docs: skip"

_FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>`{3,}|~{3,})[ \t]*(?P<info>[^\n`]*)$")


def markdown_files() -> list[Path]:
    files = [ROOT / "README.md"] if (ROOT / "README.md").exists() else []
    for path in sorted((ROOT / "docs").rglob("*.md")):
        rel = path.relative_to(ROOT).as_posix()
        if not rel.startswith(EXCLUDED):
            files.append(path)
    return files


def python_blocks(text: str) -> list[tuple[int, str]]:
    """(first line number of the code, code) of each ```python (or ```py) fenced block."""
    blocks, lines, i = [], text.splitlines(), 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, info, indent = m["fence"], m["info"].strip(), len(m["indent"])
        j = i + 1
        while j < len(lines) and not re.match(rf"^[ \t]*{re.escape(fence[0])}{{{len(fence)},}}[ \t]*$", lines[j]):
            j += 1
        lang = info.split()[0].strip("{}").lower() if info else ""
        if lang in ("python", "py"):
            code = "\n".join(line[indent:] if line[:indent].strip() == "" else line for line in lines[i + 1 : j])
            if not code.lstrip().startswith(SKIP_MARK):
                blocks.append((i + 2, code))
        i = j + 1
    return blocks


FILES = [f for f in markdown_files() if python_blocks(f.read_text(encoding="utf-8"))]


def test_block_extraction():
    text = "x\n```python\na = 1\n```\n```bash\nls\n```\n````{code-block} python\n```\n````\n  ```py\n  b = 2\n  ```\n"
    assert python_blocks(text) == [(3, "a = 1"), (12, "b = 2")]
    assert python_blocks("```python\n# docs: skip\nboom()\n```\n") == []


@pytest.mark.parametrize("path", FILES, ids=[f.relative_to(ROOT).as_posix() for f in FILES])
def test_code_blocks_run(path, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("PYDYNRAD_DOCS_SMALL", "1")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    for data in (ROOT / "examples" / "data").glob("*"):
        if data.is_file():
            shutil.copy(data, tmp_path / data.name)
    rel = path.relative_to(ROOT).as_posix()
    namespace = {"__name__": "__docs__"}
    for line, code in python_blocks(path.read_text(encoding="utf-8")):
        try:
            exec(compile(code, f"{rel}:{line}", "exec"), namespace)
        except Exception:
            pytest.fail(f"{rel}, the block starting at line {line}:\n{traceback.format_exc()}", pytrace=False)
    try:
        import matplotlib.pyplot as plt

        plt.close("all")
    except ImportError:  # matplotlib is only the plot extra: nothing to close without it
        pass
