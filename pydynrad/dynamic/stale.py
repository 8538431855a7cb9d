"""Rows a move left stale in K, and the correction of B for them (docs/design.md, 'Moving objects').

With a static F, a move makes the row at the new poses of every local patch that may see a
moved object (:meth:`pydynrad.dynamic.moves.WorldRows.refresh`); only the occlusion budget of
them is swapped into K, since each costs a slot of the swap, and at budget 0 not even the
objects' own rows are. The others are kept here, and
:meth:`StaleRows.correct` solves for B with them by iterating on the difference
D = F_current - F_kept (rows of the stale slots only):

    B_S = (I + P_S K) (L'_S + P_S D B),

where (I + P_S K) = (I - P_S F_kept)^{-1} applies K once per iteration (one pass over K per
channel) and D B reads the stale rows against B of every patch (the local set's from the last
iterate, the outside's as the frame has it: the far field's, or 0 without it). From
B^(0) = (I + P_S K) L'_S (the uncorrected answer) each iteration is
B^(n+1) = B^(0) + (I + P_S K) P_S D B^(n), mixed (Anderson) with the last iterates.

Each image is then taken one Gauss-Seidel step further on the stale rows, for one product
with D and no pass over K: the kept system that (I + P_S K) solves gives, for y = image and
g = P_S D B^(n), y_s = L'_s + g_s + rho_s F_kept[s, S] y, so the true system's row s at y,
L'_s + rho_s (F_kept[s, S] y + D[s] y), is y_s - g_s + rho_s D[s] y (with y outside S as B
there). Without it the objects' own patches (whose whole rows are in D at budget 0) and the
patches they light passed the residual to each other from pass to pass: after the moves of
bench/objects.py's block 4.6 passes over K per moving frame, 3.5e-5 of max B from the fixed
point; with it 3.0 passes and 1.9e-6 at most (PoCL, 2-core Xeon, 2026-12-03). D holds
what the objects now hide from the stale rows and their object columns' share, and at budget 0
the objects' whole rows too; the coupling through it is weak (light that reaches an object and
comes back), so a few iterations reach the fixed point, which is the solution with every stale
row at the current poses: what refreshing every row would give, without its swap slots. It
stops at :data:`CORRECTION_TOLERANCE` or after :data:`CORRECTION_ITERATIONS` (then
:attr:`StaleRows.converged` is False and the answer is the last iterate's image, from which the
next call goes on). A call after the first starts from the last answer plus the change in
L'_S and folds B^(0) into the first image, B^(1) = (I + P_S K) (L'_S + P_S D x), so a frame
with no move, no swap and the same far-field mode takes one pass over K in all (two before:
B^(0), then one iteration to confirm), a moving frame one fewer. K itself is never changed, so
a pose that comes back still gives back the same K.
"""

from __future__ import annotations

import os

import numpy as np
import scipy.sparse as sp

from ..anderson import Anderson
from ..colproduct import rows_product
from ..errors import InvalidInputError

__all__ = ["StaleRows", "rows_minus", "CORRECTION_TOLERANCE", "CORRECTION_ITERATIONS", "PARALLEL_ENTRIES"]

#: Stop when an iteration changes B on the local set by at most this much of its max. After the
#: moves of bench/objects.py's block at budget 0 (with the Gauss-Seidel step): 3 passes over K
#: per moving frame at 1e-4, 2-3 at 1e-3, whose answers are at most 1.9e-6 and 4.4e-5 of max B
#: from the fixed point (PoCL, 2-core Xeon, 2026-12-03): half a pass is not worth 20x.
CORRECTION_TOLERANCE = 1e-4
#: The most iterations per :meth:`StaleRows.correct` (each one pass over K per channel; a call
#: that starts from B^(0) takes one pass more for it).
CORRECTION_ITERATIONS = 8
#: Earlier iterates that Anderson mixing combines (:class:`~pydynrad.anderson.Anderson`). After the
#: moves of bench/objects.py's block at budget 0 (its own rows among the stale ones) plain
#: iteration took 4-7 passes over K (6.1 on average over 8 moves), mixing 4-5 (4.9) at depth 3,
#: the same at 5, 5.4 at 1 (PoCL, AMD EPYC Zen 3, 2026-12-02).
ANDERSON_DEPTH = 3


#: Entries from which :func:`rows_minus` splits its merge over the cores (a move's ~430k on the
#: bench's Cornell box: 2.2 ms on one core of the Xeon).
PARALLEL_ENTRIES = 50_000


