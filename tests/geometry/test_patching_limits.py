"""Subdivision under a memory limit: OutOfMemoryError with the numbers, never numpy's bare
MemoryError (near the subdivision cap under RLIMIT_AS)."""

import subprocess
import sys
import textwrap

import numpy as np
import pytest

import pydynrad
from pydynrad.errors import OutOfMemoryError
from pydynrad.geometry import patching

resource = pytest.importorskip("resource")

#: Runs in a child: RLIMIT_AS set to what the interpreter with pydynrad loaded already holds,
#: plus HEADROOM bytes; prints the exception's type and message.
CHILD = """
import resource, sys
import pydynrad
import pydynrad.geometry.patching as patching
with open("/proc/self/status") as f:
    size = next(int(line.split()[1]) * 1024 for line in f if line.startswith("VmSize:"))
resource.setrlimit(resource.RLIMIT_AS, (size + {headroom}, resource.getrlimit(resource.RLIMIT_AS)[1]))
{setup}
try:
    s = pydynrad.scenes.closed_box(subdivisions={subdivisions})
    print("OK", len(s))
except BaseException as exc:
    print(type(exc).__module__, type(exc).__name__, isinstance(exc, MemoryError), str(exc))
"""


def _child(subdivisions: int, headroom: int, setup: str = "") -> str:
    code = CHILD.format(subdivisions=subdivisions, headroom=headroom, setup=textwrap.dedent(setup))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr  # no signal, no traceback
    return out.stdout.strip()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc/self/status")
def test_a_subdivision_beyond_the_address_space_is_refused_before_it_starts():
    # 12 * 4^11 = 5e7 patches (about 19 GiB) under 1 GiB of address space: refused at once
    out = _child(11, 2**30)
    assert out.startswith("pydynrad.errors OutOfMemoryError True subdividing to max_area="), out
    assert "would make about 5.03e+07 patches, needing about 18" in out and "GiB is available" in out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS and /proc/self/status")
def test_numpy_running_out_anyway_is_named_too():
    # the estimate told the memory is there (it is not): numpy's MemoryError is caught and named
    out = _child(9, 2**29, "patching.available_host_bytes = lambda: 2**62")
    assert out.startswith("pydynrad.errors OutOfMemoryError True subdividing to max_area="), out
    assert "about 3.15e+06 patches" in out and "ran out of host memory" in out


def test_the_estimate_holds_the_subdivisions_peak(monkeypatch):
    """SUBDIVIDE_BYTES_PER_PATCH covers the measured peak (tracemalloc) of a subdivided scene,
    and a limit just under the estimate refuses it in the parent too."""
    import tracemalloc

    s = pydynrad.scenes.closed_box(subdivisions=1)
    area = 1e-4
    expected = patching._expected_count(s.vertices.astype(np.float64), s.faces.astype(np.int64), area, None)
    tracemalloc.start()
    try:
        out = patching.subdivide_scene(s, max_area=area)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(out) == expected
    assert peak <= expected * patching.SUBDIVIDE_BYTES_PER_PATCH
    monkeypatch.setattr(
        patching, "available_host_bytes", lambda: int(expected * patching.SUBDIVIDE_BYTES_PER_PATCH) - 1
    )
    with pytest.raises(OutOfMemoryError, match=r"about 1\.97e\+05 patches, needing about 0\.0703 GiB"):
        patching.subdivide_scene(s, max_area=area)
