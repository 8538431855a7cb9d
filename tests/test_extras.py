"""Optional dependencies (extras): the base install works without them, and each call that needs
one says which extra installs it (:class:`pydynrad.errors.MissingExtraError`, an ImportError).

A missing extra is simulated by ``sys.modules[name] = None``, which makes ``import name`` raise
ModuleNotFoundError as if the package were not installed."""

import importlib.metadata
import importlib.resources
import subprocess
import sys

import numpy as np
import pytest
from helpers import assert_one_line_error, run_main

from pydynrad.errors import MissingExtraError, PydynradError

SMALL = ["cornell_box", "--max-edge", "250", "--resolution", "8", "--quiet"]  # 336 patches


@pytest.fixture
def without_dask(monkeypatch):
    for name in ("distributed", "dask"):
        monkeypatch.setitem(sys.modules, name, None)


@pytest.fixture
def without_matplotlib(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)


def test_missing_extra_error_is_a_pydynrad_error_and_an_import_error():
    exc = MissingExtraError("precompute_distributed", "Dask", "dask", name="distributed")
    assert isinstance(exc, PydynradError) and isinstance(exc, ImportError)
    assert str(exc) == "precompute_distributed needs Dask: pip install 'pydynrad[dask]'"
    assert (exc.name, exc.extra, exc.feature) == ("distributed", "dask", "precompute_distributed")
    with_alternative = MissingExtraError("x", "Dask", "dask", alternative="use y")
    assert str(with_alternative) == "x needs Dask: pip install 'pydynrad[dask]', or use y"


def test_import_pydynrad_needs_no_extra():
    """Every module of the package imports with Dask and matplotlib absent, and a plain
    ``import pydynrad`` loads neither (they are deferred to the calls that need them)."""
    code = (
        "import sys\n"
        "import pydynrad, pydynrad.cli.main\n"
        "loaded = sorted(m for m in ('distributed', 'dask', 'matplotlib') if m in sys.modules)\n"
        "assert not loaded, loaded\n"
        "import pkgutil, importlib\n"
        "for m in ('distributed', 'dask', 'matplotlib'):\n"
        "    sys.modules[m] = None\n"
        "for info in pkgutil.walk_packages(pydynrad.__path__, 'pydynrad.'):\n"
        "    if not info.name.endswith('__main__'):\n"
        "        importlib.import_module(info.name)\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_precompute_distributed_without_dask_names_the_extra(without_dask, tmp_path):
    from pydynrad.precompute.distributed import precompute_distributed

    with pytest.raises(
        MissingExtraError, match=r"^precompute_distributed needs Dask: pip install 'pydynrad\[dask\]'$"
    ) as info:
        precompute_distributed("cornell_box", tmp_path / "ff", resolution=8, workers=1)
    assert info.value.extra == "dask"
    assert not (tmp_path / "ff").exists()  # refused before any work


def test_start_client_without_dask_names_the_extra(without_dask):
    from pydynrad.precompute.distributed import _start_client

    with pytest.raises(ImportError, match=r"pip install 'pydynrad\[dask\]'"):
        _start_client(1, None)


@pytest.mark.parametrize(
    "where, given", [(["--workers", "3"], "--workers 3"), (["--scheduler", "tcp://localhost:1"], "--scheduler")]
)
def test_cli_store_on_dask_without_dask_is_one_line(without_dask, tmp_path, capsys, where, given):
    code, out, err = run_main(["formfactors", *SMALL, "-o", str(tmp_path / "ff"), *where], capsys)
    assert_one_line_error(
        code, err, "pydynrad formfactors: error:", f"{given} needs Dask", "pip install 'pydynrad[dask]'", "--workers 0"
    )
    assert not (tmp_path / "ff").exists()


def test_cli_store_in_this_process_needs_no_dask(without_dask, tmp_path, capsys):
    code, out, err = run_main(["formfactors", *SMALL, "-o", str(tmp_path / "ff"), "--workers", "0"], capsys)
    assert code == 0, err
    assert (tmp_path / "ff").is_dir()


def test_plot_work_plane_without_matplotlib_names_the_extra(without_matplotlib, tmp_path):
    from pydynrad.photometry import plot_work_plane, work_plane

    plane = work_plane([[0, 0], [1, 0], [1, 1], [0, 1]], 0.8, spacing=0.25)
    with pytest.raises(MissingExtraError, match=r"^plot_work_plane needs matplotlib: pip install 'pydynrad\[plot\]'$"):
        plot_work_plane(tmp_path / "plane.png", plane, np.ones(len(plane)))
    assert not (tmp_path / "plane.png").exists()


def test_installed_metadata_declares_the_extras():
    """Dask is not a base dependency; the dask and plot extras carry Dask and matplotlib; the
    package is typed (py.typed shipped beside it)."""
    requires = importlib.metadata.requires("pydynrad") or []
    base = [r for r in requires if "extra ==" not in r]
    assert not any(r.startswith(("distributed", "dask", "matplotlib")) for r in base), base
    assert any(r.startswith("distributed") and 'extra == "dask"' in r for r in requires), requires
    assert any(r.startswith("matplotlib") and 'extra == "plot"' in r for r in requires), requires
    extras = importlib.metadata.metadata("pydynrad").get_all("Provides-Extra")
    assert {"dask", "plot", "test", "bench", "all"} <= set(extras), extras
    assert importlib.resources.files("pydynrad").joinpath("py.typed").is_file()