def rows_minus(rows, kept: sp.csr_matrix, slots: np.ndarray) -> sp.csr_matrix:
    """(r, N) ``rows - kept[slots]``, exact zeros dropped: ``rows`` (r, N) CSR, or a sequence of
    CSR blocks of N columns stacked in order (not copied into one), ``kept`` (M, N) CSR,
    ``slots`` (r,) rows of ``kept``. A native merge of each row with its kept row, read in place
    (``csrc/poserows.c``), in parts of about equal entries on the cores at once from
    :data:`PARALLEL_ENTRIES` entries (one after another on a pool thread,
    :func:`~pydynrad.hostthreads.map_parts`); where a row of either is out of column order, both
    are sorted first (a copy)."""
    from .. import _poserows
    from ..hostthreads import cores, map_parts, row_parts
    from .moves import native_csr, native_spans

    blocks = [sp.csr_matrix(rows)] if sp.issparse(rows) else [sp.csr_matrix(b) for b in rows]
    kept = sp.csr_matrix(kept)
    n_rows = sum(b.shape[0] for b in blocks)
    if any(b.shape[1] != kept.shape[1] for b in blocks):
        raise InvalidInputError(f"rows of {[b.shape[1] for b in blocks]} columns and kept rows {kept.shape} differ in columns")
    slots = np.ascontiguousarray(slots, np.int64)
    if slots.shape != (n_rows,):
        raise InvalidInputError(f"slots must name one kept row per row ({n_rows}); got shape {slots.shape}")
    if len(slots) and (slots.min() < 0 or slots.max() >= kept.shape[0]):
        raise InvalidInputError(f"slots must lie in [0, {kept.shape[0]}) (the kept rows); got {slots.min()}..{slots.max()}")
    k_csr, k_len = native_csr(kept), np.diff(kept.indptr)
    split = cores() if sum(b.nnz for b in blocks) >= PARALLEL_ENTRIES else 1

    def merge(task):
        (starts, ends, indices, data), sl = task
        most = int((ends - starts).sum() + k_len[sl].sum())
        # Only D's entries are written, and a zero at the index after them: the rest of the bound
        # is not touched (no page of it faulted in).
        indptr, out_i, out_d = np.empty(len(sl) + 1, np.int64), np.empty(most, np.int32), np.empty(most)
        nnz = _poserows.difference(starts, ends, indices, data, *k_csr, sl, indptr, out_i, out_d)
        return None if nnz < 0 else (indptr, out_i[:nnz], out_d[:nnz])

    def tasks():
        first = 0
        for b in blocks:
            spans = native_spans(b)
            for a, z in row_parts(b.indptr, split):
                yield tuple(x[a:z] for x in spans[:2]) + spans[2:], slots[first + a:first + z]
            first += b.shape[0]

    parts = map_parts(merge, tasks())
    if not parts:
        return sp.csr_matrix((0, kept.shape[1]))
    if any(p is None for p in parts):  # a row out of column order (scipy leaves sums of CSR matrices unsorted)
        blocks, kept = [_canonical(b) for b in blocks], _canonical(kept)
        k_csr, k_len = native_csr(kept), np.diff(kept.indptr)  # merge() reads the sorted ones
        parts = map_parts(merge, tasks())
    # One copy of the parts' entries into D (scipy's vstack of the parts' matrices took 0.24 ms of
    # a move's 2 ms merge on the bench's Cornell box).
    first = np.cumsum([0] + [len(p[1]) for p in parts])
    indptr = np.concatenate([[0]] + [p[0][1:] + f for p, f in zip(parts, first)])
    return sp.csr_matrix((np.concatenate([p[2] for p in parts]), np.concatenate([p[1] for p in parts]), indptr),
                         shape=(n_rows, kept.shape[1]))


def _canonical(m: sp.csr_matrix) -> sp.csr_matrix:
    """A copy of ``m`` with each row's columns in increasing order, duplicates summed."""
    m = m.copy()
    m.sum_duplicates()
    return m


def _stale_difference(blocks: list[sp.csr_matrix], kept: sp.csr_matrix, held: np.ndarray):
    """(slots, D): the rows of ``held`` whose ``blocks`` differ from ``kept[held]``, and the
    difference. On a pool thread the merge's parts run one after another in it: one core, the
    frame goes on with the other."""
    delta = rows_minus(blocks, kept, held)
    stale = np.diff(delta.indptr) > 0
    return held[stale], (delta if stale.all() else delta[stale])


