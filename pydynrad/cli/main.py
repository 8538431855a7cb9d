"""The ``pydynrad`` command line: one subcommand per main job.

Errors a user can cause (bad paths, bad options, unreadable meshes) end with one clear line
on stderr and exit status 2, never a traceback; warnings print as one line each.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from .. import defaults
from .._version import __version__
from ..atomic import check_file_target, check_parent_folder, write_atomic
from ..bake import MESH_FORMATS, bake_lightmap, export_mesh
from ..bake.lightmap import MIN_TEXELS_PER_PATCH, check_texel_density
from ..checks import resolution, stops
from ..comparison import reference_frame
from ..device.devices import default_device, list_devices
from ..dynamic import DynamicRadiosity, MovingObjects
from ..errors import InvalidInputError, PydynradError
from ..farfield.estimate import DEFAULT_TOLERANCE
from ..farfield.gather import clusters_without_f
from ..formfactors import checked_samples, form_factors
from ..geometry.camera import Camera, check_image_memory
from ..geometry.objects import RigidObject
from ..image_io import LINEAR_FORMATS, _format_for, write_image
from ..lights.sources import PointLight
from ..lights.text import light_syntax, parse_light, plain_number, vector
from ..paths import CameraPath, LightTrack, ObjectTrack, load_walk
from ..precompute.distributed import SceneSpec, _require_dask, precompute_distributed
from ..precompute.poses import precompute_poses, stored_poses
from ..precompute.store import compute_store
from ..renderer import RENDER_BYTES_PER_PIXEL, render
from ..rows.files import is_form_factor_file, open_form_factors, recorded_resolution, save_form_factors, whole_matrix
from ..rows.store import DEFAULT_BLOCK_ROWS, HEADER, POSE_HEADER, FormFactorStore
from ..scenes import block, cornell_box
from ..scenes.byname import BUILTIN_SCENES, scene_by_name
from ..solution import solve
from ..viewer import view
from ..viewer.server import require_websockets
from ..walks import walk

__all__ = ["main", "build_parser", "load_scene", "BUILTIN_SCENES"]


DEMO_DIR = "pydynrad-demo"
#: Chart texels of a lightmap when --texels-per-unit is not given (about a 1024 x 1024 image).
LIGHTMAP_TEXELS = 0.75 * 2**20
DEFAULT_WIDTH, DEFAULT_HEIGHT = defaults.WIDTH, defaults.HEIGHT
#: The Cornell box camera's vertical field of view (degrees), as in path files.
DEFAULT_FOV_Y = defaults.FOV_Y


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump): the message and where to get help."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


# -- option types -----------------------------------------------------------------------------
def _vec3(text: str) -> tuple[float, float, float]:
    try:
        return vector(text, "value")
    except InvalidInputError:
        raise argparse.ArgumentTypeError(f"expected three finite numbers X,Y,Z; got {text!r}") from None


def _digits(text: str) -> int | None:
    """``text`` as a whole number where it is ASCII digits alone (str.isdigit and int() take
    other scripts' digits, and int() "1_0"), else None."""
    return int(text) if text.isascii() and text.isdigit() else None


def _size(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    if len(parts) != 2 or not all((_digits(p) or 0) > 0 for p in parts):
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, e.g. 320x240; got {text!r}")
    return int(parts[0]), int(parts[1])


def _positive_int(text: str) -> int:
    if (_digits(text) or 0) < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1; got {text!r}")
    return int(text)


def _resolution(text: str) -> int:
    try:
        return resolution(text if _digits(text) is None else _digits(text))
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _ranged(lo: float, hi: float, integral: bool = False):
    """An argparse type: a finite number (a whole one when ``integral``) in [lo, hi]."""

    def parse(text: str):
        v = plain_number(text)
        v = np.nan if v is None else v
        if not (np.isfinite(v) and lo <= v <= hi) or (integral and v != int(v)):
            kind = "a whole number" if integral else "a number"
            raise argparse.ArgumentTypeError(f"expected {kind} in {lo:g}..{hi:g}; got {text!r}")
        return int(v) if integral else v

    return parse


def _count(text: str) -> int:
    if _digits(text) is None:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0; got {text!r}")
    return int(text)


def _frame_number(text: str) -> int:
    """A frame number, negative from the end: ASCII digits with an optional minus sign."""
    k = _digits(text.removeprefix("-"))
    if k is None:
        raise argparse.ArgumentTypeError(f"expected a frame number (negative: from the end); got {text!r}")
    return -k if text.startswith("-") else k


def _positive_float(text: str) -> float:
    v = plain_number(text)
    v = float("nan") if v is None else v
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number; got {text!r}")
    return v


def _stops(text: str) -> float:

    value = plain_number(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"expected a number of stops; got {text!r}")
    try:  # out of range: one line, before any work
        return stops(value)
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _exposure(text: str):
    """--exposure: "auto" (pydynrad.defaults.auto_exposure) or a number of stops."""
    return "auto" if text.strip().lower() == "auto" else _stops(text)


def _chosen_exposure(args, values, weights=None) -> float:
    """--exposure in stops; for "auto" the rule's choice for ``values``, said on stdout."""
    exposure = defaults.exposure_or_auto(args.exposure, values, weights)
    if args.exposure == "auto":
        print(
            f"exposure: {exposure:+.2f} stops (auto: log-average luminance to {defaults.KEY_VALUE}; "
            "--exposure STOPS sets it)"
        )
    return exposure


def _local_size(args, n: int, must_hold: int = 0) -> int:
    """--local-size, or the rule min(1024, N // 2) (pydynrad.defaults.default_local_size), said on stdout."""
    if args.local_size is not None:
        return min(args.local_size, n)
    m = defaults.default_local_size(n, must_hold)
    print(
        f"local set: {m} of {n} patches (default min({defaults.LOCAL_SIZE_CAP}, N/2): {n - m} stay in the far "
        "field; --local-size M sets it)"
    )
    return m


def _light(text: str):
    try:
        return parse_light(text)
    except PydynradError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _progress(args) -> bool | None:
    """--quiet: no bars; otherwise the library's rule (a bar once the work has taken two seconds)."""
    return False if args.quiet else None


# -- scenes and form-factor files -------------------------------------------------------------
def load_scene(name: str, max_edge: float | None = None):
    """SCENE: a built-in name or a mesh file (:func:`pydynrad.scenes.byname.scene_by_name`),
    split to ``max_edge`` (scene units) when given; None keeps each scene's default patching."""
    return scene_by_name(name, **_patching(max_edge))


def _patching(max_edge: float | None) -> dict:
    """The scene parameters --max-edge stands for (also what a store records as its patching)."""
    return {} if max_edge is None else {"max_edge": max_edge}


def _checked_target(path, suffixes: tuple[str, ...] | None = None) -> Path:
    """``path`` as a Path, after checking its folder exists and no folder is in its place (and its
    suffix, or image format)."""

    path = Path(path)
    if suffixes is None:
        _format_for(path)
    elif path.suffix.lower() not in suffixes:
        raise InvalidInputError(f"output file {str(path)!r} must end in {' or '.join(suffixes)}")
    return check_file_target(path)


def _samples(args) -> int:
    """--samples (1 when not given) checked against --resolution, before any work."""
    return checked_samples(1 if args.samples is None else args.samples, args.resolution)


def _form_factors(args, scene):
    """F from --form-factors PATH when given (a matrix for a .npz file, a RowCache of
    --cache-mb over a store folder, closed when the command ends; made with --samples where
    given), else computed now."""
    if getattr(args, "form_factors", None):
        # Every later hemicube (a moving object's rows, stored poses) at F's resolution: the
        # file's, or --resolution where it is given and is the file's.
        F = open_form_factors(
            scene,
            args.form_factors,
            cache_bytes=int(args.cache_mb * 2**20),
            samples=args.samples,
            resolution=args.resolution,
        )
        args.resolution = recorded_resolution(args.form_factors)
        if hasattr(F, "close"):
            args.cleanup.callback(F.close)
            print(f"form factors: {F.source!r} through a {args.cache_mb:g} MiB row cache")
        else:
            print(f"form factors: {args.form_factors} ({F.nnz} non-zeros)")
        return F

    t0 = time.perf_counter()
    if args.resolution is None:
        args.resolution = args.default_resolution
    samples = _samples(args)
    F = form_factors(scene, resolution=args.resolution, progress=_progress(args), samples=samples)
    print(
        f"form factors: {len(scene)} patches, resolution {args.resolution}"
        f"{f', {samples} hemicubes per row' if samples > 1 else ''}, {F.nnz} non-zeros, "
        f"{time.perf_counter() - t0:.1f} s"
    )
    return F


def _image_size(args) -> tuple[int, int]:
    """(width, height) from --width/--height, or from the deprecated --size WxH (one release)."""
    if args.size is not None:
        if args.width is not None or args.height is not None:
            raise InvalidInputError("give --width/--height or the deprecated --size, not both")
        warnings.warn(
            "--size WxH is deprecated and will be removed in the next release; use --width W --height H",
            DeprecationWarning,
            stacklevel=2,
        )
        return args.size
    return args.width or DEFAULT_WIDTH, args.height or DEFAULT_HEIGHT


def _fov_y(args) -> float:
    """--fov-y, or the deprecated --fov (one release)."""
    if args.fov is not None:
        if args.fov_y is not None:
            raise InvalidInputError("give --fov-y or the deprecated --fov, not both")
        warnings.warn(
            "--fov is deprecated and will be removed in the next release; use --fov-y", DeprecationWarning, stacklevel=2
        )
        return args.fov
    return DEFAULT_FOV_Y if args.fov_y is None else args.fov_y


def _default_camera(scene, args):
    """A camera from --position/--look-at/--up/--fov-y/--width/--height; unset parts frame the scene:
    looking at the bounding-box centre along +z from 1.1 diagonals away (the Cornell box's
    published view)."""

    lo, hi = scene.bbox.astype(np.float64)
    centre = (lo + hi) / 2
    look_at = np.asarray(args.look_at if args.look_at else centre)
    position = args.position if args.position else look_at - np.array([0.0, 0.0, 1.1 * scene.scale])
    width, height = _image_size(args)
    camera = Camera(position, look_at, args.up, _fov_y(args), width, height)
    check_image_memory(camera, RENDER_BYTES_PER_PIXEL, "rendering")  # before the solve, not after it
    return camera


# -- subcommands -----------------------------------------------------------------------------
def _cmd_info(args: argparse.Namespace) -> int:
    print("OpenCL devices (select one with PYOPENCL_CTX=<platform>:<device>):")
    for d in list_devices():
        print(
            f"  [{d['PYOPENCL_CTX']}] {d['platform']} / {d['device']} ({d['type']}, "
            f"{d['compute_units']} CU, {d['global_memory_MiB']} MiB)"
        )
    print("pydynrad uses:")
    for k, v in default_device().info().items():
        print(f"  {k:18s} {v}")
    return 0


def _cmd_formfactors(args: argparse.Namespace) -> int:
    _samples(args)  # a bad K fails before the scene is built
    out = Path(args.output)
    if out.suffix.lower() == ".npz":
        return _formfactors_file(args, out)
    return _formfactors_store(args, out)


def _formfactors_file(args: argparse.Namespace, out: Path) -> int:
    given = [
        o
        for o, v in (
            ("--workers", args.workers),
            ("--scheduler", args.scheduler),
            ("--block-rows", args.block_rows),
            ("--clusters", args.clusters),
            ("--cluster-resolution", args.cluster_resolution),
        )
        if v is not None
    ]
    given += [o for o, v in (("--no-f", args.no_f), ("--verify", args.verify), ("--poses", args.poses)) if v]
    if given:
        raise InvalidInputError(f"{', '.join(given)} apply to a store folder; {str(out)!r} is a single .npz file")
    out = _checked_target(out, (".npz",))  # fail before the work, not after
    if out.exists() and not args.force and not is_form_factor_file(out):
        raise InvalidInputError(
            f"{str(out)!r} exists and is not a pydynrad form-factor file: not overwriting it "
            "(pass --force to replace it)"
        )
    scene = load_scene(args.scene, args.max_edge)
    print(f"scene: {scene!r}")
    F = _form_factors(args, scene)
    save_form_factors(scene, out, F, args.resolution, _samples(args))
    print(f"wrote {out} ({out.stat().st_size / 2**20:.1f} MiB)")
    return 0


def _cluster_labels(args: argparse.Namespace, scene) -> tuple[np.ndarray | None, dict]:
    """--clusters (a count C, "auto", or LABELS.npy) as (N,) labels and the record of where they
    came from, or (None, {})."""
    if args.clusters is None:
        if args.cluster_resolution is not None or args.no_f:
            raise InvalidInputError("--cluster-resolution and --no-f need --clusters (the clusters G is made for)")
        return None, {}
    if args.clusters == "auto" or args.clusters.isdigit():
        # A store's walks have no F in memory: its clusters keep light components apart from hemicubes.
        clusters = clusters_without_f(
            scene, None if args.clusters == "auto" else int(args.clusters), progress=_progress(args)
        )
        return clusters.labels, {"made_by": "pydynrad.farfield.gather.clusters_without_f", "clusters": clusters.count}
    path = Path(args.clusters)
    try:
        labels = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InvalidInputError(
            f"--clusters {str(path)!r}: not a readable .npy file of cluster labels ({exc})"
        ) from None
    if labels.shape != (len(scene),) or not np.issubdtype(labels.dtype, np.integer) or labels.min() < 0:
        raise InvalidInputError(
            f"--clusters {str(path)!r} must hold {len(scene)} integers >= 0 (one cluster per "
            f"patch); got shape {labels.shape}, dtype {labels.dtype}"
        )
    return labels, {"labels_file": str(path.resolve())}


def _formfactors_store(args: argparse.Namespace, out: Path) -> int:
    """Create or resume the store at ``out``: in this process (--workers 0) or on a Dask cluster."""

    dask = bool(args.workers) or args.scheduler is not None  # in this process unless Dask is asked for
    if dask:  # without the dask extra: one line naming it, before the scene is loaded
        given = "--scheduler" if args.scheduler else f"--workers {args.workers}"
        _require_dask(given, "leave out --workers (or give --workers 0) to compute in this process without it")
    check_parent_folder(out)
    walk_poses = _walk_poses(args.poses) if args.poses else None  # a bad path file fails before the work
    scene = load_scene(args.scene, args.max_edge)
    print(f"scene: {scene!r}")
    labels, cluster_params = _cluster_labels(args, scene)
    # The recipe is the store's patching record, the same for every way of computing it, so
    # a store begun in this process can be finished on a cluster and the other way round.
    spec = SceneSpec(args.scene, _patching(args.max_edge)).resolved()
    block_rows = args.block_rows
    if (out / HEADER).exists():
        store = FormFactorStore.open(
            scene, out, resolution=args.resolution, patching=spec.recipe(), samples=_samples(args)
        )
        block_rows = block_rows or store.block_rows
        # Finished blocks of F are read and their checksums (bound to this store) checked on
        # every resume, G's too with --verify: a corrupt or foreign block is deleted and
        # recomputed, never reported as done.
        for part in ("F", "G") if args.verify and store.has_clusters else ("F",):
            found = store.verify(part, remove=True)
            corrupt = found["corrupt"]
            print(
                f"{'verified' if args.verify else 'resuming'} {out}{', G' if part == 'G' else ''}: "
                f"{len(found['verified'])} of {store.n_blocks} blocks already done"
                + (
                    f"; {len(corrupt)} fail their checksum and are recomputed (block {', '.join(map(str, corrupt[:8]))}"
                    f"{', ...' if len(corrupt) > 8 else ''})"
                    if corrupt
                    else ""
                )
                + (f"; {len(found['missing'])} missing" if args.verify and found["missing"] else "")
            )
        if args.verify and (out / "poses.json").exists():  # damaged pose files: removed, then recomputed by --poses
            bad = store.verify_poses(remove=True)["corrupt"]
            if bad:
                print(
                    f"verified {out}, poses: {len(bad)} damaged configuration files removed "
                    f"({', '.join(p.name for p in bad[:4])}{', ...' if len(bad) > 4 else ''}); --poses computes them again"
                )
    elif args.verify:
        raise InvalidInputError(f"--verify checks an existing store; there is none at {str(out)!r}")
    block_rows = block_rows or DEFAULT_BLOCK_ROWS
    common = dict(
        resolution=args.resolution,
        samples=_samples(args),
        block_rows=block_rows,
        progress=_progress(args),
        clusters=labels,
        cluster_resolution=args.cluster_resolution,
        cluster_params=cluster_params,
        compute_f=not args.no_f,
    )
    t0 = time.perf_counter()
    if not dask:
        store = compute_store(scene, out, patching=spec.recipe(), **common)
        where = "this process (no Dask; --workers N or --scheduler for a Dask cluster)"
    else:
        workers = None if args.scheduler else args.workers
        store = precompute_distributed(spec, out, workers=workers, scheduler=args.scheduler, **common)
        where = f"the cluster at {args.scheduler}" if args.scheduler else f"a LocalCluster of {workers} workers"
    seconds = time.perf_counter() - t0
    g = ""
    if store.has_clusters:
        g = (
            f", G for {store.cluster_count} clusters at resolution {store.cluster_resolution} "
            f"({store.cluster_basis} basis)"
        )
    f_done = "" if store.complete else " (F's rows not computed)"
    print(
        f"wrote store {out}: {store.n_patches} patches in {store.n_blocks} blocks of {store.block_rows} rows{f_done}{g}, "
        f"{store.nbytes_on_disk / 2**20:.1f} MiB, {seconds:.1f} s in {where}"
    )
    if walk_poses is not None:
        _store_poses(args, scene, store, *walk_poses)
    return 0


def _walk_poses(path) -> tuple[list, list]:
    """The moving objects of path file ``path`` and their configuration at each frame of its
    walk (the poses ``pydynrad walk --path`` moves them to)."""
    loaded = load_walk(path)
    if not loaded.objects:
        raise InvalidInputError(f"--poses {str(path)!r}: the path file moves no objects")
    frames = len(loaded.path)
    return [t.object for t in loaded.objects], [[t.at(k, frames) for t in loaded.objects] for k in range(frames)]


def _store_poses(args: argparse.Namespace, scene, store, objects, configs) -> None:
    """--poses: the rows of ``objects`` at each configuration into the store's per-pose part."""

    before = len(store.pose_files()) if (store.path / POSE_HEADER).exists() else 0
    t0 = time.perf_counter()
    poses = precompute_poses(scene, objects, configs, resolution=args.resolution, store=store, progress=_progress(args))
    print(
        f"wrote the poses of {args.poses}: {len(poses) - before} new configurations ({len(poses)} in the store, "
        f"{len(configs)} frames), {time.perf_counter() - t0:.1f} s"
    )


def _stored_poses(F, scene, tracks, resolution: int):
    """The per-pose rows of ``tracks``' objects in the store behind ``F``, or None where F is
    no store or its store holds no poses (then the moves compute their rows)."""

    store = getattr(F, "source", F)
    if not tracks or not isinstance(store, FormFactorStore) or not (store.path / POSE_HEADER).exists():
        return None
    poses = stored_poses(scene, [t.object for t in tracks], store, resolution)
    print(f"poses: {len(poses)} configurations of the objects stored in {store.path}")
    return poses


def _cmd_render(args: argparse.Namespace) -> int:

    _checked_target(args.output)  # reject a bad image name before any work
    scene = load_scene(args.scene, args.max_edge)
    camera = _default_camera(scene, args)
    sol = solve(scene, whole_matrix(_form_factors(args, scene)), args.light, progress=_progress(args))
    img = render(scene, sol.radiosity, camera, args.shading)
    linear = _format_for(Path(args.output))[1]  # auto: linear float images keep their values
    write_image(args.output, img, 0.0 if linear and args.exposure == "auto" else _chosen_exposure(args, img))
    print(f"wrote {args.output} ({camera.width}x{camera.height}, {sol.iterations} bounces)")
    if not img.any():  # e.g. the default camera outside a closed scene sees only its backs
        _warn_black(args.output, bool(sol.radiosity.any()))
    return 0


def _warn_black(what, lit: bool, camera: str = "the camera with --position and --look-at", are: bool = False) -> None:
    """One line on stderr that ``what`` came out black, and why: no light, or a view of none."""
    why = (
        "the scene has no light (no emission and no --light)"
        if not lit
        else f"no pixel sees a lit front face (place {camera})"
    )
    print(f"warning: {what} {'are' if are else 'is'} black: {why}", file=sys.stderr)


def _texels_per_unit(args, scene) -> float:
    """--texels-per-unit, or a density giving about LIGHTMAP_TEXELS texels of charts (at least
    MIN_TEXELS_PER_PATCH for the median patch, rounded up)."""
    if args.texels_per_unit is not None:
        return args.texels_per_unit
    tpu = max(
        float(np.sqrt(LIGHTMAP_TEXELS / scene.areas.sum(dtype=np.float64))),
        float(np.sqrt(MIN_TEXELS_PER_PATCH / np.median(scene.areas))),
    )
    step = 10.0 ** (np.floor(np.log10(tpu)) - 1)  # two significant digits, rounded up: never below the floor
    return float(f"{np.ceil(tpu / step * (1 - 1e-12)) * step:.2g}")


def _cmd_bake(args: argparse.Namespace) -> int:

    # Names are checked before any work: a typo must not cost a solve.
    out = _checked_target(args.output, (".glb",) if args.lightmap else MESH_FORMATS)
    if args.lightmap:
        lightmap_path = _checked_target(args.lightmap, tuple(LINEAR_FORMATS))
    source = Path(args.scene)
    for target in [out] + ([lightmap_path] if args.lightmap else []):
        if target.exists() and source.is_file() and target.samefile(source):  # the input replaced by the bake
            raise InvalidInputError(f"output {str(target)!r} is the scene file being baked: write the bake elsewhere")
    if args.lightmap and out.resolve() == lightmap_path.resolve():
        raise InvalidInputError(f"--lightmap and -o name the same file {str(out)!r}")
    scene = load_scene(args.scene, args.max_edge)
    print(f"scene: {scene!r}")
    if args.lightmap:
        check_texel_density(scene, _texels_per_unit(args, scene))  # before the solve it would waste
    sol = solve(scene, whole_matrix(_form_factors(args, scene)), args.light, progress=_progress(args))
    print(f"solved: {sol.iterations} bounces, {len(args.light)} light(s) besides the emission")
    if not sol.radiosity.any():
        _warn_black(f"the bake of {args.scene}", False)
    exposure = _chosen_exposure(args, sol.radiosity, scene.areas)  # the area-weighted log-average of the patches
    t0 = time.perf_counter()
    if not args.lightmap:
        export_mesh(scene, sol.radiosity, out, exposure=exposure, crease_angle=args.crease_angle)
        print(f"wrote {out} (vertex colours, {time.perf_counter() - t0:.2f} s)")
        return 0
    tpu = _texels_per_unit(args, scene)
    lm = bake_lightmap(
        scene, sol.radiosity, tpu, padding=args.padding, crease_angle=args.crease_angle, progress=_progress(args)
    )
    # As one pair: a mesh never beside a lightmap not its own, even after kill -9.
    lm.write_pair(out, lightmap_path, exposure=exposure)
    h, w = lm.shape
    print(
        f"wrote {lightmap_path} ({w}x{h} texels at {tpu:g} per unit, {100 * lm.coverage:.0f}% in charts) and {out} "
        f"(lightmap UVs in TEXCOORD_1, the lightmap embedded as 8-bit sRGB at the exposure) in "
        f"{time.perf_counter() - t0:.2f} s"
    )
    return 0


def _walk_and_report(args, scene, path, lights, F, out_dir, reference_frames, objects=()) -> object:

    opts = _dynamic_options(args)
    if objects:  # their rows by hemicube at F's resolution, so reference frames match F
        opts["resolution"] = args.resolution

        opts["objects"] = MovingObjects((), poses=_stored_poses(F, scene, objects, args.resolution))
    if out_dir is not None and Path(out_dir).is_dir():
        check_file_target(Path(out_dir) / "summary.txt")  # written last: checked first
    n_objects = sum(len(t.object) for t in objects)
    local_size = _local_size(args, len(scene) + n_objects, n_objects)
    video = getattr(args, "video", None)
    if out_dir is None and video is None:
        print(
            "no --out: each frame is solved (update + lighting) and timed, not rendered or written; "
            "--out DIR (or --video FILE) renders the frames and writes them"
        )
    result = walk(
        scene,
        path,
        lights=lights,
        objects=objects,
        form_factors=F,
        local_size=local_size,
        solver_options=opts,
        shading=args.shading,
        output=out_dir,
        image_format=args.format,
        exposure=args.exposure,
        reference_frames=reference_frames,
        progress=_progress(args),
        render=out_dir is not None or video is not None,
        video=video,
    )
    if video is not None:
        print(f"wrote {video} ({len(result.frames)} frames at 24 frames/s)")
    if (out_dir is not None or video is not None) and args.exposure == "auto":
        print(
            f"exposure: {result.exposure:+.2f} stops for every frame (auto: the first lit frame's log-average "
            f"luminance to {defaults.KEY_VALUE}; --exposure STOPS sets it)"
        )
    summary = result.summary()
    print(summary)
    black = [f for f in result.frames if f.black]
    if black:
        _warn_black(
            f"{len(black)} of {len(result.frames)} frames (the first {black[0].index})",
            all(f.lit for f in black),
            "the path's cameras to look at lit faces",
            are=True,
        )
    if out_dir is not None:
        write_atomic(Path(out_dir) / "summary.txt", (summary + "\n").encode())
        print(f"images in {out_dir}/")
    return result


def _cmd_walk(args: argparse.Namespace) -> int:
    loaded = load_walk(args.path)
    scene = load_scene(args.scene, args.max_edge)
    F = _form_factors(args, scene)
    _walk_and_report(
        args, scene, loaded.path, loaded.lights + list(args.light), F, args.out, args.reference_frames, loaded.objects
    )
    return 0


def demo_setup(frames: int, width: int, height: int):
    """The demo's Cornell box walk: the camera moves from the published viewpoint up to the
    box's open side and pans across it, while a point light circles above the blocks."""

    positions = [(278, 273, -800), (278, 273, -450), (150, 320, -250), (400, 220, -200)]
    look_ats = [(278, 273, 0), (278, 260, 280), (300, 200, 300), (250, 220, 300)]
    cam = CameraPath(positions, look_ats, frames, fov_y=DEFAULT_FOV_Y, width=width, height=height)
    # Above both blocks (the tall one is 330 mm high), below the ceiling (548.8 mm).
    orbit_keys = [(130, 420, 130), (130, 420, 430), (430, 420, 430), (430, 420, 130), (130, 420, 130)]
    # W/sr: the box declares millimetres, so irradiance is per square metre; the lamp
    # lights it as (60000, 50000, 30000) had when intensities were read per mm^2.
    light = LightTrack(PointLight(orbit_keys[0], (0.06, 0.05, 0.03)), orbit_keys)
    return cam, [light]


def demo_block():
    """The demo's moving block (``--moving-block``): a green 100 mm cube (48 patches) gliding
    and turning 45 degrees through the box's back left, clear of both blocks and the light."""

    keys = []
    for z, angle in ((460.0, 0.0), (395.0, 22.5), (330.0, 45.0)):
        c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        T = np.eye(4)
        T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
        T[:3, 3] = (160.0, 230.0, z)
        keys.append(T)
    return ObjectTrack(RigidObject(block(100.0, 1, albedo=(0.14, 0.45, 0.091)), keys[0], name="moving block"), keys)


def _cmd_demo(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    scene = cornell_box(max_edge=args.max_edge)
    print(f"scene: {scene!r}")
    F = _form_factors(args, scene)
    path, lights = demo_setup(args.frames, *_image_size(args))
    out = Path(args.out)
    objects = [demo_block()] if args.moving_block else []
    result = _walk_and_report(args, scene, path, lights, F, out, [0, args.frames - 1], objects)
    rows = "" if args.no_far_field else "rows: local only, far field; columns: "
    print(
        f"comparison images ({rows}dynamic | full | relative error): "
        f"{', '.join(str(f.comparison_path) for f in result.frames if f.comparison_path)}"
    )
    print(f"demo done in {time.perf_counter() - t0:.1f} s")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:

    _checked_target(args.output)
    scene = load_scene(args.scene, args.max_edge)
    camera = _default_camera(scene, args)
    F = _form_factors(args, scene)
    dyn = DynamicRadiosity(scene, F, local_size=_local_size(args, len(scene)), **_dynamic_options(args))
    dyn.update(camera.position)
    local_only = dyn.radiosity(args.light, far_field=False) if dyn.far is not None else None
    ref = reference_frame(
        scene,
        F,
        dyn.radiosity(args.light),
        camera,
        lights=args.light,
        shading=args.shading,
        exposure=args.exposure,
        local_only=local_only,
    )
    write_image(args.output, ref.image)
    if args.exposure == "auto":
        print(
            f"exposure: {ref.exposure:+.2f} stops (auto: the full solution's log-average luminance to "
            f"{defaults.KEY_VALUE}; --exposure STOPS sets it)"
        )
    if ref.black:  # a view of no lit face: its 0% error says nothing
        _warn_black(f"the view of {args.output}", bool(ref.full.any()))
    answers = [("far field", ref.error, ref.pixel_error)] if local_only is not None else []
    answers.append(
        ("local only", ref.local_only_error, ref.local_only_pixel_error)
        if local_only is not None
        else ("local only", ref.error, ref.pixel_error)
    )
    print(f"dynamic ({dyn.local_patches.size} of {len(scene)} patches local) vs full radiosity:")
    for name, error, stats in answers:
        print(
            f"  {name:10s} relative RMS error {100 * error:.3g}% over patches; per pixel mean "
            f"{100 * stats['mean']:.3g}%, 99th percentile {100 * stats['p99']:.3g}%"
        )
    if dyn.error_estimate is not None:
        print(f"  far field's own {dyn.error_estimate}")
    rows = (
        "rows: local only (top) and with far field (bottom), each on its own error scale; "
        if local_only is not None
        else ""
    )
    scales = " and ".join(f"{100 * stats['vmax']:.3g}%" for _, _, stats in answers[::-1])
    print(f"wrote {args.output} ({rows}columns: dynamic | full | error map, colour bar 0 to {scales})")
    return 0


def _cmd_view(args: argparse.Namespace) -> int:
    require_websockets()  # the optional 'view' extra, checked before any form factor is computed
    scene = load_scene(args.scene, args.max_edge)
    loaded = load_walk(args.path) if args.path else None
    F = _form_factors(args, scene)
    viewer = view(
        scene,
        F,
        lights=list(args.light),
        path=loaded,
        local_size=args.local_size,
        solver_options={**_dynamic_options(args), "resolution": args.resolution},
        host=args.host,
        port=args.port,
        open_browser=args.open,
    )
    print(f"pydynrad view: {viewer.url} (M = {viewer.dynamic.M}; Ctrl-C stops it)", flush=True)
    viewer.serve_forever()
    return 0


# -- the parser -------------------------------------------------------------------------------
def _add_scene(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "scene",
        metavar="SCENE",
        help=f"a mesh file trimesh reads (.obj with .mtl, .ply, .glb, .gltf, .stl, .off) or a built-in "
        f"scene: {', '.join(BUILTIN_SCENES)}",
    )
    p.add_argument(
        "--max-edge",
        type=_positive_float,
        default=None,
        metavar="LEN",
        help="split patches until no edge is longer than LEN (scene units; the Cornell box is in mm); "
        "default: the scene's own patching",
    )


def _add_form_factors(p: argparse.ArgumentParser, resolution: int = defaults.RESOLUTION) -> None:
    p.add_argument(
        "--form-factors",
        metavar="PATH",
        default=None,
        help="precomputed form factors from `pydynrad formfactors`: a .npz file (read whole) or a store "
        "folder (rows read on demand through a cache of --cache-mb; full solves, as in render, "
        "compare and reference frames, read all of it once); default: compute them now",
    )
    p.add_argument(
        "--cache-mb",
        type=_positive_float,
        default=256.0,
        metavar="MB",
        help="size of the row cache in MiB when --form-factors is a store folder: the form-factor rows "
        "held in memory (default 256; not used for a .npz file)",
    )
    p.add_argument(
        "--resolution",
        type=_resolution,
        default=None,
        metavar="R",
        help=f"hemicube resolution (R x R pixels on the top face; even, 2 to 4096) when computing form "
        f"factors (default {resolution}); with --form-factors, the one those were computed at (the "
        "default), which a moving object's rows are computed at too",
    )
    p.set_defaults(default_resolution=resolution)
    _add_samples(
        p,
        None,
        "when computing form factors (default 1); with --form-factors, the hemicubes per row "
        "those must have been computed with",
    )


def _add_resolution(p: argparse.ArgumentParser, default: int, when: str = "") -> None:
    p.add_argument(
        "--resolution",
        type=_resolution,
        default=default,
        metavar="R",
        help=f"hemicube resolution (R x R pixels on the top face; even, 2 to 4096){when} (default {default})",
    )


def _add_samples(p: argparse.ArgumentParser, default: int | None, when: str) -> None:
    p.add_argument(
        "--samples",
        type=_positive_int,
        default=default,
        metavar="K",
        help="hemicubes per row (1, 4, 16, ...), each of resolution R / sqrt(K) at the centroid of one of "
        "K equal strata of the patch: the same rays, without the centre point's bias under nearby "
        f"sources (pydynrad.form_factors(samples=K)), {when}",
    )


def _add_camera(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--position",
        type=_vec3,
        metavar="X,Y,Z",
        default=None,
        help="eye position in scene units (default: 1.1 scene diagonals in front of the centre, along -z)",
    )
    p.add_argument(
        "--look-at",
        type=_vec3,
        metavar="X,Y,Z",
        default=None,
        help="point the camera looks at (default: the bounding-box centre)",
    )
    p.add_argument("--up", type=_vec3, metavar="X,Y,Z", default=(0.0, 1.0, 0.0), help="up direction (default 0,1,0)")
    p.add_argument(
        "--fov-y",
        type=_positive_float,
        default=None,
        metavar="DEG",
        help=f"vertical field of view in degrees (default {DEFAULT_FOV_Y}, the Cornell box camera's)",
    )
    p.add_argument("--fov", type=_positive_float, default=None, metavar="DEG", help="deprecated spelling of --fov-y")
    _add_image_size(p)


def _add_image_size(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--width",
        type=_positive_int,
        default=None,
        metavar="PX",
        help=f"image width in pixels (default {DEFAULT_WIDTH})",
    )
    p.add_argument(
        "--height",
        type=_positive_int,
        default=None,
        metavar="PX",
        help=f"image height in pixels (default {DEFAULT_HEIGHT})",
    )
    p.add_argument(
        "--size",
        type=_size,
        default=None,
        metavar="WxH",
        help="deprecated: image size in pixels; use --width and --height",
    )


def _add_look(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--shading",
        choices=("smooth", "flat"),
        default="smooth",
        help="smooth: radiosity interpolated across patches (not across creases or material borders); "
        "flat: one value per patch (default smooth)",
    )
    _add_exposure(p, "the written images (multiplied by 2**STOPS)")
    _add_lights(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _add_exposure(p: argparse.ArgumentParser, what: str, of: str = "the (first lit) image's") -> None:
    p.add_argument(
        "--exposure",
        type=_exposure,
        default=defaults.EXPOSURE,
        metavar="STOPS|auto",
        help=f"exposure of {what} in stops, or auto (the default): {of} log-average luminance "
        f"mapped to {defaults.KEY_VALUE}, fixed once per walk so frames do not flicker; the "
        "choice is printed",
    )


def _add_lights(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--light",
        type=_light,
        action="append",
        default=[],
        metavar="KIND:FIELD=VALUE;...",
        help="add a light (repeatable, any mix of kinds; quote it: ';' ends a shell command), e.g. "
        "'point:pos=278,500,280;intensity=0.05' or 'sun:dir=0.3,-1,0.2;irradiance=800'. Kinds: "
        f"{light_syntax()}. X,Y,Z:R,G,B is a point light too. Emitting patches of the scene always "
        "shine",
    )


def _add_dynamic(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--local-size",
        type=_positive_int,
        default=None,
        metavar="M",
        help=f"patches in the local set around the observer, the size of the multibounce matrix K "
        f"(default min({defaults.LOCAL_SIZE_CAP}, N/2), so half the scene at least stays in the far "
        "field; printed; capped at the scene's patch count)",
    )
    p.add_argument(
        "--update",
        choices=("exact", "paper"),
        default="exact",
        help="local-matrix update: exact (Sherman-Morrison swaps, equals a rebuild) or paper "
        "(the published rank-one update) (default exact)",
    )
    p.add_argument(
        "--storage",
        choices=("fp16", "fp32", "fp64"),
        default="fp32",
        help="element type K is stored in on the device (default fp32)",
    )
    p.add_argument(
        "--no-far-field",
        action="store_true",
        help="the paper's method: patches outside the local set get only their own light and none of "
        "theirs reaches it (default: the far field lights every patch)",
    )
    p.add_argument(
        "--clusters",
        type=_positive_int,
        default=None,
        metavar="C",
        help="clusters of the far field's coarse level (default N/8)",
    )
    p.add_argument(
        "--tolerance",
        type=_tolerance,
        default=DEFAULT_TOLERANCE,
        metavar="REL|none",
        help="the far field refines (sweeps of F) until its estimated all-patch relative RMS error is "
        f"under this (default {DEFAULT_TOLERANCE:g}); none: estimate only",
    )


def _tolerance(text: str):
    if text.lower() == "none":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--tolerance must be a positive number or none; got {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"--tolerance must be a positive number or none; got {text!r}")
    return value


def _dynamic_options(args: argparse.Namespace) -> dict:
    """DynamicRadiosity keywords from the options of :func:`_add_dynamic`."""
    return {
        "update": args.update,
        "storage": args.storage,
        "far_field": not args.no_far_field,
        "clusters": args.clusters,
        "tolerance": args.tolerance,
    }


def _add_walk_output(p: argparse.ArgumentParser, out: str | None) -> None:
    p.add_argument(
        "--out",
        default=out,
        metavar="DIR",
        help="folder for frame_NNNN images, compare_NNNN.png and summary.txt (created if missing)"
        + (f"; default ./{out}" if out else "; default: write no images"),
    )
    p.add_argument(
        "--format",
        default="png",
        choices=("png", "jpg", "exr", "hdr", "tif"),
        help="image format of the frames (exr keeps linear float values) (default png)",
    )
    p.add_argument(
        "--video",
        default=None,
        metavar="FILE.mp4",
        help="also encode the frames into a video (.mp4, .mkv, .mov, .webm or .gif; 24 frames/s) at "
        "the frames' exposure; needs the video extra: pip install 'pydynrad[video]'",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="pydynrad",
        description="Dynamic Radiosity on OpenCL: form factors, local multibounce matrices, frame loops. "
        "Start with `pydynrad demo`.",
    )

    parser.add_argument("--version", action="version", version=f"pydynrad {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_Parser)

    # One block per subcommand, built from the shared option groups (_add_scene, _add_look, _add_lights,
    # ...): what still looks alike between blocks is argparse's declaration shape, not repeated logic.
    p = sub.add_parser(
        "info",
        help="list OpenCL devices and the one pydynrad uses",
        description="List every OpenCL device and show the one pydynrad selects "
        "(PYOPENCL_CTX overrides the default, the first PoCL CPU device).",
    )
    p.set_defaults(func=_cmd_info)

    p = sub.add_parser(
        "demo",
        help="Cornell box walk with a moving light: frames, timings, error",
        description="Render the Cornell box while the camera walks into it and a point light circles "
        "the blocks. The local multibounce matrix follows the camera; each frame is "
        "written as an image, and at the first and last frame the full radiosity is "
        "solved too, giving the local-versus-full error and a comparison image. Prints "
        "a table of per-stage timings.",
    )
    p.add_argument("--frames", type=_positive_int, default=24, metavar="N", help="number of frames (default 24)")
    _add_image_size(p)
    p.add_argument(
        "--max-edge",
        type=_positive_float,
        default=100.0,
        metavar="MM",
        help="longest patch edge in mm (default 100: 1,128 patches)",
    )
    p.add_argument(
        "--moving-block",
        action="store_true",
        help="add a green cube that glides and turns through the box (a moving rigid object: its shadow "
        "and colour bleeding follow it; reference frames solve the box with it from fresh hemicubes)",
    )
    _add_form_factors(p)
    _add_dynamic(p)
    _add_walk_output(p, DEMO_DIR)
    p.add_argument(
        "--shading", choices=("smooth", "flat"), default="smooth", help="smooth or flat shading (default smooth)"
    )
    _add_exposure(p, "the written frames")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser(
        "formfactors",
        help="precompute a scene's form factors into a file or a store folder",
        description="Compute the sparse form-factor matrix F of SCENE with hemicubes. OUT ending in "
        ".npz: one file (CSR arrays plus a header with the scene's geometry hash and the "
        "parameters), computed in this process, for scenes whose F fits in memory. Any "
        "other OUT: a form-factor store folder (compressed, checksummed row blocks, read "
        "on demand by walk/render/compare), computed in this process, or with Dask on a "
        "LocalCluster (--workers N) or an existing cluster (--scheduler). A store is "
        "resumable: running "
        "the same command again computes only the blocks still missing. Either way data is "
        "never used with the wrong scene, and files are written whole (temporary file, "
        "then rename).",
    )
    _add_scene(p)
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="OUT",
        help="FILE.npz for a single file, or a folder (new, empty, or a store to resume) for a store; "
        "its parent folder must exist",
    )
    _add_resolution(p, defaults.RESOLUTION)
    _add_samples(p, 1, "recorded in the file or store; a store resumed with other K is refused (default 1)")
    p.add_argument(
        "--force",
        action="store_true",
        help="file only: replace an existing OUT.npz that is not a pydynrad form-factor file",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=_count,
        default=None,
        metavar="N",
        help="store only: compute on a local Dask cluster of N worker processes (LocalCluster, one "
        "thread and one OpenCL context each; the dask extra); default (and 0): in this process, "
        "without Dask",
    )
    where.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="store only: address of an existing Dask cluster's scheduler (e.g. tcp://host:8786); "
        "its workers must see OUT's folder and have pydynrad installed",
    )
    p.add_argument(
        "--block-rows",
        type=_positive_int,
        default=None,
        metavar="ROWS",
        help="store only: form-factor rows per block file, the unit of reading and of resuming "
        "(default 256, or the existing store's)",
    )
    p.add_argument(
        "--clusters",
        default=None,
        metavar="C|auto|LABELS.npy",
        help="store only: also store the far field's patch-to-cluster form factors G = F Pr for these "
        "clusters (C of them made by pydynrad.farfield.cluster_patches, 'auto' for its default "
        "count, or a .npy file of one integer cluster label per patch), from hemicubes that record "
        "cluster ids; a store resumed later finishes its G too; walks then use its far field",
    )
    p.add_argument(
        "--cluster-resolution",
        type=_resolution,
        default=None,
        metavar="R",
        help="store only: hemicube resolution of G (default: --resolution, G then summed from F's "
        "stored rows, or with --no-f equal to F Pr of the rows walks compute on demand)",
    )
    p.add_argument(
        "--no-f",
        action="store_true",
        help="store only: store G alone, not F's rows, for a DynamicRadiosity with rows on demand "
        "from Python (form_factors=None, cluster_form_factors=store.cluster_form_factors(...)); "
        "the CLI's walk, render and compare need F's rows",
    )
    p.add_argument(
        "--verify",
        action="store_true",
        help="store only: read every finished block of an existing store, F's and G's, check each "
        "against its checksum (bound to this store), report the counts and recompute what fails "
        "(a resume checks F's blocks anyway)",
    )
    p.add_argument(
        "--poses",
        default=None,
        metavar="PATH.json",
        help="store only: also store the rows of the moving objects of this path file at every frame "
        "of its walk (the paper's precomputed poses; a walk with --form-factors OUT then takes "
        "its moves' object rows from there); configurations already stored are skipped",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_formfactors)

    p = sub.add_parser(
        "render",
        help="render one image of a full radiosity solution",
        description="Solve the radiosity of SCENE over all patches (emitting patches plus any "
        "--light) and render it from one camera.",
    )
    _add_scene(p)
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="IMAGE",
        help="output image: .png/.jpg (exposed, sRGB, 8-bit) or .exr/.hdr/.tif (linear float)",
    )
    _add_camera(p)
    _add_look(p)
    _add_form_factors(p)
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser(
        "bake",
        help="bake a full radiosity solution into a mesh other tools open",
        description="Solve the radiosity of SCENE over all patches (emitting patches plus any --light) "
        "and write it where Blender, game engines and web viewers read it: per-vertex "
        "colours (OUT.glb or OUT.ply, smooth across each surface, split at creases and "
        "material borders), or with --lightmap a linear float lightmap image plus OUT.glb "
        "carrying its UVs and an 8-bit copy of it any glTF viewer shows. Linear radiosity "
        "is stored unscaled; the 8-bit or clipped display colours use --exposure, stated "
        "in the file's metadata.",
    )
    _add_scene(p)
    p.add_argument(
        "-o", "--output", required=True, metavar="OUT", help="the mesh: .glb (glTF 2.0) or .ply; .glb with --lightmap"
    )
    p.add_argument(
        "--lightmap",
        metavar="IMAGE",
        default=None,
        help="also bake a lightmap into IMAGE (.exr recommended; .hdr/.tif/.pfm are linear too); "
        "OUT then holds its UVs (TEXCOORD_1)",
    )
    p.add_argument(
        "--texels-per-unit",
        type=_positive_float,
        default=None,
        metavar="T",
        help="lightmap texels per scene unit of length (default: about a 1024x1024 lightmap)",
    )
    p.add_argument(
        "--padding",
        type=_ranged(1, 64, integral=True),
        default=2,
        metavar="PX",
        help="lightmap texels between charts, filled by dilation (default 2)",
    )
    p.add_argument(
        "--crease-angle",
        type=_ranged(0.0, 180.0),
        default=30.0,
        metavar="DEG",
        help="never smooth across a sharper angle (default 30)",
    )
    _add_exposure(p, "the display colours (radiosity * 2**STOPS)", "the patches' area-weighted")
    _add_lights(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_form_factors(p)
    p.set_defaults(func=_cmd_bake)

    p = sub.add_parser(
        "walk",
        help="walk a camera path through a scene with dynamic radiosity",
        description="Follow the camera path in FILE through SCENE: per frame the local multibounce "
        "matrix follows the camera, the lights of that frame are applied and an image is "
        "rendered. Prints per-stage timings. The path file is JSON: "
        '{"frames": 48, "fov_y": 39.3, "width": 320, "height": 240, "keyframes": '
        '[{"position": [x,y,z], "look_at": [x,y,z]}, ...]} (or "orbit": {"center": '
        '[x,y,z], "radius": r, "elevation": h} instead of keyframes), optionally "lights": '
        '[{"type": "point", "intensity": [r,g,b], "keyframes": [[x,y,z], ...]}] (also '
        '"spot" and "directional") and "objects": [{"block": {"size": 100}} or {"mesh": '
        '"cube.obj"}, "keyframes": [{"position": [x,y,z], "rotation_deg": [rx,ry,rz]} or '
        "4x4 matrices, ...]}] (moving rigid bodies; every field: pydynrad.paths).",
    )
    _add_scene(p)
    p.add_argument("--path", required=True, metavar="FILE", help="camera path file (JSON, format above)")
    _add_look(p)
    _add_form_factors(p)
    _add_dynamic(p)
    _add_walk_output(p, None)
    p.add_argument(
        "--reference-frames",
        type=_frame_number,
        nargs="*",
        default=[],
        metavar="K",
        help="frames (negative: from the end) at which to also solve the full radiosity, report the "
        "error and write compare_K.png",
    )
    p.set_defaults(func=_cmd_walk)

    p = sub.add_parser(
        "compare",
        help="dynamic versus full radiosity for one view, side by side",
        description="Place the local set around the camera, compute the dynamic radiosity and the "
        "full solution, and write one image: dynamic | full | false-colour relative "
        "error with a colour bar. Prints the errors.",
    )
    _add_scene(p)
    p.add_argument("-o", "--output", required=True, metavar="IMAGE", help="output image (.png recommended)")
    _add_camera(p)
    _add_look(p)
    _add_form_factors(p)
    _add_dynamic(p)
    p.set_defaults(func=_cmd_compare)

    p = sub.add_parser(
        "view",
        help="watch the dynamic solution live in a web browser (the view extra)",
        description="Serve a page at http://HOST:PORT/ where the browser's camera is the observer: "
        "the local set follows it every frame, the lights are edited live (sun, sky, "
        "point lights), --path plays a path file, and overlays show the local set, the "
        "far field's clusters and the error against a full solve. Needs pip install "
        "'pydynrad[view]'. Over SSH: ssh -L PORT:localhost:PORT HOST, or --host 0.0.0.0.",
    )
    _add_scene(p)
    p.add_argument(
        "--path",
        default=None,
        metavar="FILE",
        help="a camera path file (JSON, as walk reads it) to play, pause and scrub",
    )
    _add_lights(p)
    _add_form_factors(p, resolution=32)
    _add_dynamic(p)
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0: every interface)",
    )
    p.add_argument(
        "--port",
        type=_ranged(0, 65535, integral=True),
        default=8080,
        help="port to listen on (default 8080; 0: any free port)",
    )
    p.add_argument("--open", action="store_true", help="open the page in this machine's web browser")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_view)
    return parser


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"pydynrad: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    with warnings.catch_warnings():
        # Deprecated options must be seen from the command line too, where Python hides
        # DeprecationWarning by default; every warning prints as one line.
        warnings.simplefilter("default", DeprecationWarning)
        warnings.showwarning = _one_line_warning
        parser = build_parser()
        args = parser.parse_args(argv)
        try:
            with contextlib.ExitStack() as args.cleanup:  # closes what a command opened (row caches)
                return int(args.func(args) or 0)
        except (PydynradError, OSError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            print(f"pydynrad {args.command}: error: {first}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print(f"pydynrad {args.command}: interrupted", file=sys.stderr)
            return 130
