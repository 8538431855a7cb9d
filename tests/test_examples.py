"""Each examples/*.py runs at the documentation's small sizes and writes its pictures.

Each runs as ``python examples/NAME.py`` would, in its own process (the Dask example starts
worker processes that import it again) and in a temporary working directory, with
``PYDYNRAD_DOCS_SMALL=1``.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"

#: What each example must leave behind (relative to where it ran).
PICTURES = {
    "baking.py": ["cbox.glb", "cbox-lightmap.exr", "cbox-lightmap.glb", "cbox-lightmap.png"],
    "cornell_walk.py": ["cornell-walk/frame_0000.png", "cornell-walk/frame_0005.png", "cornell-walk/compare_0005.png"],
    "dask_store.py": ["dask-store.png"],
    "far_field.py": ["far-field-full-solve.png", "far-field-far-field.png", "far-field-local-only.png"],
    "moving_block.py": ["moving-block-0.png", "moving-block-2.png"],
    "work_plane_luminaire.py": ["work-plane.png", "work-plane.csv"],
}
#: Examples that take longer than the default run should spend (seconds on 2 cores).
SLOW = {"dask_store.py"}


def test_every_example_is_listed():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(PICTURES)


@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in SLOW else n for n in sorted(PICTURES)]
)
def test_example_runs_and_writes_its_pictures(name, tmp_path):
    env = dict(os.environ, PYDYNRAD_DOCS_SMALL="1", MPLBACKEND="Agg")
    run = subprocess.run(
        [sys.executable, str(EXAMPLES / name)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600
    )
    assert run.returncode == 0, f"{name} failed:\n{run.stdout[-4000:]}\n{run.stderr[-8000:]}"
    for picture in PICTURES[name]:
        out = tmp_path / picture
        assert out.is_file() and out.stat().st_size > 0, f"{name} did not write {picture}"
