"""The library never modifies the arrays a caller passes in.

scipy shares index arrays between a CSR matrix and conversions of it, so an in-place
canonicalisation (sum_duplicates, sort_indices) of a converted copy can silently scramble
the caller's matrix: a non-canonical F is the input that exposes it.
"""

import numpy as np
import scipy.sparse as sp
from helpers import dense_K

import pydynrad


def _non_canonical_form_factors(n: int, seed: int = 0) -> sp.csr_matrix:
    rng = np.random.default_rng(seed)
    k = 12
    cols = rng.integers(0, n, (n, k))
    cols[cols == np.arange(n)[:, None]] = (cols[cols == np.arange(n)[:, None]] + 1) % n
    F = sp.csr_matrix((rng.random(n * k), cols.ravel(), np.arange(0, n * k + 1, k)), shape=(n, n))
    F = sp.csr_matrix(F.multiply(0.9 / np.asarray(F.sum(axis=1))), dtype=np.float32)
    # Unsorted column indices with duplicates: valid CSR, not canonical.
    F = sp.csr_matrix((F.data, F.indices, F.indptr), shape=F.shape)
    F.has_sorted_indices = False
    return F


def test_solve_and_multibounce_leave_F_untouched(device):
    scene = pydynrad.scenes.closed_box(subdivisions=1, albedo=0.6)
    F = _non_canonical_form_factors(len(scene))
    data, indices, indptr = F.data.copy(), F.indices.copy(), F.indptr.copy()
    dense = F.toarray()
    idx = np.arange(0, len(scene), 2)
    K_first = pydynrad.multibounce(scene, F, patches=idx, dtype=np.float64, device=device)
    pydynrad.solve(scene, F, method="dense")
    np.testing.assert_array_equal(F.data, data)
    np.testing.assert_array_equal(F.indices, indices)
    np.testing.assert_array_equal(F.indptr, indptr)
    K_again = pydynrad.multibounce(scene, F, patches=idx, dtype=np.float64, device=device)
    np.testing.assert_array_equal(K_first, K_again)
    np.testing.assert_allclose(K_first[0], dense_K(scene, dense, idx, channels=1)[0], rtol=1e-13)  # observed 6.5e-16
