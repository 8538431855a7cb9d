"""The frame loop: a camera walks through a scene, the local matrix follows it.

Per frame :func:`walk` does what an interactive viewer would, and times each stage:

1. ``update``: ``dynamic.update(camera.position)`` moves the local patch set to the observer
   (the paper's per-frame swaps of the multibounce matrix K);
2. ``lighting``: ``dynamic.radiosity(lights)`` with the lights of this frame (lights may move
   along :class:`~pydynrad.paths.LightTrack` keyframes): one light pass and B = L + P K L;
3. ``render``: primary visibility and shading (:class:`~pydynrad.renderer.Renderer`);
4. ``write``: the image file, when an output folder is given.

At chosen frames it can also solve the full radiosity (all N patches) for the same lights and
record the local-versus-full error, with a comparison image (:mod:`pydynrad.comparison`).
Timings are wall-clock seconds measured on the host after each stage has finished on the
device; the first frame includes kernel builds and uploads.
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .atomic import check_file_target
from .checks import integer, stops
from .comparison import reference_frame
from .defaults import auto_exposure
from .device.devices import device_or_default
from .dynamic import DynamicRadiosity
from .dynamic.moves import MovingObjects
from .errors import InvalidInputError
from .formfactors import form_factors as hemicubes
from .geometry.camera import Camera
from .geometry.loading import checked_scene
from .geometry.objects import MAX_REACH, check_reach
from .image_io import _format_for, write_image
from .paths import (
    CHECK_CHUNK,
    CameraPath,
    LightTrack,
    ObjectTrack,
    WalkFile,
    fly_through,
    lights_at,
    load_path,
    load_walk,
    orbit,
)
from .progress import progress_bar
from .renderer import Renderer
from .rows.files import whole_matrix
from .video import VideoWriter

__all__ = [
    "walk",
    "WalkResult",
    "FrameRecord",
    "CameraPath",
    "LightTrack",
    "ObjectTrack",
    "orbit",
    "fly_through",
    "load_path",
    "load_walk",
    "WalkFile",
    "STAGES",
]

STAGES = ("update", "lighting", "render", "write")


@dataclass
class FrameRecord:
    """One frame of a walk: its camera, stage times (seconds), the dynamic solver's stats,
    the image written (if any) and, at reference frames, the local-versus-full error
    (area-weighted relative RMS over patches, see :func:`pydynrad.comparison.radiosity_error`)."""

    index: int
    camera: Camera
    seconds: dict[str, float]
    stats: object = None
    image_path: Path | None = None
    error: float | None = None
    comparison_path: Path | None = None
    pixel_error: dict | None = None
    local_only_error: float | None = None  # the paper's local-only answer's error, beside a far field's
    local_only_pixel_error: dict | None = None
    black: bool = False  # no pixel of the image is lit
    lit: bool = True  # some patch has radiosity (False: the frame has no light at all)


@dataclass
class WalkResult:
    """What :func:`walk` returns: per-frame records, the last frame's radiosity (N, 3) and
    image (H, W, 3), and every image when ``keep_images`` was set."""

    frames: list[FrameRecord]
    radiosity: np.ndarray
    image: np.ndarray
    images: list[np.ndarray] = field(default_factory=list)
    exposure: float = 0.0  # the stops the frames were written with (chosen once when exposure="auto")
    rendered: bool = True  # False: render=False, the frames were solved but not rendered

    def timings(self) -> dict[str, np.ndarray]:
        """Seconds per stage, one entry per frame."""
        return {s: np.array([f.seconds.get(s, 0.0) for f in self.frames]) for s in STAGES}

    def errors(self) -> dict[int, float]:
        """Local-versus-full error at each reference frame."""
        return {f.index: f.error for f in self.frames if f.error is not None}

    def summary(self) -> str:
        """A table of stage times: first frame (warm-up), median and max of the others."""
        t = self.timings()
        lines = [f"{'stage':10s} {'first ms':>10s} {'median ms':>10s} {'max ms':>10s}   ({len(self.frames)} frames)"]
        for stage in STAGES if self.rendered else ("update", "lighting"):
            v = 1e3 * t[stage]
            rest = v[1:] if len(v) > 1 else v
            lines.append(f"{stage:10s} {v[0]:10.1f} {np.median(rest):10.1f} {rest.max():10.1f}")
        total = sum(t[s] for s in STAGES)
        rest = total[1:] if len(total) > 1 else total
        lines.append(
            f"{'frame':10s} {1e3 * total[0]:10.1f} {1e3 * np.median(rest):10.1f} {1e3 * rest.max():10.1f}"
            f"   -> {1.0 / max(np.median(rest), 1e-9):.1f} frames/s"
            + ("" if self.rendered else " (update + lighting only: nothing rendered)")
        )
        for f in self.frames:
            if f.error is None:
                continue
            line = f"dynamic vs full radiosity at frame {f.index}: relative RMS error {100 * f.error:.3g}%"
            if f.local_only_error is not None:
                line += (
                    f" with the far field, {100 * f.local_only_error:.3g}% local only (the paper's method); "
                    f"mean per pixel {100 * f.pixel_error['mean']:.3g}% and "
                    f"{100 * f.local_only_pixel_error['mean']:.3g}%"
                )
            lines.append(line)
        return "\n".join(lines)


def _frame_set(frames, n: int) -> set[int]:
    try:
        frames = list(frames)
    except TypeError:
        raise InvalidInputError(f"reference_frames must be a sequence of frame numbers; got {frames!r}") from None
    out = set()
    for f in frames:
        k = integer(f, f"a reference frame of the walk's {n} frames", -n, n - 1)  # 1.7 had been frame 1
        out.add(k + n if k < 0 else k)
    return out


def walk(
    scene,
    path: CameraPath,
    dynamic=None,
    *,
    lights=(),
    objects=(),
    form_factors=None,
    local_size: int | None = None,
    solver_options: dict | None = None,
    shading: str = "smooth",
    output=None,
    image_format: str = "png",
    exposure: float | str | None = "auto",
    reference_frames=(),
    keep_images: bool = False,
    progress: bool | None = None,
    device=None,
    render: bool = True,
    video=None,
    fps: float = 24.0,
) -> WalkResult:
    """Walk a camera through ``scene`` with dynamic radiosity.

    Parameters
    ----------
    scene : Scene
    path : CameraPath
        From :func:`orbit`, :func:`fly_through`, :class:`CameraPath` keyframes or :func:`load_path`.
    dynamic : DynamicRadiosity, optional
        The solver to drive (anything with ``update(position)`` and ``radiosity(lights)``).
        Built from ``form_factors`` when omitted.
    lights : sequence of lights and LightTrack
        Analytic lights of every frame; a :class:`LightTrack` moves along its keyframes.
    objects : sequence of ObjectTrack
        Moving objects: each frame moves every track's object to its pose before the update
        (``dynamic`` must hold those objects; built with them when omitted). Renders and
        reference solves then see the world at that frame's poses: reference frames solve it
        from fresh hemicubes at ``dynamic``'s resolution, whatever ``form_factors`` is.
    form_factors : (N, N) scipy.sparse or RowSource, optional
        F (of the static scene) for building ``dynamic`` and for the reference solves; required
        for either (except reference solves with ``objects``). A row
        source (a form-factor store, a RowCache: see :func:`pydynrad.open_form_factors`)
        streams rows to ``dynamic``; reference frames then read all of F into memory once.
    local_size : int, optional
        M, the local set's size, when building ``dynamic`` (default
        :func:`pydynrad.defaults.default_local_size`: min(1024, N // 2)).
    solver_options : dict, optional
        More keyword arguments for :class:`~pydynrad.DynamicRadiosity` (``update``,
        ``storage``, ``max_swaps_per_frame``, ...). With ``objects``, an ``objects=``
        :class:`~pydynrad.MovingObjects` there gives the moves' settings (its own objects are
        replaced by the tracks').
    shading : "smooth" or "flat"
    output : str or Path, optional
        Folder for ``frame_0000.<image_format>``, ... (created if missing); None writes nothing.
    image_format : str
        File extension of the frames: png, jpg, exr, ...
    exposure : float or "auto"
        Stops applied when writing images. "auto" (the default; None too): for 8-bit formats
        (png, jpg) fixed once for the whole walk from the first frame with a lit pixel by
        :func:`pydynrad.defaults.auto_exposure`, so frames do not flicker; linear formats (exr,
        hdr, tif) keep the values (0 stops). The value used is ``WalkResult.exposure``.
    reference_frames : iterable of int
        Frames (negative counts from the end) at which to solve the full radiosity and record
        the error; with ``output`` a ``compare_0000.png`` is written there too.
    keep_images : bool
        Return every frame's image in ``WalkResult.images``.
    progress : bool, optional
        A tqdm bar over the frames (:mod:`pydynrad.progress`); False: none.
    device : Device, optional
    render : bool
        Render the frames (default). False: only ``update`` and ``lighting`` run and are timed
        (no images, ``output`` and ``keep_images`` must not be given); reference frames still
        compare radiosity per patch, and render their comparison image.
    video : str or Path, optional
        Also encode the frames (at the walk's exposure, sRGB, 8-bit) into this video file
        (.mp4: H.264; .mkv, .mov, .webm, .gif) at ``fps`` frames per second. Needs the
        ``video`` extra (imageio with imageio-ffmpeg); without it MissingExtraError names it,
        before any work.

    Returns
    -------
    WalkResult
    """

    if not isinstance(path, CameraPath):
        raise InvalidInputError(f"path must be a CameraPath (orbit, fly_through, load_path); got {type(path).__name__}")
    device = device_or_default(device)
    lights = [lights] if not isinstance(lights, (list, tuple)) else list(lights)
    try:
        tracks = list(objects)
    except TypeError:
        raise InvalidInputError(f"objects must be a sequence of ObjectTrack; got {type(objects).__name__}") from None
    for t in tracks:
        if not isinstance(t, ObjectTrack):
            raise InvalidInputError(
                f"objects must be ObjectTrack entries (a RigidObject with keyframes); got {type(t).__name__}"
            )
    auto = exposure is None or (isinstance(exposure, str) and exposure == "auto")
    exposure = None if auto else stops(exposure)  # before any frame's work, not at the first image written
    if not render and (output is not None or keep_images or video is not None):
        raise InvalidInputError(
            "render=False renders no frames: it cannot write them (output=, video=) or keep them (keep_images=)"
        )
    movie = None
    if video is not None:
        movie = VideoWriter(video, fps, feature="walk(video=...)")  # the extra and the file, before any work
    scene = checked_scene(scene)
    n = len(path)
    # Every frame's camera and poses before any work (the solution's build included), not mid-walk:
    # tested in chunks of frames at once (a Camera and a slerp per frame left a long path silent for
    # minutes before its first frame); each frame's camera is made when the frame is.
    path.check(progress)
    _check_reach(scene, tracks, n, progress)
    refs = _frame_set(reference_frames, n)
    if refs and form_factors is None and not tracks:
        raise InvalidInputError("reference frames need the form factors (form_factors=F) for the full solve")
    if dynamic is None:
        if form_factors is None:
            raise InvalidInputError("walk needs a DynamicRadiosity (dynamic=...) or the form factors (form_factors=F)")

        m = local_size  # None: DynamicRadiosity's default rule (pydynrad.defaults.default_local_size)
        options = dict(solver_options or {})
        if tracks:  # the tracks' objects, moved as a MovingObjects in solver_options says (its defaults else)
            settings = options.get("objects")
            settings = settings if isinstance(settings, MovingObjects) else MovingObjects(())
            options["objects"] = dataclasses.replace(settings, objects=[t.object for t in tracks])
        dynamic = DynamicRadiosity(scene, form_factors, local_size=m, device=device, **options)
    out_dir = None
    if output is not None:
        out_dir = Path(output)
        _, linear = _format_for(out_dir / f"frame.{image_format}")  # reject a bad format before any work
        if linear and exposure is None:  # auto: linear float frames keep their values
            exposure = 0.0
        out_dir.mkdir(parents=True, exist_ok=True)
        _check_frame_files(out_dir, n, image_format, refs)  # a folder in a frame's place: before the first frame
    renderer = Renderer(scene, device)
    if render:
        renderer.warm_up()
    full_F = None  # all of F in memory, read at the first reference frame
    records, images = [], []
    b = img = None
    bar = progress_bar(progress, iterable=range(n), desc="walk", unit="frame")
    try:
        for k in bar:
            cam = path.camera(k)  # checked above with the others
            frame_lights = lights_at(lights, k, n)
            t0 = time.perf_counter()
            for t in tracks:
                dynamic.move(t.object, t.at(k, n))
            stats = dynamic.update(cam.position)
            t1 = time.perf_counter()
            b = np.asarray(dynamic.radiosity(frame_lights))
            t2 = time.perf_counter()
            if tracks and (render or k in refs):
                renderer = Renderer(dynamic.scene, device)  # the world at this frame's poses
            img = renderer.render(b, cam, shading) if render else None
            t3 = time.perf_counter()
            rec = FrameRecord(
                k,
                cam,
                {"update": t1 - t0, "lighting": t2 - t1, "render": t3 - t2, "write": 0.0},
                stats,
                black=img is not None and not img.any(),
                lit=bool(b.any()),
            )
            if exposure is None and img is not None and img.any():  # auto: fixed at the first lit frame
                exposure = auto_exposure(img)
            if out_dir is not None:
                rec.image_path = write_image(out_dir / f"frame_{k:04d}.{image_format}", img, exposure or 0.0)
            if movie is not None:
                movie.append(img, exposure or 0.0)
            if out_dir is not None or movie is not None:
                rec.seconds["write"] = time.perf_counter() - t3
            if k in refs and tracks:
                world = dynamic.scene
                _reference(
                    rec,
                    dynamic,
                    world,
                    hemicubes(world, dynamic.resolution, device=device),
                    frame_lights,
                    b,
                    img,
                    renderer,
                    shading,
                    out_dir,
                    exposure,
                    device,
                )
            elif k in refs:
                if full_F is None:
                    full_F = whole_matrix(form_factors)
                _reference(
                    rec, dynamic, scene, full_F, frame_lights, b, img, renderer, shading, out_dir, exposure, device
                )
            if keep_images:
                images.append(img)
            records.append(rec)
            bar.set_postfix_str(" ".join(f"{s} {1e3 * v:.0f}ms" for s, v in rec.seconds.items() if s != "write"))
    finally:
        if movie is not None:
            movie.close()
    return WalkResult(records, b, img, images, exposure=exposure or 0.0, rendered=render)


def _check_reach(scene, tracks, n: int, progress) -> None:
    """:func:`~pydynrad.geometry.objects.check_reach` for every track at every frame: the poses'
    bounding spheres in chunks of frames at once (:meth:`ObjectTrack.poses`); a frame within a
    millionth of the limit is checked at its own pose (:meth:`ObjectTrack.at`), which decides."""
    if not tracks:
        return
    limit = MAX_REACH * scene.ray_scale
    many = n > CHECK_CHUNK
    bar = progress_bar(progress if many else False, total=n * len(tracks), desc="checking the poses", unit="frame")
    try:
        for t in tracks:
            centre, radius = t.object.bounding_sphere(np.eye(4))  # in the object's own frame
            for start in range(0, n, CHECK_CHUNK):
                stop = min(start + CHECK_CHUNK, n)
                T = t.poses(n, start, stop)
                c = T[:, :3, :3] @ centre + T[:, :3, 3]
                reach = np.linalg.norm(c - scene.frame.origin, axis=1) + radius
                for k in start + np.flatnonzero(~(reach <= limit * (1.0 - 1e-6))):
                    check_reach(scene, t.object, t.at(int(k), n))
                bar.update(stop - start)
    finally:
        bar.close()


def _check_frame_files(out_dir: Path, n: int, image_format: str, refs) -> None:
    """:func:`~pydynrad.atomic.check_file_target` for every file a walk writes into ``out_dir``:
    the folder once (the first frame's name), the comparisons by name, and the frames by one
    listing of the folder (a folder there of a frame's name is refused, the first one named),
    not ``n`` look-ups of names that are mostly not there."""
    check_file_target(out_dir / f"frame_{0:04d}.{image_format}")
    for k in sorted(refs):
        check_file_target(out_dir / f"compare_{k:04d}.png")
    suffix = f".{image_format}"
    taken = []
    with os.scandir(out_dir) as entries:
        for e in entries:
            digits = e.name[len("frame_") : -len(suffix)]
            if not (e.name.startswith("frame_") and e.name.endswith(suffix) and digits.isdigit()):
                continue
            k = int(digits)
            if k < n and e.name == f"frame_{k:04d}{suffix}" and e.is_dir():
                taken.append(k)
    if taken:
        check_file_target(out_dir / f"frame_{min(taken):04d}{suffix}")


def _reference(
    rec: FrameRecord, dynamic, scene, F, lights, b, img, renderer, shading, out_dir, exposure, device
) -> None:
    """Solve the full radiosity for this frame's lights; record the error and the comparison."""

    local_only = None
    if getattr(dynamic, "far", None) is not None:  # the paper's answer from the same K, for comparison
        local_only = np.asarray(dynamic.radiosity(lights, far_field=False))
    ref = reference_frame(
        scene,
        F,
        b,
        rec.camera,
        lights=lights,
        renderer=renderer,
        image=img,
        shading=shading,
        exposure=exposure,
        local_only=local_only,
        device=device,
    )
    rec.error, rec.pixel_error = ref.error, ref.pixel_error
    rec.local_only_error, rec.local_only_pixel_error = ref.local_only_error, ref.local_only_pixel_error
    if out_dir is not None:
        rec.comparison_path = write_image(out_dir / f"compare_{rec.index:04d}.png", ref.image)
