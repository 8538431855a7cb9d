"""The prolongation Pr as stores and the far field exchange it: an (N, C) CSR matrix taking the
coarse level's values to the patches, with one entry per patch (the indicator of a cluster) or
one per linear function of a cluster (:func:`pydynrad.farfield.clusters.linear_basis`).

These are checks and read-backs of its layout only; making clusters and bases is the far field's
job (:mod:`pydynrad.farfield`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import InvalidInputError

#: The coarse bases a prolongation can be made for from cluster labels.
BASES = ("indicator", "linear")


def check_prolongation(prolongation, n: int) -> sp.csr_matrix:
    """``prolongation`` as a float64 (N, C) CSR matrix with explicit zeros removed, or InvalidInputError."""
    if sp.issparse(prolongation):
        pr = sp.csr_matrix(prolongation, dtype=np.float64, copy=True)
    else:
        try:
            a = np.asarray(prolongation, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidInputError(
                f"prolongation must be an (N, C) matrix of numbers; got {type(prolongation).__name__}"
            ) from None
        if a.ndim != 2:
            raise InvalidInputError(f"prolongation must be a 2-D (N, C) matrix; got shape {a.shape}")
        pr = sp.csr_matrix(a)
    if pr.shape[0] != n or pr.shape[1] < 1:
        raise InvalidInputError(f"prolongation must have shape (N, C) = ({n}, C >= 1) for this scene; got {pr.shape}")
    if not np.all(np.isfinite(pr.data)):
        raise InvalidInputError("prolongation holds NaN or infinite entries")
    if pr.data.size and pr.data.min() < 0:
        raise InvalidInputError(f"prolongation entries must be >= 0; the smallest is {pr.data.min():g}")
    pr.eliminate_zeros()
    pr.sort_indices()
    return pr


def as_prolongation(clusters, n: int) -> sp.csr_matrix:
    """A checked (N, C) prolongation from an (N, C) matrix, (N,) integer cluster labels (the
    indicator) or a clusters object with ``labels`` (:class:`pydynrad.farfield.Clusters`)."""
    labels = getattr(clusters, "labels", None)
    if labels is None and not sp.issparse(clusters):
        a = np.asarray(clusters)
        if a.ndim == 1:
            labels = a
    if labels is None:
        return check_prolongation(clusters, n)
    labels = np.asarray(labels)
    if labels.shape != (n,) or not np.issubdtype(labels.dtype, np.integer) or (n and labels.min() < 0):
        raise InvalidInputError(
            f"cluster labels must be {n} integers >= 0 (one per patch); got shape {labels.shape}, dtype {labels.dtype}"
        )
    C = int(getattr(clusters, "count", labels.max() + 1 if n else 1))
    return check_prolongation(sp.csr_matrix((np.ones(n), (np.arange(n), labels)), shape=(n, C)), n)


def split_prolongation(prolongation) -> tuple[np.ndarray, np.ndarray] | None:
    """(labels, scale) of a prolongation with at most one entry per row, else None.

    ``labels[i]``: the cluster of patch i (-1 where its row is empty); ``scale[i]``: the entry
    (0 where empty). A checked CSR matrix (:func:`check_prolongation`) is expected.
    """
    per_row = np.diff(prolongation.indptr)
    if per_row.size and per_row.max() > 1:
        return None
    has = per_row == 1
    labels = np.full(prolongation.shape[0], -1, np.int32)
    scale = np.zeros(prolongation.shape[0], np.float64)
    labels[has] = prolongation.indices
    scale[has] = prolongation.data
    return labels, scale


def g_samples(f_resolution: int, f_samples: int, g_resolution: int) -> int:
    """Hemicubes per row of G: F's at F's resolution (G is then F Pr of F's very rows), else 1
    (F's count need not divide another resolution)."""
    return int(f_samples) if int(g_resolution) == int(f_resolution) else 1


#: Basis functions per cluster of :func:`~pydynrad.farfield.clusters.linear_basis`.
LINEAR_FUNCTIONS = 3


def labels_of_linear(prolongation: sp.csr_matrix) -> np.ndarray | None:
    """(N,) cluster labels of a prolongation laid out like :func:`~pydynrad.farfield.clusters.linear_basis`'s (every row's
    entries in columns c + k C of one cluster c), else None."""
    pr = sp.csr_matrix(prolongation)
    if pr.shape[1] % LINEAR_FUNCTIONS or np.any(np.diff(pr.indptr) == 0):
        return None
    C = pr.shape[1] // LINEAR_FUNCTIONS
    lab = pr.indices[pr.indptr[:-1]] % C
    if np.any(pr.indices % C != np.repeat(lab, np.diff(pr.indptr))):
        return None
    return lab.astype(np.int64)
