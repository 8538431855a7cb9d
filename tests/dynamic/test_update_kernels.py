"""The update kernels (kernels/update.cl through pydynrad.dynamic.kupdate) against numpy.

Both kernel families run here on whatever device the tests use: the CPU kernels (a few fat
work-items, 8 rows of K per step in vector registers, fp16 converted with F16C on PoCL) and
the GPU kernels (coalesced, one vector per work-item), forced with ``cpu_kernels=``.
Truth: the same products and updates in float64 numpy on the matrix the device holds.
"""

import numpy as np
import pyopencl as cl
import pytest
from helpers import rel

from pydynrad.device.matrix import DeviceMatrix
from pydynrad.dynamic.kupdate import UpdateKernels


# M = 13: one partial row group; 600: ld = 640, a full and a partial column strip of the CPU
# gather and row blocks that end inside a group of 8 rows.
@pytest.mark.parametrize("cpu_kernels", [True, False], ids=["cpu-kernels", "gpu-kernels"])
@pytest.mark.parametrize("storage", ["fp16", "fp32", "fp64"])
@pytest.mark.parametrize("M", [13, 600])
def test_gather_and_rank_update_kernels(device, storage, M, cpu_kernels):
    """Both kernel families (CPU: rows in registers; GPU: coalesced) against numpy, for
    1 and many vectors, with K's padding columns still zero afterwards."""
    rng = np.random.default_rng(M)
    m = DeviceMatrix(device, rng.uniform(-1, 1, (1, M, M)), storage)
    uk = UpdateKernels(m, 32, cpu_kernels=cpu_kernels)
    K = m.to_host()[0]
    # fp16 storage: the update is computed in fp32 and rounded once to fp16 per element.
    # Observed (PoCL/Xeon): fp64 1.7e-15, fp32 6.5e-7, fp16 3.9e-4.
    tol = {"fp64": 1e-13, "fp32": 1e-5, "fp16": 2e-3}[storage]
    for n in (1, 7, 32):
        X, Y = rng.uniform(-1, 1, (n, M)), rng.uniform(-1, 1, (n, M))
        KX, YK = uk.gather(0, X, Y)
        assert rel(KX, X @ K.T) < min(tol, 1e-5) and rel(YK, Y @ K) < min(tol, 1e-5)
    for n in (1, 2, 64):
        A, B = rng.uniform(-1, 1, (n, M)) / n, rng.uniform(-1, 1, (n, M))
        uk.rank_update(0, A, B)
        want = K + A.T @ B
        K = m.to_host()[0]
        assert rel(K, want) < tol
    raw = np.empty((M, m.ld), m.dtype)
    cl.enqueue_copy(device.queue, raw, m.buffers[0], is_blocking=True)
    assert not raw[:, M:].any()  # padding stays zero


@pytest.mark.parametrize("cpu_kernels", [True, False], ids=["cpu-kernels", "gpu-kernels"])
def test_all_channels_in_one_read_back(device, cpu_kernels):
    """gather_all (with the slots' columns and rows) and the per-channel Eq. 1 reduction
    equal the single-channel operations and numpy on an RGB K."""
    rng = np.random.default_rng(3)
    M, C = 70, 3
    m = DeviceMatrix(device, rng.uniform(-1, 1, (C, M, M)), "fp64")
    uk = UpdateKernels(m, 4, cpu_kernels=cpu_kernels)
    K = m.to_host()
    X, Y = rng.uniform(-1, 1, (C, 3, M)), rng.uniform(-1, 1, (C, 3, M))
    slots = np.array([69, 2])
    KX, YK, cols, rows = uk.gather_all(X, Y, slots)
    for c in range(C):
        np.testing.assert_allclose(KX[c], X[c] @ K[c].T, rtol=0, atol=1e-13)  # observed 4.4e-15
        np.testing.assert_allclose(YK[c], Y[c] @ K[c], rtol=0, atol=1e-13)
        np.testing.assert_array_equal(cols[c], K[c][:, slots].T)
        np.testing.assert_array_equal(rows[c], K[c][slots])
    f_c, f_r, rho = rng.random(M), rng.random(M), rng.random((C, M))
    dr = uk.double_reflection(f_c, f_r, rho)
    np.testing.assert_allclose(dr, (f_c * f_r * rho).sum(axis=1), rtol=1e-14)  # observed 1.3e-16
    assert dr[1] == uk.double_reflection(f_c, f_r, rho[1])


