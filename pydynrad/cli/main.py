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

from ..errors import InvalidInputError, PydynradError
from ..scenes.byname import BUILTIN_SCENES

__all__ = ["main", "build_parser", "load_scene", "BUILTIN_SCENES"]


DEMO_DIR = "pydynrad-demo"
#: Chart texels of a lightmap when --texels-per-unit is not given (about a 1024 x 1024 image).
LIGHTMAP_TEXELS = 0.75 * 2**20
DEFAULT_WIDTH, DEFAULT_HEIGHT = 320, 240
#: The Cornell box camera's vertical field of view (degrees).
DEFAULT_FOV_Y = 39.3
DEMO_EXPOSURE = float(-np.log2(np.pi))


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump): the message and where to get help."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


# -- option types -----------------------------------------------------------------------------
def _vec3(text: str) -> tuple[float, float, float]:
    from ..lights.text import vector  # the light text's numbers: ASCII, finite

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
    from ..checks import resolution

    try:
        return resolution(text if _digits(text) is None else _digits(text))
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _ranged(lo: float, hi: float, integral: bool = False):
    """An argparse type: a finite number (a whole one when ``integral``) in [lo, hi]."""
    def parse(text: str):
        from ..lights.text import plain_number

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
    from ..lights.text import plain_number  # ASCII digits: float() reads "4_5" and other scripts' digits

    v = plain_number(text)
    v = float("nan") if v is None else v
    if not (np.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"expected a positive number; got {text!r}")
    return v


def _stops(text: str) -> float:
    from ..checks import stops
    from ..lights.text import plain_number

    value = plain_number(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"expected a number of stops; got {text!r}")
    try:  # out of range: one line, before any work
        return stops(value)
    except InvalidInputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _light(text: str):
    from ..lights.text import parse_light

    try:
        return parse_light(text)
    except PydynradError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _progress(args) -> bool | None:
    """--quiet: no bars; otherwise the library's rule (bars on a terminal)."""
    return False if args.quiet else None


# -- scenes and form-factor files -------------------------------------------------------------
def load_scene(name: str, max_edge: float | None = None):
    """SCENE: a built-in name or a mesh file (:func:`pydynrad.scenes.byname.scene_by_name`),
    split to ``max_edge`` (scene units) when given; None keeps each scene's default patching."""
    from ..scenes.byname import scene_by_name

    return scene_by_name(name, **_patching(max_edge))


def _patching(max_edge: float | None) -> dict:
    """The scene parameters --max-edge stands for (also what a store records as its patching)."""
    return {} if max_edge is None else {"max_edge": max_edge}


def _checked_target(path, suffixes: tuple[str, ...] | None = None) -> Path:
    """``path`` as a Path, after checking its folder exists and no folder is in its place (and its
    suffix, or image format)."""
    from ..atomic import check_file_target
    from ..image_io import _format_for

    path = Path(path)
    if suffixes is None:
        _format_for(path)
    elif path.suffix.lower() not in suffixes:
        raise InvalidInputError(f"output file {str(path)!r} must end in {' or '.join(suffixes)}")
    return check_file_target(path)


def _samples(args) -> int:
    """--samples (1 when not given) checked against --resolution, before any work."""
    from ..formfactors import checked_samples

    return checked_samples(1 if args.samples is None else args.samples, args.resolution)


def _form_factors(args, scene):
    """F from --form-factors PATH when given (a matrix for a .npz file, a RowCache of
    --cache-mb over a store folder, closed when the command ends; made with --samples where
    given), else computed now."""
    if getattr(args, "form_factors", None):
        from ..rows.files import open_form_factors, recorded_resolution

        # Every later hemicube (a moving object's rows, stored poses) at F's resolution: the
        # file's, or --resolution where it is given and is the file's.
        F = open_form_factors(scene, args.form_factors, cache_bytes=int(args.cache_mb * 2**20), samples=args.samples,
                              resolution=args.resolution)
        args.resolution = recorded_resolution(args.form_factors)
        if hasattr(F, "close"):
            args.cleanup.callback(F.close)
            print(f"form factors: {F.source!r} through a {args.cache_mb:g} MiB row cache")
        else:
            print(f"form factors: {args.form_factors} ({F.nnz} non-zeros)")
        return F
    from ..formfactors import form_factors

    t0 = time.perf_counter()
    if args.resolution is None:
        args.resolution = args.default_resolution
    samples = _samples(args)
    F = form_factors(scene, resolution=args.resolution, progress=_progress(args), samples=samples)
    print(f"form factors: {len(scene)} patches, resolution {args.resolution}"
          f"{f', {samples} hemicubes per row' if samples > 1 else ''}, {F.nnz} non-zeros, "
          f"{time.perf_counter() - t0:.1f} s")
    return F


