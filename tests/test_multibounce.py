"""The multibounce matrix K_S = (I - F_SS P_S)^{-1} F_SS against numpy float64, and the
radiosity B = L + P K L against the full solvers.

float32 error: Gauss-Jordan error ~ cond(I - F P) * 2^-24 with cond <= (1 + rho)/(1 - rho), a
bound of 1e-3 at rho = 0.999; observed (PoCL/Xeon) 1e-7 at rho <= 0.9 and 8e-8 at
rho = 0.999, so the tolerances sit about 100x above that: 1e-5. float64: observed ~1e-15.
"""

import time

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import box_scene, dense_K, dense_radiosity, reciprocal_F, rel

import pydynrad
from pydynrad import multibounce, multibounce_radiosity
from pydynrad.bounces import multibounce_memory


@pytest.mark.parametrize("backend", ["device", "host"])  # the OpenCL kernels and numpy, on any device
@pytest.mark.parametrize("dtype,tol", [(np.float64, 1e-13), (np.float32, 1e-5)])
def test_full_K_matches_dense_inverse_coloured(device, dtype, tol, backend):
    rng = np.random.default_rng(0)
    s = box_scene(4)  # 192 patches: two panels of 128 after padding
    s = s.with_materials(albedo=rng.uniform(0, 0.9, (len(s), 3)))
    F = reciprocal_F(s.areas, row_sum=0.95, density=0.2, seed=1)
    K = multibounce(s, F, dtype=dtype, device=device, backend=backend)
    assert K.shape == (3, len(s), len(s)) and K.dtype == dtype
    truth = dense_K(s, F)
    for c in range(3):
        assert rel(K[c], truth[c]) < tol


@pytest.mark.parametrize("cores", [1, 2, 64])
def test_host_build_side_by_side_or_in_turn(device, monkeypatch, cores):
    """The host build solves the colour channels side by side, one BLAS thread each, when the
    process has no more cores than channels, and in turn otherwise: the same K either way."""
    import importlib

    mb = importlib.import_module("pydynrad.bounces")  # the module, not the function pydynrad exports
    monkeypatch.setattr(mb, "host_cores", lambda: cores)
    rng = np.random.default_rng(5)
    s = box_scene(3).with_materials(albedo=rng.uniform(0, 0.9, (108, 3)))
    F = reciprocal_F(s.areas, row_sum=0.95, density=0.3, seed=5)
    limits = []
    real = mb.one_blas_thread
    monkeypatch.setattr(mb, "one_blas_thread", lambda: limits.append(1) or real())
    K = multibounce(s, F, dtype=np.float64, device=device, backend="host")
    assert limits == ([1] if cores <= 3 else [])
    truth = dense_K(s, F)
    assert all(rel(K[c], truth[c]) < 1e-13 for c in range(3))  # observed 3e-16


def test_subset_in_given_order_grey(device):
    s = box_scene(4, albedo=0.7)
    F = reciprocal_F(s.areas, density=0.2, seed=2)
    idx = np.random.default_rng(3).permutation(len(s))[:150]
    K = multibounce(s, F, patches=idx, dtype=np.float64, device=device)
    assert K.shape == (1, 150, 150)
    assert rel(K[0], dense_K(s, F, idx)[0]) < 1e-13


@pytest.mark.parametrize("backend", ["device", "host"])  # the OpenCL kernels and numpy, on any device
def test_albedo_0999_exact_in_float64(device, backend):
    s = box_scene(3, albedo=0.999)
    F = reciprocal_F(s.areas, seed=4)
    truth = dense_K(s, F)[0]
    assert rel(multibounce(s, F, dtype=np.float64, device=device, backend=backend)[0], truth) < 1e-12  # observed 1e-14
    assert rel(multibounce(s, F, dtype=np.float32, device=device, backend=backend)[0], truth) < 1e-5


@pytest.mark.parametrize("backend", ["device", "host"])  # the OpenCL kernels and numpy, on any device
def test_fp16_is_storage_rounding_of_fp32(device, backend):
    s = box_scene(3, albedo=0.6)
    F = reciprocal_F(s.areas, seed=5)
    K32 = multibounce(s, F, dtype=np.float32, device=device, backend=backend)
    K16 = multibounce(s, F, dtype=np.float16, device=device, backend=backend)
    assert K16.dtype == np.float16
    np.testing.assert_array_equal(K16, K32.astype(np.float16))


@pytest.mark.parametrize("backend", ["device", "host"])  # the OpenCL kernels and numpy, on any device
def test_truncated_series(device, backend):
    s = box_scene(3, albedo=0.8)
    F = reciprocal_F(s.areas, seed=6)
    Fd = F.toarray()
    FP = Fd * s.albedo[:, 0].astype(np.float64)[None, :]
    series, term = Fd.copy(), Fd.copy()
    for _ in range(4):
        term = FP @ term
        series += term
    K = multibounce(s, F, bounces=4, dtype=np.float64, device=device, backend=backend)
    assert rel(K[0], series) < 1e-14  # observed 3e-16
    np.testing.assert_array_equal(multibounce(s, F, bounces=0, dtype=np.float64, device=device, backend=backend)[0], Fd)


