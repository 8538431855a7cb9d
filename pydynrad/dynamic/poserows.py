"""Sparse rows of F at an object pose: the static rows with the entries a pose hides dropped and
its columns added by reciprocity, their differences between poses, and the swap's chunks.

See docs/design.md, 'Moving objects' and 'Batched swap'.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from .. import _poserows
from ..checks import patch_indices
from ..errors import InvalidInputError
from ..host.threads import cores, map_parts, row_parts

__all__ = [
    "stale_rows",
    "native_spans",
    "reciprocal_columns",
    "at_pose",
    "Since",
    "PoseDifference",
    "difference_at_pose",
    "kept_slots",
    "stacked_rows",
    "swap_chunks",
    "PARALLEL_ENTRIES",
]


def native_spans(m: sp.csr_matrix, select: np.ndarray | None = None):
    """(starts, ends, indices, data) of CSR ``m``'s rows ``select`` (all by default) read where
    they lie: int64 spans of its int32 indices and float64 data, as ``csrc/segments.c`` and
    ``csrc/poserows.c`` read them (no copy of the entries where they already are so)."""
    indptr = np.asarray(m.indptr)
    rows = np.arange(m.shape[0]) if select is None else patch_indices(select, m.shape[0], "rows to select")
    _, indices, data = native_csr(m)
    return (indptr[rows].astype(np.int64), indptr[rows + 1].astype(np.int64), indices, data)


def reciprocal_columns(
    row_patches: np.ndarray, object_rows: sp.csr_matrix, object_patches: np.ndarray, areas: np.ndarray, n_cols: int
) -> sp.csr_matrix:
    """(len(row_patches), n_cols): the columns ``object_patches`` of the rows of ``row_patches``
    by reciprocity, F[s, o] = A_o F[o, s] / A_s, from the objects' rows ``object_rows``
    (len(object_patches), N); zero elsewhere."""
    A = np.asarray(areas, np.float64)
    row_patches = np.asarray(row_patches, np.int64)
    # The objects' columns as rows (a transpose held by column, converted once), then the rows
    # wanted: a column slice of the objects' rows cost a third more. Scaled on the entries:
    # broadcast sparse products copy the matrix per factor.
    recip = sp.csr_matrix(object_rows).T.tocsr()[row_patches]
    recip.sort_indices()
    data = recip.data * A[object_patches][recip.indices] * np.repeat(1.0 / A[row_patches], np.diff(recip.indptr))
    return sp.csr_matrix(
        (data, np.asarray(object_patches, np.int64)[recip.indices], recip.indptr), shape=(len(row_patches), n_cols)
    )


def at_pose(
    rows: sp.csr_matrix, hidden: np.ndarray, recip: sp.csr_matrix, select: np.ndarray | None = None
) -> sp.csr_matrix:
    """Static ``rows`` (CSR, no entries in the object columns; its rows ``select``, read in
    place, all by default) at the objects' poses, shaped as ``recip``: without their entries
    ``hidden`` ((rows.nnz,) bool, :func:`~pydynrad.dynamic.occlusion.hidden_entries`), with the object columns ``recip``
    (one row per row taken, :func:`reciprocal_columns`), and capped: where a row then sums
    above 1 (the centre segments missed part of what an object hides), its static entries are
    scaled so that it sums to 1, clipped at zero; where the object columns alone sum above 1,
    they are scaled to 1 and the static entries go. No row sums above 1. One native pass
    (``csrc/poserows.c``); zeros dropped."""
    starts, ends, indices, data, hidden, recip = _pose_spans("at_pose", rows, hidden, recip, select)
    n = int((ends - starts).sum()) + recip.nnz
    indptr, out_indices, out_data = np.empty(len(starts) + 1, np.int64), np.empty(n, np.int32), np.empty(n)
    # One thread: in two parts (their outputs then stacked) it was slower, since a pass that
    # writes every entry once is bound by memory, not by a core, and stacking copies it again
    # (docs/decisions/0033-native-host-passes.md).
    nnz = _poserows.assemble(starts, ends, indices, data, hidden, *native_csr(recip), indptr, out_indices, out_data)
    return sp.csr_matrix((out_data[:nnz], out_indices[:nnz], indptr), shape=recip.shape)


def _pose_spans(caller: str, rows: sp.csr_matrix, hidden: np.ndarray, recip: sp.csr_matrix, select) -> tuple:
    """(starts, ends, indices, data, hidden as uint8, recip as CSR): the checked inputs of
    :func:`at_pose` and :func:`difference_at_pose` as ``csrc/poserows.c`` reads them."""
    if not (sp.issparse(rows) and rows.format == "csr"):
        raise InvalidInputError(
            f"{caller} needs the rows as CSR (hidden is over their entries); got {type(rows).__name__}"
        )
    recip = sp.csr_matrix(recip)
    starts, ends, indices, data = native_spans(rows, select)
    if len(starts) != recip.shape[0] or rows.shape[1] > recip.shape[1]:
        raise InvalidInputError(
            f"{len(starts)} rows of {rows.shape[1]} columns and their object columns {recip.shape} do not match"
        )
    if np.shape(hidden) != (rows.nnz,):
        raise InvalidInputError(f"hidden must have one flag per entry of the rows ({rows.nnz}); got {np.shape(hidden)}")
    return starts, ends, indices, data, _mask_bytes(hidden), recip


def _mask_bytes(mask: np.ndarray) -> np.ndarray:
    """A mask over a CSR matrix's entries as the uint8 flags ``csrc/poserows.c`` reads. A bool
    mask is read as bytes in place: it spans all of F's entries when rows are picked out of F
    (a uint8 copy would cost each move a pass over all of a large scene's F)."""
    mask = np.ascontiguousarray(mask)
    return (mask if mask.dtype == np.bool_ else mask != 0).view(np.uint8)


def kept_slots(slots: np.ndarray, n_rows: int, n_kept: int) -> np.ndarray:
    """``slots`` as contiguous int64, checked to name one of ``n_kept`` kept rows for each of
    ``n_rows`` rows (:func:`difference_at_pose`, :func:`~pydynrad.dynamic.stale.rows_minus`)."""
    slots = np.ascontiguousarray(slots, np.int64)
    if slots.shape != (n_rows,):
        raise InvalidInputError(f"slots must name one kept row per row ({n_rows}); got shape {slots.shape}")
    if len(slots) and (slots.min() < 0 or slots.max() >= n_kept):
        raise InvalidInputError(f"slots must lie in [0, {n_kept}) (the kept rows); got {slots.min()}..{slots.max()}")
    return slots


class Since(NamedTuple):
    """What :func:`difference_at_pose` may start from for some of its rows: their rows at the
    last pose, made from the same static rows, and their D then.

    ``rows`` (r,) bool: the rows whose row at the last pose was made with the mask ``hidden``
    ((nnz,) bool over the static rows' entries, as :func:`~pydynrad.dynamic.occlusion.hidden_entries` gave it then) and not
    capped, and whose D then holds against the same kept rows: row ``last_row[i]`` of ``last``
    (CSR of N columns; -1: an empty row); ``row_sums`` (r,) float64: each static row's sum;
    ``first_object``: the first object column (every static column lies below it)."""

    rows: np.ndarray
    hidden: np.ndarray
    row_sums: np.ndarray
    last: sp.csr_matrix
    last_row: np.ndarray
    first_object: int


class PoseDifference(NamedTuple):
    """:func:`difference_at_pose`'s answer: ``delta`` (r, N) CSR, D; ``capped`` (r,) bool, where
    the row at the pose was scaled or capped (:func:`at_pose`)."""

    delta: sp.csr_matrix
    capped: np.ndarray


def difference_at_pose(
    rows: sp.csr_matrix,
    hidden: np.ndarray,
    recip: sp.csr_matrix,
    kept: sp.csr_matrix,
    slots: np.ndarray,
    select: np.ndarray | None = None,
    since: Since | None = None,
) -> PoseDifference:
    """``at_pose(rows, hidden, recip, select) - kept[slots]`` (r, N) CSR, exact zeros dropped,
    without the rows at the pose: each is merged with its kept row as it is made, value for
    value as :func:`at_pose` makes it (``csrc/poserows.c``, ``moved_difference``). ``kept``
    (M, N) CSR, ``slots`` (r,) rows of it; the rest as for :func:`at_pose`. Where a kept row is
    out of column order, the kept rows are sorted first (a copy). In parts of about equal entries
    on the cores at once from :data:`PARALLEL_ENTRIES` entries.

    ``since``: for the rows it names whose row at the pose is not capped either, D is their
    last D with the entries whose presence changed since (hidden then and not now, or the
    reverse) made again, and the object columns: the same values bit for bit, reading a flag
    or two per entry instead of the static and kept rows whole (:class:`Since`). Used where both
    ``rows`` and ``kept`` are in canonical order (scipy's cached ``has_canonical_format``)."""

    starts, ends, indices, data, hidden, recip = _pose_spans("difference_at_pose", rows, hidden, recip, select)
    # Not wrapped again where it is CSR: a new wrapper forgets scipy's cached order flags.
    kept = kept if sp.issparse(kept) and kept.format == "csr" else sp.csr_matrix(kept)
    if recip.shape[1] != kept.shape[1]:
        raise InvalidInputError(f"object columns {recip.shape} and kept rows {kept.shape} do not match")
    slots = kept_slots(slots, len(starts), kept.shape[0])
    r_indptr, r_indices, r_data = native_csr(recip)
    flags, p_starts, p_ends, p_indices, p_data, hidden_prev, row_sums, first = _since_inputs(
        since, rows, hidden, len(starts), kept.shape[1]
    )
    capped = np.zeros(len(starts), np.uint8)

    def part(task):
        (a, z), (k_indptr, k_indices, k_data), use = task
        ra, rz, sl = r_indptr[a], r_indptr[z], slots[a:z]
        n = (
            int((ends[a:z] - starts[a:z]).sum())
            + int(rz - ra)
            + int((k_indptr[sl + 1] - k_indptr[sl]).sum())
            + int((p_ends[a:z] - p_starts[a:z]).sum())
        )
        # Only D's entries are written (no page of the rest of the bound faulted in).
        indptr, out_indices, out_data = np.empty(z - a + 1, np.int64), np.empty(n, np.int32), np.empty(n)
        nnz = _poserows.moved_difference(
            starts[a:z],
            ends[a:z],
            indices,
            data,
            hidden,
            r_indptr[a : z + 1] - ra,
            r_indices[ra:rz],
            r_data[ra:rz],
            k_indptr,
            k_indices,
            k_data,
            sl,
            use[a:z],
            hidden_prev,
            row_sums[a:z],
            p_starts[a:z],
            p_ends[a:z],
            p_indices,
            p_data,
            first,
            indptr,
            out_indices,
            out_data,
            capped[a:z],
        )
        return (indptr, out_indices[:nnz], out_data[:nnz]) if nnz >= 0 else a - 1 - nnz  # the row out of order

    work = np.concatenate([[0], np.cumsum(ends - starts)])
    parts = row_parts(work, cores() if work[-1] >= PARALLEL_ENTRIES else 1)
    for attempt in range(2):
        k_csr = native_csr(kept)
        # The last D is read only against kept rows in canonical order (it was made against them).
        use = flags if kept.has_canonical_format else np.zeros_like(flags)
        done = map_parts(part, [(p, k_csr, use) for p in parts])
        bad = [d for d in done if not isinstance(d, tuple)]
        if not bad:
            return PoseDifference(stacked_rows(done, recip.shape[1]), capped.view(bool))
        if attempt or np.any(np.diff(indices[starts[bad[0]] : ends[bad[0]]]) <= 0):
            break  # a static row out of order: at_pose's rows must be in order too
        kept = kept.copy()
        kept.sum_duplicates()  # scipy leaves sums of CSR matrices unsorted
    raise InvalidInputError(
        f"row {bad[0]}'s static columns are out of increasing order: difference_at_pose reads sorted rows"
    )


def _since_inputs(since: Since | None, rows: sp.csr_matrix, hidden: np.ndarray, r: int, n_cols: int) -> tuple:
    """(flags uint8 (r,), the last D's spans (starts, ends int64 (r,)), indices and data, the last
    mask uint8, row sums float64 (r,), first object column): :func:`difference_at_pose`'s
    "since" inputs, checked, or none to use."""
    empty = np.zeros(r, np.int64)
    none = (
        np.zeros(r, np.uint8),
        empty,
        empty,
        np.zeros(0, np.int32),
        np.zeros(0),
        np.zeros(0, np.uint8),
        np.zeros(r),
        0,
    )
    if since is None:
        return none
    flags, at = np.ascontiguousarray(since.rows, bool), np.asarray(since.last_row, np.int64)
    last = since.last
    if (
        flags.shape != (r,)
        or at.shape != (r,)
        or np.shape(since.row_sums) != (r,)
        or np.shape(since.hidden) != hidden.shape
        or not (sp.issparse(last) and last.format == "csr")
        or last.shape[1] != n_cols
        or (r and (at.min() < -1 or at.max() >= last.shape[0]))
    ):
        raise InvalidInputError(
            f"since must give a flag, a row sum and a row of its last D (CSR, {n_cols} columns, "
            f"or -1) for each of the {r} rows, and a mask of the same entries as hidden"
        )
    if not (flags.any() and rows.has_canonical_format):
        return none
    indptr, indices, data = native_csr(last)
    held = flags & (at >= 0)
    starts, ends = np.where(held, indptr[at], 0), np.where(held, indptr[at + 1], 0)
    return (
        flags.view(np.uint8),
        starts,
        ends,
        indices,
        data,
        _mask_bytes(since.hidden),
        np.ascontiguousarray(since.row_sums, np.float64),
        int(since.first_object),
    )


def stacked_rows(parts: list, n_cols: int) -> sp.csr_matrix:
    """One CSR matrix of ``n_cols`` columns from row parts ``[(indptr from 0, indices, data)]``
    stacked in order: one part as it is, more in one copy of their entries (scipy's vstack of
    the parts' matrices, with its checks and conversions, was a visible share of a move's merge)."""
    if len(parts) == 1:
        indptr, indices, data = parts[0]
        return sp.csr_matrix((data, indices, indptr), shape=(len(indptr) - 1, n_cols))
    first = np.cumsum([0] + [len(p[1]) for p in parts])
    indptr = np.concatenate([[0]] + [p[0][1:] + f for p, f in zip(parts, first)])
    return sp.csr_matrix(
        (np.concatenate([p[2] for p in parts]), np.concatenate([p[1] for p in parts]), indptr),
        shape=(len(indptr) - 1, n_cols),
    )


def native_csr(m: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr int64, indices int32, data float64) of CSR ``m``, contiguous, as ``csrc/poserows.c``
    reads them (no copy where they already are: scipy's int32 indices for fewer than 2^31 columns)."""
    if m.shape[1] >= 2**31:
        raise InvalidInputError(f"rows of {m.shape[1]} columns need 64-bit column indices")
    return (
        np.ascontiguousarray(m.indptr, np.int64),
        np.ascontiguousarray(m.indices, np.int32),
        np.ascontiguousarray(m.data, np.float64),
    )


def stale_rows(
    local: sp.csr_matrix,
    fresh_slots: np.ndarray,
    S: np.ndarray,
    moved_slots: np.ndarray,
    moved: np.ndarray,
    areas: np.ndarray,
) -> sp.csr_matrix:
    """The kept rows (M, N) after a move, for the slots not given fresh rows.

    ``local`` already holds the fresh rows of ``fresh_slots`` (the moved objects' patches, in
    ``moved_slots``, among them). The other rows that see a moved object, before or after,
    get its columns by reciprocity; where those would push a row's sum above 1 (it still sees
    what the object now hides), the object columns alone are scaled down to fill the row to 1.
    Only entries in the moved objects' columns change, so these rows need no slot of their
    own in the swap, and a pose that comes back gives back the same rows.
    """
    M, N = local.shape
    fresh = np.zeros(M, bool)
    fresh[fresh_slots] = True
    is_moved = np.zeros(N, bool)
    is_moved[moved] = True
    slot_of = np.full(N, -1)
    slot_of[S] = np.arange(M)
    A = np.asarray(areas, np.float64)
    # The moved objects' fresh rows give, by reciprocity, F[s, o] = A_o F[o, s] / A_s for every
    # other local s they see.
    obj = sp.csr_matrix(local[moved_slots])
    o_row = np.repeat(np.arange(len(moved_slots)), np.diff(obj.indptr))
    at = slot_of[obj.indices]
    use = (at >= 0) & ~fresh[np.maximum(at, 0)]
    r_row, r_col = at[use], moved[o_row[use]]
    r_val = A[r_col] * obj.data[use] / A[S[r_row]]
    # The stale rows' old entries in the moved columns go: a mask over the entries, cleared on
    # the fresh rows' runs, so that no row index per entry is formed (three times faster at
    # M = 1024, 426k entries); the kept rows' sums are the same sequential sums as before.
    indptr = local.indptr
    drop = is_moved[local.indices]
    fs = np.flatnonzero(fresh)
    lens = indptr[fs + 1] - indptr[fs]
    drop[np.repeat(indptr[fs] - (np.cumsum(lens) - lens), lens) + np.arange(lens.sum())] = False
    drop_row = np.searchsorted(indptr, np.flatnonzero(drop), side="right") - 1
    if not len(drop_row) and not len(r_row):
        return local
    keep = ~drop
    gone = np.zeros(M + 1, np.int64)
    np.cumsum(np.bincount(drop_row, minlength=M), out=gone[1:])
    kept = sp.csr_matrix((local.data[keep], local.indices[keep], indptr - gone), shape=(M, N))
    others = kept @ np.ones(N)
    objects = np.bincount(r_row, weights=r_val, minlength=M)
    scale = np.ones(M)
    over = (others + objects > 1.0) & (objects > 0)
    scale[over] = np.maximum(1.0 - others[over], 0.0) / objects[over]
    out = sp.csr_matrix(kept + sp.csr_matrix((r_val * scale[r_row], (r_row, r_col)), shape=(M, N)))
    out.eliminate_zeros()
    return out


def in_order(first: sp.csr_matrix, second: sp.csr_matrix, in_first: np.ndarray) -> sp.csr_matrix:
    """One float64 CSR of rows asked for in order: row i the next of ``first`` where
    ``in_first[i]``, else the next of ``second``."""
    order = np.argsort(np.concatenate([np.flatnonzero(in_first), np.flatnonzero(~in_first)]), kind="stable")
    return sp.csr_matrix(sp.vstack([first, second], format="csr")[order], dtype=np.float64)


def swap_chunks(slots: np.ndarray, size: int) -> list[np.ndarray]:
    """``slots`` cut into batches of at most ``size`` (the swap size of the device kernels)."""
    if size < 1:
        raise InvalidInputError(f"swap size must be >= 1; got {size}")
    return [slots[i : i + size] for i in range(0, len(slots), size)]


#: Entries from which :func:`~pydynrad.dynamic.stale.rows_minus` and :func:`difference_at_pose` split its merge over the cores: a move on a small
#: scene is well above it, and long enough on one core for a second to pay
#: (docs/decisions/0033-native-host-passes.md).
PARALLEL_ENTRIES = 50_000