def _take(blocks: list[sp.csr_matrix], keep: np.ndarray) -> list[sp.csr_matrix]:
    """The rows ``keep`` (increasing) of the blocks stacked in order, as blocks: a block kept
    whole is not copied."""
    out, first = [], 0
    for b in blocks:
        sel = keep[(keep >= first) & (keep < first + b.shape[0])] - first
        if len(sel) == b.shape[0]:
            out.append(b)
        elif len(sel):
            out.append(b[sel])
        first += b.shape[0]
    return out


class StaleRows:
    """The rows at the current poses of the local slots whose rows in K are stale.

    ``held`` (h,) slot indices (in the order put) and ``current`` (h, N) sparse: their rows at
    the current poses (held as the blocks put, stacked only when asked for: a stack copied the
    ~430k entries of a move at budget 0 for a merge that reads them where they are);
    ``slots`` (n,) those of them whose rows differ from K's, and ``delta`` (n, N) the
    difference, current rows minus the rows K was built from (:meth:`update`, after every
    change of either). A held row equal to K's is not stale (not in ``slots``) but stays held:
    dropping it would copy every other held row.

    :meth:`update` computes D on a host thread and returns: the frame's work up to its
    correction (the lights' direct light and the far field's, mostly on the device) goes on
    meanwhile, and whatever reads ``slots`` or ``delta`` waits for it (a move's merge, 2-3 ms on
    the 2-core Xeon, was the frame's last host-only stretch before radiosity's device work).
    """

    def __init__(self, n_patches: int) -> None:
        self.n_patches = int(n_patches)
        self._pending = None
        self._failed: BaseException | None = None  # what the last update's D raised, raised again on every read
        self.clear()

    def clear(self) -> None:
        self._settle(reading=False)
        self._failed = None
        self.held = np.empty(0, np.int64)
        self._blocks: list[sp.csr_matrix] = []  # the rows of held, stacked in order
        self._slots = np.empty(0, np.int64)
        self._delta = sp.csr_matrix((0, self.n_patches))
        self.iterations = 0  # passes over K of the last correct() (its start's included)
        self.converged = True  # whether the last correct() reached CORRECTION_TOLERANCE
        self._last: np.ndarray | None = None  # (N, 3) the last correct()'s B, per patch (where _known)
        self._known = np.zeros(0, bool)
        self._last_LS: np.ndarray | None = None  # (N, 3) the light it solved for, per patch (where _known)
        self._last_outside = False  # and whether with the far field outside

    def _settle(self, reading: bool = True) -> None:
        """Wait for the D that :meth:`update` is computing, if any (computed here in a process
        forked meanwhile: the thread computing it is not in the child). If computing it raised,
        every read raises that again until the next :meth:`update` or :meth:`clear`: no read
        gets an older D that does not match the rows held."""
        if self._pending is not None:
            (pid, pending, args), self._pending = self._pending, None
            try:
                self._slots, self._delta = pending.result() if pid == os.getpid() else _stale_difference(*args)
            except Exception as e:  # kept: every read raises it
                self._failed = e
        if reading and self._failed is not None:
            raise self._failed

    @property
    def slots(self) -> np.ndarray:
        """(n,) the held slots whose rows differ from K's."""
        self._settle()
        return self._slots

    @property
    def delta(self) -> sp.csr_matrix:
        """(n, N) CSR: their current rows minus the rows K was built from."""
        self._settle()
        return self._delta

    def __len__(self) -> int:
        return len(self.slots)

    @property
    def current(self) -> sp.csr_matrix:
        """(h, N) CSR: the held rows at the current poses, in the order of :attr:`held`."""
        if len(self._blocks) != 1:
            self._blocks = [sp.vstack(self._blocks, format="csr") if self._blocks else sp.csr_matrix((0, self.n_patches))]
        return self._blocks[0]

    @property
    def nbytes(self) -> int:
        """Host bytes of the rows and D held."""
        return self.held.nbytes + self.slots.nbytes + sum(m.data.nbytes + m.indices.nbytes + m.indptr.nbytes
                                                          for m in (*self._blocks, self.delta))

    def put(self, slots: np.ndarray, *rows: sp.csr_matrix) -> None:
        """Slots ``slots`` now have current rows ``rows`` (one or more blocks, stacked in order,
        replacing any held for them); call :meth:`update` before the next :meth:`correct`."""
        self._settle(reading=False)  # one D in the making at a time
        slots = np.asarray(slots, np.int64)
        if slots.shape != (sum(r.shape[0] for r in rows),):
            raise InvalidInputError(f"put needs one slot per row; got {slots.shape} for {sum(r.shape[0] for r in rows)} rows")
        keep = np.flatnonzero(~np.isin(self.held, slots))
        self.held = np.concatenate([self.held[keep], slots])
        # Unsorted: a sort would copy every row again.
        self._blocks = _take(self._blocks, keep) + [sp.csr_matrix(r) for r in rows if r.shape[0]]

    def drop(self, slots: np.ndarray) -> None:
        """Slots whose rows in K are current again (refreshed by a swap, or holding another
        patch): nothing to correct there."""
        keep = np.flatnonzero(~np.isin(self.held, slots))
        if len(keep) < len(self.held):
            self.held, self._blocks = self.held[keep], _take(self._blocks, keep)
        keep = np.flatnonzero(~np.isin(self.slots, slots))
        if len(keep) < len(self._slots):
            self._slots, self._delta = self._slots[keep], self._delta[keep]

    def update(self, kept: sp.csr_matrix) -> None:
        """D = current rows - ``kept[held]`` (``kept`` (M, N): the rows K was built from, not
        changed in place afterwards), and the slots where they differ; computed on a host
        thread (class docstring)."""
        from ..hostthreads import pool

        self._settle(reading=False)
        self._failed = None
        # What the merge would refuse, refused here, where the caller is.
        if any(b.shape[1] != kept.shape[1] for b in self._blocks):
            raise InvalidInputError(f"held rows and kept rows {kept.shape} differ in columns")
        if len(self.held) and (self.held.min() < 0 or self.held.max() >= kept.shape[0]):
            raise InvalidInputError(f"held slots must lie in [0, {kept.shape[0]}) (the kept rows)")
        args = (self._blocks, kept, self.held)
        self._pending = (os.getpid(), pool().submit(_stale_difference, *args), args)

    def correct(self, solve_kept, LS: np.ndarray, B: np.ndarray, S: np.ndarray, albedo: np.ndarray,
                outside: bool) -> np.ndarray:
        """(M, 3) B on the local set with the stale rows at the current poses (module docstring).

        ``solve_kept(X)``: X + P_S K X for X (M, 3); ``LS`` (M, 3): the light to solve for on the
        local set ``S``; ``B`` (N, 3): the frame's B outside the local set; ``albedo`` (N, 3);
        ``outside``: whether B outside the local set is part of the solution (the far field's),
        else it is not gathered.

        After a first call, each starts from the last answer plus the change in the light to solve
        for, per patch (a move changes L'_S where the objects cast and catch light; a patch new to
        S starts from B as given, or from its L'_S without the far field), and its first image is
        solve_kept(LS + P_S D x): B^(0) takes no pass of its own, and a frame with no move, no
        swap and the same far-field mode takes one pass over K in all. The first call starts from
        B^(0); one with the far field switched (``outside`` not the last call's) from B^(0) plus
        the last call's correction, last + (I + P_S K)(LS - last LS), one pass either way."""
        x = B.copy() if outside else np.zeros_like(B)
        passes = 1
        if self._last is None:
            x[S] = solve_kept(LS)
        elif self._last_outside != outside:
            x[S] = self._last[S] + solve_kept(LS - self._last_LS[S])
        else:
            passes = 0
            known = self._known[S]
            x[S[known]] = self._last[S[known]] + (LS[known] - self._last_LS[S[known]])
            if not outside:
                x[S[~known]] = LS[~known]
        slots, delta = self.slots, self.delta
        rho = albedo[S[slots]].astype(np.float64)
        g = np.zeros_like(LS, dtype=np.float64)
        mixing = Anderson(ANDERSON_DEPTH)
        for it in range(1, CORRECTION_ITERATIONS + 1):
            g[slots] = rho * rows_product(delta, x)
            new = solve_kept(LS + g)
            # The stale rows gather D at the new values (module docstring): one product with D.
            x_new = x.copy()
            x_new[S] = new
            new[slots] += rho * rows_product(delta, x_new) - g[slots]
            residual = new - x[S]
            scale = max(float(np.abs(new).max()), 1e-300)
            self.converged = float(np.abs(residual).max()) <= CORRECTION_TOLERANCE * scale
            if self.converged or it == CORRECTION_ITERATIONS:
                x[S] = new  # an evaluated image, never an unchecked mixed point
                break
            x[S] = mixing.next(new, residual)
        self.iterations = passes + it
        if self._last is None:
            self._last, self._last_LS, self._known = np.zeros_like(x), np.zeros_like(x), np.zeros(len(x), bool)
        self._last[S], self._known[S] = x[S], True
        self._last_LS[S], self._last_outside = LS, outside
        return x[S]
