"""The package's structure: no import cycle between modules, and no family importing a family above it.

Read from the source with ``ast`` (nothing is imported), counting imports at any depth: a deferred
import inside a function is as much a dependency as one at the top of the module.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pydynrad

PACKAGE = Path(pydynrad.__file__).parent

#: Families from the bottom up: a module may import its own family and the ones listed before it.
#: Top-level modules are their own family (named as the module).
LAYERS = [
    {"errors", "_version", "checks", "progress", "atomic", "precision", "defaults"},
    {"image_io", "video"},
    {"host"},
    {"device"},
    {"geometry"},
    {"formfactors", "smoothing", "scenes"},
    {"lights", "pathtracer", "renderer"},
    {"photometry", "rows", "solution", "bounces"},
    {"farfield"},
    {"dynamic", "comparison", "paths"},
    {"precompute", "bake", "walks"},
    {"cli", "viewer", "__main__"},
]
RANK = {family: i for i, layer in enumerate(LAYERS) for family in layer}


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE).with_suffix("").parts
        name = ".".join(("pydynrad", *parts))
        out[name.removesuffix(".__init__")] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """pydynrad modules that ``name`` imports, at any depth (a package's own __init__ when only it matches)."""
    is_package = path.name == "__init__.py"
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_package else name.split(".")[:-1]
                base = base[: len(base) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            if not target.startswith("pydynrad"):
                continue
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in modules:
                    found.add(sub)
                elif target in modules and not alias.name.startswith("_"):  # _native extensions are leaves
                    found.add(target)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names if a.name in modules)
    found.discard(name)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _family(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "pydynrad"


def test_every_family_has_a_layer():
    families = {_family(m) for m in _graph()} - {"pydynrad", "kernels"}
    assert families <= set(RANK), f"families without a layer: {sorted(families - set(RANK))}"


def test_no_import_cycles():
    graph = _graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt) :] + [nxt]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module)


def test_lower_families_never_import_upper_ones():
    wrong = []
    for module, targets in _graph().items():
        family = _family(module)
        if family == "pydynrad":  # the package's own __init__ gathers the public names
            continue
        for target in targets:
            other = _family(target)
            if other != "pydynrad" and RANK[other] > RANK[family]:
                wrong.append(f"{module} imports {target}")
    assert not wrong, "\n".join(sorted(wrong))


def test_no_module_imports_the_package_root():
    importers = [m for m, targets in _graph().items() if "pydynrad" in targets and m != "pydynrad"]
    assert not importers, f"modules importing pydynrad's __init__ (import the module that owns the name): {importers}"
