"""Distributed form-factor precomputation with Dask (``dask.distributed``).

:func:`precompute_distributed` fills a :class:`~pydynrad.FormFactorStore` with one
task per missing row block. The client writes the header once; each worker rebuilds the
scene (from a small :class:`SceneSpec`, or from arrays broadcast to it once), checks its
geometry hash against the header, computes its blocks with its own OpenCL context and writes
each block file itself, atomically. A stopped run resumes: only missing blocks become tasks.
The store's folder must be visible to every worker (any shared filesystem; a LocalCluster
shares the local one).

OpenCL contexts must not cross a fork (a forked child of a process holding one can hang), so
the LocalCluster starts its worker processes with the ``spawn`` method and every worker builds
its context after start, in a worker plugin (``opencl_worker_plugin_class``).

See docs/design.md, 'Distributed precompute'.
"""

from __future__ import annotations

import functools
import gc
import json
import logging
import os
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from ..device.devices import default_device
from ..errors import InvalidInputError, MissingExtraError, PydynradError
from ..geometry.scene import Scene
from ..progress import progress_bar
from ..rows.store import DEFAULT_BLOCK_ROWS, DEFAULT_TASK_ROWS, FormFactorStore, RowFunction
from ..scenes.byname import BUILTIN_SCENES, is_builtin, scene_by_name
from .store import compute_blocks, form_factor_rows, prepare_store, task_groups

__all__ = ["SceneSpec", "opencl_worker_plugin_class", "precompute_distributed"]


@dataclass(frozen=True)
class SceneSpec:
    """A scene by recipe, cheap to send to workers: a built-in name or a mesh file, plus parameters.

    ``SceneSpec("village", {"houses": 400})`` calls ``pydynrad.scenes.village(houses=400)``;
    ``SceneSpec("/data/house.obj", {"max_patch_area": 0.01})`` calls
    ``pydynrad.geometry.loading.load(path, max_patch_area=0.01)``. Parameters must be JSON values
    (they are recorded in the store header as its patching parameters).
    """

    name: str
    params: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        try:
            json.dumps(self.params, sort_keys=True)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(f"scene parameters must be JSON values: {exc}") from exc

    @property
    def is_builtin(self) -> bool:
        return is_builtin(self.name)

    def resolved(self) -> SceneSpec:
        """The same spec with a file path made absolute, so workers in other folders find it."""
        if self.is_builtin:
            return self
        p = Path(self.name).expanduser()
        if not p.is_file():
            raise InvalidInputError(
                f"scene {self.name!r} is neither a built-in scene ({', '.join(BUILTIN_SCENES)}) nor a mesh file"
            )
        return SceneSpec(str(p.resolve()), self.params)

    def build(self) -> Scene:
        """The scene, by :func:`pydynrad.scenes.byname.scene_by_name` (as the CLI builds it)."""
        return scene_by_name(self.resolved().name, **self.params)

    def recipe(self) -> dict:
        """JSON description: ``{"scene": name, **params}`` (what the store header records)."""
        return {"scene": self.name, **self.params}


def _as_spec(scene_spec) -> SceneSpec | Scene:
    if isinstance(scene_spec, (SceneSpec, Scene)):
        return scene_spec.resolved() if isinstance(scene_spec, SceneSpec) else scene_spec
    if isinstance(scene_spec, (str, os.PathLike)):
        return SceneSpec(str(scene_spec)).resolved()
    if isinstance(scene_spec, tuple) and len(scene_spec) == 2:
        return SceneSpec(str(scene_spec[0]), dict(scene_spec[1])).resolved()
    raise InvalidInputError(
        "scene_spec must be a SceneSpec, a built-in scene name or mesh path, a (name, params) pair or a Scene; "
        f"got {type(scene_spec).__name__}"
    )


@functools.cache
def opencl_worker_plugin_class() -> type:
    """The WorkerPlugin class that builds each worker's own OpenCL context at worker start.

    Made on first use so that ``import pydynrad`` does not import ``distributed``.
    """
    _require_dask("opencl_worker_plugin_class")
    from distributed.diagnostics.plugin import WorkerPlugin

    class OpenCLWorkerPlugin(WorkerPlugin):
        name = "pydynrad-opencl"

        def setup(self, worker) -> None:
            from pydynrad.device.devices import default_device

            default_device()

    return OpenCLWorkerPlugin


