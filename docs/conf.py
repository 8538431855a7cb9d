"""Sphinx configuration of the pydynrad documentation.

Build (from the repository root; warnings are errors)::

    python -m sphinx -W --keep-going -b html docs docs/_build/html

Needs the ``docs`` extra (``pip install -e ".[docs]"``). The examples gallery runs every
``examples/*.py`` with ``PYDYNRAD_DOCS_SMALL=1`` (small sizes, seconds each); the API pages are
generated into ``docs/api/_generated`` by autosummary on every build.
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))  # bench/ (the performance page) and an uninstalled checkout
os.environ.setdefault("PYDYNRAD_DOCS_SMALL", "1")  # the gallery runs the examples at small sizes
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("POCL_CACHE_DIR", str(Path.home() / ".cache" / "pocl"))

import pydynrad  # noqa: E402

project = "pydynrad"
author = "the pydynrad authors"
copyright = "the pydynrad authors"
release = pydynrad.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "sphinxarg.ext",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
templates_path = ["_templates"]
html_static_path = ["_static"]
exclude_patterns = [
    "_build",
    "Thumbs.db",
    ".DS_Store",
    # sphinx-gallery's own generated listing of run times, not part of the site.
    "sg_execution_times.rst",
    "auto_examples/*.ipynb",
    "auto_examples/*.py",
    "auto_examples/*.zip",
]

html_theme = "furo"
html_title = f"pydynrad {release}"

# -- MyST -------------------------------------------------------------------------------------
myst_enable_extensions = ["colon_fence", "dollarmath", "amsmath", "deflist"]
myst_heading_anchors = 3

# -- API reference: autodoc + autosummary + napoleon (numpy docstrings) -----------------------
autosummary_generate = True
autosummary_ignore_module_all = False  # a module's __all__ says what it documents
autosummary_imported_members = False
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_format = "short"
autoclass_content = "class"
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False


def _public_modules(package) -> list[str]:
    """The package and every module under it whose dotted path has no part starting with ``_``."""
    import pkgutil

    return [package.__name__] + sorted(
        m.name
        for m in pkgutil.walk_packages(package.__path__, package.__name__ + ".")
        if not any(part.startswith("_") for part in m.name.split("."))
    )


def _api_context(package) -> dict:
    """What the autosummary templates need beyond autosummary's own lists.

    ``canonical_names``: ``module.name`` of every public function and class at its shortest
    public path. A name re-exported by a package (``pydynrad.Scene``, defined in a geometry
    module) is documented there once, not again in the module defining it: one target per
    object, so every cross-reference resolves to one page. Modules are visited shallowest
    first; a module's public names are its ``__all__`` or, without one, what it defines without
    a leading ``_``.

    ``submodules``: each package's public submodules, for the recursion (autosummary's own
    list holds only those a package's ``__all__`` names).
    """
    import importlib
    import inspect

    modules = _public_modules(package)
    owner: dict[int, str] = {}
    claimed: set[str] = set()
    for modname in sorted(modules, key=lambda n: (n.count("."), n)):
        module = importlib.import_module(modname)
        public = getattr(module, "__all__", None)
        if public is None:
            public = [
                n
                for n, v in vars(module).items()
                if not n.startswith("_") and getattr(v, "__module__", None) == modname
            ]
        for name in public:
            obj = getattr(module, name, None)
            if not (inspect.isclass(obj) or inspect.isfunction(obj) or inspect.isbuiltin(obj)):
                continue
            if owner.setdefault(id(obj), modname) == modname:
                claimed.add(f"{modname}.{name}")
    # Every public path that reaches a documented object, to the path it is documented at.
    canonical = {id(getattr(importlib.import_module(n.rpartition(".")[0]), n.rpartition(".")[2])): n for n in claimed}
    for modname in modules:
        for name, obj in vars(importlib.import_module(modname)).items():
            if id(obj) in canonical and not name.startswith("_"):
                ALIASES[f"{modname}.{name}"] = canonical[id(obj)]
    submodules = {m: [s for s in modules if s.rpartition(".")[0] == m] for m in modules}
    return {"canonical_names": claimed, "submodules": submodules}


#: ``module.name`` -> the path the object is documented at (filled by :func:`_api_context`).
ALIASES: dict[str, str] = {}


autosummary_context = _api_context(pydynrad)


def _docstring_scopes(node) -> list[str]:
    """The class and module scopes (``pydynrad.rows.store.FormFactorStore.``,
    ``pydynrad.rows.store.``) of the docstring ``node`` was written in, from the source autodoc
    gives it (``.../store.py:docstring of pydynrad.rows.store.FormFactorStore.create``); none
    for a node outside a docstring."""
    from docutils.utils import get_source_line

    source = get_source_line(node)[0] or ""
    if "docstring of " not in source:
        return []
    parts = source.rpartition("docstring of ")[2].split(".")
    for cut in range(len(parts), 0, -1):  # the longest prefix that is a module
        modname = ".".join(parts[:cut])
        if modname in sys.modules:
            break
    else:
        return []
    scopes = []
    if cut < len(parts) - 1:  # a member of a class (or the class's own docstring: no harm)
        scopes.append(f"{modname}.{parts[cut]}.")
    return scopes + [".".join(parts[:k]) + "." for k in range(cut, 0, -1)]


def _resolve_alias(app, env, node, contnode):
    """A reference to an object by another of its paths (``pydynrad.geometry.scene.Scene``, or
    ``multibounce`` inside the module defining it) resolves to the one page documenting it."""
    target = node.get("reftarget", "").lstrip("~.")
    module, klass = node.get("py:module"), node.get("py:class")
    # The class, its module, the packages above it (``InvalidInputError`` written anywhere in
    # pydynrad reaches pydynrad.InvalidInputError), the docstring's own class and module, then
    # the target as written.
    parts = (module or "").split(".") if module else []
    scopes = ([f"{module}.{klass}."] if module and klass else []) + [
        ".".join(parts[:k]) + "." for k in range(len(parts), 0, -1)
    ]
    # A docstring documented on a shorter path's page (pydynrad.FormFactorStore.create, written
    # in pydynrad.rows.store) names things as its own module sees them: its class and module too.
    for scope in _docstring_scopes(node):
        if scope not in scopes:
            scopes.append(scope)
    scopes.append("")
    for scope in scopes:
        full = scope + target
        parts = full.split(".")
        for cut in range(len(parts), 0, -1):  # the longest documented prefix, then its members
            head = ".".join(parts[:cut])
            if head in ALIASES:
                new = ".".join([ALIASES[head]] + parts[cut:])
                domain = env.get_domain("py")
                resolved = domain.resolve_xref(
                    env, node.get("refdoc"), app.builder, node.get("reftype"), new, node, contnode
                )
                if resolved is not None:
                    return resolved
    return None


def _check_reference(app, env, node, contnode):
    """Cross-references the docstrings and pages write (``:func:`pydynrad.solve```,
    ``:class:`Scene```) must resolve: one that does not is a warning, so an error under -W.

    ``nitpicky`` would check more, but also every word of the numpy-style type fields
    (``(N, 3) float``, ``optional``) and every external type (no intersphinx: the build runs
    offline): hundreds of warnings that are not mistakes. This checks what an author wrote as a
    link to a pydynrad function, class, exception or module. Type fields (``refspecific``),
    names outside pydynrad, private names and module constants (not documented) are left alone.
    """
    import builtins

    if node.get("refdomain") != "py" or node.get("refspecific"):
        return None
    resolved = _resolve_alias(app, env, node, contnode)
    if resolved is not None:
        return resolved
    target = node.get("reftarget", "").lstrip("~.")
    head, last = target.split(".")[0], target.split(".")[-1]
    ours = head == "pydynrad" or ("." not in target and not hasattr(builtins, head))
    if ours and not last.startswith("_") and node.get("reftype") in ("func", "class", "exc", "mod", "meth"):
        from sphinx.util import logging

        logging.getLogger(__name__).warning(
            "cross-reference to %s %r does not resolve (not documented, or an old module path)",
            node.get("reftype"),
            target,
            location=node,
            type="pydynrad",
            subtype="xref",
        )
    return None


def setup(app):
    app.connect("missing-reference", _check_reference)


# -- Examples gallery ---------------------------------------------------------------------------
# sphinx-gallery runs each example in the folder it reads it from, and the examples write their
# pictures where they run: it reads a fresh copy in docs/_build/examples, so the build leaves
# nothing in examples/. (It re-runs an example only when its source changed.)
EXAMPLES_RUN = DOCS / "_build" / "examples"
shutil.rmtree(EXAMPLES_RUN, ignore_errors=True)
shutil.copytree(ROOT / "examples", EXAMPLES_RUN, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))

sphinx_gallery_conf = {
    "examples_dirs": str(EXAMPLES_RUN),
    "gallery_dirs": str(DOCS / "auto_examples"),
    "filename_pattern": r".*",  # every example runs (and must run in seconds)
    "ignore_pattern": r"__init__\.py|/data/",
    "image_scrapers": ("matplotlib",),
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "show_memory": False,
    "abort_on_example_error": False,
    "only_warn_on_example_error": False,
    "write_computation_times": False,
}
