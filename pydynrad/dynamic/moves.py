"""Moving rigid objects in a dynamic solution: their rows, the rows they change, and the swap.

A move of objects O is a batched swap with I = J = the slots of O's patches plus the slots of
the local patches whose rows are refreshed (the occlusion budget): remove them with their old
rows and add them back with new ones (docs/design.md, 'Moving objects', 'Batched swap'):

* O's rows: one hemicube per patch at the new pose;
* the columns F[s, O] of the other local patches: by reciprocity, A_s F[s, o] = A_o F[o, s];
* refreshed rows: hemicubes of the local patches that see the most of O's old and new
  bounding spheres (their view of the static scene changed: O now hides or uncovers parts);
* rows left stale whose sum the new object columns would push above 1: those columns are
  scaled down to fill the row to 1 (:func:`~pydynrad.dynamic.poserows.stale_rows`); being in the objects' columns, they
  need no slot of their own in the swap. With a static F their rows at the new poses are made
  too (:meth:`WorldRows.refresh`) and B is corrected for them (:mod:`pydynrad.dynamic.stale`).

The swap size bounds one batch; larger sets go in chunks, each one exact on its own: after
chunk c the device K is that of the form factors whose entries in a row or column of the
chunks done so far are new and the rest old, which is what the next chunk removes from.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..errors import InvalidInputError, PydynradError
from ..host.colproduct import rows_product
from ..host.threads import pool
from ..rows.sources import HemicubeRows
from .localrows import LocalRows
from .occlusion import GATHER_ALL_OUTSIDE, VIEW_FORM_FACTOR, hidden_entries, refresh_order, sphere_form_factor
from .poserows import Since, at_pose, difference_at_pose, in_order, reciprocal_columns
from .poses import PoseRows
from .stale import CORRECTION_TOLERANCE, rows_minus

__all__ = ["MovingObjects", "WorldRows"]


@dataclass(frozen=True)
class MovingObjects:
    """Rigid objects that move through a static scene, and how each move refreshes the rows it changes.

    Give it to :class:`~pydynrad.DynamicRadiosity` as ``objects=`` (a plain sequence of
    :class:`~pydynrad.RigidObject` means these defaults). See docs/design.md, 'Moving objects'.

    Parameters
    ----------
    objects : sequence of pydynrad.RigidObject
        The objects (exact mode only). Their patches follow the scene's N, in order, and are
        always local (their count must not exceed M).
    occlusion : int, None or "auto"
        Per move, refresh the rows of at most this many other local patches (0: none, the
        cheapest; None: every one that may see the moved objects' old or new bounding spheres):
        with a static F those whose gathered light the move changes most, else those that see
        the most of the spheres. "auto" (the default): 0 with a static F and
        ``occlusion_correction`` (there every budget gives the same error, and a refresh only
        costs its swap), else :data:`pydynrad.dynamic.radiosity.DEFAULT_OCCLUSION`.
    occlusion_correction : bool
        With a static ``form_factors``: make the row at the new poses of every local patch that
        may see a moved object (from the static F, no hemicube), swap the ``occlusion`` budget of
        them into K and correct :meth:`~pydynrad.DynamicRadiosity.radiosity` for the rest by a
        few iterations with K (:mod:`pydynrad.dynamic.stale`; about as accurate as refreshing
        every row, for no swap slots). At ``occlusion=0`` a move swaps nothing, not even the
        objects' own rows: they are corrected for like the others, K stays as built, and
        :meth:`~pydynrad.DynamicRadiosity.refresh` takes them all in. False: the rows left stale
        are used as they are (at ``occlusion=0`` the cheapest move). No effect with hemicube rows
        (``form_factors=None``).
    correction_tolerance : float
        Where that correction stops: at an estimated distance from its fixed point (the answer
        with every stale row at the current poses; an estimate from the ratio of its last two
        steps) of at most this fraction of max B, in (0, 1)
        (:data:`pydynrad.dynamic.stale.CORRECTION_TOLERANCE` by default).
    poses : PoseRows, optional
        Rows precomputed for configurations of the objects known in advance
        (:func:`pydynrad.precompute.precompute_poses`, at the solution's ``resolution``): a move
        to one of them takes its rows from there instead of hemicubes (with a static
        ``form_factors``, also the static rows it holds, instead of their estimate from F).
    """

    objects: Sequence
    occlusion: int | str | None = "auto"
    occlusion_correction: bool = True
    correction_tolerance: float = CORRECTION_TOLERANCE
    poses: PoseRows | None = None


class WorldRows:
    """Rows of F for a static scene with objects (a :class:`~pydynrad.rows.sources.RowSource`).

    Object patches' rows are hemicubes of the current world scene (or stored in ``poses``).
    Static rows come from ``static_ff`` (the static scene's (N, N) F or row source) with the
    entries the objects hide dropped (:func:`~pydynrad.dynamic.occlusion.hidden_entries`), their object columns by
    reciprocity from the objects' current rows, and capped to a sum of 1 (:func:`at_pose`),
    except those ``poses`` holds for the current configuration (hemicubes of the world there);
    with ``static_ff=None`` they are hemicubes of the world too, and exact at the current poses.
    """

    def __init__(
        self,
        world,
        n_static: int,
        objects,
        static_ff,
        static_scene,
        resolution: int,
        device,
        poses: PoseRows | None = None,
    ) -> None:
        if poses is not None:
            if not isinstance(poses, PoseRows):
                raise InvalidInputError(
                    f"poses= must be PoseRows (precompute_poses, stored_poses); got {type(poses).__name__}"
                )
            poses.check(static_scene, objects, resolution)
        self.poses = poses
        self.hemicubes = HemicubeRows(world, resolution, device)
        self.device = device
        self.n_patches = len(world)
        self.n_static = int(n_static)
        self.objects_moving = list(objects)
        self.object_patches = np.arange(self.n_static, self.n_patches)
        self.static = None if static_ff is None else LocalRows(static_scene, static_ff, resolution, device)
        self.object_rows: sp.csr_matrix | None = None  # rows of object_patches at the current poses
        self._tracing = None  # a Future of fresh(object_patches) while refresh() traces them (objects() waits)
        self._meanwhile = None  # refresh()'s work to run before objects() first waits for that trace
        self._at_pose: tuple[np.ndarray, sp.csr_matrix] | None = None  # rows made at the current poses (:meth:`_at`)
        self._outside: tuple[np.ndarray, sp.csr_matrix] | None = None  # (patches, their rows) last gathered
        # Where the objects were when the far field's coarse level was made (the first poses).
        self._first_spheres = [o.bounding_sphere() for o in self.objects_moving]
        self._in_view: np.ndarray | None = None  # (N,) bool, per pose: :meth:`in_view`
        self._first_view: np.ndarray | None = None  # its part for the first poses
        self.pose = 0  # moves so far: the number of the poses the world is at
        # (pose, hidden over the static F's entries, capped (n_static,) bool) of the last pass of
        # :meth:`differences` over the pre-test: what the next pose's differences start from
        # (a byte per entry of F held between moves: 0.45 MB on the bench's box, 35 MB on the village).
        self._made: tuple[int, np.ndarray, np.ndarray] | None = None
        self._row_sums: np.ndarray | None = None  # (n_static,) the static F's row sums, once

    @property
    def world(self):
        return self.hemicubes.scene

    def move(self, world) -> None:
        """The objects moved: later rows are of ``world`` (the objects' own rows are hemicubes
        when first needed, unless set in :attr:`object_rows`)."""
        self.hemicubes.scene = world
        self.object_rows = None
        self._at_pose, self._outside, self._in_view = None, None, None
        self.pose += 1

    def in_view(self) -> np.ndarray:
        """(N,) bool: the static patches whose view an object changes, by a form factor of at
        least :data:`VIEW_FORM_FACTOR` to its bounding sphere at its current pose or at its
        first (where the far field's coarse level has it; computed once per pose)."""
        if self._first_view is None:  # the first poses' part, once
            self._first_view = self._seeing(self._first_spheres)
        if self._in_view is None:
            self._in_view = self._first_view | self._seeing(
                [o.bounding_sphere(T) for o, T in zip(self.objects_moving, self.world.bvh.transforms)]
            )
        return self._in_view

    def _seeing(self, spheres) -> np.ndarray:
        """(N,) bool: static patches with a form factor (:func:`sphere_form_factor`) of at least
        :data:`VIEW_FORM_FACTOR` to one of ``spheres`` [(centre, radius), ...]."""
        world = self.world
        P, n = world.centers[: self.n_static], world.normals[: self.n_static]
        view = np.zeros(self.n_patches, bool)
        for c, r in spheres:
            view[: self.n_static] |= sphere_form_factor(P, n, c, r) >= VIEW_FORM_FACTOR
        return view

    def gather_outside(self, outside: np.ndarray, L: np.ndarray, B: np.ndarray) -> np.ndarray:
        """(len(outside), 3) B on the patches ``outside`` the local set: ``L + P F B`` with their
        rows at the current poses (``rows``) for those :meth:`gathered` chooses (every one,
        or in a large scene those whose view an object changes, :meth:`in_view`), so the far
        field's patches see the objects where they are, their light and their shadows; ``B`` as
        given (the far field's) for the others, which the objects change by less than
        :data:`VIEW_FORM_FACTOR` of the light around them, as the coarse level's own error does."""
        outside = np.asarray(outside, np.int64)
        chosen = self.gathered(outside)
        near = outside[chosen]
        if self._outside is None or not np.array_equal(self._outside[0], near):
            rows = self.rows(near) if len(near) else sp.csr_matrix((0, self.n_patches))
            self._outside = (near.copy(), rows)
        out = B[outside].copy()
        out[chosen] = L[near] + self.world.albedo[near].astype(np.float64) * rows_product(self._outside[1], B)
        return out

    def gathered(self, outside: np.ndarray) -> np.ndarray:
        """(len(outside),) bool: which of the patches ``outside`` the local set
        :meth:`gather_outside` gathers at the poses. Every one while they are at most
        :data:`GATHER_ALL_OUTSIDE` times the local set (the gather is then a final gather of
        the far field too, cheap beside the frame), else those :meth:`in_view`."""
        outside = np.asarray(outside, np.int64)
        if len(outside) <= GATHER_ALL_OUTSIDE * (self.n_patches - len(outside)):
            return np.ones(len(outside), bool)
        return self.in_view()[outside]

    def objects(self) -> sp.csr_matrix:
        """The objects' rows at the current poses (computed once per pose)."""
        if self._tracing is not None:
            meanwhile, self._meanwhile = self._meanwhile, None
            if meanwhile is not None:
                meanwhile()
            tracing, self._tracing = self._tracing, None
            self.object_rows = tracing.result()[0]
        if self.object_rows is None:
            self.object_rows = self.fresh(self.object_patches)[0]
        return self.object_rows

    def fresh(self, idx) -> tuple[sp.csr_matrix, int]:
        """Rows ``idx`` of the world as it is: from ``poses`` where it holds them for the current
        transforms, else hemicubes; and how many hemicubes that took."""
        return self.fresh_queued(idx)()

    def fresh_queued(self, idx):
        """:meth:`fresh` with its hemicubes queued on the device now: a callable (to call once,
        from any thread) that waits for them and returns what :meth:`fresh` does."""
        idx = np.asarray(idx, np.int64)
        stored = self._stored()
        miss = idx if stored is None else idx[~np.isin(idx, stored[0])]
        made = self.hemicubes.queued(miss) if len(miss) else lambda: sp.csr_matrix((0, self.n_patches))
        return lambda: self._stored_or(idx, lambda _: sp.csr_matrix(made(), dtype=np.float64), stored)

    def _stored(self):
        """(patches, rows) that ``poses`` holds for the current transforms, or None."""
        return None if self.poses is None else self.poses.get(self.world.bvh.transforms)

    def _stored_or(self, idx: np.ndarray, make, stored) -> tuple[sp.csr_matrix, int]:
        """Rows ``idx``: those ``stored`` (``poses``'s rows for the current transforms, or None)
        holds from there, the others by ``make(missing indices)``; and how many ``make`` made."""
        if stored is None:
            return make(idx), len(idx)
        patches, rows = stored  # patches sorted (PoseRows.add)
        have = np.isin(idx, patches)
        held = rows[np.searchsorted(patches, idx[have])]
        if have.all():
            return sp.csr_matrix(held, dtype=np.float64), 0
        miss = idx[~have]
        return in_order(held, make(miss), have), len(miss)

    def _at(self, idx: np.ndarray, make, also: np.ndarray | None = None) -> sp.csr_matrix:
        """Rows ``idx``, each made once per pose by ``make(missing indices)`` and kept until the
        next move; rows ``also`` missing are made in the same call, for later. The rows returned
        may share memory with those kept (every caller copies before it changes them)."""
        if self._at_pose is None:
            self._at_pose = (np.full(self.n_patches, -1), sp.csr_matrix((0, self.n_patches)))
        where, held = self._at_pose
        wanted = idx if also is None else np.concatenate([idx, also])
        missing = wanted[where[wanted] < 0]
        if len(missing):
            # In the order asked (first occurrences): the first call after a move then takes its
            # rows as one run of what it made, not a copy through an index.
            miss = missing[np.sort(np.unique(missing, return_index=True)[1])]
            made = sp.csr_matrix(make(miss))  # before the index: a make() that raises leaves it as it was
            where[miss] = held.shape[0] + np.arange(len(miss))
            held = made if not held.shape[0] else sp.vstack([held, made], format="csr")
            self._at_pose = (where, held)
        at = where[idx]
        if len(at) and np.array_equal(at, np.arange(at[0], at[0] + len(at))):  # a view (scipy's slice copies)
            a, z = held.indptr[at[0]], held.indptr[at[0] + len(at)]
            indptr = held.indptr[at[0] : at[0] + len(at) + 1]
            return sp.csr_matrix(
                (held.data[a:z], held.indices[a:z], indptr - a if a else indptr), shape=(len(at), held.shape[1])
            )
        return held[at]

    def _static_rows(self, s: np.ndarray) -> sp.csr_matrix:
        """Rows of static patches ``s`` at the current poses: those ``poses`` holds for them
        (hemicubes of the world there: no estimate, and no pass over their entries), the others
        from the static F (:meth:`_from_static`: patches that cannot see an object there, whose
        pre-test finds nothing to hide)."""
        return self._stored_or(np.asarray(s, np.int64), self._from_static, self._stored())[0]

    def _from_static(self, s: np.ndarray) -> sp.csr_matrix:
        """Rows of static patches ``s`` at the current poses, from the static F (class docstring)."""
        return at_pose(*self._pose_inputs(s))

    def _pose_inputs(self, s: np.ndarray) -> tuple:
        """(rows, hidden, object columns, select): :func:`at_pose`'s inputs for static patches
        ``s``, their rows of the static F read where they lie in an F held in memory (a copy of
        them was a visible share of a move), else fetched from its source."""
        F, select = (self.static.csr, s) if self.static.csr is not None else (self.static.rows(s), np.arange(len(s)))
        world = self.world
        hidden = hidden_entries(
            F, s, world.centers, world.normals, self.objects_moving, world.bvh.transforms, self.device, select
        )
        return (
            F,
            hidden,
            reciprocal_columns(s, self.objects(), self.object_patches, world.areas, self.n_patches),
            select,
        )

    def differences(
        self, s: np.ndarray, kept: sp.csr_matrix, at: np.ndarray, also: np.ndarray | None = None, held=None
    ) -> sp.csr_matrix:
        """(len(s), N) CSR: the rows of static patches ``s`` at the current poses (``rows``)
        minus ``kept[at]`` (``kept`` (M, N), ``at`` (len(s),) its rows). From the static F they
        are never made: :func:`difference_at_pose` merges each with its kept row as it is made
        (writing a move's entries at the pose into fresh memory, then reading them back to merge
        them, was a large share of a moving frame; docs/decisions/0033-native-host-passes.md). Rows ``also``
        missing at the pose are made in the same pass (one pre-test of both) and kept for the
        pose, as ``rows`` keeps them (distinct patches). Rows ``poses`` holds come from
        there, merged.

        ``held``: the stale rows (:class:`~pydynrad.dynamic.stale.StaleRows`) whose D, where put
        at the last pose by this pass and held since against the same kept rows, the pass starts
        from (:class:`Since`): it then reads the rows' hidden flags then and now, not their
        entries."""
        s, at = np.asarray(s, np.int64), np.asarray(at, np.int64)
        also = np.empty(0, np.int64) if also is None else np.asarray(also, np.int64)
        if len(np.unique(also)) != len(also):
            raise InvalidInputError("differences() needs distinct patches in also")
        if self._stored() is not None:
            return rows_minus(self._at(s, self._static_rows, also), kept, at)
        if self._at_pose is not None:  # rows already made at this pose are not made again
            also = also[self._at_pose[0][also] < 0]
        both = np.concatenate([s, also])
        F, hidden, recip, select = self._pose_inputs(both)
        if len(also):

            def made(miss):
                # _at() asks for all of them, in order: distinct, none at the pose yet (a dict from
                # patch to place in both, for any order, cost a move far more than this check).
                if not np.array_equal(miss, also):
                    raise PydynradError("differences(): the outside rows asked for are not those made")
                return at_pose(F, hidden, recip[len(s) :], select[len(s) :])

            self._at(also, made)
        since = self._since(s, at, held) if F is self.static.csr else None
        D, capped = difference_at_pose(F, hidden, recip[: len(s)], kept, at, select[: len(s)], since)
        if F is self.static.csr:
            flags = np.ones(self.n_static, bool)  # rows not made here: never started from
            flags[s] = capped
            self._made = (self.pose, hidden, flags)
        return D

    def _since(self, s: np.ndarray, at: np.ndarray, held) -> Since | None:
        """What :meth:`differences` at this pose starts from for static patches ``s`` in slots
        ``at``: their D that ``held`` put at the last pose, where that pose's pass made their
        rows uncapped."""
        made = self._made  # over the same static F's entries as this pose's mask
        if held is None or made is None or made[0] != self.pose - 1:
            return None
        flags, last, last_row = held.since(at, made[0])
        flags &= ~made[2][s]
        if not flags.any():
            return None
        if self._row_sums is None:
            self._row_sums = np.asarray(self.static.csr.sum(axis=1), np.float64).ravel()
        return Since(flags, made[1], self._row_sums[s], last, last_row, self.n_static)

    def rows(self, idx) -> sp.csr_matrix:
        idx = np.asarray(idx, np.int64)
        if self.static is None:
            return self._at(idx, lambda miss: self.fresh(miss)[0])
        obj = idx >= self.n_static
        static = self._at(idx[~obj], self._static_rows)
        if not obj.any():
            return static
        return in_order(static, self.objects()[idx[obj] - self.n_static], ~obj)

    def refresh(
        self,
        moved: np.ndarray,
        candidates: np.ndarray,
        slots: np.ndarray,
        kept: sp.csr_matrix,
        spheres,
        budget: int | None,
        weight: np.ndarray | None,
        correct: bool = False,
        outside: np.ndarray | None = None,
        meanwhile=None,
        held=None,
    ) -> tuple[np.ndarray, sp.csr_matrix, int, tuple | None]:
        """Which of the static ``candidates`` (patch indices in ``slots``; ``kept`` the local
        set's rows (M, N) in slot order, so theirs are ``current = kept[slots]``, sliced only
        when the budget ranks them) to refresh after a move, and the new rows of ``moved``
        (object patches) and of those.

        Hemicube rows (no static F): the ``budget`` candidates that see the most of the objects'
        old and new bounding ``spheres`` (:func:`~pydynrad.dynamic.occlusion.refresh_order`), by hemicube. With a static F:
        every candidate that may see a sphere gets its row at the new poses from the static F
        (``rows``, no hemicube; kept for the pose), and the ``budget`` whose gathered light
        that changes most relative to their own are kept (a shortlist by solid angle first
        loses: 6.6% mean pixel error at 32 rows against 4.5%, bench/objects.py's scene): ``A_s rho_s |(new_s - current_s) w| / w_s`` with
        ``w`` (N,) the last radiosity summed over channels (ones before any), the row's share of
        the mean relative error over the surface. At budget 0 only when ``correct``, and then
        only their differences from their kept rows are made, not the rows (:meth:`differences`).
        Returns (indices into ``candidates``, rows of ``moved`` then of those, hemicubes
        computed, left): with ``correct``, ``left`` is (indices into ``candidates``, D) for the
        candidates made but not kept (with a static F and a budget that leaves some): their rows
        at the new poses minus their kept rows ``kept[slots[...]]``, for
        :class:`~pydynrad.dynamic.stale.StaleRows`; else None.
        ``outside``: patches whose rows the frame will gather at the new poses
        (:meth:`gather_outside`): with a static F made in the same pass as the candidates'.
        ``meanwhile``: a callable run once while the objects' hemicubes trace on the device,
        after the static rows' pre-test on the host (with hemicube rows: before they are
        made), so that the host's work of the caller overlaps the trace. ``held``: the stale
        rows the differences at budget 0 may start from (:meth:`differences`)."""
        world = self.world
        if self.static is None:
            order, _ = refresh_order(world.centers[candidates], world.normals[candidates], spheres)
            order = order[:budget]
            if meanwhile is not None:
                meanwhile()
            rows, hemicubes = self.fresh(np.concatenate([moved, candidates[order]]))
            return order, rows, hemicubes, None
        tracing = None
        try:
            if self.object_rows is None:
                # The objects' hemicubes trace on the device while this thread runs the static
                # rows' pre-test on the host; a pool thread waits for them, and their reciprocal
                # columns for it (objects()). A CPU device tracing them alone left part
                # of its cores idle. Queued by this thread, first: the pool thread only
                # waits, and takes the interpreter's lock once they are traced (queued by it, both
                # threads had wanted the lock for small numpy steps at once, which slowed those
                # steps many times over and started the trace after them;
                # docs/decisions/0026-moving-frame-cost.md).

                tracing = self._tracing = pool().submit(self.fresh_queued(self.object_patches))
                self._meanwhile = meanwhile
            elif meanwhile is not None:
                meanwhile()
            order, _ = refresh_order(world.centers[candidates], world.normals[candidates], spheres)
            # Objects that did not move are seen by those that did: their rows, new anyway, go in too.
            still = np.flatnonzero(candidates >= self.n_static)
            order = order[candidates[order] < self.n_static] if budget != 0 or correct else order[:0]
            also = None if outside is None else outside[self.gathered(outside)]
            if budget == 0:  # every row made is left stale: only their differences are wanted
                left = (order, self.differences(candidates[order], kept, slots[order], also, held))
                order, new = order[:0], sp.csr_matrix((0, self.n_patches))
            else:
                new, left = self._at(candidates[order], self._static_rows, also), None
        except BaseException:
            self._meanwhile = None  # the refresh failed: no work of the caller's to overlap
            raise
        finally:
            try:
                if self._tracing is not None:  # never a trace left running past the call (nor its meanwhile not run)
                    self.objects()
            finally:
                self._meanwhile = None
        hemicubes = 0 if tracing is None else tracing.result()[1]
        if budget != 0 and budget is not None and len(order) > budget:
            w = np.ones(self.n_patches) if weight is None else np.asarray(weight, np.float64)
            keep = np.ones(self.n_patches)
            keep[self.object_patches] = 0.0
            change = np.abs((new - kept[slots[order]]) @ (keep * w))
            p = candidates[order]
            rho = world.albedo[p].astype(np.float64).mean(axis=1)
            score = world.areas[p] * rho * change / np.maximum(w[p], 1e-3 * max(float(w.mean()), 1e-300))
            best = np.argsort(-score, kind="stable")[:budget]
            best = best[score[best] > 0]
            rest = np.setdiff1d(np.arange(len(order)), best)
            left = (order[rest], rows_minus(new[rest], kept, slots[order[rest]])) if correct else None
            order, new = order[best], new[best]
        rows = self.object_rows[np.concatenate([moved, candidates[still]]) - self.n_static]
        return (
            np.concatenate([still, order]),
            sp.vstack([rows, new], format="csr"),
            hemicubes,
            left if correct else None,
        )
