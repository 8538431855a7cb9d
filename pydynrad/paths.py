"""Camera and light paths for walks: keyframes interpolated per frame, orbits, fly-throughs,
and the JSON path file that ``pydynrad walk --path FILE`` reads.

A :class:`CameraPath` holds K keyframes (eye positions and look-at points) and a frame count;
frame i samples the keyframe curve at parameter ``i (K - 1) / (frames - 1)``, uniformly in
keyframe index (Catmull-Rom, which passes through every keyframe, or linear). A
:class:`LightTrack` moves a point or spot light the same way.

Path file (JSON); its fields are named as the Python API names them (:class:`Camera`,
:func:`orbit`, :mod:`pydynrad.lights.sources`), and any other field is an error::

    {
      "frames": 48,                       # number of frames (>= 1)
      "fov_y": 39.3,                      # vertical field of view, degrees (default 39.3, as --fov-y)
      "width": 320, "height": 240,        # image size in pixels (default 320 x 240)
      "up": [0, 1, 0],                    # optional, default +y
      "interpolation": "catmull-rom",     # or "linear"
      "keyframes": [{"position": [x, y, z], "look_at": [x, y, z]}, ...],
      # instead of "keyframes": "orbit": {"center": [..], "radius": r, "elevation": h,
      #                                     "start_angle": degrees, "turns": 1.0}
      "lights": [{"type": "point", "intensity": [r, g, b], "keyframes": [[x, y, z], ...]},
                 {"type": "spot", "direction": [x, y, z], "intensity": [r, g, b],
                  "inner_angle_deg": 20, "outer_angle_deg": 30, "keyframes": [[x, y, z], ...]},
                 {"type": "directional", "direction": [x, y, z], "irradiance": [r, g, b]}],
      "objects": [{"mesh": "cube.obj",              # relative to the path file; or instead
                   # "block": {"size": 100, "subdivisions": 1},   (see pydynrad.scenes.block)
                   "albedo": [r, g, b], "emission": [r, g, b],    # optional: replace the mesh's
                   "name": "crate",                               # optional
                   "keyframes": [[[1, 0, 0, x], [0, 1, 0, y], [0, 0, 1, z], [0, 0, 0, 1]],
                                 {"position": [x, y, z], "rotation_deg": [rx, ry, rz]}, ...],
                   "interpolation": "catmull-rom"}]
    }

``"lights"`` is optional. Point and spot lights (intensity in W/sr; spot cone half-angles in
degrees, as on the command line, ``"inner_angle_deg"`` defaulting to ``"outer_angle_deg"``, a
hard edge; the radians keys ``"inner_angle"``/``"outer_angle"`` of earlier releases are still
read, with a DeprecationWarning, for one release) move through their position keyframes
(one keyframe: a fixed light; ``"interpolation"`` per light, default catmull-rom); a spot
light keeps its direction. A directional light has a direction and an irradiance.

``"objects"`` is optional too, and only :func:`load_walk` reads it: moving rigid objects
(:class:`~pydynrad.RigidObject`) following their pose keyframes as an :class:`ObjectTrack`.
A keyframe is a rigid 4x4 object-to-world matrix or a position with rotations in degrees about
the world x, then y, then z axis (default none). ``"albedo"`` and ``"emission"`` (one value or
RGB, for every patch of the object) replace the mesh's own.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .checks import floats, number, unit_vector
from .defaults import FOV_Y
from .errors import InvalidInputError
from .geometry.camera import Camera
from .geometry.loading import load
from .geometry.objects import RigidObject, rigid_transform
from .lights.sources import DirectionalLight, PointLight, SpotLight
from .scenes import block

__all__ = [
    "CameraPath",
    "LightTrack",
    "ObjectTrack",
    "orbit",
    "fly_through",
    "load_path",
    "load_walk",
    "WalkFile",
    "INTERPOLATIONS",
]

INTERPOLATIONS = ("catmull-rom", "linear")


def _keyframes(value, what: str) -> np.ndarray:
    a = floats(value, what)  # numbers, not text that spells them (as every other field)
    if a.ndim == 1 and a.shape == (3,):
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
        raise InvalidInputError(f"{what} must be a list of (x, y, z) points; got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{what} must be finite")
    return a


#: Most frames a path may have: a walk renders and solves every one (10^9 frames at the
#: demo's ~0.4 s each would run for 13 years), so a typo is refused before anything starts.
MAX_FRAMES = 1_000_000
#: The largest path file read (a path of a million keyframes is ~100 MB of JSON; /dev/zero is endless).
MAX_PATH_FILE_BYTES = 256 * 2**20


def _frame_count(frames) -> int:
    if isinstance(frames, (bool, str, bytes)) or not isinstance(frames, (int, float, np.integer, np.floating)):
        raise InvalidInputError(f"frames must be a whole number >= 1; got {frames!r}")
    if isinstance(frames, (int, np.integer)):
        n = int(frames)  # an int past float64 (10**400) compared as it is
    elif np.isfinite(frames) and float(frames).is_integer():
        n = int(frames)
    else:
        raise InvalidInputError(f"frames must be a whole number >= 1; got {frames!r}")
    if n < 1:
        raise InvalidInputError(f"frames must be a whole number >= 1; got {n}")
    if n > MAX_FRAMES:
        raise InvalidInputError(
            f"frames must be at most {MAX_FRAMES:,} (a walk renders every frame); got {n:,}"
            if n < 10**30
            else f"frames must be at most {MAX_FRAMES:,}; got a {len(str(n))}-digit number"
        )
    return n


def _check_interpolation(value) -> None:
    """The one rule for a path's ``interpolation`` (camera, light and object tracks)."""
    if value not in INTERPOLATIONS:
        raise InvalidInputError(f"interpolation must be one of {', '.join(INTERPOLATIONS)}; got {value!r}")


