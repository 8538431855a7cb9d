"""Passes over the structure of a large sparse F without a transpose (``csrc/csrgraph.c``):
its weakly connected components and its copy by column in float32, both made once by the far
field's precompute."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .errors import InvalidInputError

__all__ = ["weak_components", "columns_float32"]


def _csr(F) -> sp.csr_matrix:
    if not sp.issparse(F):
        raise InvalidInputError(f"F must be a scipy sparse matrix; got {type(F).__name__}")
    return F if F.format == "csr" else sp.csr_matrix(F)


def weak_components(F) -> np.ndarray:
    """(N,) int64 component of each node of the square sparse ``F``'s graph, i and j joined
    where F[i, j] or F[j, i] is stored: ``scipy.sparse.csgraph.connected_components(F,
    connection="weak")[1]``, numbered the same way (by each component's smallest node), by a
    union-find over F's entries instead of a pass over F plus its transpose."""
    from . import _csrgraph

    F = _csr(F)
    if F.shape[0] != F.shape[1]:
        raise InvalidInputError(f"weak_components needs a square matrix; got shape {F.shape}")
    labels = np.empty(F.shape[0], np.int64)
    _csrgraph.weak_components(F.indptr.astype(np.int64), F.indices, labels)
    return labels


def columns_float32(F) -> sp.csc_matrix:
    """``sp.csc_matrix(F, dtype=np.float32)`` for a float64 ``F`` of fewer than 2^31 rows (int32
    row indices, ascending within each column), in one counting pass and one scatter."""
    from . import _csrgraph

    F = _csr(F)
    if F.dtype != np.float64:
        F = F.astype(np.float64)
    n_rows, n_cols = F.shape
    indptr = np.empty(n_cols + 1, np.int64)
    indices = np.empty(F.nnz, np.int32)
    data = np.empty(F.nnz, np.float32)
    _csrgraph.to_columns(F.indptr.astype(np.int64), F.indices, F.data, n_cols, indptr, indices, data)
    return sp.csc_matrix((data, indices, indptr), shape=F.shape)
