"""Kernel layouts chosen from what a device reports (pydynrad.device.launch), for devices that are not
here: described by hand as DeviceTraits (an AVX-512, an AVX2 and an SSE/NEON CPU, GPUs), and
the kernels built at those widths run on the test device against numpy.

Truth for the choices: the widths of the SIMD registers each CPU has (16, 8, 4 floats; half
as many doubles) and the limits a GPU states (work-group size, local memory).
"""

import dataclasses

import numpy as np
import pytest
from helpers import coloured_box, dense_K, reciprocal_F, rel

from pydynrad import multibounce
from pydynrad.device.devices import DeviceTraits
from pydynrad.device.launch import (
    GEMM_GRAIN,
    RAY_WG_CPU,
    UpdateLayout,
    cpu_vector_width,
    gemm_layout,
    matvec_layout,
    spmv_layout,
)
from pydynrad.device.matrix import DeviceMatrix, padded_ld
from pydynrad.dynamic.kupdate import UpdateKernels

AVX512 = DeviceTraits(
    cpu=True,
    compute_units=2,
    float_width=16,
    double_width=8,
    max_work_group=4096,
    local_mem_bytes=2**21,
    aligned_vectors=True,
)
AVX2 = dataclasses.replace(AVX512, compute_units=32, float_width=8, double_width=4)
SSE = dataclasses.replace(AVX512, compute_units=4, float_width=4, double_width=2, aligned_vectors=False)
GPU = DeviceTraits(
    cpu=False, compute_units=132, float_width=1, double_width=1, max_work_group=1024, local_mem_bytes=48 * 1024
)
SMALL_GPU = dataclasses.replace(GPU, compute_units=4, max_work_group=32, local_mem_bytes=256)