# Per worker process: the last scene built, keyed by its geometry hash. One entry only, since
# a million-patch scene with its BVH is large and a run works on one scene.
_WORKER_SCENE: dict[str, Scene] = {}


def _worker_scene(payload, geometry_hash: str) -> Scene:
    scene = _WORKER_SCENE.get(geometry_hash)
    if scene is None:
        scene = payload.build() if isinstance(payload, SceneSpec) else Scene(*payload)
        if scene.geometry_hash() != geometry_hash:
            raise InvalidInputError(
                f"the scene rebuilt on this worker (pid {os.getpid()}) has geometry hash {scene.geometry_hash()[:12]}..., "
                f"the store expects {geometry_hash[:12]}...; check that workers run the same pydynrad and see the same files"
            )
        _WORKER_SCENE.clear()
        _WORKER_SCENE[geometry_hash] = scene
    return scene


# Per worker process: the last prolongation read, keyed by its checksum (G's tasks all need it).
_WORKER_PROLONGATION: dict[str, object] = {}


def _worker_prolongation(store: FormFactorStore):
    digest = store._require_clusters()["prolongation_sha256"]
    pr = _WORKER_PROLONGATION.get(digest)
    if pr is None:
        pr = store.prolongation()
        _WORKER_PROLONGATION.clear()
        _WORKER_PROLONGATION[digest] = pr
    return pr


def _blocks_task(
    path: str,
    group: list[int],
    payload,
    geometry_hash: str,
    resolution: int,
    patching: dict,
    row_function: RowFunction,
    part: str = "F",
    samples: int = 1,
) -> tuple[list[int], int, float]:
    """Compute and write the consecutive blocks ``group`` of F or G on a worker; returns (group, rows, seconds)."""
    t0 = time.perf_counter()
    scene = _worker_scene(payload, geometry_hash)
    store = FormFactorStore.open(scene, path, resolution=resolution, patching=patching, samples=samples)
    pr = _worker_prolongation(store) if part == "G" else None
    rows = compute_blocks(store, scene, group, row_function, default_device(), part, pr)
    return group, rows, time.perf_counter() - t0


def _require_dask(feature: str, alternative: str = "") -> None:
    """Raise :class:`MissingExtraError` naming the ``dask`` extra if Dask's ``distributed`` is not
    installed. Deferred: Dask is an optional dependency (the ``dask`` extra), and ``import pydynrad``
    needs neither it nor its start-up time."""
    try:
        import dask  # noqa: F401
        import distributed  # noqa: F401
    except ImportError as exc:
        raise MissingExtraError(feature, "Dask", "dask", alternative=alternative, name=exc.name) from exc


def _start_client(workers: int | None, scheduler: str | None):
    _require_dask("precompute_distributed")
    import dask
    from distributed import Client, LocalCluster

    if scheduler is not None:
        if workers is not None:
            raise InvalidInputError(
                "give either workers (for a LocalCluster) or scheduler (an existing cluster), not both"
            )
        try:
            return Client(scheduler), None
        except ValueError as exc:  # distributed's address parser: no port, unknown scheme, ...
            problem = str(exc)
        # The Client fails so after starting its IO loop, and the half-built one is left in a
        # cycle through the traceback: its __del__ stops that loop on whichever thread the
        # collector next runs, and on a later LocalCluster's new IO loop thread that blocked the
        # cluster's start for 10 s, then failed it (distributed 2026.8). Collected here, now
        # that the exception is no longer held, with no other loop starting.
        gc.collect()
        raise InvalidInputError(
            f"malformed scheduler address {scheduler!r} ({problem}); expected one like tcp://host:8786"
        )
    n = workers if workers is not None else (os.cpu_count() or 1)
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise InvalidInputError(f"workers must be a positive integer; got {workers!r}")
    with dask.config.set({"distributed.worker.multiprocessing-method": "spawn"}):
        try:
            # The scheduler's HTTP server listens even without a dashboard, on 8787 unless told
            # otherwise; any free port spares a second precompute (or a user's own cluster) the
            # multi-line "Port 8787 is already in use" warning.
            cluster = LocalCluster(
                n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=logging.ERROR
            )
        except (RuntimeError, OSError) as exc:  # a worker died while starting ("Nanny failed to start.")
            raise PydynradError(
                f"the local Dask cluster of {n} workers failed to start ({exc}): "
                "a worker process exited or could not be spawned"
            ) from exc
    return Client(cluster), cluster


