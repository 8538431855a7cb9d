"""Argument validators shared by the public API: each returns the clean value or raises
:class:`~pydynrad.errors.InvalidInputError` naming the argument and the bad value.

Form-factor matrices are validated here too (:func:`check_form_factors`), once per entry
point, by everything that accepts an F: the full solve, the multibounce build and the dynamic
solution."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .errors import InvalidInputError

__all__ = [
    "floats",
    "vec3",
    "unit_vector",
    "number",
    "flag",
    "stops",
    "integer",
    "finite",
    "patch_indices",
    "resolution",
    "check_form_factors",
    "check_form_factor_rows",
    "sparse_structure",
    "ROW_SUM_SLACK",
    "MAX_RESOLUTION",
]


def floats(value, what: str) -> np.ndarray:
    """``value`` as a float64 array; InvalidInputError naming ``what`` if it holds non-numbers.

    Text is refused even where it spells a number (numpy would parse ``"45"`` as 45.0), as
    :func:`integer` refuses it: a path file's ``"fov_y": "45"`` is a typing mistake to name,
    not a number to guess; so are booleans (``"radius": true`` had been 1) and complex numbers."""
    try:
        a = np.asarray(value)
        if a.dtype.kind in "SUV" or (a.dtype.kind == "O" and any(isinstance(x, (str, bytes)) for x in a.flat)):
            raise TypeError
        if a.dtype.kind == "b" or _holds_bool(value):
            raise InvalidInputError(f"{what} must be numbers; got True or False ({_brief(value)})")
        if a.dtype.kind == "c" or (a.dtype.kind == "O" and any(isinstance(x, complex) for x in a.flat)):
            raise InvalidInputError(f"{what} must be real numbers; got complex values ({_brief(value)})")
        return a.astype(np.float64, copy=False)
    except InvalidInputError:
        raise
    except (TypeError, ValueError, OverflowError) as exc:
        text = _brief(value)
        if isinstance(exc, OverflowError):  # a Python int past float64 (10**400)
            raise InvalidInputError(
                f"{what} must be numbers within float64's range (about 1.8e308); got {text}"
            ) from None
        raise InvalidInputError(f"{what} must be numbers; got {text}") from None


def _holds_bool(value) -> bool:
    """Whether a scalar, list or tuple (nested) holds a bool: numpy turns [1.0, True] into floats."""
    if isinstance(value, (bool, np.bool_)):
        return True
    return isinstance(value, (list, tuple)) and any(_holds_bool(x) for x in value)


def _brief(value) -> str:
    """``repr(value)`` for a message, cut where it would fill a screen (an array, a long list, a
    400-digit integer)."""
    text = repr(value)
    if len(text) <= 80:
        return text
    if isinstance(value, np.ndarray):
        return f"an array of {value.dtype} values, shape {value.shape}"
    return f"{text[:60]}... ({type(value).__name__}{f' of {len(value)}' if hasattr(value, '__len__') else ''})"


def number(value, what: str) -> float:
    """``value`` as a finite float; InvalidInputError naming ``what`` otherwise."""
    try:
        a = floats(value, what)
    except InvalidInputError:
        a = None  # not a number: refused below, in this function's words
    if a is None or a.shape != () or not np.isfinite(a):
        raise InvalidInputError(f"{what} must be one finite number; got {_brief(value)}")
    return float(a)


#: The most photographic stops an exposure may have either way: 2**126 is the largest power of
#: two whose inverse is normal in float32 too (2**-126 the smallest normal number).
MAX_STOPS = 126


def stops(value, what: str = "exposure") -> float:
    """An exposure in photographic stops (values are scaled by ``2 ** stops``): a finite number
    within +-:data:`MAX_STOPS`; InvalidInputError naming ``what`` otherwise."""
    v = number(value, what)
    if abs(v) > MAX_STOPS:
        raise InvalidInputError(
            f"{what} must lie within +-{MAX_STOPS} stops (a gain of 2**{v:g} is outside float32's "
            f"normal range); got {value!r}"
        )
    return v


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


def unit_vector(value, what: str) -> np.ndarray:
    """``value`` as a unit 3-vector (float64, normalised here), or InvalidInputError if it is zero."""
    v = vec3(value, what).astype(np.float64)
    big = float(np.abs(v).max())
    if big == 0.0:
        raise InvalidInputError(f"{what} must be a non-zero vector")
    v = v / big  # first: the norm of (1e300, ...) overflows, and of (1e-300, ...) underflows
    return v / float(np.linalg.norm(v))


def flag(value, what: str) -> bool:
    """``value`` as a bool; InvalidInputError naming ``what`` for anything but True or False
    (``"no"`` is a true string, and had meant yes)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InvalidInputError(f"{what} must be True or False; got {value!r}")
    return bool(value)


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
        raise InvalidInputError(
            f"{what} contains NaN or infinite values ({bad.sum()} of {bad.size}; first at index {where}: {a[first]})"
        )