def test_B_from_K_matches_iterative_and_dense(device):
    rng = np.random.default_rng(7)
    s = box_scene(3)
    s = s.with_materials(albedo=rng.uniform(0, 0.9, (len(s), 3)), emission=(rng.random((len(s), 3)) < 0.1) * 3.0)
    F = reciprocal_F(s.areas, row_sum=0.9, seed=8)
    lights = [pydynrad.PointLight((0.3, 0.6, 0.5), 2.0)]
    L = pydynrad.light_vector(s, lights, device=device)
    K = multibounce(s, F, dtype=np.float64, device=device)
    B = multibounce_radiosity(s, K, light=L)
    dense = pydynrad.solve(s, F, lights=lights, method="dense", device=device).radiosity
    iterative = pydynrad.solve(s, F, lights=lights, dtype=np.float64, tol=1e-12, device=device).radiosity
    np.testing.assert_allclose(B, dense, rtol=1e-13)  # observed 1.1e-15
    np.testing.assert_allclose(B, iterative, rtol=1e-10)  # the iteration's tol 1e-12: observed 1.1e-12
    # The same product on the device, from K stored in fp32 and fp16.
    for storage, tol in (("fp32", 3e-6), ("fp16", 1e-3)):  # observed 2.7e-8 and 1.5e-5
        Bd = multibounce_radiosity(s, pydynrad.device.DeviceMatrix(device, K, storage), light=L)
        assert rel(Bd, dense) < tol


def test_B_over_a_subset_is_N_by_3_with_L_outside(device):
    """multibounce_radiosity over patches S returns the whole (N, 3) B, as DynamicRadiosity does:
    L + P K L on S (the dense solve of the closed sub-system) and L itself elsewhere."""
    rng = np.random.default_rng(11)
    s = box_scene(2)
    s = s.with_materials(albedo=rng.uniform(0, 0.9, (len(s), 3)), emission=(rng.random((len(s), 3)) < 0.2) * 2.0)
    F = reciprocal_F(s.areas, row_sum=0.9, seed=12)
    S = rng.choice(len(s), 20, replace=False)
    K = multibounce(s, F, patches=S, dtype=np.float64, device=device)
    L = np.asarray(s.emission, dtype=np.float64)
    B = multibounce_radiosity(s, K, patches=S, device=device)
    outside = np.setdiff1d(np.arange(len(s)), S)
    assert B.shape == (len(s), 3)
    np.testing.assert_allclose(B[S], dense_radiosity(s, F, L, patches=S), rtol=1e-13, atol=1e-15)  # observed 8e-16
    np.testing.assert_array_equal(B[outside], L[outside])


def test_grey_K_with_coloured_light(device):
    s = box_scene(2, albedo=0.5)
    F = reciprocal_F(s.areas, seed=9)
    L = np.zeros((len(s), 3))
    L[:5] = [1.0, 0.2, 0.0]
    K = multibounce(s, F, dtype=np.float64, device=device)
    assert K.shape[0] == 1
    dense = pydynrad.solve(s, F, method="dense", light=L, device=device).radiosity
    np.testing.assert_allclose(multibounce_radiosity(s, K, light=L), dense, rtol=1e-13, atol=1e-15)  # observed 8e-16
    np.testing.assert_allclose(
        multibounce_radiosity(s, pydynrad.device.DeviceMatrix(device, K, "fp64"), light=L),
        dense,
        rtol=1e-13,
        atol=1e-15,
    )


def test_paper_scale_refused_quickly(device):
    n = 63125  # the paper's scene: K over all patches would take 44 GiB (3 channels, fp32)
    pts = np.random.default_rng(0).random((3 * n, 3))
    s = pydynrad.Scene(pts, np.arange(3 * n).reshape(n, 3), albedo=(0.5, 0.4, 0.3))
    t0 = time.perf_counter()
    with pytest.raises(pydynrad.errors.OutOfMemoryError, match="GiB"):
        multibounce(s, sp.csr_matrix((n, n), dtype=np.float32), device=device)
    assert time.perf_counter() - t0 < 5.0  # refused before allocating or validating anything big
    need = multibounce_memory(n, 3, np.float32)
    assert need["host"] > 44e9


def test_bad_arguments(device):
    s = box_scene(2, albedo=0.5)
    F = reciprocal_F(s.areas, seed=10)
    with pytest.raises(pydynrad.InvalidInputError, match="repeated"):
        multibounce(s, F, patches=[0, 1, 1], device=device)
    with pytest.raises(pydynrad.InvalidInputError, match=r"patch indices in 0\.\.47"):
        multibounce(s, F, patches=[0, 48], device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="dtype"):
        multibounce(s, F, dtype=np.int8, device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="bounces"):
        multibounce(s, F, bounces=-1, device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="backend"):
        multibounce(s, F, device=device, backend="gpu")
    with pytest.raises(pydynrad.InvalidInputError, match="sums to"):
        multibounce(s, F * 2, device=device)
