"""Where rows of F come from: the ``RowSource`` protocol and the sources that are not files.

Dynamic radiosity needs only the rows of patches entering the local set (the columns it needs,
F[S, J], it reads from the local set's own rows, which it keeps; see :mod:`pydynrad.dynamic`).
Anything with ``n_patches`` and ``rows(idx) -> csr (len(idx), N)`` can supply them:

* :class:`CSRRows`: an in-memory sparse matrix (what :func:`pydynrad.form_factors` returns);
* :class:`HemicubeRows`: hemicubes per requested row, computed on the device, nothing stored;
* :class:`pydynrad.rows.store.FormFactorStore`: rows read from disk block by block;
* :class:`pydynrad.rows.cache.RowCache`: any source behind a bounded, prefetching LRU cache.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np
import scipy.sparse as sp

from ..checks import check_form_factor_rows, patch_indices
from ..checks import resolution as checked_resolution
from ..errors import InvalidInputError
from ..formfactors import checked_samples, hemicube_blocks, stack_blocks

__all__ = ["RowSource", "CSRRows", "HemicubeRows", "as_row_source", "read_rows"]


@runtime_checkable
class RowSource(Protocol):
    """Supplies rows of the (N, N) gathering form-factor matrix F.

    The checked-rows contract: a source whose every ``rows`` block has already passed
    :func:`pydynrad.checks.check_form_factor_rows` (structure, shape (len(idx), N), finite,
    >= 0, row sums) says so with a class attribute ``rows_checked = True``, and
    :func:`read_rows` then does not check its blocks again. It is not a protocol member: a
    source without it is checked by every reader.
    """

    n_patches: int

    def rows(self, idx) -> sp.csr_matrix:
        """Rows ``idx`` (1-D ints in [0, N)) as a float32 CSR matrix of shape (len(idx), N)."""
        ...


def read_rows(source: RowSource, idx) -> sp.csr_matrix:
    """Rows ``idx`` of ``source`` as a validated float64 CSR matrix (len(idx), N).

    Checked here (structure first: scipy indexes with it unchecked), unless the source keeps
    the checked-rows contract (see :class:`RowSource`). ``idx`` names rows in errors.
    """
    rows = source.rows(idx)
    if getattr(source, "rows_checked", False) is True:
        return sp.csr_matrix(rows, dtype=np.float64)
    return check_form_factor_rows(rows, "form-factor rows", idx, (len(idx), int(source.n_patches)))


class CSRRows:
    """An in-memory (N, N) sparse F as a :class:`RowSource`, checked once when made."""

    rows_checked = True

    def __init__(self, matrix) -> None:
        shape = getattr(matrix, "shape", ())
        if len(shape) != 2 or shape[0] != shape[1]:
            raise InvalidInputError(f"a form-factor matrix must be square (N, N); got shape {shape}")
        f = check_form_factor_rows(matrix, "form-factor matrix").astype(np.float32)
        self.matrix = f
        self.n_patches = f.shape[0]

    def rows(self, idx) -> sp.csr_matrix:
        return self.matrix[patch_indices(idx, self.n_patches, "row indices")]

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
    """Rows of F computed on demand (:func:`pydynrad.form_factors`).

    The row source behind ``DynamicRadiosity(scene, None, ...)``: no form factors are stored,
    each entering patch costs ``samples`` hemicubes of ``resolution / sqrt(samples)`` (3 R^2
    rays), the rows of ``form_factors(scene, resolution, rows, samples=samples)``.
    """

    def __init__(self, scene, resolution: int, device=None, *, samples: int = 1) -> None:
        self.scene, self.resolution, self.device = scene, checked_resolution(resolution), device
        self.samples = checked_samples(samples, self.resolution)
        self.n_patches = len(scene)

    def rows(self, idx) -> sp.csr_matrix:
        return self.queued(idx)()

    def queued(self, idx):
        """``rows`` with their hemicubes queued on the device now: a callable (to call once,
        from any thread) that waits for them and returns the rows."""
        blocks = hemicube_blocks(self.scene, self.resolution, idx, self.device, samples=self.samples)
        return lambda: stack_blocks(blocks, self.n_patches)
