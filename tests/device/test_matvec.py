"""DeviceMatrix: storage round trips and products against numpy in float64.

Tolerances (relative to max |y|, inputs in [0, 1)): the stored matrix differs from K by the
storage rounding (fp16: 2^-11 relative per element, fp32: 2^-24); products accumulate in the
compute type (fp32 for fp16/fp32, fp64 for fp64). So fp16 ~1e-3, fp32 ~1e-6, fp64 ~1e-13; observed (PoCL/Xeon) 5e-5, 2.4e-7, 1.1e-15.
"""

import numpy as np
import pytest
from helpers import rel

import pydynrad
from pydynrad.device.matrix import DeviceMatrix

TOL = {"fp16": 1e-3, "fp32": 2e-6, "fp64": 1e-13}
LAYOUTS = [None, (4, 64), (8, 4)]  # the default, the GPU layout, one in between


@pytest.mark.parametrize("storage", ["fp16", "fp32", "fp64"])
@pytest.mark.parametrize("layout", LAYOUTS)
def test_products_match_numpy(device, storage, layout):
    rng = np.random.default_rng(1)
    C, M = 3, 203  # M not a multiple of the padding: exercises the padded tail
    K = rng.random((C, M, M))
    x = rng.random((C, M))
    m = DeviceMatrix(device, K, storage, layout=layout)
    assert (m.C, m.M, m.storage) == (C, M, storage)
    assert m.ld >= M and m.ld % 64 == 0
    assert len(m.buffers) == C
    assert (
        m.nbytes
        == C
        * M
        * m.ld
        * np.dtype(np.float16 if storage == "fp16" else np.float32 if storage == "fp32" else np.float64).itemsize
    )
    y = m.matvec(x)
    assert y.dtype == np.float64 and y.shape == (C, M)
    assert rel(y, np.einsum("cij,cj->ci", K, x)) < TOL[storage]
    assert rel(m.rmatvec(x), np.einsum("cij,ci->cj", K, x)) < TOL[storage]


@pytest.mark.parametrize("storage", ["fp16", "fp32", "fp64"])
def test_to_host_is_storage_rounding(device, storage):
    rng = np.random.default_rng(2)
    K = rng.random((1, 70, 70))
    m = DeviceMatrix(device, K, storage)
    back = m.to_host()
    assert back.dtype == np.float64 and back.shape == K.shape
    # Exactly numpy's round-to-nearest-even conversion to the storage type.
    np.testing.assert_array_equal(back, K.astype(m.dtype).astype(np.float64))


def test_single_vector_applies_to_every_channel(device):
    rng = np.random.default_rng(3)
    K = rng.random((3, 40, 40))
    x = rng.random(40)
    y = DeviceMatrix(device, K, "fp64").matvec(x)
    np.testing.assert_allclose(y, K @ x, rtol=1e-14)  # observed 2e-16


def test_zeros_and_upload(device):
    m = DeviceMatrix.zeros(device, 2, 50, "fp32")
    assert np.all(m.to_host() == 0)
    K = np.arange(2 * 50 * 50, dtype=np.float64).reshape(2, 50, 50) / 5000
    m.upload(K)
    np.testing.assert_allclose(m.to_host(), K, rtol=1e-7)


def test_bad_inputs(device):
    K = np.ones((1, 8, 8))
    with pytest.raises(pydynrad.InvalidInputError, match="fp16, fp32, fp64"):
        DeviceMatrix(device, K, "bf16")
    with pytest.raises(pydynrad.InvalidInputError, match="shape"):
        DeviceMatrix(device, np.ones((8, 8)), "fp32")
    with pytest.raises(pydynrad.InvalidInputError, match="finite"):
        DeviceMatrix(device, np.full((1, 4, 4), np.nan), "fp32")
    m = DeviceMatrix(device, K, "fp32")
    with pytest.raises(pydynrad.InvalidInputError, match="shape"):
        m.matvec(np.ones((2, 8)))
    with pytest.raises(pydynrad.InvalidInputError, match="NaN"):
        m.matvec(np.full(8, np.inf))


def test_fp64_refused_without_device_support(device, monkeypatch):
    monkeypatch.setattr(type(device), "supports_fp64", property(lambda self: False))
    with pytest.raises(pydynrad.errors.DeviceError, match="fp64"):
        DeviceMatrix(device, np.ones((1, 4, 4)), "fp64")


