"""The CPU name given to PoCL 3.0's LLVM where it does not know the host (pydynrad/pocl_target.py)."""

import numpy as np

from pydynrad.pocl_target import _cpu_flags, _generic_triple, library_cpu, psabi_level, replaced_cpu

# /proc/cpuinfo flags of the machines named (subsets: the flags the levels read, plus noise).
V2 = {"fpu", "sse2", "cx16", "lahf_lm", "popcnt", "sse4_1", "sse4_2", "ssse3"}
V3 = V2 | {"avx", "avx2", "bmi1", "bmi2", "f16c", "fma", "abm", "movbe", "xsave"}
ZEN5 = V3 | {"avx512f", "avx512bw", "avx512cd", "avx512dq", "avx512vl", "avx512_bf16", "avx512_vp2intersect"}


def test_levels_follow_the_psabi():
    assert psabi_level(set()) == "x86-64"
    assert psabi_level(V2) == "x86-64-v2"
    assert psabi_level(V3) == "x86-64-v3"
    assert psabi_level(ZEN5) == "x86-64-v4"


def test_a_level_needs_every_flag_of_the_levels_below():
    assert psabi_level(V3 - {"movbe"}) == "x86-64-v2"
    assert psabi_level(ZEN5 - {"popcnt"}) == "x86-64"  # AVX-512 without v2 is no level at all
    assert psabi_level(ZEN5 - {"avx512vl"}) == "x86-64-v3"


def test_the_kernel_library_s_own_cpu_where_the_host_has_its_level():
    """PoCL 3.0 picks its kernel library variant by flags; compiling for the CPU that variant was
    built for lets LLVM inline its builtins (measured: with x86-64-v4, floor and fmin on float16 were
    calls in the kernel's object code; with skylake-avx512 none was left)."""
    assert library_cpu(ZEN5) == "skylake-avx512"
    assert library_cpu(V3) == "haswell"
    assert library_cpu(V2) == "penryn"
    assert library_cpu(set()) == "x86-64"
    # AVX-512F without the rest of psABI v4 (a Xeon Phi): the avx512 variant, not its CPU's level
    assert library_cpu(V3 | {"avx512f"}) == "x86-64-v3"


def test_the_device_builds_and_says_what_it_was_given(device):
    """Every test builds kernels; this one names the case: where PoCL's compiler reports
    ``generic`` (LLVM 14 on a CPU it predates, e.g. AMD Zen 5) the device was given a level,
    and a kernel built for it computes."""
    import pyopencl as cl

    d = device.cl_device
    if _generic_triple(d) is not None:
        assert replaced_cpu(d) == library_cpu(_cpu_flags())
        assert "compiler_cpu" in device.info()
    else:
        assert replaced_cpu(d) is None and "compiler_cpu" not in device.info()
    prg = cl.Program(device.context, "__kernel void twice(__global float *a) { a[get_global_id(0)] *= 2.0f; }").build()
    a = np.arange(37, dtype=np.float32)
    buf = cl.Buffer(device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
    prg.twice(device.queue, a.shape, None, buf)
    out = np.empty_like(a)
    cl.enqueue_copy(device.queue, out, buf)
    assert np.array_equal(out, 2 * a)
