"""Every kernel launch states its work-group size ('GPU rules in code').

Runs the Oclgrind cases (tests/oclgrind/cases.py: every kernel of kernels/ on tiny inputs,
with the GPU layouts and with CPU traits) on the default device with pyopencl's kernel call
wrapped: each launch must come through :func:`pydynrad.device.launch.enqueue_kernel`, with a
local size (never ``None``), within the kernel's ``CL_KERNEL_WORK_GROUP_SIZE``, and a global
size that is a whole number of work-groups.
"""

from __future__ import annotations

import importlib.util
import math
import re
import sys
from pathlib import Path

import pyopencl as cl
import pytest

from pydynrad.device.launch import RAY_WG_CPU, WG, enqueue_kernel, fit_work_group, kernel_work_group_limit

ROOT = Path(__file__).resolve().parents[2]


def _cases():
    spec = importlib.util.spec_from_file_location("oclgrind_cases", ROOT / "tests" / "oclgrind" / "cases.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _declared() -> set[str]:
    names = set()
    for path in (ROOT / "kernels").glob("*.cl"):
        src = re.sub(r"//[^\n]*|/\*.*?\*/", "", path.read_text(), flags=re.S)
        names |= set(re.findall(r"__kernel\b[^;{]*?\bvoid\s+(\w+)\s*\(", src))
    return names


@pytest.fixture
def launches(monkeypatch):
    """(kernel name, global, local, called from enqueue_kernel) of every launch meanwhile."""
    seen = []
    call = cl.Kernel.__call__

    def recording(self, queue, global_size, local_size, *args, **kwargs):
        via = sys._getframe(1).f_code is enqueue_kernel.__code__
        seen.append((self.function_name, tuple(global_size), local_size, via, kernel_work_group_limit_of(self, queue)))
        return call(self, queue, global_size, local_size, *args, **kwargs)

    def kernel_work_group_limit_of(kernel, queue):
        return kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, queue.device)

    monkeypatch.setattr(cl.Kernel, "__call__", recording)
    monkeypatch.setenv("PYDYNRAD_FORCE_DEVICE", "1")
    return seen


def test_every_launch_states_its_local_size(device, launches):
    cases = _cases()
    cpu = device.with_traits(cpu=True, compute_units=2, float_width=16, double_width=8)
    gpu = device.with_traits(cpu=False)  # the GPU layouts and kernels, on this device
    for dev, label in ((gpu, "gpu"), (cpu, "cpu")):
        cases.matrices(dev, label)
        cases.updates(dev, label, label == "cpu")
        cases.scene_cases(dev, label)
    cases.dynamic_walk(gpu, "gpu")
    assert launches
    for name, global_size, local, via, limit in launches:
        assert local is not None, f"{name} launched with the work-group size left to the runtime"
        assert via, f"{name} launched past pydynrad.device.launch.enqueue_kernel"
        assert len(local) == len(global_size), name
        assert math.prod(local) <= limit, f"{name}: work-group {local} above its CL_KERNEL_WORK_GROUP_SIZE {limit}"
        assert all(g % lo == 0 for g, lo in zip(global_size, local)), f"{name}: {global_size} not whole groups {local}"
    missing = _declared() - {"scale"} - {name for name, *_ in launches}  # scale: the selftest kernel
    assert not missing, f"kernels no case launched: {sorted(missing)}"


def test_work_group_fits_the_kernel_and_device(device):
    k = device.kernel("selftest.cl", "scale")
    limit = kernel_work_group_limit(k, device)
    assert 1 <= limit <= device.cl_device.max_work_group_size
    assert fit_work_group(device, k, (WG,)) == (min(WG, limit),)
    small = device.with_traits(max_work_group=16)
    assert kernel_work_group_limit(k, small) == min(16, limit)
    assert fit_work_group(small, k, (64, 4)) == (4, 4)  # the largest dimension halved until it fits
    assert fit_work_group(small, k, (RAY_WG_CPU,)) == (RAY_WG_CPU,)
    from pydynrad.errors import DeviceError

    with pytest.raises(DeviceError, match="built for work-groups"):
        fit_work_group(small, k, (64,), fixed=True)
    with pytest.raises(TypeError, match="explicit local size"):
        enqueue_kernel(device, k, (64,), None)
