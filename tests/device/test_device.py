import pytest

import pydynrad
from pydynrad.device.devices import kernel_dir


def test_default_device_is_shared(device):
    assert pydynrad.default_device() is device
    info = device.info()
    assert info["compute_units"] >= 1
    assert info["device"]


def test_kernel_sources_ship_as_package_data():
    assert any(kernel_dir().glob("*.cl"))


def test_program_is_built_once(device):
    a = device.program("selftest.cl")
    assert device.program("selftest.cl") is a
    assert device.program("selftest.cl", {"SELFTEST_SCALE": 3}) is not a


def test_kernel_runs(device):
    import numpy as np
    import pyopencl as cl

    x = np.arange(16, dtype=np.float32)
    buf = cl.Buffer(device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=x)
    k = device.kernel("selftest.cl", "scale", {"SELFTEST_SCALE": 3})
    k(device.queue, (16,), None, buf)
    out = np.empty_like(x)
    cl.enqueue_copy(device.queue, out, buf)
    np.testing.assert_array_equal(out, 3 * x)


def test_kernels_are_reused_per_thread_not_shared_across_threads(device):
    """One kernel object per thread and program: the same one again in a thread, another for
    other defines, and a thread of its own gets its own (a kernel holds its arguments)."""
    import threading

    import numpy as np
    import pyopencl as cl

    k = device.kernel("selftest.cl", "scale", {"SELFTEST_SCALE": 3})
    assert device.kernel("selftest.cl", "scale", {"SELFTEST_SCALE": 3}) is k
    assert device.kernel("selftest.cl", "scale", {"SELFTEST_SCALE": 5}) is not k
    other = []
    thread = threading.Thread(target=lambda: other.append(device.kernel("selftest.cl", "scale", {"SELFTEST_SCALE": 3})))
    thread.start()
    thread.join()
    assert other[0] is not k
    x = np.arange(16, dtype=np.float32)  # the reused object still runs with new arguments
    for scale in (3, 3):
        buf = cl.Buffer(device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=x)
        device.kernel("selftest.cl", "scale", {"SELFTEST_SCALE": scale})(device.queue, (16,), None, buf)
        out = np.empty_like(x)
        cl.enqueue_copy(device.queue, out, buf)
        np.testing.assert_array_equal(out, scale * x)


def test_build_error_carries_log(device):
    with pytest.raises(pydynrad.errors.KernelBuildError) as info:
        device.program("selftest.cl", {"SELFTEST_BREAK": 1})
    assert "selftest.cl" in str(info.value)
    assert info.value.build_log


@pytest.mark.parametrize("asked", [None, "PYOPENCL_COMPILER_OUTPUT", "PYDYNRAD_DEBUG"])
def test_compiler_output_only_when_asked(device, monkeypatch, asked):
    import warnings

    import pyopencl as cl

    for var in ("PYOPENCL_COMPILER_OUTPUT", "PYDYNRAD_DEBUG"):
        monkeypatch.delenv(var, raising=False)
    if asked:
        monkeypatch.setenv(asked, "1")
    device._programs.pop(("selftest.cl", ("-DSELFTEST_WARN=1",)), None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        device.program("selftest.cl", {"SELFTEST_WARN": 1})
    shown = [w for w in caught if issubclass(w.category, cl.CompilerWarning)]
    assert bool(shown) == bool(asked)
    if asked:
        assert "selftest: a build that succeeds" in str(shown[0].message)


def test_pocl_cache_folder(monkeypatch, tmp_path):
    import os

    from pydynrad.device.devices import _use_pocl_cache
    from pydynrad.device.pocl import cache_tag

    monkeypatch.setenv("POCL_CACHE_DIR", str(tmp_path / "mine"))
    _use_pocl_cache()
    assert os.environ["POCL_CACHE_DIR"] == str(tmp_path / "mine")  # the user's choice stands
    monkeypatch.delenv("POCL_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    _use_pocl_cache()
    assert os.environ["POCL_CACHE_DIR"] == str(tmp_path / "cache" / "pocl" / cache_tag())
    assert (tmp_path / "cache" / "pocl" / cache_tag()).is_dir()
    monkeypatch.delenv("POCL_CACHE_DIR")
    monkeypatch.setenv("PYDYNRAD_POCL_CPU", "znver3")  # a chosen name gets a cache of its own
    _use_pocl_cache()
    assert os.environ["POCL_CACHE_DIR"] == str(tmp_path / "cache" / "pocl" / "znver3")