def sample_curve(keys: np.ndarray, s: float, interpolation: str) -> np.ndarray:
    """Point at parameter ``s`` in [0, K-1] on the curve through ``keys`` (K, 3)."""
    k = len(keys)
    if k == 1:
        return keys[0].copy()
    s = min(max(float(s), 0.0), k - 1.0)
    i = min(int(np.floor(s)), k - 2)
    t = s - i
    p1, p2 = keys[i], keys[i + 1]
    if interpolation == "linear":
        return (1.0 - t) * p1 + t * p2
    # Uniform Catmull-Rom; end segments reflect the missing neighbour so the curve starts and
    # ends with the direction of its first and last chords.
    p0 = keys[i - 1] if i > 0 else 2.0 * p1 - p2
    p3 = keys[i + 2] if i + 2 < k else 2.0 * p2 - p1
    t2, t3 = t * t, t * t * t
    return 0.5 * (
        (2.0 * p1) + (-p0 + p2) * t + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2 + (-p0 + 3.0 * p1 - 3.0 * p2 + p3) * t3
    )


def _param(frame: int, frames: int, n_keys: int) -> float:
    if not 0 <= frame < frames:
        raise InvalidInputError(f"frame {frame} outside 0..{frames - 1}")
    return 0.0 if frames == 1 else frame * (n_keys - 1) / (frames - 1)


#: Frames a path is checked in at once (:meth:`CameraPath.check`, :meth:`ObjectTrack.poses`):
#: 65,536 frames' views or poses are a few MB.
CHECK_CHUNK = 65536


def _params(start: int, stop: int, frames: int, n_keys: int) -> np.ndarray:
    """:func:`_param` of frames ``start..stop-1`` at once (the same float64 values: the
    products are exact below 2^53, and one division rounds them as Python's does)."""
    if frames == 1:
        return np.zeros(stop - start)
    return np.arange(start, stop, dtype=np.int64) * (n_keys - 1) / float(frames - 1)


def sample_curves(keys: np.ndarray, s: np.ndarray, interpolation: str) -> np.ndarray:
    """:func:`sample_curve` at many parameters ``s`` (m,) at once: (m, 3)."""
    k = len(keys)
    s = np.asarray(s, dtype=np.float64)
    if k == 1:
        return np.repeat(keys[:1], len(s), axis=0)
    s = np.minimum(np.maximum(s, 0.0), k - 1.0)
    i = np.minimum(np.floor(s).astype(np.int64), k - 2)
    t = (s - i)[:, None]
    p1, p2 = keys[i], keys[i + 1]
    if interpolation == "linear":
        return (1.0 - t) * p1 + t * p2
    p0 = np.where((i > 0)[:, None], keys[np.maximum(i - 1, 0)], 2.0 * p1 - p2)
    p3 = np.where((i + 2 < k)[:, None], keys[np.minimum(i + 2, k - 1)], 2.0 * p2 - p1)
    t2, t3 = t * t, t * t * t
    return 0.5 * (
        (2.0 * p1) + (-p0 + p2) * t + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2 + (-p0 + 3.0 * p1 - 3.0 * p2 + p3) * t3
    )


