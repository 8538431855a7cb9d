"""The wheel installs and runs where there is no compiler (tools/check_wheel.sh): built from this
checkout, installed in a fresh virtual environment with its dependencies from the package index,
then used on PoCL. Slow (a build and an install; about 40 s with pip's cache warm) and needs the
index, so only with ``pytest -m slow``."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
@pytest.mark.skipif(
    not sys.platform.startswith("linux") or shutil.which("bash") is None,
    reason="tools/check_wheel.sh is a Linux bash script",
)
def test_wheel_installs_and_runs_without_a_compiler():
    done = subprocess.run(
        ["bash", str(ROOT / "tools" / "check_wheel.sh")],
        capture_output=True,
        text=True,
        timeout=900,
        env={**os.environ, "PYTHON": sys.executable},
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    assert "row sums of F" in done.stdout and "pip install 'pydynrad[dask]'" in done.stdout
    assert done.stdout.rstrip().endswith("check_wheel: ok")
