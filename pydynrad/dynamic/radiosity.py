"""Dynamic radiosity: a local multibounce matrix over the M patches nearest the observer.

:class:`DynamicRadiosity` keeps K = K_S = (I - F_SS P_S)^{-1} F_SS (one M x M matrix per colour
channel, on the OpenCL device) for the local set S and updates it as the observer moves, so
a frame costs O(M^2) device work instead of O(N^2):

* ``update(observer)`` swaps the farthest local patches for nearer ones outside the set (the
  paper's loop, at most ``max_swaps_per_frame`` per frame) and updates K in place, either as
  the paper does (``update="paper"``, :mod:`pydynrad.dynamic.paper`) or exactly
  (``update="exact"``, :mod:`pydynrad.dynamic.exact`: after any sequence of swaps K equals a fresh
  build over the same set, to rounding);
* ``radiosity(lights)`` (or ``radiosity(light=L)``) returns B (N, 3) for every patch. With the
  far field (the default, :mod:`pydynrad.farfield`) patches outside the local set get a coarse
  cluster-level solution B_far, and the light they reflect is injected into the local set before
  B = L' + P K L';
  with ``far_field=False`` (the paper's method) the local set gets B = L + P K L and every other
  patch only L (emitted plus direct light). :attr:`DynamicRadiosity.patch_levels` says which.
* with ``objects=[...]`` (:class:`pydynrad.RigidObject`), ``move(obj, transform)`` queues a new
  pose that the next ``update`` applies as one batched swap of the objects' patches (always
  local) and of the rows the move changed most (``occlusion``, a row budget per frame):
  :mod:`pydynrad.dynamic.moves`; with a static F the other rows it changed are corrected in
  ``radiosity`` (``occlusion_correction``, :mod:`pydynrad.dynamic.stale`), and at budget 0 the
  objects' rows too, with no swap.

Form factors come from a precomputed sparse F, any row source (:mod:`pydynrad.rows`:
a form-factor store on disk, a row cache) or, with ``form_factors=None``, from one hemicube
per entering patch. Only rows are ever fetched: the entering patches' columns restricted to
the local set, F[S, J], are read from the rows of S, which are kept (sparse, M rows) from
when each patch entered. Hemicube form factors are not exactly reciprocal, so deriving
columns by reciprocity would give a K that differs from a fresh build over the same rows.

See docs/design.md, 'Conventions', 'Local set' and 'Drift and refresh'.
"""

from __future__ import annotations

import functools
import threading
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from ..bounces import multibounce_block, multibounce_memory, warn_precision
from ..checks import flag, integer, number, vec3
from ..checks import resolution as checked_resolution
from ..defaults import RESOLUTION, default_local_size
from ..device.devices import device_or_default
from ..device.matrix import DeviceMatrix, padded_ld
from ..errors import InvalidInputError, OutOfMemoryError, PydynradError
from ..farfield import FarField, far_field_for
from ..farfield.estimate import DEFAULT_TOLERANCE, ErrorControl, coarse_tolerance
from ..geometry.loading import checked_scene
from ..geometry.objects import _objects, check_reach, instanced, rigid_transform
from ..host.memory import available_host_bytes
from ..lights.areas import analytic_emitter_light
from ..lights.sources import (
    SHADOW_EPSILON,
    DirectionalLight,
    PointLight,
    SpotLight,
    _point_irradiance,
    check_radiosity_range,
    checked_lights,
)
from ..precision import compute_dtype, storage_dtype
from .exact import exact_swap
from .kupdate import UpdateKernels, scratch_nbytes
from .localrows import LocalRows, _replace_rows
from .moves import MovingObjects, WorldRows
from .occlusion import shadow_rays_near
from .paper import UsedPatches, paper_swap
from .poserows import stale_rows, swap_chunks
from .selection import NearestSet
from .stale import CORRECTION_TOLERANCE, StaleRows, rows_minus

__all__ = ["DynamicRadiosity", "FrameStats"]

UPDATE_MODES = ("exact", "paper")
#: The most swaps one frame may batch (the gather keeps this many vectors in private memory).
MAX_SWAPS_LIMIT = 32
#: The most patches one batch of a move swaps (objects' patches and refreshed rows): a move
#: batches up to this many of its slots, more than a frame's swaps, since chunks of a move
#: each pay a gather and a rank pass of their own (private arrays of twice this many terms).
MOVE_SWAPS_LIMIT = 64
#: Rows refreshed per move for the occlusion of moving objects by default (``occlusion="auto"``)
#: where a refresh buys accuracy: with hemicube rows, or without the correction of stale rows.
DEFAULT_OCCLUSION = 32


def _locked(method):
    """Run ``method`` holding the solution's lock (:attr:`DynamicRadiosity.lock`, re-entrant):
    a call waits for a frame in progress in another thread and sees K, the local set and the
    far field's light as that frame left them, never half of one."""

    @functools.wraps(method)
    def locked(self, *args, **kwargs):
        with self._lock:
            return method(self, *args, **kwargs)

    return locked


def swap_size(max_swaps: int, object_patches: int) -> int:
    """The most vectors per batch of the update kernels: a frame's swaps, or a move's batch
    of the objects' patches when larger (a 48-patch block in one batch, not 32 + 16)."""
    return max(max_swaps, min(object_patches, MOVE_SWAPS_LIMIT))


@dataclass
class FrameStats:
    """What one :meth:`DynamicRadiosity.update` call did. Times in seconds (wall clock)."""

    frame: int
    swaps: int
    removed: np.ndarray = field(repr=False)  # patch indices that left the local set
    added: np.ndarray = field(repr=False)  # patch indices that entered it
    t_select: float = 0.0  # choosing the swaps (k-d tree query, partial order of M distances)
    t_form_factors: float = 0.0  # fetching or computing the entering patches' rows and columns
    t_update: float = 0.0  # updating K on the device (all channels), waited for
    t_prefetch: float = 0.0  # asking a prefetching row source for the next frame's likely rows
    refreshed: bool = False  # K was (re)built from scratch this frame
    residual: float | None = None  # probe estimate of K's relative error, when checked
    moved: int = 0  # objects moved this frame
    hemicubes: int = 0  # rows the moves computed by hemicube (not taken from poses=)
    rows_refreshed: int = 0  # rows of other local patches refreshed for the objects' occlusion
    t_move: float = 0.0  # applying the moves: the objects' and refreshed rows' hemicubes and the swap, waited for
    #: The far field's :class:`~pydynrad.farfield.estimate.ErrorEstimate` of this frame's answer: filled in by
    #: the radiosity() call that follows this update (None until then, and without a far field).
    error_estimate: object = None

    @property
    def t_total(self) -> float:
        return self.t_select + self.t_form_factors + self.t_update + self.t_prefetch + self.t_move