def _image_size(args) -> tuple[int, int]:
    """(width, height) from --width/--height, or from the deprecated --size WxH (one release)."""
    if args.size is not None:
        if args.width is not None or args.height is not None:
            raise InvalidInputError("give --width/--height or the deprecated --size, not both")
        warnings.warn("--size WxH is deprecated and will be removed in the next release; use --width W --height H",
                      DeprecationWarning, stacklevel=2)
        return args.size
    return args.width or DEFAULT_WIDTH, args.height or DEFAULT_HEIGHT


def _fov_y(args) -> float:
    """--fov-y, or the deprecated --fov (one release)."""
    if args.fov is not None:
        if args.fov_y is not None:
            raise InvalidInputError("give --fov-y or the deprecated --fov, not both")
        warnings.warn("--fov is deprecated and will be removed in the next release; use --fov-y",
                      DeprecationWarning, stacklevel=2)
        return args.fov
    return DEFAULT_FOV_Y if args.fov_y is None else args.fov_y


def _default_camera(scene, args):
    """A camera from --position/--look-at/--up/--fov-y/--width/--height; unset parts frame the scene:
    looking at the bounding-box centre along +z from 1.1 diagonals away (the Cornell box's
    published view)."""
    from ..geometry.camera import Camera, check_image_memory
    from ..renderer import RENDER_BYTES_PER_PIXEL

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
    from ..device.devices import default_device, list_devices

    print("OpenCL devices (select one with PYOPENCL_CTX=<platform>:<device>):")
    for d in list_devices():
        print(f"  [{d['PYOPENCL_CTX']}] {d['platform']} / {d['device']} ({d['type']}, "
              f"{d['compute_units']} CU, {d['global_memory_MiB']} MiB)")
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
    from ..rows.files import is_form_factor_file, save_form_factors

    given = [o for o, v in (("--workers", args.workers), ("--scheduler", args.scheduler),
                            ("--block-rows", args.block_rows), ("--clusters", args.clusters),
                            ("--cluster-resolution", args.cluster_resolution)) if v is not None]
    given += [o for o, v in (("--no-f", args.no_f), ("--verify", args.verify), ("--poses", args.poses)) if v]
    if given:
        raise InvalidInputError(f"{', '.join(given)} apply to a store folder; {str(out)!r} is a single .npz file")
    out = _checked_target(out, (".npz",))  # fail before the work, not after
    if out.exists() and not args.force and not is_form_factor_file(out):
        raise InvalidInputError(f"{str(out)!r} exists and is not a pydynrad form-factor file: not overwriting it "
                                "(pass --force to replace it)")
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
        from ..farfield.gather import clusters_without_f

        # A store's walks have no F in memory: its clusters keep light components apart from hemicubes.
        clusters = clusters_without_f(scene, None if args.clusters == "auto" else int(args.clusters),
                                      progress=_progress(args))
        return clusters.labels, {"made_by": "pydynrad.farfield.gather.clusters_without_f", "clusters": clusters.count}
    path = Path(args.clusters)
    try:
        labels = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InvalidInputError(f"--clusters {str(path)!r}: not a readable .npy file of cluster labels ({exc})") from None
    if labels.shape != (len(scene),) or not np.issubdtype(labels.dtype, np.integer) or labels.min() < 0:
        raise InvalidInputError(f"--clusters {str(path)!r} must hold {len(scene)} integers >= 0 (one cluster per "
                                f"patch); got shape {labels.shape}, dtype {labels.dtype}")
    return labels, {"labels_file": str(path.resolve())}


def _formfactors_store(args: argparse.Namespace, out: Path) -> int:
    """Create or resume the store at ``out``: in this process (--workers 0) or on a Dask cluster."""
    from ..precompute.distributed import SceneSpec, _require_dask, precompute_distributed
    from ..atomic import check_parent_folder
    from ..rows.store import DEFAULT_BLOCK_ROWS, HEADER, FormFactorStore
    from ..precompute.store import compute_store

    if args.workers != 0:  # without the dask extra: one line naming it, before the scene is loaded
        given = ("--scheduler" if args.scheduler else "--workers 2 (the default)" if args.workers is None
                 else f"--workers {args.workers}")
        _require_dask(given, "--workers 0 computes in this process without it")
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
        store = FormFactorStore.open(scene, out, resolution=args.resolution, patching=spec.recipe(),
                                     samples=_samples(args))
        block_rows = block_rows or store.block_rows
        # Finished blocks of F are read and their checksums (bound to this store) checked on
        # every resume, G's too with --verify: a corrupt or foreign block is deleted and
        # recomputed, never reported as done.
        for part in ("F", "G") if args.verify and store.has_clusters else ("F",):
            found = store.verify(part, remove=True)
            corrupt = found["corrupt"]
            print(f"{'verified' if args.verify else 'resuming'} {out}{', G' if part == 'G' else ''}: "
                  f"{len(found['verified'])} of {store.n_blocks} blocks already done"
                  + (f"; {len(corrupt)} fail their checksum and are recomputed (block {', '.join(map(str, corrupt[:8]))}"
                     f"{', ...' if len(corrupt) > 8 else ''})" if corrupt else "")
                  + (f"; {len(found['missing'])} missing" if args.verify and found["missing"] else ""))
    elif args.verify:
        raise InvalidInputError(f"--verify checks an existing store; there is none at {str(out)!r}")
    block_rows = block_rows or DEFAULT_BLOCK_ROWS
    common = dict(resolution=args.resolution, samples=_samples(args), block_rows=block_rows, progress=_progress(args),
                  clusters=labels,
                  cluster_resolution=args.cluster_resolution,
                  cluster_params=cluster_params, compute_f=not args.no_f)
    t0 = time.perf_counter()
    if args.workers == 0:
        store = compute_store(scene, out, patching=spec.recipe(), **common)
        where = "this process (no Dask)"
    else:
        workers = None if args.scheduler else (args.workers or 2)
        store = precompute_distributed(spec, out, workers=workers, scheduler=args.scheduler, **common)
        where = f"the cluster at {args.scheduler}" if args.scheduler else f"a LocalCluster of {workers} workers"
    seconds = time.perf_counter() - t0
    g = ""
    if store.has_clusters:
        g = (f", G for {store.cluster_count} clusters at resolution {store.cluster_resolution} "
             f"({store.cluster_basis} basis)")
    f_done = "" if store.complete else " (F's rows not computed)"
    print(f"wrote store {out}: {store.n_patches} patches in {store.n_blocks} blocks of {store.block_rows} rows{f_done}{g}, "
          f"{store.nbytes_on_disk / 2**20:.1f} MiB, {seconds:.1f} s in {where}")
    if walk_poses is not None:
        _store_poses(args, scene, store, *walk_poses)
    return 0


