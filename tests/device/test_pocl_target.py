"""The CPU name given to PoCL 3.0's LLVM where it does not know the host (pydynrad/device/pocl.py)."""

import numpy as np

from pydynrad.device.pocl import _cpu_flags, compiler_target, library_cpu, needs_replacing, psabi_level, replaced_cpu

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


def test_which_names_are_replaced():
    """``generic`` always; a CPU without AVX-512 only where the kernel library variant has it (LLVM 14
    calls a Zen 4 ``znver3``: measured on a Zen 4 EPYC, every 16-wide builtin then aborted inside
    LLVM); a name LLVM knows for what the host is, never."""
    assert needs_replacing("generic", V3) and needs_replacing("generic", ZEN5)
    assert needs_replacing("znver3", ZEN5) and needs_replacing("haswell", ZEN5)
    assert not needs_replacing("znver3", V3) and not needs_replacing("znver2", V3)
    assert not needs_replacing("rocketlake", ZEN5) and not needs_replacing("skylake-avx512", ZEN5)
    assert not needs_replacing("znver4", ZEN5)  # a later LLVM that knows the CPU
    assert needs_replacing("znver3", V3 | {"avx512f"})  # PoCL's avx512 variant goes by avx512f alone


def test_the_device_builds_and_says_what_it_was_given(device):
    """Every test builds kernels; this one names the case: where PoCL's compiler CPU cannot compile
    its kernel library (``generic`` on Zen 5, ``znver3`` on Zen 4) the device was given the
    library's CPU, and a kernel built for it computes, 16-wide builtins included."""
    import pyopencl as cl

    d = device.cl_device
    target = compiler_target(d)
    if target is not None and needs_replacing(target[1], _cpu_flags()):
        assert replaced_cpu(d) == library_cpu(_cpu_flags())
        assert "compiler_cpu" in device.info()
    else:
        assert replaced_cpu(d) is None and "compiler_cpu" not in device.info()
    wide = cl.Program(
        device.context,
        "__kernel void roots(__global float16 *a) "
        "{ size_t i = get_global_id(0); a[i] = floor(rsqrt(fabs(a[i])) + 0.5f); }",
    ).build()
    v = np.full(16 * 3, -0.01, np.float32)
    vbuf = cl.Buffer(device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=v)
    wide.roots(device.queue, (3,), None, vbuf)
    cl.enqueue_copy(device.queue, v, vbuf)
    assert np.array_equal(v, np.full_like(v, 10.0))  # 1/sqrt(0.01) = 10, to within rsqrt's ulps
    prg = cl.Program(device.context, "__kernel void twice(__global float *a) { a[get_global_id(0)] *= 2.0f; }").build()
    a = np.arange(37, dtype=np.float32)
    buf = cl.Buffer(device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=a)
    prg.twice(device.queue, a.shape, None, buf)
    out = np.empty_like(a)
    cl.enqueue_copy(device.queue, out, buf)
    assert np.array_equal(out, 2 * a)
