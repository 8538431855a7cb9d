"""Where rows of F come from: the ``RowSource`` protocol and the sources that are not files.

Dynamic radiosity needs only the rows of patches entering the local set (the columns it needs,
F[S, J], it reads from the local set's own rows, which it keeps; see :mod:`pydynrad.dynamic`).
Anything with ``n_patches`` and ``rows(idx) -> csr (len(idx), N)`` can supply them:

* :class:`CSRRows`: an in-memory sparse matrix (what :func:`pydynrad.form_factors` returns);
* :class:`HemicubeRows`: one hemicube per requested row, computed on the device, nothing stored;
* :class:`pydynrad.rows.store.FormFactorStore`: rows read from disk block by block;
* :class:`pydynrad.rows.cache.RowCache`: any source behind a bounded, prefetching LRU cache.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
import scipy.sparse as sp

from ..errors import InvalidInputError

__all__ = ["RowSource", "CSRRows", "HemicubeRows", "as_row_source", "check_row_indices"]


@runtime_checkable
class RowSource(Protocol):
    """Supplies rows of the (N, N) gathering form-factor matrix F."""

    n_patches: int

    def rows(self, idx) -> sp.csr_matrix:
        """Rows ``idx`` (1-D ints in [0, N)) as a float32 CSR matrix of shape (len(idx), N)."""
        ...


def check_row_indices(idx, n: int) -> np.ndarray:
    """``idx`` as a 1-D int64 array, or :class:`InvalidInputError` naming what is wrong."""
    a = np.asarray(idx)
    if a.ndim != 1 or (a.size and not np.issubdtype(a.dtype, np.integer)):
        raise InvalidInputError(f"row indices must be a 1-D integer array; got shape {a.shape}, dtype {a.dtype}")
    a = a.astype(np.int64)
    if a.size and (a.min() < 0 or a.max() >= n):
        raise InvalidInputError(f"row indices must lie in 0..{n - 1}")
    return a


class CSRRows:
    """An in-memory (N, N) sparse F as a :class:`RowSource`."""

    def __init__(self, matrix) -> None:
        f = sp.csr_matrix(matrix, dtype=np.float32)
        if f.shape[0] != f.shape[1]:
            raise InvalidInputError(f"a form-factor matrix must be square (N, N); got {f.shape}")
        self.matrix = f
        self.n_patches = f.shape[0]

    def rows(self, idx) -> sp.csr_matrix:
        return self.matrix[check_row_indices(idx, self.n_patches)]

    @property
    def nbytes(self) -> int:
        m = self.matrix
        return m.data.nbytes + m.indices.nbytes + m.indptr.nbytes


def as_row_source(form_factors) -> RowSource:
    """A sparse or dense (N, N) matrix wrapped as :class:`CSRRows`; a RowSource passes through."""
    if isinstance(form_factors, RowSource):
        return form_factors
    if sp.issparse(form_factors) or isinstance(form_factors, np.ndarray):
        return CSRRows(form_factors)
    raise InvalidInputError(
        "form_factors must be an (N, N) sparse matrix or a RowSource (FormFactorStore, RowCache, CSRRows); "
        f"got {type(form_factors).__name__}"
    )


class HemicubeRows:
    """Rows of F computed on demand, one hemicube per patch (:func:`pydynrad.form_factors`).

    The row source behind ``DynamicRadiosity(scene, None, ...)``: no form factors are stored,
    each entering patch costs one hemicube of ``resolution``.
    """

    def __init__(self, scene, resolution: int, device=None) -> None:
        self.scene, self.resolution, self.device = scene, resolution, device
        self.n_patches = len(scene)

    def rows(self, idx) -> sp.csr_matrix:
        from ..formfactors import form_factors

        return form_factors(self.scene, resolution=self.resolution, rows=check_row_indices(idx, self.n_patches),
                            device=self.device)
