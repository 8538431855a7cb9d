"""Memory limits: large allocations are checked against what the process may
allocate (RLIMIT_AS, the cgroup, the machine) and the device's memory before they happen, so a
limit gives an OutOfMemoryError and never a signal.

Each case runs in a child process under ``RLIMIT_AS`` (``ulimit -v``), set in the child before it
imports pydynrad. Before: ``DynamicRadiosity`` at M = 30,000 under 3 GiB died of signal 11 in
PoCL's failed host allocation.
"""

import resource
import subprocess
import sys
import textwrap

import pytest

LIMIT = 3 * 2**30


def _run(code: str, limit: int = LIMIT, timeout: float = 120) -> subprocess.CompletedProcess:
    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=timeout,
        preexec_fn=limited,
    )


def _refused(code: str) -> str:
    """Run ``code`` (which must raise) under the limit: the child exits normally (no signal) and
    prints the OutOfMemoryError's message; returns it."""
    body = textwrap.indent(textwrap.dedent(code).strip(), "    ")
    proc = _run(
        "import pydynrad\ntry:\n" + body + "\nexcept pydynrad.OutOfMemoryError as exc:\n"
        "    print('REFUSED', exc)\nelse:\n    print('RAN')\n"
    )
    assert proc.returncode == 0, (proc.returncode, proc.stderr[-2000:])  # -11 was the segfault
    assert "REFUSED" in proc.stdout, proc.stdout + proc.stderr[-2000:]
    return proc.stdout


def test_the_issues_dynamic_radiosity_is_refused_not_a_segfault():
    out = _refused("""
        import scipy.sparse as sp
        s = pydynrad.scenes.closed_box(subdivisions=6)
        pydynrad.DynamicRadiosity(s, sp.csr_matrix((len(s),) * 2, dtype="f4"), local_size=30000,
                                  observer=[.5] * 3, far_field=False)
        """)
    assert "M = 30000" in out and "ulimit -v" in out


def test_a_dynamic_radiosity_that_fits_still_runs_under_the_limit():
    proc = _run("""
        import scipy.sparse as sp
        import pydynrad
        s = pydynrad.scenes.closed_box(subdivisions=6)
        d = pydynrad.DynamicRadiosity(s, sp.csr_matrix((len(s),) * 2, dtype="f4"), local_size=1000,
                                      observer=[.5] * 3, far_field=False)
        d.update([0.4, 0.5, 0.5])
        print("RAN", d.radiosity().shape)
        """)
    assert proc.returncode == 0 and "RAN" in proc.stdout, proc.stderr[-2000:]


def test_a_render_past_the_limit_is_refused():
    _refused("""
        s = pydynrad.scenes.closed_box()
        cam = pydynrad.Camera([0.5, 0.5, 0.5], [0.5, 0.5, 0.0], width=16384, height=16384)
        pydynrad.render(s, s.emission.astype(float), cam)
        """)


def test_multibounce_past_the_limit_is_refused():
    _refused("""
        import scipy.sparse as sp
        s = pydynrad.scenes.closed_box(subdivisions=6)
        pydynrad.multibounce(s, sp.csr_matrix((len(s),) * 2, dtype="f4"))
        """)


@pytest.mark.parametrize("limit_gib", [1.5, 2.5])
def test_tighter_limits_refuse_the_same_way(limit_gib):
    """The same construction under other limits: a refusal each time, never a signal."""
    proc = _run(
        """
        import scipy.sparse as sp
        import pydynrad
        s = pydynrad.scenes.closed_box(subdivisions=6)
        try:
            pydynrad.DynamicRadiosity(s, sp.csr_matrix((len(s),) * 2, dtype="f4"), local_size=20000,
                                      observer=[.5] * 3, far_field=False)
        except (pydynrad.OutOfMemoryError, pydynrad.errors.DeviceError) as exc:
            print("REFUSED", type(exc).__name__)
        """,
        limit=int(limit_gib * 2**30),
    )
    assert proc.returncode == 0 and "REFUSED" in proc.stdout, (proc.returncode, proc.stderr[-2000:])
