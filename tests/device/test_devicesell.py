"""SELL-C-sigma F (pydynrad.device.sell) against the CSR matrix it was built from: the layout's
arrays rebuilt into a dense matrix in numpy, and its bounces against scipy's products."""

import numpy as np
import pytest
import scipy.sparse as sp

from pydynrad.device.launch import SellLayout
from pydynrad.device.sell import DeviceSELL, sell_slices


def _ragged(n, seed):
    """An (n, n) CSR with rows of very different lengths, some empty."""
    rng = np.random.default_rng(seed)
    lengths = rng.integers(0, n // 2, n)
    lengths[rng.choice(n, n // 10, replace=False)] = 0
    rows = np.repeat(np.arange(n), lengths)
    cols = np.concatenate([rng.choice(n, k, replace=False) for k in lengths])
    return sp.csr_matrix((rng.uniform(0, 1 / n, len(rows)), (rows, cols)), shape=(n, n))


@pytest.mark.parametrize("c, sigma", [(4, 4), (8, 64), (16, 10**6)])
def test_slices_hold_the_renumbered_matrix(c, sigma):
    A = _ragged(203, seed=1)
    S = sell_slices(A, c, sigma)
    n, slices = A.shape[0], len(S.sptr) - 1
    assert S.rows == slices * c >= n > S.rows - c
    assert sorted(S.perm) == list(range(n))
    dense = np.zeros((S.rows, n))
    for s in range(slices):
        block = S.sptr[s + 1] - S.sptr[s]
        assert block % c == 0
        lanes = np.arange(block) % c + s * c
        np.add.at(dense, (lanes, S.cols[S.sptr[s] : S.sptr[s + 1]]), S.vals[S.sptr[s] : S.sptr[s + 1]])
    # Row p of the renumbered matrix is old row perm[p], its columns renumbered the same way.
    np.testing.assert_allclose(dense[:n], A.toarray()[np.ix_(S.perm, S.perm)], rtol=1e-6)
    assert not dense[n:].any()
    # Within each window the longer rows come first.
    lengths = np.diff(A.indptr)[S.perm]
    for w in range(0, n, sigma):
        assert np.all(np.diff(lengths[w : w + sigma]) <= 0)


@pytest.mark.parametrize("c", [4, 8, 16])
@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_bounces_match_scipy(device, c, channels, dtype):
    """Every slice width (the portable lane-by-lane gather at 4 and 8 floats, the AVX-512 one at
    16 floats or 8 doubles where the compiler has it), grey and RGB, against float64 scipy."""
    A = _ragged(301, seed=2)
    rng = np.random.default_rng(3)
    L, rho = rng.uniform(0, 1, (301, channels)), rng.uniform(0, 0.9, (301, channels))
    M = DeviceSELL(device, A, dtype, SellLayout(c, 8 * c, 5))
    B, sweeps, change, history = M.jacobi(L, rho, L, -1.0, 3)
    truth, prev = L.copy(), None
    for _ in range(3):
        prev, truth = truth, L + rho * (A @ truth)
    rtol = 1e-13 if dtype == np.float64 else 2e-6  # observed 2e-16 and 1.5e-7
    np.testing.assert_allclose(B, truth, rtol=rtol)
    assert sweeps == 3 and len(history) == 3
    assert change == pytest.approx(
        np.abs(truth - prev).max() / np.abs(truth).max(), rel=1e-3 if dtype == np.float32 else 1e-10
    )
    # observed 1e-4 (float32: y - x of a change near 3e-4 keeps ~3 digits) and 1e-13
    assert M.nbytes >= M.stored * (4 + np.dtype(dtype).itemsize) and M.stored >= A.nnz


def test_a_non_square_matrix_is_refused(device):
    from pydynrad import InvalidInputError

    with pytest.raises(InvalidInputError, match="square"):
        DeviceSELL(
            device, sp.random(40, 7, density=0.2, format="csr", random_state=1), np.float32, SellLayout(4, 16, 2)
        )