def patch_indices(
    value, n: int, what: str = "patch indices", *, unique: bool = False, nonempty: bool = False
) -> np.ndarray:
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


def _row_namer(row_names):
    """Row i of a block by the name the caller knows it by (its patch index), or i itself."""
    return (lambda i: int(i)) if row_names is None else (lambda i: int(np.asarray(row_names)[i]))


def sparse_structure(indptr, indices, shape, what: str = "F", nnz: int | None = None, row_names=None) -> None:
    """Refuse compressed-row arrays that would send a reader outside them; O(nnz), vectorised.

    scipy's sparse kernels (and ours) trust ``indptr`` and ``indices``: an index out of range,
    a decreasing or negative ``indptr`` or a short array reads or writes past memory, which
    crashes the process or returns garbage. Checks that ``indptr`` has ``shape[0] + 1``
    integer entries, starts at 0, never decreases and ends at ``nnz`` (default: the length of
    ``indices``), and that every entry of ``indices`` is an integer in ``0..shape[1]-1``.
    The message names the first offending row (``row_names[i]`` when given, e.g. the patch a
    block row belongs to).
    """
    indptr, indices = np.asarray(indptr), np.asarray(indices)
    m, n = (int(v) for v in shape)
    name = _row_namer(row_names)
    for arr, label in ((indptr, "indptr"), (indices, "indices")):
        if arr.ndim != 1 or not (np.issubdtype(arr.dtype, np.integer) or arr.size == 0):
            raise InvalidInputError(
                f"{what}: {label} must be a 1-D integer array; got shape {arr.shape}, dtype {arr.dtype}"
            )
    if len(indptr) != m + 1:
        raise InvalidInputError(f"{what}: indptr has {len(indptr)} entries; {m} rows need {m + 1}")
    nnz = len(indices) if nnz is None else int(nnz)
    if indptr[0] != 0:
        raise InvalidInputError(f"{what}: indptr must start at 0; got {int(indptr[0])}")
    steps = np.diff(indptr)
    if steps.size and steps.min() < 0:
        i = int(np.argmax(steps < 0))
        raise InvalidInputError(
            f"{what}: row {name(i)} has a negative length (indptr decreases from "
            f"{int(indptr[i])} to {int(indptr[i + 1])})"
        )
    if indptr[-1] != nnz or len(indices) != nnz:
        raise InvalidInputError(
            f"{what}: indptr ends at {int(indptr[-1])} but there are {len(indices)} indices and {nnz} values"
        )
    if nnz:
        bad = (indices < 0) | (indices >= n)
        if bad.any():
            p = int(np.argmax(bad))
            i = int(np.searchsorted(indptr, p, side="right")) - 1
            hint = " (1-based indices? pydynrad's are 0-based)" if indices.min() == 1 and indices.max() == n else ""
            raise InvalidInputError(
                f"{what}: row {name(i)} has column index {int(indices[p])} outside 0..{n - 1}{hint}"
            )


def _as_safe_csr(F, what: str, row_names=None) -> sp.csr_matrix:
    """Sparse ``F`` as a float64 CSR copy, its structure checked before scipy converts it."""
    if F.format == "csr":
        sparse_structure(F.indptr, F.indices, F.shape, what, nnz=len(F.data), row_names=row_names)
    elif F.format == "csc":
        sparse_structure(F.indptr, F.indices, F.shape[::-1], f"{what} (CSC; its rows are columns)", nnz=len(F.data))
    elif F.format == "coo":
        for arr, dim, label in ((F.row, F.shape[0], "row"), (F.col, F.shape[1], "column")):
            if arr.size and (arr.min() < 0 or arr.max() >= dim):
                raise InvalidInputError(
                    f"{what}: COO {label} indices in [{arr.min()}, {arr.max()}] lie outside 0..{dim - 1}"
                )
    # copy=True: scipy shares indices with the caller's matrix, and sum_duplicates later
    # sorts them in place, which would scramble the caller's (non-canonical) F.
    return sp.csr_matrix(F, dtype=np.float64, copy=True)


def check_form_factors(scene, F) -> sp.csr_matrix:
    """F as a validated float64 CSR matrix of shape (N, N) for ``scene``.

    Refuses a broken sparse structure (:func:`sparse_structure`), a wrong shape, NaN/inf,
    complex or negative entries, rows summing above 1 (beyond :data:`ROW_SUM_SLACK`), and a
    non-zero diagonal: such an F has no physical meaning and can make B diverge.
    """
    n = len(scene)
    shape = np.shape(F)
    if len(shape) != 2:
        raise InvalidInputError(f"F must be a 2-D (sparse or dense) matrix; got shape {shape}")
    if shape != (n, n):
        raise InvalidInputError(f"F must have shape ({n}, {n}) for this {n}-patch scene; got {shape}")
    F = check_form_factor_rows(F)
    own = F.diagonal()
    if own.any():  # a flat patch sees none of itself: another matrix's rows, or a shifted index
        i = int(np.flatnonzero(own)[0])
        raise InvalidInputError(
            f"F[{i}, {i}] = {own[i]:g}: a patch is flat and sees none of itself (F's diagonal is 0)"
        )
    return F


