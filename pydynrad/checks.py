"""Argument validators shared by the public API: each returns the clean value or raises
:class:`~pydynrad.errors.InvalidInputError` naming the argument and the bad value.

Form-factor matrices are validated here too (:func:`check_form_factors`), once per entry
point, by everything that accepts an F: the full solve, the multibounce build and the dynamic
solution."""

from __future__ import annotations

import os

import numpy as np
import scipy.sparse as sp

from .errors import InvalidInputError

__all__ = ["floats", "vec3", "number", "integer", "finite", "scene", "patch_indices", "resolution", "check_form_factors",
           "check_form_factor_rows", "ROW_SUM_SLACK", "MAX_RESOLUTION"]


def floats(value, what: str) -> np.ndarray:
    """``value`` as a float64 array; InvalidInputError naming ``what`` if it holds non-numbers."""
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{what} must be numbers; got {value!r}") from None


def number(value, what: str) -> float:
    """``value`` as a finite float; InvalidInputError naming ``what`` otherwise."""
    a = floats(value, what)
    if a.shape != () or not np.isfinite(a):
        raise InvalidInputError(f"{what} must be one finite number; got {value!r}")
    return float(a)


def vec3(value, what: str) -> np.ndarray:
    """``value`` as a (3,) float64 array (a point or direction in scene units).

    Raises InvalidInputError naming ``what`` unless ``value`` is three finite numbers.
    """
    a = floats(value, what)
    if a.shape != (3,):
        raise InvalidInputError(f"{what} must be a 3-vector (three numbers x, y, z); got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{what} must be finite (no NaN or infinite values); got {a.tolist()}")
    return a


def integer(value, what: str, lo: int = 1, hi: int | None = None) -> int:
    """``value`` as an int in ``lo..hi`` (inclusive; no upper bound when ``hi`` is None).

    Python and numpy integers pass; bools, floats and strings raise InvalidInputError.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise InvalidInputError(f"{what} must be an integer; got {value!r}")
    if value < lo or (hi is not None and value > hi):
        bound = f"lie in {lo}..{hi}" if hi is not None else f"be >= {lo}"
        raise InvalidInputError(f"{what} must {bound}; got {value}")
    return int(value)


def finite(a: np.ndarray, what: str) -> None:
    """Raise InvalidInputError naming ``what`` and the first NaN or infinite element of ``a``."""
    bad = ~np.isfinite(a)
    if bad.any():
        first = np.unravel_index(int(np.argmax(bad)), np.shape(a))
        where = first[0] if len(first) == 1 else tuple(int(i) for i in first)
        raise InvalidInputError(f"{what} contains NaN or infinite values ({bad.sum()} of {bad.size}; "
                                f"first at index {where}: {a[first]})")


def scene(value, what: str = "scene"):
    """``value`` if it is a :class:`pydynrad.Scene`, else InvalidInputError naming its type."""
    from .scene import Scene

    if not isinstance(value, Scene):
        # Functions that take a scene and a file take them in that order: f(scene, path, ...).
        hint = " (the scene comes first, then the path)" if isinstance(value, (str, os.PathLike)) else ""
        raise InvalidInputError(f"{what} must be a pydynrad.Scene; got {type(value).__name__}{hint}")
    return value


def patch_indices(value, n: int, what: str = "patch indices", *, unique: bool = False,
                  nonempty: bool = False) -> np.ndarray:
    """``value`` as a 1-D int64 array of patch indices in ``0..n-1``, or InvalidInputError naming ``what``.

    The one rule for every argument that names patches (rows of F, the patches of K, path
    tracing targets): integers (an empty list of any type is none), 1-D, in range; ``unique``
    refuses repeats (where each index is a row and column of a matrix), ``nonempty`` an empty set.
    """
    a = np.asarray(value)
    if a.ndim != 1 or (a.size and not np.issubdtype(a.dtype, np.integer)):
        raise InvalidInputError(f"{what} must be a 1-D array of integers; got shape {a.shape}, dtype {a.dtype}")
    if nonempty and not a.size:
        raise InvalidInputError(f"{what} must not be empty")
    a = a.astype(np.int64)
    if a.size and (a.min() < 0 or a.max() >= n):
        raise InvalidInputError(f"{what} must be patch indices in 0..{n - 1}; got values in [{a.min()}, {a.max()}]")
    if unique and a.size:
        values, counts = np.unique(a, return_counts=True)
        if len(values) != len(a):
            raise InvalidInputError(f"{what} contains repeated indices, e.g. {values[counts > 1][:5].tolist()}")
    return a


#: Largest hemicube resolution accepted anywhere (3 R^2 = 50 M rays per patch already).
MAX_RESOLUTION = 4096


def resolution(value, what: str = "resolution") -> int:
    """A hemicube resolution R: an even integer in 2..MAX_RESOLUTION (side faces are R x R/2).

    The one rule for every R pydynrad accepts or records: :func:`pydynrad.form_factors`,
    form-factor files and stores, ``DynamicRadiosity(resolution=)`` and the CLI.
    """
    R = integer(value, what, 2, MAX_RESOLUTION)
    if R % 2:
        raise InvalidInputError(f"{what} must be an even integer (hemicube side faces are R x R/2); got {R}")
    return R


#: Hemicube rows are sums of discretised delta form factors; allow them to exceed 1 by this much.
ROW_SUM_SLACK = 1e-3


def check_form_factors(scene, F) -> sp.csr_matrix:
    """F as a validated float64 CSR matrix of shape (N, N) for ``scene``.

    Refuses a wrong shape, NaN/inf or negative entries, and rows summing above 1 (beyond
    :data:`ROW_SUM_SLACK`): such an F has no physical meaning and can make B diverge.
    """
    n = len(scene)
    if sp.issparse(F):
        # copy=True: scipy shares indices with the caller's matrix, and sum_duplicates below
        # sorts them in place, which would scramble the caller's (non-canonical) F.
        F = sp.csr_matrix(F, dtype=np.float64, copy=True)
    else:
        a = np.asarray(F)
        if a.ndim != 2:
            raise InvalidInputError(f"F must be a 2-D (sparse or dense) matrix; got shape {a.shape}")
        F = sp.csr_matrix(a.astype(np.float64))
    if F.shape != (n, n):
        raise InvalidInputError(f"F must have shape ({n}, {n}) for this {n}-patch scene; got {F.shape}")
    return check_form_factor_rows(F)


def check_form_factor_rows(rows: sp.csr_matrix, what: str = "F") -> sp.csr_matrix:
    """``rows`` (some rows of F, or a block of them) after the checks of :func:`check_form_factors`
    that need no shape: NaN/inf or negative entries, rows summing above 1 (beyond
    :data:`ROW_SUM_SLACK`). Duplicate entries are summed in place."""
    rows.sum_duplicates()
    if not np.all(np.isfinite(rows.data)):
        raise InvalidInputError(f"{what} contains NaN or infinite entries")
    if rows.nnz and rows.data.min() < 0:
        raise InvalidInputError(f"form factors must be >= 0; {what} has minimum {rows.data.min():g}")
    sums = np.asarray(rows.sum(axis=1)).ravel()
    if sums.max(initial=0.0) > 1.0 + ROW_SUM_SLACK:
        i = int(sums.argmax())
        raise InvalidInputError(
            f"row {i} of {what} sums to {sums[i]:.6g} > 1: a patch cannot send out more than all its energy "
            f"(tolerance {ROW_SUM_SLACK:g})"
        )
    return rows