def _walk_poses(path) -> tuple[list, list]:
    """The moving objects of path file ``path`` and their configuration at each frame of its
    walk (the poses ``pydynrad walk --path`` moves them to)."""
    from ..paths import load_walk

    loaded = load_walk(path)
    if not loaded.objects:
        raise InvalidInputError(f"--poses {str(path)!r}: the path file moves no objects")
    frames = len(loaded.path)
    return [t.object for t in loaded.objects], [[t.at(k, frames) for t in loaded.objects] for k in range(frames)]


def _store_poses(args: argparse.Namespace, scene, store, objects, configs) -> None:
    """--poses: the rows of ``objects`` at each configuration into the store's per-pose part."""
    from ..precompute.poses import precompute_poses
    from ..rows.store import POSE_HEADER

    before = len(store.pose_files()) if (store.path / POSE_HEADER).exists() else 0
    t0 = time.perf_counter()
    poses = precompute_poses(scene, objects, configs, resolution=args.resolution, store=store)
    print(f"wrote the poses of {args.poses}: {len(poses) - before} new configurations ({len(poses)} in the store, "
          f"{len(configs)} frames), {time.perf_counter() - t0:.1f} s")


def _stored_poses(F, scene, tracks, resolution: int):
    """The per-pose rows of ``tracks``' objects in the store behind ``F``, or None where F is
    no store or its store holds no poses (then the moves compute their rows)."""
    from ..precompute.poses import stored_poses
    from ..rows.store import POSE_HEADER, FormFactorStore

    store = getattr(F, "source", F)
    if not tracks or not isinstance(store, FormFactorStore) or not (store.path / POSE_HEADER).exists():
        return None
    poses = stored_poses(scene, [t.object for t in tracks], store, resolution)
    print(f"poses: {len(poses)} configurations of the objects stored in {store.path}")
    return poses


def _cmd_render(args: argparse.Namespace) -> int:
    from ..rows.files import whole_matrix
    from ..image_io import write_image
    from ..renderer import render
    from ..solution import solve

    _checked_target(args.output)  # reject a bad image name before any work
    scene = load_scene(args.scene, args.max_edge)
    camera = _default_camera(scene, args)
    sol = solve(scene, whole_matrix(_form_factors(args, scene)), args.light)
    img = render(scene, sol.radiosity, camera, args.shading)
    write_image(args.output, img, args.exposure)
    print(f"wrote {args.output} ({camera.width}x{camera.height}, {sol.iterations} bounces)")
    if not img.any():  # e.g. the default camera outside a closed scene sees only its backs
        _warn_black(args.output, bool(sol.radiosity.any()))
    return 0


def _warn_black(what, lit: bool, camera: str = "the camera with --position and --look-at", are: bool = False) -> None:
    """One line on stderr that ``what`` came out black, and why: no light, or a view of none."""
    why = ("the scene has no light (no emission and no --light)" if not lit else
           f"no pixel sees a lit front face (place {camera})")
    print(f"warning: {what} {'are' if are else 'is'} black: {why}", file=sys.stderr)


def _texels_per_unit(args, scene) -> float:
    """--texels-per-unit, or a density giving about LIGHTMAP_TEXELS texels of charts (at least
    MIN_TEXELS_PER_PATCH for the median patch, rounded up)."""
    from ..bake.lightmap import MIN_TEXELS_PER_PATCH

    if args.texels_per_unit is not None:
        return args.texels_per_unit
    tpu = max(float(np.sqrt(LIGHTMAP_TEXELS / scene.areas.sum(dtype=np.float64))),
              float(np.sqrt(MIN_TEXELS_PER_PATCH / np.median(scene.areas))))
    step = 10.0 ** (np.floor(np.log10(tpu)) - 1)  # two significant digits, rounded up: never below the floor
    return float(f"{np.ceil(tpu / step * (1 - 1e-12)) * step:.2g}")


