"""Products of a sparse matrix with a few dense columns on the host's cores (``csrc/colproduct.c``):
y = A[:, cols] x over chosen columns of a matrix held by column (the far field's first bounce
over F's lit columns), and y = A x by row (a frame's products of rows of F with B)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import _colproduct
from ..errors import InvalidInputError
from .threads import cores, map_parts, row_parts

__all__ = ["columns_product", "rows_product", "PARALLEL_ENTRIES"]

#: Entries from which :func:`columns_product` splits its columns over the cores (each part with
#: its own sum, added at the end: an (n_rows, k) add per part), and :func:`rows_product` its rows.
PARALLEL_ENTRIES = 200_000


def columns_product(A: sp.csc_matrix, cols: np.ndarray, x: np.ndarray) -> np.ndarray:
    """(A.shape[0], k) float64: the sum over t of column ``cols[t]`` of ``A`` (CSC) times
    ``x[t]``, for x (len(cols), k), 1 <= k <= 4; A's entries are read once, in its own type,
    and summed in float64. Equals ``A[:, cols] @ x`` without copying the columns out."""
    if not (sp.issparse(A) and A.format == "csc"):
        raise InvalidInputError(f"columns_product needs a CSC matrix; got {type(A).__name__}")
    if A.dtype not in (np.float32, np.float64) or A.indices.dtype not in (np.int32, np.int64):
        raise InvalidInputError(
            f"columns_product needs float32/float64 values and int32/int64 indices; got {A.dtype} and {A.indices.dtype}"
        )
    cols = np.ascontiguousarray(cols, np.int64)
    x = np.ascontiguousarray(x, np.float64)
    if x.ndim != 2 or x.shape[0] != len(cols) or not 1 <= x.shape[1] <= 4:
        raise InvalidInputError(f"x must have shape ({len(cols)}, k) with 1 <= k <= 4; got {x.shape}")
    k, n_rows = x.shape[1], A.shape[0]
    if len(cols) and (cols.min() < 0 or cols.max() >= A.shape[1]):
        raise InvalidInputError(f"column numbers must lie in 0..{A.shape[1] - 1}")
    indptr = A.indptr.astype(np.int64)
    run_ends = np.zeros(len(cols) + 1, np.int64)
    np.cumsum(indptr[cols + 1] - indptr[cols], out=run_ends[1:])
    parts = row_parts(run_ends, cores() if run_ends[-1] >= PARALLEL_ENTRIES else 1)
    outs = [np.zeros((n_rows, k)) for _ in parts]

    def part(i: int) -> None:
        a, b = parts[i]
        _colproduct.columns_times(indptr, A.indices, A.data, cols[a:b], x[a:b], outs[i], k)

    map_parts(part, range(len(parts)))
    return outs[0] if len(outs) == 1 else np.sum(outs, axis=0)


def rows_product(A: sp.csr_matrix, x: np.ndarray) -> np.ndarray:
    """(A.shape[0], k) float64 ``A @ x`` for CSR ``A`` and x (A.shape[1], k), 1 <= k <= 4 (or
    (A.shape[1],), giving (A.shape[0],)): each row summed in float64 in its entries' order
    (scipy's product with one vector; with several it may differ in the last bits), the rows
    split over the cores (``csrc/colproduct.c``, rows_times)."""
    if not (sp.issparse(A) and A.format == "csr"):
        raise InvalidInputError(f"rows_product needs a CSR matrix; got {type(A).__name__}")
    if A.dtype not in (np.float32, np.float64) or A.indices.dtype not in (np.int32, np.int64):
        raise InvalidInputError(
            f"rows_product needs float32/float64 values and int32/int64 indices; got {A.dtype} and {A.indices.dtype}"
        )
    x = np.asarray(x)
    vector = x.ndim == 1
    x = np.ascontiguousarray(x[:, None] if vector else x, np.float64)
    if x.ndim != 2 or x.shape[0] != A.shape[1] or not 1 <= x.shape[1] <= 4:
        raise InvalidInputError(f"x must have shape ({A.shape[1]}, k) with 1 <= k <= 4; got {x.shape}")
    k, indptr = x.shape[1], np.ascontiguousarray(A.indptr, np.int64)
    out = np.empty((A.shape[0], k))
    parts = row_parts(indptr, cores() if A.nnz >= PARALLEL_ENTRIES else 1)
    map_parts(lambda p: _colproduct.rows_times(indptr, A.indices, A.data, p[0], p[1], x, out, k), parts)
    return out[:, 0] if vector else out
