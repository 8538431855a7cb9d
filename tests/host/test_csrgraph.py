"""weak_components, columns_float32 and sum_by_label against scipy's connected_components,
csc_matrix and sparse product."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from pydynrad import InvalidInputError, _csrgraph
from pydynrad.host.csrgraph import columns_float32, sum_by_label, weak_components


def _graph(n, density, seed, index_dtype=np.int32):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=density, format="csr", random_state=rng, dtype=np.float64)
    return sp.csr_matrix((A.data, A.indices.astype(index_dtype), A.indptr), shape=A.shape)


@pytest.mark.parametrize(
    "n, density, index_dtype", [(1, 0.0, np.int32), (50, 0.01, np.int32), (400, 0.003, np.int64), (300, 0.05, np.int32)]
)
def test_weak_components_match_scipy(n, density, index_dtype):
    A = _graph(n, density, n, index_dtype)  # sparse enough for many components and lone nodes
    expected = connected_components(A, directed=True, connection="weak")[1]
    np.testing.assert_array_equal(weak_components(A), expected)


def test_weak_components_join_one_way_edges():
    # 3 -> 0 and 1 -> 3 only one way each: weakly one component {0, 1, 3}; 2 and 4 alone.
    A = sp.csr_matrix((np.ones(2), ([3, 1], [0, 3])), shape=(5, 5))
    assert weak_components(A).tolist() == [0, 0, 1, 0, 2]


@pytest.mark.parametrize(
    "shape, dtype", [((60, 60), np.float64), ((7, 300), np.float64), ((300, 7), np.float64), ((60, 60), np.float32)]
)
def test_columns_float32_matches_scipy(shape, dtype):
    rng = np.random.default_rng(1)
    A = sp.random(*shape, density=0.05, format="csr", random_state=rng, dtype=np.float64)
    A.data = rng.standard_normal(A.nnz) * 10.0 ** rng.integers(-30, 30, A.nnz)  # rounding to float32 checked
    A = A.astype(dtype)
    got, want = columns_float32(A), sp.csc_matrix(A, dtype=np.float32)
    for a, b in ((got.indptr, want.indptr), (got.indices, want.indices), (got.data, want.data)):
        np.testing.assert_array_equal(a, b)
    assert got.dtype == np.float32 and got.shape == shape


@pytest.mark.parametrize(
    "dtype, index_dtype, weighted",
    [(np.float32, np.int32, False), (np.float64, np.int32, True), (np.float32, np.int64, True)],
)
def test_sum_by_label_is_scipys_product_bit_for_bit(dtype, index_dtype, weighted):
    # G = F Pr for a prolongation of one entry per row: the same entries, values and order as
    # scipy's product (which the far field used), exact zeros dropped as scipy drops them.
    rng = np.random.default_rng(2)
    n, C = 300, 23
    A = _graph(n, 0.06, 3, index_dtype).astype(dtype)
    A.data = (rng.standard_normal(A.nnz) * 10.0 ** rng.integers(-8, 8, A.nnz)).astype(dtype)
    labels = rng.integers(0, C, n)
    # Entries that cancel exactly within a row and a label: the zero sum is dropped.
    A = A.tolil()
    A[0, :] = 0
    A[0, 0], A[0, 1] = 1.5, -1.5
    A = sp.csr_matrix(A)
    labels[1] = labels[0]
    w = rng.random(n) + 0.5 if weighted else np.ones(n)
    w[1] = w[0]
    Pr = sp.csr_matrix((w, (np.arange(n), labels)), shape=(n, C))
    want, got = sp.csr_matrix(A @ Pr, dtype=np.float64), sum_by_label(A, labels, w, C)
    for a, b in ((got.indptr, want.indptr), (got.indices, want.indices), (got.data, want.data)):
        np.testing.assert_array_equal(a, b)
    assert got.shape == (n, C) and got[0].nnz == 0
    with pytest.raises(InvalidInputError, match="shape"):
        sum_by_label(A, labels[:-1], w, C)
    with pytest.raises(ValueError, match="labels in"):
        sum_by_label(A, np.where(labels == 0, C, labels), w, C)
    with pytest.raises(InvalidInputError, match="n_labels must be an integer"):
        sum_by_label(A, labels, w, 23.0)
    # Values and indices that are views with a stride are read, as scipy reads them.
    strided = sp.csr_matrix((np.repeat(A.data, 2)[::2], np.repeat(A.indices, 2)[::2], A.indptr), shape=A.shape)
    np.testing.assert_array_equal(sum_by_label(strided, labels, w, C).data, want.data)


def test_labels_changed_under_the_native_pass_are_refused_not_read_out_of_bounds():
    # The labels are checked before the pass and read again in it without the GIL: an output
    # that is the labels array itself (or another thread) writing labels beyond n_labels is an
    # error, not a write past the scratch arrays.
    F = sp.csr_matrix(np.ones((3, 3)))
    labels = np.array([0, 1, 1], np.int64)
    with pytest.raises(ValueError, match="out of range"):
        _csrgraph.label_counts(F.indptr.astype(np.int64), F.indices, labels, 2, labels)
    F = sp.csr_matrix(np.ones((3, 4)))
    labels = np.array([0, 1, 0, 1], np.int64)
    with pytest.raises(ValueError, match="out of range"):
        _csrgraph.sum_by_label(
            F.indptr.astype(np.int64),
            F.indices,
            F.data,
            labels,
            np.ones(4),
            2,
            labels,
            np.empty(8, np.int32),
            np.empty(8),
        )


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
        _csrgraph.to_columns(
            ip, ix, np.ones(2), 3, np.empty(4, np.int64), np.empty(2, np.int32), np.empty(2, np.float32)
        )