def _cmd_bake(args: argparse.Namespace) -> int:
    from ..bake import MESH_FORMATS, bake_lightmap, export_mesh
    from ..rows.files import whole_matrix
    from ..solution import solve

    # Names are checked before any work: a typo must not cost a solve.
    out = _checked_target(args.output, (".glb",) if args.lightmap else MESH_FORMATS)
    if args.lightmap:
        from ..image_io import LINEAR_FORMATS

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
        from ..bake.lightmap import check_texel_density

        check_texel_density(scene, _texels_per_unit(args, scene))  # before the solve it would waste
    sol = solve(scene, whole_matrix(_form_factors(args, scene)), args.light)
    print(f"solved: {sol.iterations} bounces, {len(args.light)} light(s) besides the emission")
    if not sol.radiosity.any():
        _warn_black(f"the bake of {args.scene}", False)
    t0 = time.perf_counter()
    if not args.lightmap:
        export_mesh(scene, sol.radiosity, out, exposure=args.exposure, crease_angle=args.crease_angle)
        print(f"wrote {out} (vertex colours, {time.perf_counter() - t0:.2f} s)")
        return 0
    tpu = _texels_per_unit(args, scene)
    lm = bake_lightmap(scene, sol.radiosity, tpu, padding=args.padding, crease_angle=args.crease_angle)
    # The mesh first: its embedded 8-bit image is what an exposure can be refused for, and then
    # no lightmap file is left without its mesh.
    lm.write_mesh(out, exposure=args.exposure, image_name=lightmap_path.name)
    lm.write(lightmap_path)
    h, w = lm.shape
    print(f"wrote {lightmap_path} ({w}x{h} texels at {tpu:g} per unit, {100 * lm.coverage:.0f}% in charts) and {out} "
          f"(lightmap UVs in TEXCOORD_1, the lightmap embedded as 8-bit sRGB at the exposure) in "
          f"{time.perf_counter() - t0:.2f} s")
    return 0


def _walk_and_report(args, scene, path, lights, F, out_dir, reference_frames, objects=()) -> object:
    from ..atomic import check_file_target, write_atomic
    from ..walks import walk

    opts = _dynamic_options(args)
    if objects:  # their rows by hemicube at F's resolution, so reference frames match F
        opts["resolution"] = args.resolution
        opts["poses"] = _stored_poses(F, scene, objects, args.resolution)
    if out_dir is not None and Path(out_dir).is_dir():
        check_file_target(Path(out_dir) / "summary.txt")  # written last: checked first
    result = walk(scene, path, lights=lights, objects=objects, form_factors=F,
                  local_size=min(args.local_size, len(scene) + sum(len(t.object) for t in objects)),
                  solver_options=opts, shading=args.shading, output=out_dir, image_format=args.format,
                  exposure=args.exposure, reference_frames=reference_frames, progress=_progress(args))
    summary = result.summary()
    print(summary)
    black = [f for f in result.frames if f.black]
    if black:
        _warn_black(f"{len(black)} of {len(result.frames)} frames (the first {black[0].index})", all(f.lit for f in black),
                    "the path's cameras to look at lit faces", are=True)
    if out_dir is not None:
        write_atomic(Path(out_dir) / "summary.txt", (summary + "\n").encode())
        print(f"images in {out_dir}/")
    return result


def _cmd_walk(args: argparse.Namespace) -> int:
    from ..paths import load_walk

    loaded = load_walk(args.path)
    scene = load_scene(args.scene, args.max_edge)
    F = _form_factors(args, scene)
    _walk_and_report(args, scene, loaded.path, loaded.lights + list(args.light), F, args.out, args.reference_frames,
                     loaded.objects)
    return 0


def demo_setup(frames: int, width: int, height: int):
    """The demo's Cornell box walk: the camera moves from the published viewpoint up to the
    box's open side and pans across it, while a point light circles above the blocks."""
    from ..lights.sources import PointLight
    from ..paths import CameraPath, LightTrack

    positions = [(278, 273, -800), (278, 273, -450), (150, 320, -250), (400, 220, -200)]
    look_ats = [(278, 273, 0), (278, 260, 280), (300, 200, 300), (250, 220, 300)]
    cam = CameraPath(positions, look_ats, frames, fov_y=DEFAULT_FOV_Y, width=width, height=height)
    # Above both blocks (the tall one is 330 mm high), below the ceiling (548.8 mm).
    orbit_keys = [(130, 420, 130), (130, 420, 430), (430, 420, 430), (430, 420, 130), (130, 420, 130)]
    light = LightTrack(PointLight(orbit_keys[0], (60000.0, 50000.0, 30000.0)), orbit_keys)
    return cam, [light]