@pytest.mark.parametrize("cpu_kernels", [True, False], ids=["cpu-kernels", "gpu-kernels"])
@pytest.mark.parametrize("storage", ["fp16", "fp32", "fp64"])
def test_update_slots_is_a_rank_update_then_a_slot_write(device, storage, cpu_kernels):
    """update_slots (every upload queued before its pass; on a CPU the slot writes inside the
    rank pass) against numpy: K + A^T B, then the slots' columns and rows overwritten (agreeing
    where they cross); rank_update and write_slots one after the other give the same bits."""
    rng = np.random.default_rng(11)
    M, slots = 70, np.array([3, 64])
    K0 = rng.uniform(-1, 1, (1, M, M))
    A, B = rng.uniform(-1, 1, (2, 4, M))
    cols, rows = rng.uniform(-1, 1, (2, 2, M))
    cols[:, slots] = rows[:, slots].T  # cols[m][slots[a]] = rows[a][slots[m]]: one value per crossing cell
    want = K0[0] + A.T @ B
    want[:, slots] = cols.T
    want[slots, :] = rows
    m = DeviceMatrix(device, K0, storage)
    uk = UpdateKernels(m, 4, cpu_kernels=cpu_kernels)
    uk.update_slots(0, A, B, slots, cols, rows)
    got = m.to_host()[0]
    # observed 4.4e-16 (fp64), 2.3e-7 (fp32), 1.1e-3 (fp16): each rounds K + A B and the written values to its type
    np.testing.assert_allclose(got, want, rtol=0, atol={"fp64": 1e-14, "fp32": 1e-6, "fp16": 4e-3}[storage])
    two = DeviceMatrix(device, K0, storage)
    uk2 = UpdateKernels(two, 4, cpu_kernels=cpu_kernels)
    uk2.rank_update(0, A, B)
    uk2.write_slots(0, slots, cols, rows)
    np.testing.assert_array_equal(two.to_host()[0], got)


@pytest.mark.parametrize("storage", ["fp16", "fp32", "fp64"])
def test_portable_cpu_kernels_equal_clang_vector_kernels(device, portable_kernels, storage):
    """The CPU kernels built with vload/vstore (any OpenCL CPU) give, bit for bit, what the
    build with PoCL's 16-wide dereference gives: gathers (dense and sparse), a rank update, slot reads."""
    rng = np.random.default_rng(7)
    M = 600
    K = rng.uniform(-1, 1, (1, M, M))
    X, Y = rng.uniform(-1, 1, (2, 7, M))
    A, B = rng.uniform(-1, 1, (2, 5, M)) / 5
    slots = np.array([0, 599, 13])

    sparse = X[None] * (rng.random((1, 7, M)) < 0.05)

    def run(m):
        uk = UpdateKernels(m, 8, cpu_kernels=True)
        KX, YK = uk.gather(0, X, Y)
        sparse_KX, sparse_YK = uk.gather_all(sparse, sparse, sparse=True)
        uk.rank_update(0, A, B)
        return (KX, YK, sparse_KX, sparse_YK, *uk.read_slots(0, slots), m.to_host())

    clang = run(DeviceMatrix(device, K, storage))
    with portable_kernels():
        portable = run(DeviceMatrix(device, K, storage))
    for a, b in zip(portable, clang):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("storage", ["fp16", "fp32", "fp64"])
