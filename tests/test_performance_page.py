"""docs/performance.md is generated from bench/results by bench/report.py."""

import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package lives in the repo root
from bench.report import RESULTS_ROOT, performance_markdown, write_performance_page  # noqa: E402


def _device_folders(root):
    return sorted(p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name != "tmp")


def test_page_lists_every_device_folder_with_dated_runs():
    page = performance_markdown()
    assert page.startswith("# Performance\n")
    headings = re.findall(r"^## `([^`]+)`$", page, re.M)
    assert headings == _device_folders(RESULTS_ROOT)
    assert re.search(
        r"^Device `[^`]+`, run \d{4}-\d{2}-\d{2} \d{2}:\d{2} UTC, size `\w+`; from `bench/results/", page, re.M
    )
    assert performance_markdown() == page  # deterministic


def test_latest_run_of_each_section_per_device(tmp_path):
    dev = {"platform": "P", "device": "D", "type": "CPU", "compute_units": 2}

    def report(date, value, size="quick"):
        return {
            "device": dev,
            "date": date,
            "size": size,
            "sections": {
                "paper": {
                    "title": "Paper",
                    "tables": [{"title": "t", "columns": ["a", "b|c"], "rows": [[value, None]]}],
                }
            },
        }

    (tmp_path / "dev-a" / "old").mkdir(parents=True)
    (tmp_path / "dev-b").mkdir()
    (tmp_path / "dev-a" / "old" / "quick.json").write_text(json.dumps(report("2026-01-01T00:00:00+00:00", 1.0)))
    (tmp_path / "dev-a" / "quick.json").write_text(json.dumps(report("2026-02-01T10:20:00+00:00", 2.0)))
    (tmp_path / "dev-a" / "full.json").write_text(json.dumps(report("2025-01-01T00:00:00", 3.0, "full")))
    (tmp_path / "dev-a" / "other.json").write_text(json.dumps({"not": "a report"}))
    page = performance_markdown(tmp_path)
    assert re.findall(r"^## `([^`]+)`$", page, re.M) == ["dev-a", "dev-b"]
    assert "run 2026-02-01 10:20 UTC, size `quick`; from `bench/results/dev-a/quick.json`" in page
    assert "| 2 | — |" in page and "| 1 | — |" not in page  # only the latest quick run
    assert "| 3 | — |" in page  # the full run is another bench
    assert "| a | b\\|c |" in page  # a pipe cannot break the table
    assert "No benchmark report in this folder." in page
    out = write_performance_page(tmp_path / "performance.md", tmp_path)
    assert out.read_text() == page
