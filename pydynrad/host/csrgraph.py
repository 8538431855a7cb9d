"""Passes over a large sparse F without a transpose or a general product (``csrc/csrgraph.c``):
its weakly connected components, its copy by column in float32 and its columns summed by
cluster (G = F Pr), all made once by the far field's precompute."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import _csrgraph
from ..checks import integer
from ..errors import InvalidInputError

__all__ = ["weak_components", "columns_float32", "sum_by_label"]


def _csr(F) -> sp.csr_matrix:
    if not sp.issparse(F):
        raise InvalidInputError(f"F must be a scipy sparse matrix; got {type(F).__name__}")
    return F if F.format == "csr" else sp.csr_matrix(F)


def weak_components(F) -> np.ndarray:
    """(N,) int64 component of each node of the square sparse ``F``'s graph, i and j joined
    where F[i, j] or F[j, i] is stored: ``scipy.sparse.csgraph.connected_components(F,
    connection="weak")[1]``, numbered the same way (by each component's smallest node), by a
    union-find over F's entries instead of a pass over F plus its transpose."""
    F = _csr(F)
    if F.shape[0] != F.shape[1]:
        raise InvalidInputError(f"weak_components needs a square matrix; got shape {F.shape}")
    labels = np.empty(F.shape[0], np.int64)
    _csrgraph.weak_components(F.indptr.astype(np.int64), F.indices, labels)
    return labels


def columns_float32(F) -> sp.csc_matrix:
    """``sp.csc_matrix(F, dtype=np.float32)`` for an ``F`` of fewer than 2^31 rows (int32 row
    indices, ascending within each column), in one counting pass and one scatter, from F's own
    float32 or float64 values."""
    F = _csr(F)
    if F.dtype not in (np.float32, np.float64):
        F = F.astype(np.float64)
    n_rows, n_cols = F.shape
    indptr = np.empty(n_cols + 1, np.int64)
    indices = np.empty(F.nnz, np.int32)
    data = np.empty(F.nnz, np.float32)
    _csrgraph.to_columns(
        F.indptr.astype(np.int64),
        np.ascontiguousarray(F.indices),
        np.ascontiguousarray(F.data),
        n_cols,
        indptr,
        indices,
        data,
    )
    return sp.csc_matrix((data, indices, indptr), shape=F.shape)


def sum_by_label(F, labels: np.ndarray, weights: np.ndarray, n_labels: int) -> sp.csr_matrix:
    """(rows, n_labels) float64 CSR of ``F``'s columns summed by label, column j weighted by
    ``weights[j]``: ``F @ Pr`` for the float64 prolongation ``Pr = csr_matrix((weights,
    (arange(n), labels)))`` of one entry per row. For a CSR ``F`` (other formats are converted
    to CSR first, so a CSC F's rows come in another order than scipy's CSC product gives) the
    same entries in the same order as scipy's product, exact zeros dropped, from F's own values
    (float32 or float64) without a converted copy.

    labels : (columns,) integers in [0, n_labels); weights : (columns,) float64.
    """

    F = _csr(F)
    n_labels = integer(n_labels, "n_labels", 1, 2**31 - 1)
    n_rows, n_cols = F.shape
    labels = np.ascontiguousarray(labels, dtype=np.int64)
    weights = np.ascontiguousarray(weights, dtype=np.float64)
    if labels.shape != (n_cols,) or weights.shape != (n_cols,):
        raise InvalidInputError(
            f"labels and weights must have shape ({n_cols},); got {labels.shape} and {weights.shape}"
        )
    data = np.ascontiguousarray(F.data if F.dtype in (np.float32, np.float64) else F.data.astype(np.float64))
    indices, indptr = np.ascontiguousarray(F.indices), F.indptr.astype(np.int64)
    counts = np.empty(n_rows, np.int64)
    _csrgraph.label_counts(indptr, indices, labels, n_labels, counts)
    capacity = int(counts.sum())
    out_indptr = np.empty(n_rows + 1, np.int64)
    out_indices = np.empty(capacity, np.int32)
    out_data = np.empty(capacity, np.float64)
    nnz = _csrgraph.sum_by_label(indptr, indices, data, labels, weights, n_labels, out_indptr, out_indices, out_data)
    # Sums that came out exactly zero are dropped, as scipy drops them: views of the rest.
    out_indices, out_data = out_indices[:nnz], out_data[:nnz]
    G = sp.csr_matrix(
        (out_data, out_indices, out_indptr.astype(np.int32) if nnz < 2**31 else out_indptr), shape=(n_rows, n_labels)
    )
    G.has_sorted_indices = False
    return G