@pytest.mark.parametrize("M", [13, 600])
def test_sparse_gathers_equal_the_dense_pass(device, storage, M):
    """gather_all's sparse kernels (K's part on the vectors' non-zero slots) against the dense
    pass and numpy, for vectors as sparse as a swap batch's form factors and for dense ones,
    on an RGB K whose channels differ; a zero side (no non-zero slot) gives zeros."""
    rng = np.random.default_rng(M + 1)
    C = 3
    m = DeviceMatrix(device, rng.uniform(-1, 1, (C, M, M)), storage)
    uk = UpdateKernels(m, 8)
    K = m.to_host()
    tol = {"fp64": 1e-13, "fp32": 1e-5, "fp16": 1e-5}[storage]  # K as stored: the products are in REAL
    for n, density in ((1, 0.1), (8, 0.05), (8, 1.0)):
        mask_x, mask_y = rng.random((n, M)) < density, rng.random((n, M)) < density
        mask_x[:, rng.integers(M)] = mask_y[:, rng.integers(M)] = True  # no all-zero vector
        X = rng.uniform(0, 1, (C, n, M)) * mask_x
        Y = rng.uniform(0, 1, (C, n, M)) * mask_y
        sparse = uk.gather_all(X, Y, sparse=True)
        dense = uk.gather_all(X, Y, sparse=False)
        for c in range(C):
            want_x, want_y = X[c] @ K[c].T, Y[c] @ K[c]
            assert rel(sparse[0][c], want_x) < tol and rel(sparse[1][c], want_y) < tol
            assert rel(sparse[0][c], dense[0][c]) < tol and rel(sparse[1][c], dense[1][c]) < tol
    Y = rng.uniform(0, 1, (C, 2, M))
    KX, YK = uk.gather_all(np.zeros((C, 2, M)), Y, sparse=True)
    assert not KX.any() and rel(YK[1], Y[1] @ K[1]) < tol


def test_crossover_of_the_sparse_gathers():
    from pydynrad.dynamic.kupdate import crossover

    # sparse 2 s at 4%, 6 s at 24%: 20 s per unit of density; it meets a 10 s dense pass at 44%
    assert crossover(10.0, (2.0, 6.0), (0.04, 0.24)) == pytest.approx(0.44)
    assert crossover(1.0, (2.0, 6.0), (0.04, 0.24)) == 0.02  # dense always faster: the floor
    assert crossover(100.0, (2.0, 6.0), (0.04, 0.24)) == 0.5  # a probe tells no more than this
    assert crossover(5.0, (3.0, 3.0), (0.04, 0.24)) == 0.24  # flat (noise): as far as measured
    assert crossover(2.0, (3.0, 3.0), (0.04, 0.24)) == 0.04


def test_warm_up_measures_the_crossover_once(device, monkeypatch):
    import pydynrad
    from pydynrad.dynamic import kupdate

    monkeypatch.delenv("PYDYNRAD_SPARSE_DENSITY", raising=False)
    monkeypatch.setattr(kupdate, "_CROSSOVERS", {})
    M = 96
    m = DeviceMatrix(device, np.random.default_rng(3).random((1, M, M)) * 1e-2, "fp32")
    first = UpdateKernels(m, 4)
    assert first.sparse_density == kupdate.SPARSE_DENSITY  # before warm_up
    first.warm_up()
    assert 0.02 <= first.sparse_density <= 0.5 and len(kupdate._CROSSOVERS) == 1
    again = UpdateKernels(m, 4)
    again.warm_up()
    assert again.sparse_density == first.sparse_density and len(kupdate._CROSSOVERS) == 1
    monkeypatch.setenv("PYDYNRAD_SPARSE_DENSITY", "0.3")
    again.warm_up()
    assert again.sparse_density == 0.3
    assert UpdateKernels(m, 4).sparse_density == 0.3  # fixed before any warm_up too
    monkeypatch.setenv("PYDYNRAD_SPARSE_DENSITY", "lots")
    with pytest.raises(pydynrad.InvalidInputError, match="PYDYNRAD_SPARSE_DENSITY"):
        again.warm_up()