def demo_block():
    """The demo's moving block (``--moving-block``): a green 100 mm cube (48 patches) gliding
    and turning 45 degrees through the box's back left, clear of both blocks and the light."""
    from ..geometry.objects import RigidObject
    from ..paths import ObjectTrack
    from ..scenes import block

    keys = []
    for z, angle in ((460.0, 0.0), (395.0, 22.5), (330.0, 45.0)):
        c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        T = np.eye(4)
        T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
        T[:3, 3] = (160.0, 230.0, z)
        keys.append(T)
    return ObjectTrack(RigidObject(block(100.0, 1, albedo=(0.14, 0.45, 0.091)), keys[0], name="moving block"), keys)


def _cmd_demo(args: argparse.Namespace) -> int:
    from ..scenes import cornell_box

    t0 = time.perf_counter()
    scene = cornell_box(max_edge=args.max_edge)
    print(f"scene: {scene!r}")
    F = _form_factors(args, scene)
    path, lights = demo_setup(args.frames, *_image_size(args))
    out = Path(args.out)
    objects = [demo_block()] if args.moving_block else []
    result = _walk_and_report(args, scene, path, lights, F, out, [0, args.frames - 1], objects)
    rows = "" if args.no_far_field else "rows: local only, far field; columns: "
    print(f"comparison images ({rows}dynamic | full | relative error): "
          f"{', '.join(str(f.comparison_path) for f in result.frames if f.comparison_path)}")
    print(f"demo done in {time.perf_counter() - t0:.1f} s")
    return 0


def _cmd_compare(args: argparse.Namespace) -> int:
    from ..comparison import reference_frame
    from ..dynamic import DynamicRadiosity
    from ..image_io import write_image

    _checked_target(args.output)
    scene = load_scene(args.scene, args.max_edge)
    camera = _default_camera(scene, args)
    F = _form_factors(args, scene)
    dyn = DynamicRadiosity(scene, F, local_size=min(args.local_size, len(scene)), **_dynamic_options(args))
    dyn.update(camera.position)
    local_only = dyn.radiosity(args.light, far_field=False) if dyn.far is not None else None
    ref = reference_frame(scene, F, dyn.radiosity(args.light), camera, lights=args.light, shading=args.shading,
                          exposure=args.exposure, local_only=local_only)
    write_image(args.output, ref.image)
    if ref.black:  # a view of no lit face: its 0% error says nothing
        _warn_black(f"the view of {args.output}", bool(ref.full.any()))
    answers = [("far field", ref.error, ref.pixel_error)] if local_only is not None else []
    answers.append(("local only", ref.local_only_error, ref.local_only_pixel_error) if local_only is not None
                   else ("local only", ref.error, ref.pixel_error))
    print(f"dynamic ({dyn.local_patches.size} of {len(scene)} patches local) vs full radiosity:")
    for name, error, stats in answers:
        print(f"  {name:10s} relative RMS error {100 * error:.3g}% over patches; per pixel mean "
              f"{100 * stats['mean']:.3g}%, 99th percentile {100 * stats['p99']:.3g}%")
    rows = "local only (top) and far field (bottom): " if local_only is not None else ""
    print(f"wrote {args.output} ({rows}dynamic | full | error map, colour bar 0 to "
          f"{100 * ref.pixel_error['vmax']:.3g}%)")
    return 0


# -- the parser -------------------------------------------------------------------------------
def _add_scene(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", metavar="SCENE",
                   help=f"a mesh file trimesh reads (.obj with .mtl, .ply, .glb, .gltf, .stl, .off) or a built-in "
                        f"scene: {', '.join(BUILTIN_SCENES)}")
    p.add_argument("--max-edge", type=_positive_float, default=None, metavar="LEN",
                   help="split patches until no edge is longer than LEN (scene units; the Cornell box is in mm); "
                        "default: the scene's own patching")


def _add_form_factors(p: argparse.ArgumentParser, resolution: int = 64) -> None:
    p.add_argument("--form-factors", metavar="PATH", default=None,
                   help="precomputed form factors from `pydynrad formfactors`: a .npz file (read whole) or a store "
                        "folder (rows read on demand through a cache of --cache-mb; full solves, as in render, "
                        "compare and reference frames, read all of it once); default: compute them now")
    p.add_argument("--cache-mb", type=_positive_float, default=256.0, metavar="MB",
                   help="size of the row cache in MiB when --form-factors is a store folder: the form-factor rows "
                        "held in memory (default 256; not used for a .npz file)")
    p.add_argument("--resolution", type=_resolution, default=None, metavar="R",
                   help=f"hemicube resolution (R x R pixels on the top face; even, 2 to 4096) when computing form "
                        f"factors (default {resolution}); with --form-factors, the one those were computed at (the "
                        "default), which a moving object's rows are computed at too")
    p.set_defaults(default_resolution=resolution)
    _add_samples(p, None, "when computing form factors (default 1); with --form-factors, the hemicubes per row "
                          "those must have been computed with")