def test_oversized_matrix_refused_before_allocating(device):
    # 63,125 patches (the paper's full scene) in fp32: 16 GB per channel.
    with pytest.raises(pydynrad.errors.OutOfMemoryError, match="MiB"):
        DeviceMatrix.zeros(device, 3, 63125, "fp32")


@pytest.mark.parametrize("storage", ["fp16", "fp32", "fp64"])
@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("r", [3, 6])
def test_matmat_matches_numpy_and_per_vector_products(device, storage, layout, r):
    """r right-hand sides per channel (6: two passes of MAX_RHS = 4 and 2) equal numpy in
    float64 and, bit for bit in fp64, the one-vector products."""
    rng = np.random.default_rng(4)
    C, M = 2, 203
    K = rng.random((C, M, M))
    X = rng.random((C, r, M))
    m = DeviceMatrix(device, K, storage, layout=layout)
    Y = m.matmat(X)
    assert Y.dtype == np.float64 and Y.shape == (C, r, M)
    assert rel(Y, np.einsum("cij,cqj->cqi", K, X)) < TOL[storage]
    single = np.stack([m.matvec(X[:, q]) for q in range(r)], axis=1)
    if storage == "fp64":
        np.testing.assert_allclose(Y, single, rtol=1e-15, atol=0)
    else:  # observed bit for bit here too; 1e-6 leaves room for another FMA contraction of the fp32 sums
        assert rel(Y, single) < 1e-6


def test_matmat_one_grey_K_three_colour_channels(device):
    """The dynamic lighting case: one channel of K, three colour vectors, one call."""
    rng = np.random.default_rng(5)
    K = rng.random((1, 97, 97))
    L = rng.random((3, 97))
    Y = DeviceMatrix(device, K, "fp64").matmat(L)
    np.testing.assert_allclose(Y[0], L @ K[0].T, rtol=1e-14)  # observed 3e-16


def test_matmat_bad_inputs(device):
    m = DeviceMatrix(device, np.ones((2, 8, 8)), "fp32")
    for bad in (np.ones((3, 1, 8)), np.ones((2, 0, 8)), np.ones((2, 1, 7)), np.ones(8)):
        with pytest.raises(pydynrad.InvalidInputError, match="shape"):
            m.matmat(bad)
    with pytest.raises(pydynrad.InvalidInputError, match="NaN"):
        m.matmat(np.full((2, 8), np.nan))
    with pytest.raises(pydynrad.InvalidInputError, match="nrhs"):
        m.enqueue_matvec(0, None, None, nrhs=5)


@pytest.mark.parametrize("storage", ["fp16", "fp32", "fp64"])
def test_portable_kernels_equal_clang_vector_kernels(device, portable_kernels, storage):
    """The vload/vstore build (any OpenCL CPU) computes what PoCL's 16-wide dereference build
    computes: the same sums in the same order, bit for bit."""
    rng = np.random.default_rng(6)
    C, M = 2, 203
    K, x, X = rng.random((C, M, M)), rng.random((C, M)), rng.random((C, 3, M))
    clang = DeviceMatrix(device, K, storage)
    with portable_kernels():
        portable = DeviceMatrix(device, K, storage)
        got = portable.matvec(x), portable.rmatvec(x), portable.matmat(X)
    for a, b in zip(got, (clang.matvec(x), clang.rmatvec(x), clang.matmat(X))):
        np.testing.assert_array_equal(a, b)
    assert rel(got[0], np.einsum("cij,cj->ci", K, x)) < TOL[storage]


@pytest.mark.parametrize("nrhs", [1, 3])
def test_rows_side_by_side_equal_one_row_per_item(device, nrhs):
    """A CPU item streaming RI rows side by side (their own accumulators) computes each row's
    sum in the order one row per item does: bit for bit. Without a cache an fp16 K takes RI = 1."""
    one_row = device.with_traits(cache_bytes=0)
    rng = np.random.default_rng(8)
    K, X = rng.random((1, 203, 203)), rng.random((1, nrhs, 203))
    side, single = DeviceMatrix(device, K, "fp16"), DeviceMatrix(one_row, K, "fp16")
    if not device.traits.cpu or side._layout.rows_per_item(nrhs) == 1:
        pytest.skip(f"{device.name} streams one row per item here")
    assert single._layout.rows_per_item(nrhs) == 1
    np.testing.assert_array_equal(side.matmat(X), single.matmat(X))
    assert rel(side.matmat(X), np.einsum("cij,cqj->cqi", K, X)) < TOL["fp16"]