def check_form_factor_rows(rows, what: str = "F", row_names=None, shape: tuple | None = None) -> sp.csr_matrix:
    """``rows`` (F, some rows of it, or a block) as a validated float64 CSR copy.

    The checks of :func:`check_form_factors` that need no scene, once per matrix or block: the
    sparse structure (:func:`sparse_structure`, before scipy touches it), ``shape`` when given,
    NaN/inf or negative entries, rows summing above 1 (beyond :data:`ROW_SUM_SLACK`). Messages
    name the offending row as ``row_names[i]`` when given (the patch a row source's row
    belongs to). The caller's matrix is never modified.
    """
    if np.iscomplexobj(rows.data if sp.issparse(rows) else np.asarray(rows)):
        raise InvalidInputError(f"{what} must hold real numbers; got complex values")
    if not sp.issparse(rows):
        a = np.asarray(rows)
        if a.ndim != 2 or not np.issubdtype(a.dtype, np.number):
            raise InvalidInputError(
                f"{what} must be a (sparse or dense) 2-D matrix of numbers; got {type(rows).__name__}"
            )
        rows = sp.csr_matrix(a.astype(np.float64))
    if shape is not None and rows.shape != tuple(shape):
        raise InvalidInputError(f"{what} must have shape {tuple(shape)}; got {rows.shape}")
    F = _as_safe_csr(rows, what, row_names)
    F.sum_duplicates()
    name = _row_namer(row_names)
    if not np.all(np.isfinite(F.data)):
        bad = int(np.searchsorted(F.indptr, int(np.argmax(~np.isfinite(F.data))), side="right")) - 1
        raise InvalidInputError(f"{what} contains NaN or infinite entries (first in row {name(bad)})")
    if F.nnz and F.data.min() < 0:
        bad = int(np.searchsorted(F.indptr, int(np.argmin(F.data)), side="right")) - 1
        raise InvalidInputError(f"form factors must be >= 0; {what} has minimum {F.data.min():g} (row {name(bad)})")
    sums = np.asarray(F.sum(axis=1)).ravel()
    if sums.max(initial=0.0) > 1.0 + ROW_SUM_SLACK:
        i = int(sums.argmax())
        raise InvalidInputError(
            f"row {name(i)} of {what} sums to {sums[i]:.6g} > 1: a patch cannot send out more than all its energy "
            f"(tolerance {ROW_SUM_SLACK:g})"
        )
    return F


def checked_sensors(points, normals) -> tuple[np.ndarray, np.ndarray]:
    """``points`` (n, 3) and unit ``normals`` (n, 3) float64 (normalised here), or InvalidInputError.

    A single point (3,) is accepted as (1, 3); a zero or non-finite normal is an error
    naming the first offending sensor.
    """
    p = floats(points, "sensor points")
    nrm = floats(normals, "sensor normals")
    p = p.reshape(1, 3) if p.shape == (3,) else p
    if p.ndim != 2 or p.shape[1] != 3:  # before the normals are broadcast to it
        raise InvalidInputError(f"sensor points must have shape (n, 3); got {np.shape(points)}")
    nrm = np.broadcast_to(nrm, p.shape) if nrm.shape == (3,) else nrm
    if nrm.shape != p.shape:
        raise InvalidInputError(f"sensor normals must have shape {p.shape} (or (3,)); got {np.shape(normals)}")
    for a, what in ((p, "points"), (nrm, "normals")):
        bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1))
        if len(bad):
            raise InvalidInputError(f"sensor {what}[{bad[0]}] is not finite: {a[bad[0]].tolist()}")
    length = np.linalg.norm(nrm, axis=1)
    bad = np.flatnonzero(length < 1e-12)
    if len(bad):
        raise InvalidInputError(f"sensor normals[{bad[0]}] is zero: a sensor needs the direction it faces")
    return np.ascontiguousarray(p), np.ascontiguousarray(nrm / length[:, None])


def vec3_tuple(value, what: str) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in vec3(value, what))
    return x, y, z


def rgb_tuple(value, what: str) -> tuple[float, float, float]:
    a = floats(value, what)
    if a.ndim == 0:
        a = np.full(3, float(a))
    rgb = vec3_tuple(a, what)
    if min(rgb) < 0:
        raise InvalidInputError(f"{what} must be >= 0; got {rgb}")
    return rgb


def unit_tuple(value, what: str) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in unit_vector(value, what))
    return x, y, z
