"""weak_components and columns_float32 against scipy's connected_components and csc_matrix."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from pydynrad import InvalidInputError, _csrgraph
from pydynrad.csrgraph import columns_float32, weak_components


def _graph(n, density, seed, index_dtype=np.int32):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=density, format="csr", random_state=rng, dtype=np.float64)
    return sp.csr_matrix((A.data, A.indices.astype(index_dtype), A.indptr), shape=A.shape)


@pytest.mark.parametrize("n, density, index_dtype", [(1, 0.0, np.int32), (50, 0.01, np.int32), (400, 0.003, np.int64),
                                                     (300, 0.05, np.int32)])
def test_weak_components_match_scipy(n, density, index_dtype):
    A = _graph(n, density, n, index_dtype)  # sparse enough for many components and lone nodes
    expected = connected_components(A, directed=True, connection="weak")[1]
    np.testing.assert_array_equal(weak_components(A), expected)


def test_weak_components_join_one_way_edges():
    # 3 -> 0 and 1 -> 3 only one way each: weakly one component {0, 1, 3}; 2 and 4 alone.
    A = sp.csr_matrix((np.ones(2), ([3, 1], [0, 3])), shape=(5, 5))
    assert weak_components(A).tolist() == [0, 0, 1, 0, 2]


@pytest.mark.parametrize("shape", [(60, 60), (7, 300), (300, 7)])
def test_columns_float32_matches_scipy(shape):
    rng = np.random.default_rng(1)
    A = sp.random(*shape, density=0.05, format="csr", random_state=rng, dtype=np.float64)
    A.data = rng.standard_normal(A.nnz) * 10.0 ** rng.integers(-30, 30, A.nnz)  # rounding to float32 checked
    got, want = columns_float32(A), sp.csc_matrix(A, dtype=np.float32)
    for a, b in ((got.indptr, want.indptr), (got.indices, want.indices), (got.data, want.data)):
        np.testing.assert_array_equal(a, b)
    assert got.dtype == np.float32 and got.shape == shape


def test_bad_structures_are_refused():
    with pytest.raises(InvalidInputError, match="square"):
        weak_components(sp.csr_matrix((3, 4)))
    with pytest.raises(InvalidInputError, match="sparse"):
        columns_float32(np.eye(3))
    ip, ix, labels = np.array([0, 1, 2], np.int64), np.array([0, 5], np.int32), np.empty(2, np.int64)
    with pytest.raises(ValueError, match="out of range"):
        _csrgraph.weak_components(ip, ix, labels)
    with pytest.raises(ValueError, match="non-decreasing"):
        _csrgraph.weak_components(np.array([0, 2, 1], np.int64), ix, labels)
    with pytest.raises(ValueError, match="out of range"):
        _csrgraph.to_columns(ip, ix, np.ones(2), 3, np.empty(4, np.int64), np.empty(2, np.int32),
                             np.empty(2, np.float32))