def _add_resolution(p: argparse.ArgumentParser, default: int, when: str = "") -> None:
    p.add_argument("--resolution", type=_resolution, default=default, metavar="R",
                   help=f"hemicube resolution (R x R pixels on the top face; even, 2 to 4096){when} (default {default})")


def _add_samples(p: argparse.ArgumentParser, default: int | None, when: str) -> None:
    p.add_argument("--samples", type=_positive_int, default=default, metavar="K",
                   help="hemicubes per row (1, 4, 16, ...), each of resolution R / sqrt(K) at the centroid of one of "
                        "K equal strata of the patch: the same rays, without the centre point's bias under nearby "
                        f"sources (pydynrad.form_factors(samples=K)), {when}")


def _add_camera(p: argparse.ArgumentParser) -> None:
    p.add_argument("--position", type=_vec3, metavar="X,Y,Z", default=None,
                   help="eye position in scene units (default: 1.1 scene diagonals in front of the centre, along -z)")
    p.add_argument("--look-at", type=_vec3, metavar="X,Y,Z", default=None,
                   help="point the camera looks at (default: the bounding-box centre)")
    p.add_argument("--up", type=_vec3, metavar="X,Y,Z", default=(0.0, 1.0, 0.0), help="up direction (default 0,1,0)")
    p.add_argument("--fov-y", type=_positive_float, default=None, metavar="DEG",
                   help=f"vertical field of view in degrees (default {DEFAULT_FOV_Y}, the Cornell box camera's)")
    p.add_argument("--fov", type=_positive_float, default=None, metavar="DEG", help="deprecated spelling of --fov-y")
    _add_image_size(p)


def _add_image_size(p: argparse.ArgumentParser) -> None:
    p.add_argument("--width", type=_positive_int, default=None, metavar="PX",
                   help=f"image width in pixels (default {DEFAULT_WIDTH})")
    p.add_argument("--height", type=_positive_int, default=None, metavar="PX",
                   help=f"image height in pixels (default {DEFAULT_HEIGHT})")
    p.add_argument("--size", type=_size, default=None, metavar="WxH",
                   help="deprecated: image size in pixels; use --width and --height")


