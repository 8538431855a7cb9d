"""Memory limits: RLIMIT_AS and cgroups, and work refused before it would exceed them."""

import subprocess
import sys
import textwrap

import pytest

import pydynrad
from pydynrad.errors import InvalidInputError


def test_resolution_needing_more_than_memory_is_refused(monkeypatch, closed_box_48, device):
    with pytest.raises(InvalidInputError, match=r"resolution must lie in 2\.\.4096; got 8192"):
        pydynrad.form_factors(closed_box_48, resolution=8192, rows=[0], device=device)
    monkeypatch.setattr(pydynrad.formfactors, "available_host_bytes", lambda: 8 * 2**30)
    with pytest.raises(
        pydynrad.errors.OutOfMemoryError, match="resolution 4096 needs about 11.2 GiB .* 8.0 GiB is available"
    ):
        pydynrad.form_factors(closed_box_48, resolution=4096, rows=[0], device=device)  # main: 11 GiB in numpy first


def test_available_memory_obeys_rlimit_as():
    code = textwrap.dedent("""
        import resource
        from pydynrad.host.memory import available_host_bytes
        size = next(int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith("VmSize:"))
        resource.setrlimit(resource.RLIMIT_AS, (size + 2**30, resource.getrlimit(resource.RLIMIT_AS)[1]))
        print(available_host_bytes())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 0.9 * 2**30 < int(out.stdout) <= 2**30  # main: MemAvailable, whatever ulimit -v said


@pytest.mark.parametrize("layout", ["v2", "v1"])
def test_available_memory_obeys_the_cgroup_limit(monkeypatch, tmp_path, layout):
    from pydynrad.host import memory

    folder = tmp_path if layout == "v2" else tmp_path / "memory"
    folder.mkdir(exist_ok=True)
    limit, usage, stat = (
        ("memory.max", "memory.current", "inactive_file")
        if layout == "v2"
        else ("memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file")
    )
    (folder / limit).write_text(f"{2 * 2**30}\n")
    (folder / usage).write_text(f"{3 * 2**29}\n")
    (folder / "memory.stat").write_text(f"anon 123\n{stat} {2**28}\n")
    monkeypatch.setattr(memory, "CGROUP_ROOT", tmp_path)
    assert memory._cgroup_bytes() == 2 * 2**30 - 3 * 2**29 + 2**28  # the limit, less usage, plus reclaimable cache
    assert memory.available_host_bytes() <= 3 * 2**28  # main: MemAvailable of the whole machine
    (folder / limit).write_text("max\n")
    assert memory._cgroup_bytes() is None