# Per CPU: update/GEMM width in floats and in doubles, matvec width in floats and in doubles.
@pytest.mark.parametrize(
    "traits,widths",
    [(AVX512, (16, 8, 16, 16)), (AVX2, (8, 4, 16, 8)), (SSE, (4, 4, 8, 4))],
    ids=["avx512", "avx2", "sse"],
)
def test_cpu_kernels_take_the_devices_register_width(traits, widths):
    """Update and GEMM kernels: one register of REALs per vector (4 at least: the narrowest
    kernel vector); matvec and the sparse gathers: two registers, at most 16; fp16 storage
    computes in float."""
    M, ld = 1000, padded_ld(1000)
    f32, f64, mv32, mv64 = widths
    for k_size, real, want, mv_want in ((2, 4, f32, mv32), (4, 4, f32, mv32), (8, 8, f64, mv64)):
        lay = UpdateLayout.make(traits, M, ld, k_size, real)
        assert lay.cpu and lay.vw == want and lay.defines(8)["VW"] == want and lay.sw == mv_want
        assert ("PDR_CLANG_VECTORS" in lay.defines(8)) == traits.aligned_vectors
        assert gemm_layout(traits, real).vw == want and GEMM_GRAIN % want == 0
        mv = matvec_layout(traits, M, ld, real_itemsize=real)
        assert (mv.vw, mv.lx) == (mv_want, 1)
    # Every core gets work: ~8 rank-update items and 16 solve blocks per compute unit.
    lay = UpdateLayout.make(traits, 4096, 4096, 4, 4)
    assert lay.rank_grid[0][0] == min(4096 // 8, 8 * traits.compute_units)
    assert spmv_layout(traits, 10**6).blocks == 16 * traits.compute_units


def test_matvec_rows_side_by_side_hide_the_fma_latency():
    """RI rows per CPU item: MATVEC_CHAINS accumulator registers at least (one per row, vector
    and register of REALs), at most MATVEC_ACC_REGS; narrow storage from memory keeps one row;
    a GPU and the LX > 1 layout always one; the grid covers every row."""
    from pydynrad.device.launch import MATVEC_ACC_REGS, MATVEC_CHAINS

    M, ld = 1000, padded_ld(1000)
    cached = dataclasses.replace(AVX512, cache_bytes=2**25)
    for traits in (cached, dataclasses.replace(AVX2, cache_bytes=2**25)):
        for real, k in ((4, 2), (4, 4), (8, 8)):
            mv = matvec_layout(traits, M, ld, real_itemsize=real, k_itemsize=k)
            for nrhs in range(1, 5):
                ri, regs = mv.rows_per_item(nrhs), mv.regs * nrhs
                assert ri * regs >= MATVEC_CHAINS or (ri + 1) * regs > MATVEC_ACC_REGS
                assert ri * regs <= max(regs, MATVEC_ACC_REGS) and mv.defines(nrhs)["RI"] == ri
                (g,), local = mv.matvec_grid(M, nrhs)
                assert local == (mv.wg,) and RAY_WG_CPU <= mv.wg <= 64 and g % mv.wg == 0
                assert g * ri >= M and (g - mv.wg) * ri < M
    assert matvec_layout(cached, M, ld, real_itemsize=4, k_itemsize=2).rows_per_item(1) == 4
    assert matvec_layout(AVX512, M, ld, real_itemsize=4, k_itemsize=2).rows_per_item(1) == 1  # no cache reported
    assert matvec_layout(AVX512, M, ld, real_itemsize=4, k_itemsize=4).rows_per_item(1) == 4
    assert matvec_layout(cached, 4096, 4096, real_itemsize=4, k_itemsize=2).rows_per_item(1) == 1  # 32 MiB: memory
    assert matvec_layout(cached, M, ld, (8, 4), real_itemsize=4).rows_per_item(1) == 1
    assert matvec_layout(GPU, M, ld).rows_per_item(1) == 1


def test_reported_widths_off_the_kernel_widths_round_down():
    odd = dataclasses.replace(AVX512, float_width=1, double_width=0)
    assert cpu_vector_width(odd, 4) == cpu_vector_width(odd, 8) == 4
    wide = dataclasses.replace(AVX512, float_width=32, double_width=12)
    assert cpu_vector_width(wide, 4) == 16 and cpu_vector_width(wide, 8) == 8


@pytest.mark.parametrize("traits", [GPU, SMALL_GPU], ids=["gpu", "small-gpu"])
def test_gpu_layouts_stay_within_the_devices_limits(traits):
    """GPU kernels: coalesced float4 loads, work-groups no larger than the device allows, the
    matvec's reduction (one REAL per item and right-hand side) inside its local memory."""
    M, ld = 3000, padded_ld(3000)
    for real in (4, 8):
        mv = matvec_layout(traits, M, ld, real_itemsize=real)
        assert mv.vw == 4 and 1 < mv.lx <= min(64, traits.max_work_group) and mv.lx & (mv.lx - 1) == 0
        assert 4 * mv.lx * real <= traits.local_mem_bytes
        grid, local = mv.matvec_grid(M)
        assert grid == (M * mv.lx,) and local == (mv.lx,)
        up = UpdateLayout.make(traits, M, ld, real, real)
        assert not up.cpu and up.vw == up.sw == 4 and "PDR_CLANG_VECTORS" not in up.defines(8)
        assert up.gather_grid(7)[1][0] == up.wg <= min(64, traits.max_work_group)
        g = gemm_layout(traits, real)
        assert (g.vw, g.tm) == (4, 4) and g.grid(256, 256)[1][1] <= traits.max_work_group
    lx = spmv_layout(traits, 10**6)
    assert lx.lx == min(64, traits.max_work_group) and lx.blocks == 256 * traits.compute_units
    assert matvec_layout(GPU, M, ld).lx == 64 and matvec_layout(SMALL_GPU, M, ld).lx == 16  # 256 B / (4 RHS x 4 B)


@pytest.mark.parametrize(
    "width,aligned,storage",
    [(8, True, "fp16"), (8, True, "fp64"), (4, False, "fp32")],
    ids=["avx2-clang-fp16", "avx2-clang-fp64", "portable-4-fp32"],
)
def test_kernels_at_other_widths_against_numpy(device, width, aligned, storage):
    """The kernels an AVX2 CPU (8 floats) or a 4-wide CPU without PoCL's clang would get, built
    and run here: gathers (dense and sparse), rank update, products with K and the device
    GEMM build of K against float64 numpy on the matrix as stored."""
    if aligned and not device.traits.aligned_vectors:
        pytest.skip(f"{device.name} has no clang vector path")
    dev = device.with_traits(cpu=True, float_width=width, double_width=width // 2, aligned_vectors=aligned)
    built, program = [], dev.program
    dev.program = lambda filename, defines=None: (
        built.append((filename, dict(defines or {}))) or program(filename, defines)
    )
    rng = np.random.default_rng(width)
    M = 203  # ld = 256: rows past the last group of 8, sparse steps and column strips that end early
    m = DeviceMatrix(dev, rng.uniform(-1, 1, (1, M, M)), storage)
    uk = UpdateKernels(m, 8)
    assert uk.layout.vw == (width // 2 if storage == "fp64" else width) and m._layout.vw == 2 * uk.layout.vw
    K = m.to_host()[0]
    tol = 1e-13 if storage == "fp64" else 1e-5  # products in REAL; observed 2e-16 / 3e-7
    X, Y = rng.uniform(-1, 1, (2, 7, M))
    KX, YK = uk.gather(0, X, Y)
    assert rel(KX, X @ K.T) < tol and rel(YK, Y @ K) < tol
    sparse = X * (rng.random((7, M)) < 0.05)
    sKX, sYK = uk.gather_all(sparse[None], sparse[None], sparse=True)
    assert rel(sKX[0], sparse @ K.T) < tol and rel(sYK[0], sparse @ K) < tol
    x = rng.random(M)
    assert rel(m.matvec(x)[0], K @ x) < tol and rel(m.rmatvec(x)[0], x @ K) < tol
    assert rel(m.matmat(X[:3])[0], X[:3] @ K.T) < tol
    A, B = rng.uniform(-1, 1, (2, 5, M)) / 5
    uk.rank_update(0, A, B)
    # fp16: the update in fp32, rounded once to fp16 per element (observed 3.9e-4 at 16 wide).
    assert rel(m.to_host()[0], K + A.T @ B) < {"fp16": 2e-3, "fp32": 1e-5, "fp64": 1e-13}[storage]
    s = coloured_box(2, seed=width)
    F = reciprocal_F(s.areas, row_sum=0.9, seed=width)
    dtype = np.float64 if storage == "fp64" else np.float32
    got = multibounce(s, F, dtype=dtype, device=dev, backend="device")
    assert rel(got, dense_K(s, F)) < (1e-12 if storage == "fp64" else 1e-5)
    vws = {(f, d["VW"], "PDR_CLANG_VECTORS" in d) for f, d in built}
    real = width // 2 if storage == "fp64" else width
    assert {("update.cl", real, aligned), ("matvec.cl", 2 * real, aligned), ("gemm.cl", real, False)} <= vws


def test_a_walk_with_gpu_layouts_equals_one_with_cpu_layouts(device):
    """DynamicRadiosity on a GPU-like description of the test device (every GPU layout: the
    coalesced gather and rank update, a work-group per row of K and of F, 128-item groups)
    walks to the same K as a fresh float64 build and lights the scene as the CPU layouts do."""
    from helpers import observer_walk

    import pydynrad

    gpu = device.with_traits(
        cpu=False,
        compute_units=16,
        float_width=1,
        double_width=1,
        max_work_group=128,
        local_mem_bytes=32768,
        aligned_vectors=False,
    )
    scene = coloured_box(4, seed=3, emitters=4)
    F = reciprocal_F(scene.areas, row_sum=0.95, density=0.08, seed=3)
    walks = []
    for dev in (gpu, device):
        dyn = pydynrad.DynamicRadiosity(
            scene, F, local_size=48, storage="fp32", max_swaps_per_frame=6, observer=[0.5, 0.5, 0.5], device=dev
        )
        swaps = sum(dyn.update(p).swaps for p in observer_walk(np.random.default_rng(8), 30))
        walks.append((swaps, dyn))
    (swaps, dyn), (_, ref) = walks
    assert swaps > 20 and not dyn._kernels.layout.cpu and dyn.matrix._layout.lx == 64
    assert np.array_equal(dyn.local_patches, ref.local_patches)
    assert rel(dyn.matrix.to_host(), dense_K(scene, F, dyn.local_patches, 3)) < 2e-5  # as exact fp32 walks
    light = [pydynrad.PointLight([0.5, 0.9, 0.5], 3.0)]
    assert rel(dyn.radiosity(light), ref.radiosity(light)) < 1e-5  # float32 products in another order