@dataclass(frozen=True, eq=False)
class CameraPath:
    """A camera moving through keyframes.

    Parameters
    ----------
    positions : (K, 3) float
        Eye keyframes, scene units.
    look_ats : (K, 3) float or None
        Look-at keyframes; None looks along the path (a fly-through).
    frames : int
        Number of frames rendered along the path.
    fov_y, width, height, up : the lens and image size of every frame (see :class:`Camera`).
    interpolation : "catmull-rom" or "linear"
    """

    positions: np.ndarray
    look_ats: np.ndarray | None
    frames: int
    fov_y: float = FOV_Y
    width: int = 320
    height: int = 240
    up: tuple = (0.0, 1.0, 0.0)
    interpolation: str = "catmull-rom"

    def __post_init__(self) -> None:
        pos = _keyframes(self.positions, "camera keyframe positions")
        object.__setattr__(self, "positions", pos)
        if self.look_ats is not None:
            look = _keyframes(self.look_ats, "camera keyframe look_at points")
            if look.shape != pos.shape:
                raise InvalidInputError(f"{len(pos)} position keyframes but {len(look)} look_at keyframes")
            object.__setattr__(self, "look_ats", look)
        elif len(pos) < 2:
            raise InvalidInputError("a path without look_at points needs at least 2 positions to look along")
        object.__setattr__(self, "frames", _frame_count(self.frames))
        _check_interpolation(self.interpolation)
        self.camera(0)  # validates the lens and the first view now rather than mid-walk

    def __len__(self) -> int:
        return self.frames

    def __iter__(self):
        return (self.camera(i) for i in range(self.frames))

    def camera(self, frame: int) -> Camera:
        """The camera of frame ``frame`` (0-based)."""
        k = len(self.positions)
        s = _param(frame, self.frames, k)
        eye = sample_curve(self.positions, s, self.interpolation)
        if self.look_ats is not None:
            target = sample_curve(self.look_ats, s, self.interpolation)
        else:
            # Look along the curve: a point a little further on (or back, at the very end).
            ds = 0.05
            ahead = sample_curve(self.positions, min(s + ds, k - 1.0), self.interpolation)
            behind = sample_curve(self.positions, max(s - ds, 0.0), self.interpolation)
            target = eye + (ahead - behind)
        return Camera(eye, target, self.up, self.fov_y, self.width, self.height)

    def views(self, start: int = 0, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The eyes and look-at points (m, 3) of frames ``start..stop-1`` at once, as
        :meth:`camera` places them."""
        stop = self.frames if stop is None else stop
        k = len(self.positions)
        s = _params(start, stop, self.frames, k)
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is found by the check
            eye = sample_curves(self.positions, s, self.interpolation)
            if self.look_ats is not None:
                return eye, sample_curves(self.look_ats, s, self.interpolation)
            ahead = sample_curves(self.positions, np.minimum(s + 0.05, k - 1.0), self.interpolation)
            behind = sample_curves(self.positions, np.maximum(s - 0.05, 0.0), self.interpolation)
            return eye, eye + (ahead - behind)

    def check(self, progress: bool | None = None) -> None:
        """Refuse the path if any frame's camera would be refused (:meth:`camera` raises its
        :class:`~pydynrad.errors.InvalidInputError`, naming the frame): before a walk's first
        frame, not at frame 700,000 of it.

        The views are computed and tested in chunks of :data:`CHECK_CHUNK` frames at once
        (a :class:`Camera` per frame is far too slow for a path of millions of frames; the runs are
        in docs/decisions/0034-robustness-limits.md); a frame within twice the camera's tolerances of being refused is then made as
        its :class:`Camera`, which decides. ``progress``: a bar over the frames
        (:mod:`pydynrad.progress`, for paths of more than one chunk; by default shown once the
        check has run for 2 s)."""
        from .progress import progress_bar

        up = np.asarray(self.camera(0).up)  # the lens, the image size and the up vector: every frame's
        one_chunk = self.frames <= CHECK_CHUNK  # nothing to show progress over
        bar = progress_bar(False if one_chunk else progress, total=self.frames, desc="checking the path", unit="frame")
        try:
            for start in range(0, self.frames, CHECK_CHUNK):
                stop = min(start + CHECK_CHUNK, self.frames)
                eye, target = self.views(start, stop)
                with np.errstate(over="ignore", invalid="ignore"):
                    forward = target - eye
                    dist = np.linalg.norm(forward, axis=1)
                    near = dist <= 2e-9 * np.maximum(1.0, np.linalg.norm(eye, axis=1))
                    side = np.linalg.norm(np.cross(forward / dist[:, None], up), axis=1)
                    doubt = ~(np.isfinite(eye).all(axis=1) & np.isfinite(target).all(axis=1))
                    doubt |= near | ~(side >= 2e-6)
                for k in start + np.flatnonzero(doubt):
                    try:
                        self.camera(int(k))
                    except InvalidInputError as exc:
                        raise InvalidInputError(f"frame {k} of {self.frames}: {exc}") from None
                bar.update(stop - start)
        finally:
            bar.close()


def orbit(
    center,
    radius: float,
    elevation: float,
    frames: int,
    *,
    start_angle: float = 0.0,
    turns: float = 1.0,
    up=(0.0, 1.0, 0.0),
    fov_y: float = FOV_Y,
    width: int = 320,
    height: int = 240,
) -> CameraPath:
    """A circle of ``radius`` around ``center`` at ``elevation`` above it (along ``up``), always
    looking at ``center``; ``turns`` full turns over ``frames`` frames, starting at
    ``start_angle`` degrees. ``fov_y`` (degrees), ``width`` and ``height`` (pixels) set the
    lens and the image, as in :class:`Camera`.
    """
    c = _keyframes(center, "orbit center")[0]
    n = _frame_count(frames)
    radius, elevation = number(radius, "orbit radius"), number(elevation, "orbit elevation")
    start_angle, turns = number(start_angle, "orbit start_angle"), number(turns, "orbit turns")
    if not radius > 0:
        raise InvalidInputError(f"orbit radius must be > 0; got {radius!r}")
    up_v = unit_vector(up, "orbit up")
    a = np.cross(up_v, [1.0, 0.0, 0.0] if abs(up_v[0]) < 0.9 else [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(up_v, a)
    # Frames sample the full turn without repeating the start when turns == 1.
    angles = np.radians(start_angle) + 2.0 * np.pi * turns * np.arange(n) / n
    pos = c + radius * (np.cos(angles)[:, None] * a + np.sin(angles)[:, None] * b) + elevation * up_v
    return CameraPath(
        pos, np.repeat(c[None], n, axis=0), n, fov_y, width, height, up=tuple(up_v), interpolation="linear"
    )


def fly_through(
    points, frames: int, *, up=(0.0, 1.0, 0.0), fov_y: float = FOV_Y, width: int = 320, height: int = 240
) -> CameraPath:
    """Fly through ``points`` (K >= 2, Catmull-Rom) in ``frames`` frames, looking ahead;
    lens and image as in :func:`orbit`."""
    return CameraPath(_keyframes(points, "fly-through points"), None, _frame_count(frames), fov_y, width, height, up=up)


@dataclass(frozen=True, eq=False)
class LightTrack:
    """A light whose position follows keyframes over a walk.

    ``light`` is a :class:`~pydynrad.lights.sources.PointLight` or ``SpotLight`` (any frozen dataclass
    with a ``position`` field); frame i of an n-frame walk places it on the curve through
    ``positions`` at parameter ``i (K - 1) / (n - 1)``.
    """

    light: object
    positions: np.ndarray
    interpolation: str = "catmull-rom"

    def __post_init__(self) -> None:
        if not (dataclasses.is_dataclass(self.light) and hasattr(self.light, "position")):
            raise InvalidInputError(f"a LightTrack needs a light with a position; got {self.light!r}")
        object.__setattr__(self, "positions", _keyframes(self.positions, "light keyframes"))
        _check_interpolation(self.interpolation)

    def at(self, frame: int, frames: int):
        """The light at frame ``frame`` of ``frames``."""
        s = _param(frame, frames, len(self.positions))
        return dataclasses.replace(self.light, position=sample_curve(self.positions, s, self.interpolation))


@dataclass(frozen=True, eq=False)
class ObjectTrack:
    """A :class:`~pydynrad.RigidObject` whose pose follows keyframes over a walk.

    ``transforms`` (K, 4, 4) are rigid object-to-world poses; frame i of an n-frame walk puts
    the object at parameter ``i (K - 1) / (n - 1)``: its translation on the curve through the
    keyframes' translations (``interpolation``), its rotation spherically interpolated between
    the two nearest keyframes. A frame that lands on a keyframe gets that keyframe exactly.
    """

    object: object
    transforms: np.ndarray
    interpolation: str = "catmull-rom"

    def __post_init__(self) -> None:
        if not isinstance(self.object, RigidObject):
            raise InvalidInputError(f"an ObjectTrack needs a RigidObject; got {type(self.object).__name__}")
        T = np.asarray(self.transforms, dtype=np.float64)
        T = T[None] if T.ndim == 2 else T
        if T.ndim != 3 or len(T) == 0:
            raise InvalidInputError(
                f"object keyframes must be (K, 4, 4) transforms; got shape {np.shape(self.transforms)}"
            )
        object.__setattr__(
            self, "transforms", np.stack([rigid_transform(t, f"object keyframe {k}") for k, t in enumerate(T)])
        )
        _check_interpolation(self.interpolation)

    def at(self, frame: int, frames: int) -> np.ndarray:
        """The (4, 4) pose at frame ``frame`` of ``frames``."""
        from scipy.spatial.transform import Rotation, Slerp

        T = self.transforms
        s = _param(frame, frames, len(T))
        k = int(np.floor(s))
        if s == k:
            return T[k].copy()
        out = np.eye(4)
        out[:3, 3] = sample_curve(T[:, :3, 3], s, self.interpolation)
        out[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix(T[k : k + 2, :3, :3]))(s - k).as_matrix()
        return out

    def poses(self, frames: int, start: int = 0, stop: int | None = None) -> np.ndarray:
        """The (m, 4, 4) poses of frames ``start..stop-1`` of ``frames`` at once, as :meth:`at`
        makes them (its rotation's slerp to rounding: a pose to place the object by is :meth:`at`'s)."""
        from scipy.spatial.transform import Rotation

        stop = frames if stop is None else stop
        T = self.transforms
        s = _params(start, stop, frames, len(T))
        out = np.repeat(np.eye(4)[None], len(s), axis=0)
        out[:, :3, 3] = sample_curves(T[:, :3, 3], s, self.interpolation)
        k = np.minimum(np.floor(s).astype(np.int64), max(len(T) - 2, 0))
        if len(T) == 1:
            out[:, :3, :3] = T[0, :3, :3]
            return out
        keys = Rotation.from_matrix(T[:, :3, :3])
        steps = (keys[:-1].inv() * keys[1:]).as_rotvec()  # scipy's Slerp, between each pair of keyframes
        out[:, :3, :3] = (keys[k] * Rotation.from_rotvec((s - k)[:, None] * steps[k])).as_matrix()
        on_key = s == np.floor(s)
        out[on_key] = T[np.floor(s[on_key]).astype(np.int64)]  # a keyframe's pose exactly, as at() gives it
        return out


def lights_at(lights, frame: int, frames: int) -> list:
    """The lights of one frame: :class:`LightTrack` entries placed, fixed lights as they are."""
    return [l.at(frame, frames) if isinstance(l, LightTrack) else l for l in lights]


def _field(doc: dict, key: str, where: str, default=None, required: bool = False):
    if key not in doc:
        if required:
            raise InvalidInputError(f"{where}: missing field {key!r}")
        return default
    return doc[key]


def _known_fields(doc: dict, allowed: tuple[str, ...], where: str) -> None:
    """Refuse fields the format does not have (a misspelt or renamed one would be ignored silently)."""
    unknown = sorted(set(doc) - set(allowed))
    if unknown:
        renamed = {k: RENAMED[k] for k in unknown if k in RENAMED}
        hint = "; ".join(f"{k!r} is now {v}" for k, v in renamed.items())
        raise InvalidInputError(
            f"{where}: unknown field {', '.join(map(repr, unknown))} (allowed: {', '.join(allowed)})"
            + (f"; {hint}" if hint else "")
        )


#: Fields of earlier path files and what replaced them (named in the error for the old one).
RENAMED = {"fov": "'fov_y'", "size": "'width' and 'height'"}

_TOP_FIELDS = ("frames", "fov_y", "width", "height", "up", "interpolation", "keyframes", "orbit", "lights", "objects")
_ORBIT_FIELDS = ("center", "radius", "elevation", "start_angle", "turns")
_OBJECT_FIELDS = ("mesh", "block", "albedo", "emission", "name", "keyframes", "interpolation")
_BLOCK_FIELDS = ("size", "subdivisions")
#: Per light type: the light's own fields (its dataclass's, position aside) and whether it moves.
_LIGHT_FIELDS = {
    "point": (("intensity",), True),
    "spot": (("direction", "intensity", "outer_angle_deg"), True),
    "directional": (("direction", "irradiance"), False),
}


def _spot_degrees(item: dict, where: str) -> tuple[dict, dict]:
    """A spot light's fields, and the angles given by the radians keys of earlier releases
    ("inner_angle", "outer_angle": read as they were, with a DeprecationWarning, their degree
    keys then standing in for them); both spellings of one angle are an error."""
    import warnings

    old = [k for k in ("inner_angle", "outer_angle") if k in item]
    if not old:
        return item, {}
    item, radians = dict(item), {}
    for k in old:
        if f"{k}_deg" in item:
            raise InvalidInputError(
                f"{where}: give {k + '_deg'!r} (degrees) or the deprecated {k!r} (radians), not both"
            )
        radians[k] = number(item.pop(k), f"{where}: {k}")
        item[f"{k}_deg"] = float(np.degrees(radians[k]))
    warnings.warn(
        f"{where}: {' and '.join(map(repr, old))} (radians) are deprecated and will be removed in the next "
        f"release; give the cone half-angles in degrees as {' and '.join(repr(k + '_deg') for k in old)}",
        DeprecationWarning,
        stacklevel=4,
    )
    return item, radians


def _parse_light(item, where: str):
    if not isinstance(item, dict):
        raise InvalidInputError(f"{where}: a light must be an object with a 'type'")
    kind = _field(item, "type", where, required=True)
    if not isinstance(kind, str) or kind not in _LIGHT_FIELDS:
        raise InvalidInputError(f"{where}: unknown light type {kind!r}; use {', '.join(map(repr, _LIGHT_FIELDS))}")
    fields, moves = _LIGHT_FIELDS[kind]
    radians = {}
    if kind == "spot":
        item, radians = _spot_degrees(item, where)
    optional = ("inner_angle_deg",) if kind == "spot" else ()
    _known_fields(item, ("type", *fields, *optional, *(("keyframes", "interpolation") if moves else ())), where)
    values = {f: _field(item, f, where, required=True) for f in fields}
    if kind == "spot":  # degrees in the file, radians in SpotLight
        outer = radians.get("outer_angle") or np.radians(
            number(values.pop("outer_angle_deg"), f"{where}: outer_angle_deg")
        )
        values.pop("outer_angle_deg", None)
        inner = radians.get("inner_angle") or np.radians(
            number(_field(item, "inner_angle_deg", where, np.degrees(outer)), f"{where}: inner_angle_deg")
        )
        values["outer_angle"], values["inner_angle"] = float(outer), float(inner)
    if not moves:
        return DirectionalLight(**values)
    keys = _keyframes(_field(item, "keyframes", where, required=True), f"{where}: keyframes")
    light = (PointLight if kind == "point" else SpotLight)(position=keys[0], **values)
    interpolation = item.get("interpolation", "catmull-rom")
    try:  # also for one keyframe, where it is not used: a typo is still named
        _check_interpolation(interpolation)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{where}: {exc}") from None
    return LightTrack(light, keys, interpolation) if len(keys) > 1 else light


def _pose(key, where: str) -> np.ndarray:
    """A keyframe of an object: a 4x4 matrix, or {"position", "rotation_deg"}."""
    from scipy.spatial.transform import Rotation

    if not isinstance(key, dict):
        return rigid_transform(key, where)
    _known_fields(key, ("position", "rotation_deg"), where)
    pos = floats(_field(key, "position", where, required=True), f"{where}: position")
    angles = floats(_field(key, "rotation_deg", where, (0.0, 0.0, 0.0)), f"{where}: rotation_deg")
    for name, v in (("position", pos), ("rotation_deg", angles)):
        if v.shape != (3,) or not np.all(np.isfinite(v)):
            raise InvalidInputError(f"{where}: {name!r} must be 3 finite numbers; got {v.tolist()!r}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    T[:3, 3] = pos
    return T


def _object_scene(item: dict, base: Path, where: str):
    """The object-space Scene of an object entry: its mesh file or a built-in block."""
    if ("mesh" in item) == ("block" in item):
        raise InvalidInputError(f"{where}: give exactly one of 'mesh' (a file) or 'block'")
    if "mesh" in item:
        mesh = item["mesh"]
        if not isinstance(mesh, str):
            raise InvalidInputError(f"{where}: 'mesh' must be a file name; got {mesh!r}")
        # Confined to the path file's folder (and below): a path file names meshes beside it, not
        # any file the reader may open ('../x.obj', an absolute path, a link leading out).
        target = (base / mesh).resolve()
        if Path(mesh).is_absolute() or not target.is_relative_to(base.resolve()):
            raise InvalidInputError(
                f"{where}: 'mesh' {mesh!r} is outside the path file's folder {str(base)!r}; "
                "put the mesh in that folder (or below it) and name it relative to it"
            )
        try:
            return load(base / mesh)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{where}: 'mesh': {exc}") from None
    b = item["block"]
    if not isinstance(b, dict):
        raise InvalidInputError(f'{where}: \'block\' must be an object like {{"size": 100, "subdivisions": 1}}')
    _known_fields(b, _BLOCK_FIELDS, f"{where}: block")
    size = floats(_field(b, "size", f"{where}: block", required=True), f"{where}: block size")
    if size.shape not in ((), (3,)) or not np.all(np.isfinite(size)) or not np.all(size > 0):
        raise InvalidInputError(f"{where}: block 'size' must be one length or three, each > 0; got {size.tolist()!r}")
    sub = _field(b, "subdivisions", where, 1)
    # 5 is already 12,288 patches, all pinned in the local set: a larger count is a typo.
    if isinstance(sub, bool) or not isinstance(sub, int) or not 0 <= sub <= 5:
        raise InvalidInputError(f"{where}: block 'subdivisions' must be a whole number 0..5; got {sub!r}")
    return block(size.tolist(), sub)


def _parse_object(item, base: Path, where: str) -> ObjectTrack:
    if not isinstance(item, dict):
        raise InvalidInputError(f"{where}: an object must be a JSON object with 'mesh' or 'block' and 'keyframes'")
    _known_fields(item, _OBJECT_FIELDS, where)
    scene = _object_scene(item, base, where)
    try:
        scene = scene.with_materials(item.get("albedo"), item.get("emission"))
    except InvalidInputError as exc:
        raise InvalidInputError(f"{where}: {exc}") from None
    keys = _field(item, "keyframes", where, required=True)
    if not isinstance(keys, list) or not keys:
        raise InvalidInputError(
            f"{where}: 'keyframes' must be a non-empty list of 4x4 matrices or "
            '{"position": [x, y, z], "rotation_deg": [rx, ry, rz]} objects'
        )
    poses = [_pose(k, f"{where}: keyframe {i}") for i, k in enumerate(keys)]
    obj = RigidObject(scene, poses[0], name=item.get("name"))
    return ObjectTrack(obj, poses, item.get("interpolation", "catmull-rom"))


@dataclass(frozen=True, eq=False)
class WalkFile:
    """What a path file holds, ready for :func:`pydynrad.walk`: the camera path, the lights
    (fixed lights and :class:`LightTrack` s) and the moving objects (:class:`ObjectTrack` s)."""

    path: CameraPath
    lights: list
    objects: list


def load_walk(path) -> WalkFile:
    """Read a JSON path file (format in the module docstring), moving objects included.

    Mesh files of objects are read relative to the path file's folder, and only from there or
    below (a name leading out of it is refused). Every problem raises
    :class:`~pydynrad.errors.InvalidInputError` naming the file and the field.
    """
    path = Path(path)
    if path.exists() and not path.is_file():  # a folder, or /dev/zero: read without end
        raise InvalidInputError(f"path file {str(path)!r}: not a regular file")
    if path.is_file() and path.stat().st_size > MAX_PATH_FILE_BYTES:
        raise InvalidInputError(
            f"path file {str(path)!r}: {path.stat().st_size:,} bytes, more than a path file's {MAX_PATH_FILE_BYTES:,}"
        )
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise InvalidInputError(f"path file {str(path)!r}: no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InvalidInputError(f"path file {str(path)!r}: cannot read: {exc}") from None
    except json.JSONDecodeError as exc:
        raise InvalidInputError(f"path file {str(path)!r}: not valid JSON: {exc}") from None
    except RecursionError:
        raise InvalidInputError(f"path file {str(path)!r}: nested too deeply to be a path file") from None
    where = f"path file {str(path)!r}"
    if not isinstance(doc, dict):
        raise InvalidInputError(f"{where}: the top level must be a JSON object")
    try:
        _known_fields(doc, _TOP_FIELDS, where)
        lens = {
            "fov_y": _field(doc, "fov_y", where, FOV_Y),
            "width": _field(doc, "width", where, 320),
            "height": _field(doc, "height", where, 240),
        }
        up = tuple(unit_vector(_field(doc, "up", where, (0.0, 1.0, 0.0)), "up"))
        frames = _field(doc, "frames", where, required=True)
        if "orbit" in doc and ("keyframes" in doc or "interpolation" in doc):
            # An orbit is its own curve: keyframes or their interpolation beside it would be ignored.
            raise InvalidInputError(f"{where}: give 'orbit' or 'keyframes' (with 'interpolation'), not both")
        if "orbit" in doc:
            o = doc["orbit"]
            if not isinstance(o, dict):
                raise InvalidInputError(f"{where}: 'orbit' must be an object")
            _known_fields(o, _ORBIT_FIELDS, f"{where}: orbit")
            cam = orbit(
                _field(o, "center", where, required=True),
                _field(o, "radius", where, required=True),
                _field(o, "elevation", where, 0.0),
                frames,
                start_angle=_field(o, "start_angle", where, 0.0),
                turns=_field(o, "turns", where, 1.0),
                up=up,
                **lens,
            )
        else:
            keys = _field(doc, "keyframes", where, required=True)
            if not isinstance(keys, list) or not keys or not all(isinstance(k, dict) for k in keys):
                raise InvalidInputError(
                    f"{where}: 'keyframes' must be a non-empty list of "
                    '{"position": [x, y, z], "look_at": [x, y, z]} objects'
                )
            positions = [_field(k, "position", f"{where}: keyframe {i}", required=True) for i, k in enumerate(keys)]
            look_ats = [_field(k, "look_at", f"{where}: keyframe {i}", required=True) for i, k in enumerate(keys)]
            for i, k in enumerate(keys):
                _known_fields(k, ("position", "look_at"), f"{where}: keyframe {i}")
            cam = CameraPath(
                positions, look_ats, frames, up=up, interpolation=doc.get("interpolation", "catmull-rom"), **lens
            )
        items = _field(doc, "lights", where, [])
        if not isinstance(items, list):
            raise InvalidInputError(f"{where}: 'lights' must be a list")
        lights = [_parse_light(item, f"{where}: light {i}") for i, item in enumerate(items)]
        items = _field(doc, "objects", where, [])
        if not isinstance(items, list):
            raise InvalidInputError(f"{where}: 'objects' must be a list")
        objects = [_parse_object(item, path.parent, f"{where}: object {i}") for i, item in enumerate(items)]
    except InvalidInputError as exc:
        msg = str(exc)
        raise InvalidInputError(msg if msg.startswith(where) else f"{where}: {msg}") from None
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"{where}: {exc}") from None
    return WalkFile(cam, lights, objects)


def load_path(path) -> tuple[CameraPath, list]:
    """Read a JSON path file without moving objects (format in the module docstring).

    Returns ``(camera_path, lights)``: lights are fixed lights and :class:`LightTrack` s,
    ready for :func:`pydynrad.walk`. A file with ``"objects"`` is refused (they would be
    dropped); :func:`load_walk` reads it. Every problem raises
    :class:`~pydynrad.errors.InvalidInputError` naming the file and the field.
    """
    loaded = load_walk(path)
    if loaded.objects:
        raise InvalidInputError(f"path file {str(path)!r} has moving 'objects': read it with load_walk")
    return loaded.path, loaded.lights
