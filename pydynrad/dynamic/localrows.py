"""The form-factor rows a dynamic solution keeps: F's rows of the local set, in slot order.

F[S, J] (what the local set receives from entering patches) is read from these kept rows, so
only rows are ever fetched from a source (no columns, no reciprocity: hemicube form factors are
not exactly reciprocal, and a K built from derived columns would differ from a fresh build).

See docs/design.md, 'Local set'.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..checks import check_form_factors
from ..errors import InvalidInputError
from ..rows.cache import RowCache
from ..rows.sources import HemicubeRows, RowSource, read_rows

__all__ = ["LocalRows"]


def _replace_rows(A: sp.csr_matrix, slots: np.ndarray, rows: sp.csr_matrix) -> sp.csr_matrix:
    """A copy of ``A`` (M, N) with row ``slots[m]`` := ``rows[m]`` (explicit zeros dropped).

    Splices the index arrays directly: one copy of A's entries in at most 2k + 1 runs, no
    sparse products (rows are put in whole, so the result equals the row-wise assignment).
    """
    rows = sp.csr_matrix(rows)
    if not rows.data.all():  # explicit zeros dropped from a copy: rows may be views of rows held elsewhere
        rows = rows.copy()
        rows.eliminate_zeros()
    lengths = np.diff(A.indptr)
    lengths[slots] = np.diff(rows.indptr)
    indptr = np.zeros(len(lengths) + 1, dtype=np.int64)
    np.cumsum(lengths, out=indptr[1:])
    indices = np.empty(indptr[-1], dtype=A.indices.dtype)
    data = np.empty(indptr[-1], dtype=A.data.dtype)
    order = np.argsort(slots)
    start = 0  # first row of the current run of kept rows
    for m in order.tolist():
        s = int(slots[m])
        src, dst = slice(A.indptr[start], A.indptr[s]), slice(indptr[start], indptr[s])
        indices[dst], data[dst] = A.indices[src], A.data[src]
        src, dst = slice(rows.indptr[m], rows.indptr[m + 1]), slice(indptr[s], indptr[s + 1])
        indices[dst], data[dst] = rows.indices[src], rows.data[src]
        start = s + 1
    src, dst = slice(A.indptr[start], A.indptr[-1]), slice(indptr[start], indptr[-1])
    indices[dst], data[dst] = A.indices[src], A.data[src]
    return sp.csr_matrix((data, indices, indptr), shape=A.shape)


def source_geometry(source) -> str | None:
    """The geometry hash of the scene a row source serves (a store's, a hemicube source's scene,
    through a row cache), or None where it does not say (rows in memory, a source of the
    library's own making that follows the scene as it moves)."""
    if isinstance(source, RowCache):
        source = source.source
    header = getattr(source, "header", None)
    if isinstance(header, dict) and "geometry_hash" in header:
        return str(header["geometry_hash"])
    if isinstance(source, HemicubeRows):
        return source.scene.geometry_hash()
    return None


class LocalRows:
    """Blocks of the scene's F for the local set, from a sparse matrix or a row source.

    ``local`` holds F's rows of the local set in slot order (M, N), so that F[S, J] and F_SS
    never need rows other than those already fetched.
    """

    def __init__(self, scene, form_factors, resolution: int, device, samples: int = 1) -> None:
        n = len(scene)
        self.n_patches = n
        self.csr = None
        self.local: sp.csr_matrix | None = None
        self._column_of: np.ndarray | None = None  # (N,) scratch of _scatter_rows, -1 between calls
        if form_factors is None:
            self.source = HemicubeRows(scene, resolution, device, samples=samples)
        elif isinstance(form_factors, RowSource):
            if int(form_factors.n_patches) != n:
                raise InvalidInputError(f"form_factors serves {form_factors.n_patches} patches; the scene has {n}")
            made_for = source_geometry(form_factors)
            if made_for is not None and made_for != scene.geometry_hash():
                raise InvalidInputError(
                    f"form_factors serves the rows of another scene geometry than {scene.name!r} "
                    f"(the same {n} patches in number): give this scene's"
                )
            self.source = form_factors
        else:
            shape = getattr(form_factors, "shape", None)
            if shape != (n, n):
                raise InvalidInputError(
                    f"form_factors must have shape ({n}, {n}) for this {n}-patch scene; got {shape}"
                )
            self.csr = check_form_factors(scene, form_factors)  # float64, kept at full precision
            self.source = None

    def rows(self, idx: np.ndarray) -> sp.csr_matrix:
        idx = np.asarray(idx, dtype=np.int64)
        if self.csr is not None:
            return self.csr[idx]
        return read_rows(self.source, idx)  # checked, once: not again for a RowCache or CSRRows

    def fetch_local(self, local_patches: np.ndarray) -> None:
        """Fetch the rows of a whole new local set (a build or refresh), validated by ``rows``."""
        self.local = self.rows(local_patches)

    def entering(self, local_patches: np.ndarray, J: np.ndarray, slots: np.ndarray):
        """F[S, J] (M, k), F[J, S] (k, M), F[J, J] (k, k) and F[S, R] (M, k), dense float64, for
        patches J entering ``slots`` and the patches R = ``local_patches[slots]`` leaving them;
        afterwards the kept rows of those slots are J's rows.

        F[S, J] and F[S, R] are one column slice of the kept rows (scipy's: one pass over their
        entries whatever the columns, the fastest of those tried at M = 1,024 and 4,096; F[S, R]
        carries the far field's injection over the swap,
        :meth:`~pydynrad.farfield.level.FarField.follow_swap`); F[J, S]
        and F[J, J] are scattered from J's own rows (:meth:`_scatter_rows`), which costs
        O(nnz(rows_J) + M), not O(N)."""
        slots = np.asarray(slots)
        J = np.asarray(J, dtype=np.int64)
        rows_J = self.rows(J)
        cols = self.local[:, np.concatenate([J, np.asarray(local_patches)[slots]])].toarray()
        F_SJ, F_SR = np.ascontiguousarray(cols[:, : len(J)]), np.ascontiguousarray(cols[:, len(J) :])
        F_JS = self._scatter_rows(rows_J, local_patches)
        F_JJ = self._scatter_rows(rows_J, J)
        self.local = _replace_rows(self.local, slots, rows_J)
        return F_SJ, F_JS, F_JJ, F_SR

    def _scatter_rows(self, rows: sp.csr_matrix, patches: np.ndarray) -> np.ndarray:
        """``rows[:, patches]`` (distinct patches) as a dense float64 (len(rows), len(patches))
        array, through a patch-to-column map kept between calls (scipy's column slice builds an
        O(N) map per call); duplicate entries are summed, as ``toarray`` does."""
        if self._column_of is None:
            self._column_of = np.full(self.n_patches, -1, dtype=np.int64)
        k, m = rows.shape[0], len(patches)
        self._column_of[patches] = np.arange(m)
        col = self._column_of[rows.indices]
        self._column_of[patches] = -1
        hit = col >= 0
        row = np.repeat(np.arange(k), np.diff(rows.indptr))[hit]
        flat = np.bincount(row * m + col[hit], weights=rows.data[hit], minlength=k * m)
        return flat.reshape(k, m)

    def square(self, local_patches: np.ndarray) -> sp.csr_matrix:
        """F_SS (M, M) sparse for the current local set, rows and columns in slot order."""
        return sp.csr_matrix(self.local[:, local_patches])

    @property
    def nbytes(self) -> int:
        """Host bytes of the kept local rows."""
        if self.local is None:
            return 0
        return self.local.data.nbytes + self.local.indices.nbytes + self.local.indptr.nbytes