def _add_look(p: argparse.ArgumentParser) -> None:
    p.add_argument("--shading", choices=("smooth", "flat"), default="smooth",
                   help="smooth: radiosity interpolated across patches (not across creases or material borders); "
                        "flat: one value per patch (default smooth)")
    p.add_argument("--exposure", type=_stops, default=0.0, metavar="STOPS",
                   help="multiply the written image by 2**STOPS: brighter (positive) or darker (negative) (default 0)")
    _add_lights(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _add_lights(p: argparse.ArgumentParser) -> None:
    from ..lights.text import light_syntax

    p.add_argument("--light", type=_light, action="append", default=[], metavar="KIND:FIELD=VALUE;...",
                   help="add a light (repeatable, any mix of kinds; quote it: ';' ends a shell command), e.g. "
                        "'point:pos=278,500,280;intensity=5e4' or 'sun:dir=0.3,-1,0.2;irradiance=800'. Kinds: "
                        f"{light_syntax()}. X,Y,Z:R,G,B is a point light too. Emitting patches of the scene always "
                        "shine")


def _add_dynamic(p: argparse.ArgumentParser, local_size: int = 1024) -> None:
    p.add_argument("--local-size", type=_positive_int, default=local_size, metavar="M",
                   help=f"patches in the local set around the observer, the size of the multibounce matrix K "
                        f"(default {local_size}; capped at the scene's patch count)")
    p.add_argument("--update", choices=("exact", "paper"), default="exact",
                   help="local-matrix update: exact (Sherman-Morrison swaps, equals a rebuild) or paper "
                        "(the published rank-one update) (default exact)")
    p.add_argument("--storage", choices=("fp16", "fp32", "fp64"), default="fp32",
                   help="element type K is stored in on the device (default fp32)")
    p.add_argument("--no-far-field", action="store_true",
                   help="the paper's method: patches outside the local set get only their own light and none of "
                        "theirs reaches it (default: the far field lights every patch)")
    p.add_argument("--clusters", type=_positive_int, default=None, metavar="C",
                   help="clusters of the far field's coarse level (default N/8)")


def _dynamic_options(args: argparse.Namespace) -> dict:
    """DynamicRadiosity keywords from the options of :func:`_add_dynamic`."""
    return {"update": args.update, "storage": args.storage, "far_field": not args.no_far_field,
            "clusters": args.clusters}


def _add_walk_output(p: argparse.ArgumentParser, out: str | None) -> None:
    p.add_argument("--out", default=out, metavar="DIR",
                   help="folder for frame_NNNN images, compare_NNNN.png and summary.txt (created if missing)"
                        + (f"; default ./{out}" if out else "; default: write no images"))
    p.add_argument("--format", default="png", choices=("png", "jpg", "exr", "hdr", "tif"),
                   help="image format of the frames (exr keeps linear float values) (default png)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="pydynrad",
        description="Dynamic Radiosity on OpenCL: form factors, local multibounce matrices, frame loops. "
                    "Start with `pydynrad demo`.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, parser_class=_Parser)

    # One block per subcommand, built from the shared option groups (_add_scene, _add_look, _add_lights,
    # ...): what still looks alike between blocks is argparse's declaration shape, not repeated logic.
    p = sub.add_parser("info", help="list OpenCL devices and the one pydynrad uses",
                       description="List every OpenCL device and show the one pydynrad selects "
                                   "(PYOPENCL_CTX overrides the default, the first PoCL CPU device).")
    p.set_defaults(func=_cmd_info)

    p = sub.add_parser("demo", help="Cornell box walk with a moving light: frames, timings, error",
                       description="Render the Cornell box while the camera walks into it and a point light circles "
                                   "the blocks. The local multibounce matrix follows the camera; each frame is "
                                   "written as an image, and at the first and last frame the full radiosity is "
                                   "solved too, giving the local-versus-full error and a comparison image. Prints "
                                   "a table of per-stage timings.")
    p.add_argument("--frames", type=_positive_int, default=24, metavar="N", help="number of frames (default 24)")
    _add_image_size(p)
    p.add_argument("--max-edge", type=_positive_float, default=100.0, metavar="MM",
                   help="longest patch edge in mm (default 100: 1,128 patches)")
    p.add_argument("--moving-block", action="store_true",
                   help="add a green cube that glides and turns through the box (a moving rigid object: its shadow "
                        "and colour bleeding follow it; reference frames solve the box with it from fresh hemicubes)")
    _add_form_factors(p, resolution=32)
    _add_dynamic(p, local_size=768)
    _add_walk_output(p, DEMO_DIR)
    p.add_argument("--shading", choices=("smooth", "flat"), default="smooth", help="smooth or flat shading (default smooth)")
    p.add_argument("--exposure", type=_stops, default=DEMO_EXPOSURE, metavar="STOPS",
                   help=f"exposure of the written frames in stops (default {DEMO_EXPOSURE:.2f} = log2(1/pi): pixels "
                        "hold radiosity, so this shows the radiance B/pi, as a path tracer would)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_cmd_demo)

    p = sub.add_parser("formfactors", help="precompute a scene's form factors into a file or a store folder",
                       description="Compute the sparse form-factor matrix F of SCENE with hemicubes. OUT ending in "
                                   ".npz: one file (CSR arrays plus a header with the scene's geometry hash and the "
                                   "parameters), computed in this process, for scenes whose F fits in memory. Any "
                                   "other OUT: a form-factor store folder (compressed, checksummed row blocks, read "
                                   "on demand by walk/render/compare), computed with Dask on a LocalCluster "
                                   "(--workers) or an existing cluster (--scheduler). A store is resumable: running "
                                   "the same command again computes only the blocks still missing. Either way data is "
                                   "never used with the wrong scene, and files are written whole (temporary file, "
                                   "then rename).")
    _add_scene(p)
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="FILE.npz for a single file, or a folder (new, empty, or a store to resume) for a store; "
                        "its parent folder must exist")
    _add_resolution(p, 64)
    _add_samples(p, 1, "recorded in the file or store; a store resumed with other K is refused (default 1)")
    p.add_argument("--force", action="store_true",
                   help="file only: replace an existing OUT.npz that is not a pydynrad form-factor file")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_count, default=None, metavar="N",
                       help="store only: worker processes of a local Dask cluster (LocalCluster, one thread and one "
                            "OpenCL context each) (default 2); 0 computes in this process without Dask")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="store only: address of an existing Dask cluster's scheduler (e.g. tcp://host:8786); "
                            "its workers must see OUT's folder and have pydynrad installed")
    p.add_argument("--block-rows", type=_positive_int, default=None, metavar="ROWS",
                   help="store only: form-factor rows per block file, the unit of reading and of resuming "
                        "(default 256, or the existing store's)")
    p.add_argument("--clusters", default=None, metavar="C|auto|LABELS.npy",
                   help="store only: also store the far field's patch-to-cluster form factors G = F Pr for these "
                        "clusters (C of them made by pydynrad.farfield.cluster_patches, 'auto' for its default "
                        "count, or a .npy file of one integer cluster label per patch), from hemicubes that record "
                        "cluster ids; a store resumed later finishes its G too; walks then use its far field")
    p.add_argument("--cluster-resolution", type=_resolution, default=None, metavar="R",
                   help="store only: hemicube resolution of G (default: --resolution, G then summed from F's "
                        "stored rows, or with --no-f equal to F Pr of the rows walks compute on demand)")
    p.add_argument("--no-f", action="store_true",
                   help="store only: store G alone, not F's rows, for a DynamicRadiosity with rows on demand "
                        "from Python (form_factors=None, cluster_form_factors=store.cluster_form_factors(...)); "
                        "the CLI's walk, render and compare need F's rows")
    p.add_argument("--verify", action="store_true",
                   help="store only: read every finished block of an existing store, F's and G's, check each "
                        "against its checksum (bound to this store), report the counts and recompute what fails "
                        "(a resume checks F's blocks anyway)")
    p.add_argument("--poses", default=None, metavar="PATH.json",
                   help="store only: also store the rows of the moving objects of this path file at every frame "
                        "of its walk (the paper's precomputed poses; a walk with --form-factors OUT then takes "
                        "its moves' object rows from there); configurations already stored are skipped")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_formfactors)

    p = sub.add_parser("render", help="render one image of a full radiosity solution",
                       description="Solve the radiosity of SCENE over all patches (emitting patches plus any "
                                   "--light) and render it from one camera.")
    _add_scene(p)
    p.add_argument("-o", "--output", required=True, metavar="IMAGE",
                   help="output image: .png/.jpg (exposed, sRGB, 8-bit) or .exr/.hdr/.tif (linear float)")
    _add_camera(p)
    _add_look(p)
    _add_form_factors(p)
    p.set_defaults(func=_cmd_render)

    p = sub.add_parser("bake", help="bake a full radiosity solution into a mesh other tools open",
                       description="Solve the radiosity of SCENE over all patches (emitting patches plus any --light) "
                                   "and write it where Blender, game engines and web viewers read it: per-vertex "
                                   "colours (OUT.glb or OUT.ply, smooth across each surface, split at creases and "
                                   "material borders), or with --lightmap a linear float lightmap image plus OUT.glb "
                                   "carrying its UVs and an 8-bit copy of it any glTF viewer shows. Linear radiosity "
                                   "is stored unscaled; the 8-bit or clipped display colours use --exposure, stated "
                                   "in the file's metadata.")
    _add_scene(p)
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="the mesh: .glb (glTF 2.0) or .ply; .glb with --lightmap")
    p.add_argument("--lightmap", metavar="IMAGE", default=None,
                   help="also bake a lightmap into IMAGE (.exr recommended; .hdr/.tif/.pfm are linear too); "
                        "OUT then holds its UVs (TEXCOORD_1)")
    p.add_argument("--texels-per-unit", type=_positive_float, default=None, metavar="T",
                   help="lightmap texels per scene unit of length (default: about a 1024x1024 lightmap)")
    p.add_argument("--padding", type=_ranged(1, 64, integral=True), default=2, metavar="PX",
                   help="lightmap texels between charts, filled by dilation (default 2)")
    p.add_argument("--crease-angle", type=_ranged(0.0, 180.0), default=30.0, metavar="DEG",
                   help="never smooth across a sharper angle (default 30)")
    p.add_argument("--exposure", type=_stops, default=0.0, metavar="STOPS",
                   help="display colours are radiosity * 2**STOPS (default 0; log2(1/pi) = -1.65 shows radiance)")
    _add_lights(p)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    _add_form_factors(p)
    p.set_defaults(func=_cmd_bake)

    p = sub.add_parser("walk", help="walk a camera path through a scene with dynamic radiosity",
                       description="Follow the camera path in FILE through SCENE: per frame the local multibounce "
                                   "matrix follows the camera, the lights of that frame are applied and an image is "
                                   "rendered. Prints per-stage timings. The path file is JSON: "
                                   '{"frames": 48, "fov_y": 39.3, "width": 320, "height": 240, "keyframes": '
                                   '[{"position": [x,y,z], "look_at": [x,y,z]}, ...]} (or "orbit": {"center": '
                                   '[x,y,z], "radius": r, "elevation": h} instead of keyframes), optionally "lights": '
                                   '[{"type": "point", "intensity": [r,g,b], "keyframes": [[x,y,z], ...]}] (also '
                                   '"spot" and "directional") and "objects": [{"block": {"size": 100}} or {"mesh": '
                                   '"cube.obj"}, "keyframes": [{"position": [x,y,z], "rotation_deg": [rx,ry,rz]} or '
                                   '4x4 matrices, ...]}] (moving rigid bodies; every field: pydynrad.paths).')
    _add_scene(p)
    p.add_argument("--path", required=True, metavar="FILE", help="camera path file (JSON, format above)")
    _add_look(p)
    _add_form_factors(p)
    _add_dynamic(p)
    _add_walk_output(p, None)
    p.add_argument("--reference-frames", type=_frame_number, nargs="*", default=[], metavar="K",
                   help="frames (negative: from the end) at which to also solve the full radiosity, report the "
                        "error and write compare_K.png")
    p.set_defaults(func=_cmd_walk)

    p = sub.add_parser("compare", help="dynamic versus full radiosity for one view, side by side",
                       description="Place the local set around the camera, compute the dynamic radiosity and the "
                                   "full solution, and write one image: dynamic | full | false-colour relative "
                                   "error with a colour bar. Prints the errors.")
    _add_scene(p)
    p.add_argument("-o", "--output", required=True, metavar="IMAGE", help="output image (.png recommended)")
    _add_camera(p)
    _add_look(p)
    _add_form_factors(p)
    _add_dynamic(p)
    p.set_defaults(func=_cmd_compare)
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