def precompute_distributed(
    scene_spec,
    path,
    *,
    resolution: int,
    block_rows: int = DEFAULT_BLOCK_ROWS,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool | None = None,
    verify: bool = False,
    row_function: RowFunction = form_factor_rows,
    blocks: Iterable[int] | None = None,
    task_rows: int = DEFAULT_TASK_ROWS,
    clusters=None,
    cluster_resolution: int | None = None,
    cluster_params: dict | None = None,
    compute_f: bool = True,
    cluster_basis: str = "linear",
    samples: int = 1,
) -> FormFactorStore:
    """Compute every missing block of the store at ``path`` on a Dask cluster; returns the store.

    Parameters
    ----------
    scene_spec : SceneSpec, str, (name, params) or Scene
        The scene. A spec (built-in name or mesh path, with parameters) is what workers get:
        a few bytes. A :class:`~pydynrad.geometry.scene.Scene` is sent as its (vertices, faces)
        arrays, broadcast once to every worker.
    path : folder of the store (created, or resumed if its header matches).
    resolution : hemicube resolution (pixels on the top face's side).
    samples : hemicubes per row (1, 4, 16, ...: :func:`pydynrad.form_factors`), recorded in the
        header; a resume with other samples raises :class:`~pydynrad.rows.StoreMismatchError`.
    block_rows : rows per block file (the unit of reads and of resuming).
    workers : worker processes of the LocalCluster started by default (one thread each;
        default: one per CPU core).
    scheduler : address of an existing cluster's scheduler (``tcp://host:8786``) instead.
    progress : a tqdm bar over the rows (None: when stderr is a terminal).
    verify : re-check finished blocks' checksums and recompute corrupt ones.
    row_function : ``f(scene, rows, resolution, device=...) -> csr``; must be importable (or
        cloudpickle-able) on the workers. Default: :func:`pydynrad.precompute.store.form_factor_rows`.
    blocks : compute only these block indices (to split one store over several runs).
    task_rows : rows per task: consecutive missing blocks are computed by one row-function
        call of at most this many rows (at least one block), amortising per-call set-up.
    clusters, cluster_resolution, cluster_params, compute_f, cluster_basis : the far field's G beside F, as
        for :func:`pydynrad.precompute.store.compute_store`; workers read the prolongation from the store.

    The patching parameters recorded in the header are the spec's recipe (empty for a Scene).
    """
    _require_dask("precompute_distributed")
    from distributed import as_completed

    spec = _as_spec(scene_spec)
    scene = spec if isinstance(spec, Scene) else spec.build()
    patching = {} if isinstance(spec, Scene) else spec.recipe()
    path = Path(path).resolve()
    store, todo = prepare_store(
        scene,
        path,
        resolution=resolution,
        block_rows=block_rows,
        patching=patching,
        verify=verify,
        blocks=blocks,
        clusters=clusters,
        cluster_resolution=cluster_resolution,
        cluster_params=cluster_params,
        compute_f=compute_f,
        cluster_basis=cluster_basis,
        samples=samples,
    )
    if not todo["F"] and not todo["G"]:
        return store
    client, cluster = _start_client(workers, scheduler)
    try:
        client.register_plugin(opencl_worker_plugin_class()())
        payload = spec if isinstance(spec, SceneSpec) else client.scatter((scene.vertices, scene.faces), broadcast=True)
        ghash = scene.geometry_hash()
        rows = sum(len(store.block_range(k)) for part in ("F", "G") for k in todo[part])
        with progress_bar(
            progress, total=rows, unit="row", desc="form factors" + (" and G" if todo["G"] else "")
        ) as bar:
            # F first, then G: G's tasks then find F's blocks on disk and sum them (compute_blocks), no hemicubes.
            for part in ("F", "G"):
                futures = [
                    client.submit(
                        _blocks_task,
                        str(path),
                        group,
                        payload,
                        ghash,
                        resolution,
                        patching,
                        row_function,
                        part,
                        samples,
                        pure=False,
                        key=f"pydynrad-{part}blocks-{ghash[:16]}-{group[0]}-{group[-1]}",
                    )
                    for group in task_groups(store, todo[part], task_rows)
                ]
                for fut in as_completed(futures):
                    _, nrows, _ = fut.result()  # re-raises a worker's error here, with its traceback
                    bar.update(nrows)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return store