class DynamicRadiosity:
    """The local multibounce matrix of the M patches nearest the observer, updated per frame.

    Parameters
    ----------
    scene : pydynrad.Scene
    form_factors : (N, N) sparse matrix, RowSource, or None
        F as :func:`pydynrad.form_factors` returns it; a row source (form-factor store, row
        cache) serving its rows; or None for one hemicube per entering patch.
    local_size : int, optional
        M, the number of local patches, 1 <= M <= N. Default: min(1024, N // 2), at least the
        moving objects' patches (:func:`pydynrad.defaults.default_local_size`), so at least
        half of the scene is far field; the size chosen is :attr:`M`.
    update : "exact" | "paper"
        The paper's update (sections 3-4, with section 4.1's bitset) or the exact one.
    storage : "fp16" | "fp32" | "fp64"
        Element type of K on the device (fp16 and fp32 compute in fp32).
    max_swaps_per_frame : int
        k, the most patches exchanged per :meth:`update` (exact mode batches them in one
        read pass and one rank-2k pass over K; paper mode does them one after another).
    refresh_tolerance : float or None
        Rebuild K from scratch when :meth:`residual` exceeds this; checked every
        ``refresh_interval`` frames (None: never).
    refresh_interval : int
        Frames between residual checks when ``refresh_tolerance`` is set.
    observer : (3,) float, optional
        Initial observer position: the local set and K are built here. Without it they are
        built by the first :meth:`update` call, around that call's position.
    keep_emitters : bool
        Never evict emitting patches once local (the authors' code does this for the paper's
        update; we do the same in exact mode, since an emitter outside the set lights
        nothing). If every slot holds an emitter, no more swaps happen.
    resolution : int
        Hemicube resolution when ``form_factors`` is None, and of every moving object's rows
        (default 64, :data:`pydynrad.defaults.RESOLUTION`, as :func:`pydynrad.form_factors`).
    samples : int
        Hemicubes per row when ``form_factors`` is None (1, 4, 16, ...:
        :func:`pydynrad.form_factors`); given form factors carry their own, and moving objects'
        rows are single hemicubes, so either with ``samples`` > 1 is refused.
    far_field : bool or pydynrad.farfield.FarField
        Light the patches outside the local set with the coarse level and inject their light
        into it (default), or leave them at L as the paper does (False). A ready FarField
        (built for this scene) is used as given.
    clusters : int or pydynrad.farfield.Clusters, optional
        The far field's clusters, or their count C (default: from N).
    cluster_form_factors : (N, C) sparse, optional
        G for those clusters; by default F Pr from F, a form-factor store's own G, or G by
        cluster-id hemicubes for rows computed on demand (:func:`pydynrad.farfield.far_field_for`).
    objects : sequence of pydynrad.RigidObject or MovingObjects, optional
        Moving objects (exact mode only), with how each move refreshes the rows it changes
        (:class:`~pydynrad.dynamic.moves.MovingObjects`; a plain sequence takes its defaults).
        Their patches follow the scene's N, in order, and are always local (their count must
        not exceed M); :attr:`scene` is then the combined scene at the current poses, traced
        through a two-level BVH. ``form_factors`` stays the static scene's (rows fetched or
        refreshed then come from it at the current poses: the entries an object hides dropped,
        object columns by reciprocity), or None: every row a hemicube of the world as it is, so
        K equals a fresh build over the same set when ``occlusion`` is None. With the far field,
        the patches outside the local set are gathered at the current poses in :meth:`radiosity`.
    device : pydynrad.device.Device, optional
    tolerance : float or None
        With the far field: every answer's all-patch error is estimated from its residual
        L + P F B - B (:attr:`error_estimate`; :mod:`pydynrad.farfield.estimate`), and while the
        estimate exceeds ``tolerance`` (area-weighted relative RMS of the reflected light; default
        :data:`~pydynrad.farfield.estimate.DEFAULT_TOLERANCE`, 0.1%) sweeps B <- L + P F B refine
        it (F in memory; a frame with unchanged lights only beyond twice the tolerance; patches
        that trap light solved directly, :mod:`pydynrad.farfield.trapped`), and the far field it
        builds stops its coarse sweeps at :data:`~pydynrad.farfield.estimate.COARSE_SHARE` times
        the tolerance. None: estimate only. Without F in memory, a light change is refined from a store's blocks (kept
        after the first pass where they fit the memory budget); with rows on demand the residual
        is sampled and nothing is refined.

    Notes
    -----
    Threads: one solution may be shared by threads (a viewer serving requests while another thread walks).
    Every method that reads or writes K, the local set, the kept rows, the queued moves or the
    far field's light (:meth:`update`, :meth:`radiosity`, :meth:`refresh`, :meth:`residual`,
    :meth:`move`, :meth:`warm_up`, :attr:`local_patches`, :attr:`local_mask`,
    :attr:`patch_levels`, :attr:`memory_bytes`, :attr:`host_memory_bytes`) holds one re-entrant
    lock, :attr:`lock`, for the whole call: a reader waits for a frame in progress and sees the
    state that frame leaves, whole. Two :meth:`update` calls must not overlap: the second
    raises :class:`~pydynrad.errors.PydynradError` at once rather than queue a frame behind
    another. A FarField shared by solutions serves each :meth:`radiosity` its own light under
    the far field's own lock (:attr:`pydynrad.farfield.FarField.lock`). To read several things
    of one frame together (:attr:`frame` and :meth:`radiosity`, or :attr:`matrix`, which is the
    device buffer itself), hold ``with solution.lock:`` around them.
    """

    def __init__(
        self,
        scene,
        form_factors,
        local_size: int | None = None,
        update: str = "exact",
        storage: str = "fp32",
        max_swaps_per_frame: int = 8,
        refresh_tolerance: float | None = None,
        refresh_interval: int = 32,
        observer=None,
        keep_emitters: bool = True,
        resolution: int = RESOLUTION,
        far_field=True,
        clusters=None,
        cluster_form_factors=None,
        objects=None,
        device=None,
        samples: int = 1,
        tolerance: float | None = DEFAULT_TOLERANCE,
    ) -> None:
        scene = checked_scene(scene)
        moving = objects if isinstance(objects, MovingObjects) or objects is None else MovingObjects(objects)
        occlusion = "auto" if moving is None else moving.occlusion
        occlusion_correction = True if moving is None else moving.occlusion_correction
        correction_tolerance = CORRECTION_TOLERANCE if moving is None else moving.correction_tolerance
        self.device = device_or_default(device)
        self.objects, self._pending = [], {}
        self._last_B: np.ndarray | None = None  # (N,) the last radiosity() summed over channels: ranks a move's rows
        self._held_light: HeldLight | None = None  # the last radiosity()'s with lights=: _light_vector
        self.occlusion_correction = flag(occlusion_correction, "occlusion_correction")
        self.correction_tolerance = number(correction_tolerance, "correction_tolerance")  # finite, not a str or bool
        if not 0 < self.correction_tolerance < 1:
            raise InvalidInputError(f"correction_tolerance must be a number in (0, 1); got {correction_tolerance!r}")
        if isinstance(occlusion, str):
            if occlusion != "auto":
                raise InvalidInputError(f"occlusion must be a row count, None or 'auto'; got {occlusion!r}")
            # With a static F and the correction every budget gives the same error (the rows left
            # stale are corrected for) and swapping rows only costs time
            # (docs/decisions/0025-moving-objects-rows-and-correction.md).
            occlusion = 0 if form_factors is not None and self.occlusion_correction else DEFAULT_OCCLUSION
        self.occlusion = None if occlusion is None else integer(occlusion, "occlusion", 0)
        if samples != 1 and (form_factors is not None or objects is not None):
            raise InvalidInputError(
                f"samples={samples!r} applies to rows computed on demand (form_factors=None) without "
                "moving objects; pass HemicubeRows(scene, R, samples=K) or form factors computed "
                "with samples=K instead"
            )
        if moving is not None:
            scene, form_factors = self._with_objects(
                scene, form_factors, moving.objects, update, local_size, checked_resolution(resolution), moving.poses
            )
        n = len(scene)
        self.scene = scene
        self._stale = StaleRows(n)  # rows a move left stale in K (a static F with occlusion_correction)
        if local_size is None:  # the rule of pydynrad.defaults: at least half the scene stays far
            local_size = default_local_size(n, n - len(getattr(self, "static_scene", scene)))
        self.M = integer(local_size, "local_size (M)", 1, n)
        if update not in UPDATE_MODES:
            raise InvalidInputError(f"update must be one of {UPDATE_MODES}; got {update!r}")
        self.mode = update
        storage_dtype(storage)
        self.storage = storage
        self._precision_warned = False  # _check_precision's warning, once
        self.max_swaps = integer(max_swaps_per_frame, "max_swaps_per_frame", 1, MAX_SWAPS_LIMIT)
        if refresh_tolerance is not None:
            if isinstance(refresh_tolerance, (str, bytes, bool)) or not (
                np.isfinite(number(refresh_tolerance, "refresh_tolerance")) and refresh_tolerance > 0
            ):
                raise InvalidInputError(
                    f"refresh_tolerance must be a positive number or None; got {refresh_tolerance!r}"
                )
            refresh_tolerance = float(refresh_tolerance)
        self.refresh_tolerance = refresh_tolerance
        self.refresh_interval = integer(refresh_interval, "refresh_interval", 1, 2**31 - 1)
        self.resolution = checked_resolution(resolution)  # of hemicube rows (entering patches, objects)
        self._ff = LocalRows(scene, form_factors, self.resolution, self.device, samples)
        self.C = 1 if scene.is_grey else 3
        pinned = scene.emission.max(axis=1) > 0 if flag(keep_emitters, "keep_emitters") else np.zeros(n, bool)
        pinned[self._object_patches] = True
        self._select = NearestSet(scene.centers, pinned)
        self._local_patches: np.ndarray | None = None
        self._local_mask = np.zeros(n, dtype=bool)
        self._last_observer: np.ndarray | None = None
        self._matrix: DeviceMatrix | None = None
        self._kernels = None
        self._used = None
        self._update_lock = threading.Lock()  # held by update() alone: a second caller is refused
        self._lock = threading.RLock()  # held by every call that reads or writes the solution (Threads)
        self.frame = 0
        self.refreshes = 0
        self._rng = np.random.default_rng(0x5EEAC106)
        self._check_memory()  # before any of it is allocated: a refusal, never a signal
        self.far = self._far_field(far_field, clusters, cluster_form_factors, coarse_tolerance(self._ff, tolerance))
        # The far field's error, estimated on every answer, and sweeps to ``tolerance`` (farfield/estimate.py).
        self._errors = None if self.far is None else ErrorControl(scene, self.far, self._ff, self.device, tolerance)
        self._frame_stats: FrameStats | None = None  # the last update()'s, whose error_estimate radiosity() fills
        self._allocate()
        if observer is not None:
            self._build(self._initial_set(self._observer(observer, "observer")))

    def _with_objects(self, scene, form_factors, objects, update: str, local_size, resolution: int, poses):
        """The world scene and its row source for a static scene with moving objects."""

        if update != "exact":
            raise InvalidInputError(
                f"moving objects need update='exact' (a move is an exact batched swap); got {update!r}"
            )
        self.objects = _objects(objects)
        self.static_scene = scene
        world = instanced(scene, self.objects)
        n_static, n_obj = len(scene), len(world) - len(scene)
        if isinstance(local_size, (int, np.integer)) and n_obj > local_size:
            raise InvalidInputError(
                f"the objects have {n_obj} patches, more than local_size M = {local_size}: "
                "every object patch must be local"
            )
        self._ranges = {}
        start = n_static
        for o in self.objects:
            self._ranges[id(o)] = np.arange(start, start + len(o))
            start += len(o)
        rows = WorldRows(world, n_static, self.objects, form_factors, scene, resolution, self.device, poses)
        return world, rows

    @property
    def _swap_size(self) -> int:
        return swap_size(self.max_swaps, len(self._object_patches))

    @property
    def _object_patches(self) -> np.ndarray:
        n = len(self.scene)
        return np.arange(len(self.static_scene), n) if self.objects else np.empty(0, np.int64)

    def _initial_set(self, obs: np.ndarray) -> np.ndarray:
        """The M patches nearest ``obs``, every object patch among them."""
        objs = self._object_patches
        idx = self._select.nearest(obs, self.M + len(objs))[0]
        return np.concatenate([objs, idx[~np.isin(idx, objs)][: self.M - len(objs)]])

    # -- state -------------------------------------------------------------------------------------
    @property
    def built(self) -> bool:
        return self._local_patches is not None

    def _require_built(self) -> None:
        if not self.built:
            raise PydynradError("the local set is not built yet: pass observer= or call update(position) first")

    @property
    @_locked
    def local_patches(self) -> np.ndarray:
        """(M,) patch index held by each slot (row/column of K)."""
        self._require_built()
        return self._local_patches.copy()

    @property
    @_locked
    def local_mask(self) -> np.ndarray:
        """(N,) bool: True on the patches whose radiosity K computes."""
        self._require_built()
        return self._local_mask.copy()

    @property
    @_locked
    def patch_levels(self) -> np.ndarray:
        """(N,) str: how :meth:`radiosity` solves each patch now: ``"local"`` (the local matrix K),
        ``"far"`` (the far field's coarse level) or ``"light"`` (L only: no far field, or a call
        with ``far_field=False`` for every patch outside the local set)."""
        self._require_built()
        levels = np.full(len(self.scene), "far" if self.far is not None else "light", dtype="<U5")
        levels[self._local_patches] = "local"
        return levels

    def _far_field(self, far_field, clusters, G, tol: float | None):
        if far_field is not True and (clusters is not None or G is not None):  # they build one; none is built
            given = " and ".join(n for n, v in (("clusters", clusters), ("cluster_form_factors", G)) if v is not None)
            raise InvalidInputError(f"{given} build the far field; with far_field={far_field!r} they would be ignored")
        if far_field is False or far_field is None:
            return None
        if isinstance(far_field, FarField):
            if far_field.scene.content_hash() != self.scene.content_hash():
                raise InvalidInputError("far_field was built for another scene (content hash differs)")
            return far_field
        if far_field is not True:
            raise InvalidInputError(f"far_field must be True, False or a FarField; got {far_field!r}")
        return far_field_for(self.scene, self._ff, clusters, G, self.device, tol)

    @property
    def lock(self) -> threading.RLock:
        """The re-entrant lock every call that reads or writes this solution holds (class
        docstring, 'Threads'): hold it to read several things of one frame together."""
        return self._lock

    @property
    def matrix(self) -> DeviceMatrix:
        """The device-resident K (C, M, M) in slot order (see :attr:`local_patches`): the buffer
        itself, which the next :meth:`update` changes in place; read it under :attr:`lock`
        where another thread may update."""
        self._require_built()
        return self._matrix

    @property
    @_locked
    def memory_bytes(self) -> int:
        """Device bytes of K (all channels), the update's scratch buffers and the far field's
        F_c and G (or F) where they are on the device (:attr:`FarField.device_memory_bytes
        <pydynrad.farfield.FarField.device_memory_bytes>`)."""
        self._require_built()
        far = self.far.device_memory_bytes if self.far is not None else 0
        return self._matrix.nbytes + self._kernels.nbytes + far

    @staticmethod
    def estimate_memory_bytes(
        M: int, channels: int, storage: str, max_swaps_per_frame: int = 8, device=None, object_patches: int = 0
    ) -> int:
        """What :attr:`memory_bytes` will be for these sizes without a far field (K and the
        update's scratch), without building anything; a far field adds its
        :attr:`~pydynrad.farfield.FarField.device_memory_bytes`. ``object_patches``: the moving
        objects' patches together (a move batches up to ``MOVE_SWAPS_LIMIT`` of them)."""

        device = device_or_default(device)
        ld = padded_ld(M)
        real = compute_dtype(storage).itemsize
        item = storage_dtype(storage).itemsize
        swaps = swap_size(max_swaps_per_frame, object_patches)
        return channels * M * ld * item + scratch_nbytes(device, M, ld, item, real, swaps, channels)

    def _check_memory(self) -> None:
        """OutOfMemoryError where K and the update's scratch (:meth:`estimate_memory_bytes`) and
        K's build (:func:`pydynrad.bounces.multibounce_memory`) would not fit: on the device
        (its memory, and its largest buffer) and in what this process may still allocate
        (:func:`pydynrad.host.memory.available_host_bytes`: the machine's, the cgroup's and
        RLIMIT_AS's headroom), which on a CPU device holds the device's buffers too. PoCL's
        failed host allocation under ``ulimit -v`` had crashed the process (signal 11)."""
        gib = 2.0**30
        dtype = compute_dtype(self.storage)
        device_need = self.estimate_memory_bytes(
            self.M, self.C, self.storage, self.max_swaps, self.device, len(self._object_patches)
        )
        build = multibounce_memory(self.M, self.C, dtype)
        host_need = build["host"] + ((device_need + build["device"]) if self.device.traits.cpu else 0)
        have = available_host_bytes()
        if host_need > have:
            raise OutOfMemoryError(
                f"a DynamicRadiosity of M = {self.M} local patches ({self.C} channel(s), {self.storage}) needs about "
                f"{host_need / gib:.2f} GiB of host memory for K, its scratch and its build; this process may "
                f"allocate {have / gib:.2f} GiB (the least of the machine's, its cgroup's and ulimit -v's). Use a "
                "smaller local_size or fp16 storage"
            )
        if device_need + build["device"] > self.device.global_mem_bytes:
            raise OutOfMemoryError(
                f"a DynamicRadiosity of M = {self.M} local patches needs about {(device_need + build['device']) / gib:.2f} "
                f"GiB of device memory; {self.device.name} has {self.device.global_mem_bytes / gib:.2f} GiB. Use a "
                "smaller local_size or fp16 storage"
            )

    @property
    @_locked
    def host_memory_bytes(self) -> int:
        """Host bytes of the bookkeeping: slot map, local mask, the local set's form-factor
        rows, the rows moves left stale, (paper mode) the bitsets and the far field (G, F_c, R,
        labels, B_far, the last lights and answers it combines)."""
        self._require_built()
        used = self._used.nbytes if self._used is not None else 0
        far = self.far.host_memory_bytes if self.far is not None else 0
        return self._local_patches.nbytes + self._local_mask.nbytes + self._ff.nbytes + self._stale.nbytes + used + far

    def _rho(self, patches: np.ndarray) -> np.ndarray:
        """(C, len(patches)) albedo per K channel."""
        return self.scene.albedo[patches, : self.C].T.astype(np.float64)

    # -- building ----------------------------------------------------------------------------------
    def _fresh_K(self, local_patches: np.ndarray, fetch: bool = True) -> np.ndarray:
        if fetch:
            self._ff.fetch_local(local_patches)
        # The rows were validated when fetched (LocalRows.rows) or made here at a pose (moves.at_pose
        # and stale_rows cap every row to a sum of 1; hemicube rows are so by construction): not
        # checked again (checking them was a sizeable share of the solve).
        return multibounce_block(
            self._ff.square(local_patches),
            self._rho(local_patches).T,
            dtype=compute_dtype(self.storage),
            device=self.device,
            checked=True,
        )

    def _allocate(self) -> None:
        """K's device buffers and the update's kernels, built and launched once (on zeros) here
        rather than inside the first frame."""
        self._matrix = DeviceMatrix.zeros(self.device, self.C, self.M, self.storage)
        self._kernels = UpdateKernels(self._matrix, self._swap_size)
        self._warm_up()

    def _build(self, local_patches: np.ndarray, fetch: bool = True) -> None:
        local_patches = np.asarray(local_patches, dtype=np.int64)
        self._check_precision(local_patches)
        if not fetch and len(self._stale):  # a rebuild takes the stale rows at the current poses
            self._ff.local = _replace_rows(self._ff.local, *self._stale.current(self._ff.local))
        self._stale.clear()
        self._matrix.upload(self._fresh_K(local_patches, fetch))
        self._local_patches = local_patches.copy()
        self._local_mask[:] = False
        self._local_mask[local_patches] = True
        if self.mode == "paper":
            self._used = self._used or UsedPatches(self.M, len(self.scene))
            self._used.reset_all(self._local_mask)

    def _check_precision(self, local_patches: np.ndarray) -> None:
        """:func:`pydynrad.bounces.warn_precision` for this K's arithmetic, once."""
        if not self._precision_warned and len(local_patches):
            rho = float(self.scene.albedo[local_patches].max())
            self._precision_warned = warn_precision(rho, "float64" if self.storage == "fp64" else "float32", 4)

    def _warm_up(self) -> None:
        """Launch, once, every kernel that frames will use, so no frame waits for PoCL to
        compile one: the update's, the products with K (one right-hand side per channel, three
        under one grey K, residual()'s one), and radiosity()'s light pass and far field (lit by
        a light of zero power while it holds no light yet: lit, it has run its kernels, and
        relighting it would discard the B_far it keeps for an unchanged light). K is left as it was."""

        self._kernels.warm_up()
        self._matrix.matvec(np.zeros(self.M))
        if self.C == 1:
            self._matrix.matmat(np.zeros((3, self.M)))
        L, _ = analytic_emitter_light(
            self.scene, [PointLight(self.scene.centers[0], 0.0)], None, "hemicube", self.device
        )
        if self.far is not None and self.far.B_far is None:
            self.far.light(L)

    @_locked
    def warm_up(self) -> None:
        """Launch every kernel the frames will use once, leaving K and the far field's light as
        they are. Construction does this; a second call costs a read pass and a read-write pass
        over one channel of K and changes nothing."""
        self._warm_up()

    @_locked
    def refresh(self) -> None:
        """Rebuild K from scratch over the current local set and its kept rows (slots keep their
        patches; rows refreshed for moving objects stay)."""
        self._require_built()
        self._build(self._local_patches, fetch=False)
        self.refreshes += 1

    # -- the frame -----------------------------------------------------------------------------------
    def update(self, observer_position) -> FrameStats:
        """Move the observer: swap patches in and out of the local set and update K.

        Returns a :class:`FrameStats`. The first call builds the set if the constructor had no
        ``observer`` (that frame reports ``refreshed=True`` and no swaps). Not re-entrant: the
        local set and K change in place, so a call while another is running (another thread)
        raises :class:`~pydynrad.errors.PydynradError` instead of corrupting them. The frame
        holds :attr:`lock`: other threads' reads wait for it and see it whole.
        """
        obs = self._observer(observer_position, "observer_position")
        if not self._update_lock.acquire(blocking=False):
            raise PydynradError(
                "DynamicRadiosity.update() is already running (another thread): its local set and K "
                "change in place, so calls must not overlap; use one DynamicRadiosity per thread "
                "or hold a lock around update()"
            )
        try:
            with self._lock:
                self._frame_stats = self._update(obs)
                return self._frame_stats
        finally:
            self._update_lock.release()

    def _observer(self, value, what: str) -> np.ndarray:
        """An observer position (3,), refused where its squared distances to the patches, which the
        selection sorts by, are not finite in float64 (beyond ~1e154 from the scene)."""
        obs = vec3(value, what)
        with np.errstate(over="ignore"):
            far = not np.isfinite(np.sum((obs - self.scene.frame.origin) ** 2))
        if far:
            raise InvalidInputError(
                f"{what} {obs.tolist()} is too far from the scene for its distances "
                "to the patches to be computed in float64"
            )
        return obs

    def _update(self, obs: np.ndarray) -> FrameStats:
        self.frame += 1
        empty = np.empty(0, np.int64)
        if not self.built:
            t0 = time.perf_counter()
            moves, transforms = self._moves()
            if moves:
                self._moved_world(transforms)  # refused (an intersection as an error): nothing moved
                self._commit(moves)
            self._build(self._initial_set(obs))
            t1 = time.perf_counter()
            self._prefetch_next(obs)
            return FrameStats(
                self.frame, 0, empty, empty, t_update=t1 - t0, t_prefetch=time.perf_counter() - t1, refreshed=True
            )
        moved, rows_refreshed, hemicubes, t_move = len(self._moves()[0]), 0, 0, 0.0
        if moved:
            t_move = time.perf_counter()
            rows_refreshed, hemicubes = self._apply_moves()
            self.device.queue.finish()
            t_move = time.perf_counter() - t_move
        t0 = time.perf_counter()
        slots, J = self._select.propose(obs, self._local_patches, self._local_mask, self.max_swaps)
        t1 = time.perf_counter()
        removed = self._local_patches[slots].copy()
        t_ff = 0.0
        if len(slots):
            t_ff = self._exact_frame(slots, J) if self.mode == "exact" else self._paper_frame(slots, J)
        # Before waiting for the device: the background reads overlap the update of K.
        t_pre = time.perf_counter()
        self._prefetch_next(obs)
        t_pre = time.perf_counter() - t_pre
        self.device.queue.finish()
        t2 = time.perf_counter()
        stats = FrameStats(
            self.frame,
            len(slots),
            removed,
            J,
            t_select=t1 - t0,
            t_form_factors=t_ff,
            t_update=t2 - t1 - t_ff - t_pre,
            t_prefetch=t_pre,
            moved=moved,
            rows_refreshed=rows_refreshed,
            hemicubes=hemicubes,
            t_move=t_move,
        )
        if self.refresh_tolerance is not None and self.frame % self.refresh_interval == 0:
            stats.residual = self.residual()
            if stats.residual > self.refresh_tolerance:
                self.refresh()
                stats.refreshed = True
        return stats

    # -- moving objects -------------------------------------------------------------------------------
    @_locked
    def move(self, obj, transform) -> None:
        """Queue a new (4, 4) rigid pose for ``obj``; the next :meth:`update` applies every queued move.
        A pose the device cannot resolve the object at is refused here, nothing queued
        (``pydynrad.geometry.objects.check_reach``)."""
        if not any(o is obj for o in self.objects):
            raise InvalidInputError(f"{obj!r} was never added to this DynamicRadiosity (pass it in objects=)")
        T = rigid_transform(transform)
        check_reach(self.static_scene, obj, T)
        self._pending[id(obj)] = (obj, T)

    def _moves(self) -> tuple[list, list]:
        """([(object, new pose)] of the objects that move, the poses of every object): the queued
        moves, and an object whose ``transform`` was set directly or by another solution sharing
        it (it differs from the pose this one holds) moves there too."""
        held = self.scene.bvh.transforms if self.objects else []
        moves, transforms = [], []
        for obj, T_held in zip(self.objects, held):
            T = self._pending[id(obj)][1] if id(obj) in self._pending else obj.transform
            if id(obj) in self._pending or not np.array_equal(T, T_held):
                moves.append((obj, T))
            transforms.append(T)
        return moves, transforms

    def _commit(self, moves: list) -> None:
        """The objects are at their new poses now that the world is: their transforms set, the queue emptied."""
        for obj, T in moves:
            obj.transform = T
        self._pending.clear()

    def _moved_world(self, transforms) -> None:
        """Put :attr:`scene` (and the BVH every kernel traces) at ``transforms``, one per object;
        where that is refused, nothing has changed."""
        self.scene = instanced(self.static_scene, self.objects, transforms, bvh=self.scene.bvh)
        self._ff.source.move(self.scene)

    def _apply_moves(self) -> tuple[int, int]:
        """Swap the moved objects' patches and the most changed rows with their new rows (at
        budget 0 with the correction: put them all among the stale rows, no swap); the count
        refreshed and the hemicubes computed."""

        moves, transforms = self._moves()
        held = dict(zip(map(id, self.objects), self.scene.bvh.transforms))
        spheres = []
        for obj, T in moves:
            spheres += [obj.bounding_sphere(held[id(obj)]), obj.bounding_sphere(T)]
        self._moved_world(transforms)
        source, S, M = self._ff.source, self._local_patches, self.M
        moved = np.concatenate([self._ranges[id(o)] for o, _ in moves])
        slot_of = np.full(len(self.scene), -1)
        slot_of[S] = np.arange(M)
        others = np.flatnonzero(~np.isin(S, moved))
        # With the far field, radiosity() gathers the patches outside S at the new poses.
        outside = np.flatnonzero(~self._local_mask) if self.far is not None else None
        try:
            # The relight's shadow rays go on the device's queue ahead of the objects' hemicubes.
            follow = self._follow_light()
            order, new_rows, hemicubes, left = source.refresh(
                moved,
                S[others],
                others,
                self._ff.local,
                spheres,
                self.occlusion,
                self._last_B,
                self.occlusion_correction,
                outside,
                meanwhile=follow,
                held=self._stale,
            )
        except BaseException:
            # Nothing of the move reached K or the stale rows: the world goes back to the poses
            # they are of, and the moves stay queued for the next update.
            self._moved_world([held[id(o)] for o in self.objects])
            raise
        self._commit(moves)
        slots = np.concatenate([slot_of[moved], others[order]])
        if self.occlusion == 0 and left is not None:
            # Budget 0 with the correction: no swap. The objects' new rows join the rows left
            # stale, K keeps the rows it was built from, and radiosity() solves with all of them
            # (a rank-2k swap of every object slot cost more than the rest of the move).
            self._stale.put(
                np.concatenate([slots, others[left[0]]]),
                rows_minus(new_rows, self._ff.local, slots),
                left[1],
                pose=source.pose,
            )
            return 0, hemicubes
        before = self._ff.local
        local = _replace_rows(before, slots, new_rows)
        local = stale_rows(local, slots, S, slot_of[moved], moved, self.scene.areas)
        rho = self._rho(S)
        # The swapped slots' columns and rows of F_SS, sliced out of the (M, N) rows once for
        # every chunk (a column slice passes over all of local's entries).
        cols = local[:, S[slots]].tocsc()
        rows = local[slots][:, S]
        for p in swap_chunks(np.arange(len(slots)), self._swap_size):
            c = slots[p]
            F_SJ = cols[:, p].toarray()
            F_SJ[c, :] = 0.0
            F_JS = rows[p].toarray()
            F_JJ = F_JS[:, c]
            F_JS[:, c] = 0.0
            exact_swap(self._kernels, c, F_SJ, F_JS, F_JJ, rho, rho[:, c])
        self._ff.local = local
        source.object_rows = local[slot_of[self._object_patches]]
        self._stale.drop(slots)
        if left is not None:  # their differences from the kept rows before the swap
            self._stale.put(others[left[0]], left[1])
        self._stale.rebase(before, local)
        return len(order), hemicubes

    def _prefetch_next(self, obs: np.ndarray) -> None:
        """Ask a row source with ``prefetch`` (a RowCache) for the rows the next frame will likely need.

        Those are the k nearest patches outside the local set to where the observer will be if it keeps its
        last step (k = max_swaps_per_frame): one k-d tree query of M + k points, like the
        selection's own, so O((M + k) log N) per frame.
        """
        prefetch = getattr(self._ff.source, "prefetch", None)
        ahead = obs if self._last_observer is None else 2 * obs - self._last_observer
        self._last_observer = obs
        if prefetch is None or self.M >= len(self.scene):
            return
        idx, _ = self._select.nearest(ahead, self.M + self.max_swaps)
        prefetch(idx[~self._local_mask[idx]][: self.max_swaps])

    def _swap_local(self, slots: np.ndarray, J: np.ndarray) -> None:
        self._stale.drop(slots)  # J enter with their rows at the current poses
        self._local_mask[self._local_patches[slots]] = False
        self._local_patches[slots] = J
        self._local_mask[J] = True

    def _entering(self, slots: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """F[S, J], F[J, S], F[J, J] of the patches J entering ``slots`` (their rows now kept);
        the far field's last injection follows the swap (no pass over the rows in radiosity())."""
        before = self._ff.local
        F_SJ, F_JS, F_JJ, F_SR = self._ff.entering(self._local_patches, J, slots)
        if self.far is not None:
            members = self._local_patches.copy()
            members[slots] = J
            self.far.follow_swap(before, self._ff.local, members, slots, F_SJ, F_SR)
        return F_SJ, F_JS, F_JJ

    def _exact_frame(self, slots: np.ndarray, J: np.ndarray) -> float:
        t0 = time.perf_counter()
        F_SJ, F_JS, F_JJ = self._entering(slots, J)
        F_SJ[slots, :] = 0.0  # the leaving patches take no part in the new paths
        F_JS[:, slots] = 0.0
        t_ff = time.perf_counter() - t0
        exact_swap(self._kernels, slots, F_SJ, F_JS, F_JJ, self._rho(self._local_patches), self._rho(J))
        self._swap_local(slots, J)
        return t_ff

    def _paper_frame(self, slots: np.ndarray, J: np.ndarray) -> float:
        # One fetch per frame (slots are distinct): step t's local set is the frame's first set
        # with slots[:t] holding J[:t], so its f_c and f_r are F_SJ[:, t] and F_JS[t] with those
        # slots read from F_JJ: the same values a fetch per step would give.
        t0 = time.perf_counter()
        F_SJ, F_JS, F_JJ = self._entering(slots, J)
        t_ff = time.perf_counter() - t0
        for t, (s, j) in enumerate(zip(slots.tolist(), J.tolist())):
            self._swap_local(np.array([s]), np.array([j]))
            f_c, f_r = F_SJ[:, t].copy(), F_JS[t].copy()
            f_c[slots[:t]] = F_JJ[:t, t]
            f_r[slots[:t]] = F_JJ[t, :t]
            f_c[s] = f_r[s] = 0.0
            rho_S, rho_j = self._rho(self._local_patches), self._rho(np.array([j]))[:, 0]
            mask = ~self._used.holding(j)
            paper_swap(self._kernels, s, f_c, f_r, rho_S, rho_j, mask)
            self._used.add(j)
            self._used.reset(s, self._local_mask)
        return t_ff

    # -- lighting ----------------------------------------------------------------------------------------
    @_locked
    def radiosity(self, lights=(), *, light=None, far_field: bool = True, emitters: str = "hemicube") -> np.ndarray:
        """B (N, 3) float64 for every patch (see :attr:`patch_levels` for how each was solved).

        With the far field: B_far (the coarse level, recomputed when the light vector changes)
        outside the local set S, and L'_S + P_S K L'_S on S, where L'_S = L_S + P_S F[S, X] B_far[X]
        adds the light reflected by the patches outside. Without it: L + P K L on S, L elsewhere.

        ``lights``: analytic lights (see :func:`pydynrad.light_vector`; emission alone when
        empty), whose light vector is kept while the same or equal lights light the same world
        (after a move, lit again where it may have changed); or ``light``: a precomputed light
        vector L of shape (N, 3). K is only read.
        ``far_field=False`` gives the paper's answer from the same K (the local-only
        comparison), also when this solution has a far field.
        ``emitters="analytic"``: emitting patches light the others by the exact point-to-polygon
        form factor, not through K (as in :func:`pydynrad.solve`): the same solution for B - E
        with the reflected light vector L_r, plus E.
        """

        self._require_built()
        far_field = flag(far_field, "far_field")
        L, E = self._light_vector(lights, light, emitters)
        check_radiosity_range(L, self.scene.albedo, compute_dtype(self.storage))  # the K passes' type
        S = self._local_patches
        LS = L[S]
        far = None
        if far_field and self.far is not None:
            with self.far.lock:  # a FarField shared with other solutions: this light and its injection together
                far = self.far.light(L)
                LS = LS + self.far.injection(self._ff.local, S)
        B = far.copy() if far is not None else L.copy()
        if len(self._stale):
            B[S] = self._stale.correct(
                self._solve_kept, LS, B, S, self.scene.albedo, far is not None, self.correction_tolerance
            )
        else:
            B[S] = self._solve_kept(LS)
        if far is not None and not self.objects and not len(self._stale):  # its residual, and sweeps to tolerance
            with self.far.lock:
                B = self._errors.check(L, B, S, far, lambda B_far: self._resolved(L, B_far), E is None)
            if self._frame_stats is not None:
                self._frame_stats.error_estimate = self._errors.last
        if self.objects:
            if far is not None:  # the coarse level is of the first poses: gather the outside at these
                outside = np.flatnonzero(~self._local_mask)
                B[outside] = self._ff.source.gather_outside(outside, L, B)
            self._last_B = B.sum(axis=1)
        return B if E is None else B + E

    def _resolved(self, L: np.ndarray, B_far: np.ndarray) -> np.ndarray:
        """The whole answer with the far field's answer replaced by ``B_far`` (a refinement sweep's,
        :mod:`pydynrad.farfield.estimate`): B_far outside the local set, the local set solved
        from its injection. Under the far field's lock."""
        S = self._local_patches
        self.far.B_far = B_far
        B = B_far.copy()
        B[S] = self._solve_kept(L[S] + self.far.injection(self._ff.local, S))
        return B

    @property
    @_locked
    def error_estimate(self):
        """The far field's :class:`~pydynrad.farfield.estimate.ErrorEstimate` of the last
        :meth:`radiosity` answer (None before one, without a far field, with moving objects, or
        after a call with ``far_field=False`` only). Its ``error`` estimates the area-weighted
        all-patch relative RMS error against the full solve of the same F, relative to the
        reflected radiosity B - E (the emitters' own emission left out of the norm:
        ``comparison.radiosity_error(..., emission=)``)."""
        return None if self._errors is None else self._errors.last

    def _light_vector(self, lights, light, emitters: str) -> tuple[np.ndarray, np.ndarray | None]:
        """:func:`~pydynrad.lights.areas.analytic_emitter_light` of the world as it is, reused
        while the light objects (equal ones, in order), the emitter mode and the world are those
        of the last call. A walk's frames under lights that stay put then trace no shadow ray and
        gather no sky again (a SkyLight's light vector is a hemicube per patch, a point light's
        one ray per patch). After a move only the patches whose shadows it may change are lit
        again (:meth:`_relit`). The arrays are read-only: every caller copies."""

        if light is None:
            lights = checked_lights(lights)
            held = self._held_light
            if held is not None and held.emitters == emitters and _same_lights(held.lights, lights):
                if held.world is self.scene:
                    self._held_light = held._replace(steady=True)
                    return held.L, held.E
                L = self._relit(held.L, held.poses, lights) if emitters == "hemicube" else None
                if L is not None:
                    return self._hold(emitters, lights, L, None, steady=True)
        L, E = analytic_emitter_light(self.scene, lights, light, emitters, self.device)
        return (L, E) if light is not None else self._hold(emitters, lights, L, E, steady=False)

    def _follow_light(self):
        """After a move, the held light vector brought to the world as it is (:meth:`_relit`)
        and the far field's answer for it, which the next :meth:`radiosity` with the same lights
        then finds: its shadow rays queued now, ahead of the objects' hemicubes, and a callable
        (or None) that the move runs while those trace (with hemicube rows and no static F, just
        before they are queued), which takes the rays' result and gives
        the far field its light (on the host beside a CPU device, :mod:`pydynrad.host.product`, so
        that nothing of it waits behind the trace; radiosity()'s own light pass and coarse level
        after a move had been a sizeable share of a moving frame. Queued ahead, the rays delay the
        trace a little, which the far field's light after it makes up: the same frame time, its
        cores busy either way; docs/decisions/0026-moving-frame-cost.md). Only for lights that were steady, the last call's
        those of the call before: lights that change every frame would have the move relight them
        for nothing, since radiosity() computes other lights' vector whole. An answer the far
        field cannot give (a light past float32, coarse sweeps that do not converge) is left to
        radiosity(), which raises it where the caller asked for it."""
        held = self._held_light
        if held is None or not held.steady or held.world is self.scene or held.emitters != "hemicube":
            return None
        try:
            relit = self._relit_queued(held.L, held.poses, held.lights)
        except Exception:  # a guess that failed (a device error) must not fail the move:
            return None  # radiosity() lights the world itself and raises what it meets there
        if relit is None:
            return None

        def follow() -> None:
            try:
                L = relit()
                if L is None:
                    return
                check_radiosity_range(L, self.scene.albedo, compute_dtype(self.storage))
                if self.far is not None:
                    self.far.light(L)
            except Exception:  # as above; a light past float32 is raised by radiosity()
                return
            self._hold(held.emitters, held.lights, L, None, steady=True)

        return follow

    def _hold(self, emitters: str, lights: list, L: np.ndarray, E: np.ndarray | None, steady: bool) -> tuple:
        """Keep (L, E) of ``lights`` for the world as it is, read-only; returns them. ``steady``:
        whether these lights are those of the call before (:meth:`_follow_light`)."""
        for a in (L, E):
            if a is not None:
                a.flags.writeable = False
        self._held_light = HeldLight(self.scene, emitters, lights, L, E, self._poses(), steady)
        return L, E

    def _poses(self) -> tuple:
        """The objects' poses now, as copies (the world's InstancedBVH is moved in place)."""
        return tuple(np.array(T) for T in self.scene.bvh.transforms) if self.objects else ()

    def _relit(self, L: np.ndarray, poses: tuple, lights: list) -> np.ndarray | None:
        """Light vector ``L`` of point, spot and directional ``lights`` in the world at ``poses``,
        brought to the world as it is: only the patches whose direct light a move may change
        are lit again (each the value a pass over every patch gives): every object's patch, and
        the static patches whose shadow ray to a light passes near a moved object's bounding
        sphere at its old or new pose (:func:`~pydynrad.dynamic.moves.shadow_rays_near`, widened
        by twice the rays' offset from their patches). None (the caller lights the whole world)
        where that does not hold: lights of another kind (a sky's light is a hemicube per patch,
        a luminaire's its own table), no lights, no objects, or a direct light past float32."""
        relit = self._relit_queued(L, poses, lights)
        return None if relit is None else relit()

    def _relit_queued(self, L: np.ndarray, poses: tuple, lights: list):
        """:meth:`_relit` with its shadow rays queued on the device: a callable that waits for
        them and returns its answer (None for a direct light past float32), or None where
        :meth:`_relit` does not hold for other reasons."""

        if (
            not self.objects
            or len(poses) != len(self.objects)
            or not lights
            or any(type(x) not in (PointLight, SpotLight, DirectionalLight) for x in lights)
        ):
            return None
        world, n = self.scene, len(self.static_scene)
        spheres = [
            s
            for o, before, now in zip(self.objects, poses, world.bvh.transforms)
            if not np.array_equal(before, now)
            for s in (o.bounding_sphere(before), o.bounding_sphere(now))
        ]
        redo = np.zeros(len(world), bool)
        redo[n:] = True
        slack = 2.0 * SHADOW_EPSILON * world.ray_scale
        widened = [(c, r * (1.0 + 1e-6) + slack) for c, r in spheres]
        for light in lights:
            redo[:n] |= shadow_rays_near(world.centers[:n], light, widened)
        patches = np.flatnonzero(redo)
        irradiance = _point_irradiance(world, None, None, lights, self.device, patches=patches, queued=True)

        def relit() -> np.ndarray | None:
            E = irradiance()
            if not np.all(np.isfinite(E)):
                return None  # light_vector's own pass says what overflows
            out = np.array(L)
            out[patches] = world.emission[patches].astype(np.float64) + world.albedo[patches].astype(np.float64) * E
            return out

        return relit

    def _solve_kept(self, X: np.ndarray) -> np.ndarray:
        """(M, 3) X + P_S K X for X (M, 3) on the local set: (I - P_S F_SS)^{-1} X."""
        if self.C == 3:
            KX = self._matrix.matvec(X.T)
        else:  # one K serves the three colour channels
            KX = self._matrix.matmat(X.T[None])[0]  # all three in one pass over K
        return X + self.scene.albedo[self._local_patches].astype(np.float64) * KX.T

    # -- drift -------------------------------------------------------------------------------------------
    @_locked
    def residual(self, probes: int | None = None) -> float:
        """K's relative error on ``probes`` random columns: max over them and the channels of
        ``|K e_j - K_fresh e_j|_inf`` over a scale of K's entries, an estimate of max entry
        error / max entry; inf where K holds non-finite values. ``probes``: 8 by default, or M
        where fewer (a local set of 4 has 4 columns to probe).

        The scale is the largest entry met (of the probed columns, and of F_SS, which K bounds
        from below entry by entry: K = F + F P F + ...). A column's own largest entry would not
        do: a patch that no other local patch sees has a column of zeros in a fresh K and of
        rounding residue (~1e-8) after exact swaps, which read as an error of ~1 and refreshed
        an accurate K again and again.

        The error d = K e_j - K_fresh e_j is solved for directly: with A = I - F_SS P_S,
        A d = A K e_j - F_SS e_j (the residual of K's own column, formed in float64 from K as
        stored), by GMRES from zero on the sparse F_SS to 1e-3 of d. Nothing is warm-started
        from K, so a fresh fp64 K reads ~1e-16 (not 0) and fp32 its own rounding (~1e-7 after a
        build); drift adds to that. Columns, not a positive probe vector: a positive x sees
        K x, whose error (1e-7 for fp32 after 10,000 frames) averages the entries' (9e-6).
        Cost O(probes * (M + iterations * nnz(F_SS))), no O(M^3) work.
        """
        from scipy.sparse.linalg import LinearOperator, gmres

        self._require_built()
        n_probe = min(8, self.M) if probes is None else integer(probes, "probes", 1, self.M)
        S, M = self._local_patches, self.M
        F = self._ff.square(S)
        rho = self._rho(S)
        worst, scale = 0.0, float(F.max()) if F.nnz else 0.0
        for j in self._rng.choice(M, size=n_probe, replace=False):
            e = np.zeros(M)
            e[j] = 1.0
            Ke = self._matrix.matvec(e)
            if not np.all(np.isfinite(Ke)):
                return float("inf")
            scale = max(scale, float(np.abs(Ke).max()))
            Fe = F @ e
            for c in range(self.C):
                A = LinearOperator((M, M), matvec=lambda v, r=rho[c]: v - F @ (r * v), dtype=np.float64)
                r = A.matvec(Ke[c]) - Fe
                if not r.any():
                    continue
                d, _ = gmres(A, r, rtol=1e-3, atol=0.0, restart=min(M, 50), maxiter=20)
                worst = max(worst, float(np.abs(d).max()))
        return worst / max(scale, 1e-300)


class HeldLight(NamedTuple):
    """The light vector of the last ``radiosity(lights=...)``: the world it lit (a move makes a
    new one), the emitter mode, the light objects, L and E, the objects' poses then, and whether
    the lights were those of the call before (steady: a move brings the vector along)."""

    world: object
    emitters: str
    lights: list
    L: np.ndarray
    E: np.ndarray | None
    poses: tuple
    steady: bool


def _same_lights(a: list, b: list) -> bool:
    """Whether two lists of light objects light the scene alike: the same objects, or equal ones
    in order (the frozen dataclasses compare their fields; a light without field equality, such as
    a LuminaireLight, only to itself)."""
    if len(a) != len(b):
        return False
    try:
        return all(x is y or (type(x) is type(y) and bool(x == y)) for x, y in zip(a, b))
    except (TypeError, ValueError):  # fields that do not compare to one truth value
        return False
