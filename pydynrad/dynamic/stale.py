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
patches they light passed the residual to each other from pass to pass, which took more passes over K to a worse answer than with the step
(docs/decisions/0025-moving-objects-rows-and-correction.md). D holds
what the objects now hide from the stale rows and their object columns' share, and at budget 0
the objects' whole rows too; the coupling through it is weak (light that reaches an object and
comes back), so a few iterations reach the fixed point, which is the solution with every stale
row at the current poses: what refreshing every row would give, without its swap slots. It
stops where the answer's estimated distance from that fixed point is at most the tolerance
(:data:`CORRECTION_TOLERANCE` of max B by default): for an iteration that contracts by q, an
image lies within q / (1 - q) of its step from the fixed point, and q is estimated by the
ratio of the last two steps (:func:`_error_estimate`). Or it stops after
:data:`CORRECTION_ITERATIONS` (then :attr:`StaleRows.converged` is False and the answer is the
last iterate's image, from which the next call goes on). A call after the first starts from the last answer plus the change in
L'_S and folds B^(0) into the first image, B^(1) = (I + P_S K) (L'_S + P_S D x), so a frame
with no move, no swap and the same far-field mode takes one pass over K in all (two before:
B^(0), then one iteration to confirm), a moving frame one fewer. K itself is never changed, so
a pose that comes back still gives back the same K.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import _poserows
from ..errors import InvalidInputError
from ..host.anderson import Anderson
from ..host.colproduct import rows_product
from ..host.threads import cores, map_parts, row_parts
from .poserows import PARALLEL_ENTRIES, kept_slots, native_csr, native_spans, stacked_rows

__all__ = ["StaleRows", "rows_minus", "CORRECTION_TOLERANCE", "CORRECTION_ITERATIONS"]

#: Stop where the answer's estimated distance from the fixed point on the local set is at most
#: this much of its max (:func:`_error_estimate`). A tighter stop buys nothing visible: each
#: further pass over K is a share of a moving frame, and the rows the correction solves with
#: are themselves much further than this from a full solve
#: (docs/decisions/0025-moving-objects-rows-and-correction.md). ``MovingObjects(correction_tolerance=...)`` sets it per solution.
CORRECTION_TOLERANCE = 2e-4
#: The ratio of successive steps below which :meth:`StaleRows.correct` takes the iteration as
#: contracting by that ratio, and estimates an answer's error by it (:func:`_error_estimate`).
CONTRACTION_LIMIT = 0.5
#: The most iterations per :meth:`StaleRows.correct` (each one pass over K per channel; a call
#: that starts from B^(0) takes one pass more for it).
CORRECTION_ITERATIONS = 8
#: Earlier iterates that Anderson mixing combines (:class:`~pydynrad.host.anderson.Anderson`): after a move,
#: mixing takes fewer passes over K than plain iteration; a depth of 5 saves no more than 3, a
#: depth of 1 less (docs/decisions/0025-moving-objects-rows-and-correction.md).
ANDERSON_DEPTH = 3


def rows_minus(rows, kept: sp.csr_matrix, slots: np.ndarray) -> sp.csr_matrix:
    """(r, N) ``rows - kept[slots]``, exact zeros dropped: ``rows`` (r, N) CSR, or a sequence of
    CSR blocks of N columns stacked in order (not copied into one), ``kept`` (M, N) CSR,
    ``slots`` (r,) rows of ``kept``. A native merge of each row with its kept row, read in place
    (``csrc/poserows.c``), in parts of about equal entries on the cores at once from
    :data:`PARALLEL_ENTRIES` entries (one after another on a pool thread,
    :func:`~pydynrad.host.threads.map_parts`); where a row of either is out of column order, both
    are sorted first (a copy)."""

    blocks = [sp.csr_matrix(rows)] if sp.issparse(rows) else [sp.csr_matrix(b) for b in rows]
    kept = sp.csr_matrix(kept)
    n_rows = sum(b.shape[0] for b in blocks)
    if any(b.shape[1] != kept.shape[1] for b in blocks):
        raise InvalidInputError(
            f"rows of {[b.shape[1] for b in blocks]} columns and kept rows {kept.shape} differ in columns"
        )
    slots = kept_slots(slots, n_rows, kept.shape[0])
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
                yield tuple(x[a:z] for x in spans[:2]) + spans[2:], slots[first + a : first + z]
            first += b.shape[0]

    parts = map_parts(merge, tasks())
    if not parts:
        return sp.csr_matrix((0, kept.shape[1]))
    if any(p is None for p in parts):  # a row out of column order (scipy leaves sums of CSR matrices unsorted)
        blocks, kept = [_canonical(b) for b in blocks], _canonical(kept)
        k_csr, k_len = native_csr(kept), np.diff(kept.indptr)  # merge() reads the sorted ones
        parts = map_parts(merge, tasks())
    return stacked_rows(parts, kept.shape[1])


def _canonical(m: sp.csr_matrix) -> sp.csr_matrix:
    """A copy of ``m`` with each row's columns in increasing order, duplicates summed."""
    m = m.copy()
    m.sum_duplicates()
    return m


def _error_estimate(change: float, last: float) -> float:
    """How far the image whose step from the last iterate was ``change`` (max norm) lies from the
    fixed point, estimated, the step before having been ``last``: for a map that contracts by q,
    at most q / (1 - q) times the step, with q estimated as change / last where that shows a
    contraction by :data:`CONTRACTION_LIMIT` or more; else the step itself (the first, or no
    clear contraction). An estimate, not a bound: the ratio of two steps is the contraction
    along the last direction only, and after Anderson mixing (from the third step) it measures
    the mixing's gain as well. After the bench's moves (stopping at the second step, whose ratio
    is of two plain images), and on random contractions mixed by Anderson over more steps, the
    true distance stayed within a small multiple of the estimate
    (docs/decisions/0025-moving-objects-rows-and-correction.md)."""
    q = change / last if 0.0 < last < np.inf else np.inf
    return q / (1.0 - q) * change if q <= CONTRACTION_LIMIT else change


class StaleRows:
    """The local slots whose rows in K are stale, and how: ``slots`` (n,) and ``delta`` (n, N)
    CSR, D = their rows at the current poses minus the rows K was built from (the kept rows).

    Only D is held, never the rows at the pose: a move at budget 0 makes D without them
    (:meth:`~pydynrad.dynamic.moves.WorldRows.differences`), and a rebuild takes them as the kept
    rows plus D (:meth:`current`). A slot whose row at the pose equals its kept row is not
    stale and not held. Where the kept rows change under the held slots (a move that swaps rows
    in, :meth:`rebase`), D follows them, so it always holds against K as it is.
    """

    def __init__(self, n_patches: int) -> None:
        self.n_patches = int(n_patches)
        self.clear()

    def clear(self) -> None:
        self.slots = np.empty(0, np.int64)
        self.delta = sp.csr_matrix((0, self.n_patches))
        # Per slot, the pose (WorldRows.pose) whose rows minus the kept rows its D is, bit for bit
        # as the pass that put it made it (an empty D not held), or -1: for since().
        self._made_at = np.full(0, -1, np.int64)
        self.iterations = 0  # passes over K of the last correct() (its start's included)
        self.converged = True  # whether the last correct() reached its tolerance
        self._last: np.ndarray | None = None  # (N, 3) the last correct()'s B, per patch (where _known)
        self._known = np.zeros(0, bool)
        self._last_LS: np.ndarray | None = None  # (N, 3) the light it solved for, per patch (where _known)
        self._last_outside = False  # and whether with the far field outside

    def __len__(self) -> int:
        return len(self.slots)

    def current(self, kept: sp.csr_matrix) -> tuple[np.ndarray, sp.csr_matrix]:
        """(slots, their rows at the current poses): ``kept[slots] + delta`` for the kept rows
        ``kept`` (M, N) of K, zeros dropped."""
        rows = sp.csr_matrix(sp.csr_matrix(kept)[self.slots] + self.delta)
        rows.eliminate_zeros()
        return self.slots, rows

    @property
    def nbytes(self) -> int:
        """Host bytes of the slots and D held."""
        return self.slots.nbytes + self.delta.data.nbytes + self.delta.indices.nbytes + self.delta.indptr.nbytes

    def put(self, slots: np.ndarray, *deltas: sp.csr_matrix, pose: int | None = None) -> None:
        """Slots ``slots`` (k,) now have rows at the current poses that differ from their kept rows
        by ``deltas`` (one or more blocks of CSR rows of N columns, k rows in all, in order),
        replacing what was held for them; rows that are empty leave their slots current. One
        copy of D's rows at most (each held row is put once per move). ``pose``: the pose whose
        rows minus the kept rows ``deltas`` are exactly, as made (:meth:`since`), if any."""
        slots = np.asarray(slots, np.int64)
        blocks = [sp.csr_matrix(d) for d in deltas]
        if any(b.shape[1] != self.n_patches for b in blocks) or sum(b.shape[0] for b in blocks) != len(slots):
            raise InvalidInputError(
                f"put needs one row of {self.n_patches} columns per slot ({len(slots)}); got "
                f"{[b.shape for b in blocks]}"
            )
        if len(np.unique(slots)) != len(slots):
            raise InvalidInputError("put needs each slot once: a slot's row differs from its kept row in one way")
        given = slots
        self._made_slots(given)[given] = -1  # until the new D is held (a put that fails leaves no pose on the old)
        keep = ~np.isin(self.slots, slots)
        if keep.any():
            blocks.insert(0, self.delta if keep.all() else self.delta[np.flatnonzero(keep)])
            slots = np.concatenate([self.slots[keep], slots])
        blocks = [b for b in blocks if b.shape[0]] or [sp.csr_matrix((0, self.n_patches))]
        delta = (
            blocks[0]
            if len(blocks) == 1
            else stacked_rows(
                [(b.indptr, b.indices[: b.indptr[-1]], b.data[: b.indptr[-1]]) for b in blocks], self.n_patches
            )
        )
        stale = np.diff(delta.indptr) > 0
        if not stale.all():  # the empty rows go from the row pointers alone: they hold no entries
            nnz = delta.indptr[-1]
            delta = sp.csr_matrix(
                (delta.data[:nnz], delta.indices[:nnz], np.concatenate([[0], delta.indptr[1:][stale]])),
                shape=(int(stale.sum()), self.n_patches),
            )
            slots = slots[stale]
        self.slots, self.delta = slots, delta
        if pose is not None:
            self._made_at[given] = int(pose)

    def _made_slots(self, slots: np.ndarray) -> np.ndarray:
        """The per-slot poses of :meth:`since`, grown to hold ``slots``."""
        need = int(slots.max()) + 1 if len(slots) else 0
        if need > len(self._made_at):
            self._made_at = np.concatenate([self._made_at, np.full(need - len(self._made_at), -1, np.int64)])
        return self._made_at

    def since(self, slots: np.ndarray, pose: int) -> tuple[np.ndarray, sp.csr_matrix, np.ndarray]:
        """For each of ``slots`` (k,): whether its D was put for ``pose`` and has held since against
        the same kept rows; D as held; and the row of D that is its own (-1: none held, its D
        empty). For :meth:`~pydynrad.dynamic.moves.WorldRows.differences`."""
        slots = np.asarray(slots, np.int64)
        made = self._made_slots(slots)
        row = np.full(len(made), -1, np.int64)
        row[self.slots] = np.arange(len(self.slots))
        return made[slots] == pose, self.delta, row[slots]

    def drop(self, slots: np.ndarray) -> None:
        """Slots whose rows in K are current again (refreshed by a swap, or holding another
        patch): nothing to correct there."""
        slots = np.asarray(slots, np.int64)
        self._made_slots(slots)[slots] = -1
        keep = np.flatnonzero(~np.isin(self.slots, slots))
        if len(keep) < len(self.slots):
            self.slots, self.delta = self.slots[keep], self.delta[keep]

    def rebase(self, before: sp.csr_matrix, after: sp.csr_matrix) -> None:
        """The kept rows changed from ``before`` to ``after`` (M, N): D of every held slot follows,
        D + before[slots] - after[slots], so the rows at the pose stay what they were."""
        if not len(self.slots):
            return
        change = rows_minus(sp.csr_matrix(after)[self.slots], before, self.slots)
        self.put(self.slots, sp.csr_matrix(self.delta - change))  # no pose: D is no longer as a pass made it

    def correct(
        self,
        solve_kept,
        LS: np.ndarray,
        B: np.ndarray,
        S: np.ndarray,
        albedo: np.ndarray,
        outside: bool,
        tolerance: float = CORRECTION_TOLERANCE,
    ) -> np.ndarray:
        """(M, 3) B on the local set with the stale rows at the current poses (module docstring).

        ``solve_kept(X)``: X + P_S K X for X (M, 3); ``LS`` (M, 3): the light to solve for on the
        local set ``S``; ``B`` (N, 3): the frame's B outside the local set; ``albedo`` (N, 3);
        ``outside``: whether B outside the local set is part of the solution (the far field's),
        else it is not gathered; ``tolerance``: it stops where the answer's estimated distance
        from the fixed point (:func:`_error_estimate`) is at most this fraction of its max.

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
        last_change = np.inf
        for it in range(1, CORRECTION_ITERATIONS + 1):
            g[slots] = rho * rows_product(delta, x)
            new = solve_kept(LS + g)
            # The stale rows gather D at the new values (module docstring): one product with D.
            x_new = x.copy()
            x_new[S] = new
            new[slots] += rho * rows_product(delta, x_new) - g[slots]
            residual = new - x[S]
            scale = max(float(np.abs(new).max()), 1e-300)
            change = float(np.abs(residual).max())
            self.converged = _error_estimate(change, last_change) <= tolerance * scale
            last_change = change
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
