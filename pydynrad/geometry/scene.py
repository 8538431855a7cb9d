"""The patch scene: planar triangles with a diffuse albedo and an emission each.

A :class:`Scene` is the unit every other part of pydynrad works on. Patches are triangles
(``faces`` index into ``vertices``, trimesh's names); shared vertices carry the mesh's
connectivity so the renderer can interpolate radiosity smoothly. Geometry is validated once here, so kernels
never see NaNs, degenerate triangles or out-of-range materials.

Units: lengths in the scene's own unit, which the scene declares (:attr:`Scene.unit`, metres
per scene unit: the Cornell box is in millimetres, ``unit = 0.001``), and its up axis
(:attr:`Scene.up`); albedo dimensionless in [0, 1), emission as radiant exitance per square
metre (W/m^2 or lm/m^2, any consistent scale: radiosity is linear in it). Form factors are
dimensionless, so only lights given per solid angle (point, spot, luminaire intensities, W/sr
or cd) depend on the unit: their irradiance is ``I cos / (d * unit)^2``, per square metre.

See docs/guide/units.md.
"""

from __future__ import annotations

import hashlib
import warnings
from functools import cached_property

import numpy as np

from ..checks import floats
from ..device.launch import float4
from ..errors import InvalidInputError
from .bvh import BVH
from .materials import MaterialTable, scene_summary

__all__ = ["Scene", "DegenerateTriangleWarning", "DeviceFrame", "PrecisionWarning"]


class DegenerateTriangleWarning(UserWarning):
    """Zero-area triangles were dropped from a scene."""


class PrecisionWarning(UserWarning):
    """Some patches are too small, against the whole scene, for float32 ray casting."""


#: Patches whose longest edge is below this fraction of the scene's diagonal get a
#: :class:`PrecisionWarning`: float32 on the device resolves ~6e-8 of the scene's extent, and
#: hemicube rays start SURFACE_OFFSET (1e-5) of it above their patch.
MIN_RELATIVE_SIZE = 1e-5


#: Metres per unit, by the unit names :func:`unit_metres` accepts.
UNIT_NAMES = {
    "m": 1.0,
    "metre": 1.0,
    "meter": 1.0,
    "metres": 1.0,
    "meters": 1.0,
    "cm": 0.01,
    "mm": 0.001,
    "km": 1000.0,
    "in": 0.0254,
    "inch": 0.0254,
    "ft": 0.3048,
    "foot": 0.3048,
    "feet": 0.3048,
}
_AXES = {"x": 0, "y": 1, "z": 2}


def unit_metres(unit) -> float:
    """Metres per scene unit from a name (``"m"``, ``"cm"``, ``"mm"``, ``"in"``, ``"ft"``, ``"km"``)
    or a positive number of metres; InvalidInputError otherwise."""
    if isinstance(unit, str):
        key = unit.strip().lower()
        if key not in UNIT_NAMES:
            raise InvalidInputError(
                f"unknown length unit {unit!r}; use one of m, cm, mm, in, ft, km or metres per unit as a number"
            )
        return UNIT_NAMES[key]
    if isinstance(unit, bool):
        raise InvalidInputError(f"unit must be a unit name or metres per unit; got {unit!r}")
    try:
        value = float(unit)
    except (TypeError, ValueError):
        raise InvalidInputError(f"unit must be a unit name or metres per unit; got {unit!r}") from None
    if not (np.isfinite(value) and value > 0):
        raise InvalidInputError(f"unit (metres per scene unit) must be positive and finite; got {unit!r}")
    return value


def unit_name(metres: float) -> str:
    """The short name of ``metres`` per unit ("mm", ...), or the number in metres."""
    for name in ("m", "cm", "mm", "km", "in", "ft"):
        if UNIT_NAMES[name] == metres:
            return name
    return f"{metres:g} m"


def up_vector(up) -> np.ndarray:
    """A unit up vector (3,) float64 from ``"+y"``, ``"y"``, ``"-z"``, ... or a non-zero 3-vector."""
    if isinstance(up, str):
        text = up.strip().lower()
        sign = -1.0 if text.startswith("-") else 1.0
        axis = text.lstrip("+-")
        if axis not in _AXES:
            raise InvalidInputError(f"up must be an axis such as '+y', '-z' or a 3-vector; got {up!r}")
        v = np.zeros(3)
        v[_AXES[axis]] = sign
        return v
    v = floats(up, "up")
    if v.shape != (3,) or not np.all(np.isfinite(v)) or np.linalg.norm(v) == 0:
        raise InvalidInputError(f"up must be a non-zero finite 3-vector or an axis name; got {up!r}")
    return v / np.linalg.norm(v)


def rotation_to(up, target=(0.0, 1.0, 0.0)) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit ``up`` to ``target`` (half a turn about x, or about
    z for an up along x, when they are opposite)."""
    a, b = up_vector(up), up_vector(target)
    c = float(a @ b)
    if c > 1.0 - 1e-15:
        return np.eye(3)
    if c < -1.0 + 1e-15:
        axis = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        axis = axis - a * (axis @ a)
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    v = np.cross(a, b)
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


class DeviceFrame:
    """The frame geometry is in on the device: x_device = (x - origin) / unit, float32.

    Re-centred on the scene's bounding box and scaled by a power of two near its diagonal, so a
    scene far from the origin (a unit box at 1e7) or at an extreme scale (1e-15, 1e14) becomes
    float32 without losing its patches: float32 keeps 24 bits relative to the scene's size
    instead of to its distance from the origin, and the ray-triangle test's products (lengths
    cubed) stay far from float32's overflow and underflow. Ray parameters t are unchanged when
    directions are scaled by the same unit (:meth:`directions`); lengths convert by ``unit``.
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray, metres: float = 1.0, up=None) -> None:
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        #: The scene's metres per unit (light intensities per m^2 are packed through it) and up axis.
        self.metres = float(metres)
        self.up = None if up is None else tuple(map(float, up))
        self.origin = 0.5 * (lo + hi)
        diag = float(np.linalg.norm(hi - lo))
        self.unit = float(2.0 ** np.round(np.log2(diag))) if diag > 0 else 1.0  # exact divisions

    def points(self, p) -> np.ndarray:
        """Positions (..., 3) in the user's frame -> float32 device positions."""
        return ((np.asarray(p, np.float64) - self.origin) / self.unit).astype(np.float32)

    def directions(self, d) -> np.ndarray:
        """Ray directions (..., 3) -> float32 device directions with the same ray parameter t."""
        return (np.asarray(d, np.float64) / self.unit).astype(np.float32)

    def length(self, x: float) -> float:
        """A length in the user's unit -> device units."""
        return float(x) / self.unit


def _as_rgb(value, n: int, what: str) -> np.ndarray:
    a = floats(value, what)
    if a.ndim == 0:
        a = np.full((n, 3), float(a))
    elif a.shape == (3,):
        a = np.broadcast_to(a, (n, 3))
    elif a.shape == (n,):
        a = np.repeat(a[:, None], 3, axis=1)
    if a.shape != (n, 3):
        raise InvalidInputError(
            f"{what} must be a scalar, an RGB triple, (N,) or (N, 3) with N={n}; got shape {np.shape(value)}"
        )
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(f"{what} contains NaN or infinite values")
    if np.abs(a).max(initial=0.0) > np.finfo(np.float32).max:
        raise InvalidInputError(
            f"{what} exceeds float32's range (3.4e38), in which it is stored; got "
            f"{np.abs(a).max():g}: scale it down (radiosity is linear in emission)"
        )
    return _frozen(np.array(a, dtype=np.float32))  # a copy: never the caller's array


def _frozen(a: np.ndarray) -> np.ndarray:
    """``a`` made read-only: a Scene's arrays are validated once, so they must not change after
    (as trimesh protects its cached arrays); writing albedo = 1 in place, or moving points
    under a built BVH, would bypass every check."""
    a.flags.writeable = False
    return a


def _doubled_areas(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cross products (n, 3), their lengths (n,)) of triangles ``v`` (n, 3, 3) float64: twice
    each triangle's area, along its normal."""
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return cross, np.linalg.norm(cross, axis=1)


def _patch_arrays(v: np.ndarray, cross: np.ndarray, dbl_area: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centres float64, unit normals float32, areas float32) of triangles ``v`` (n, 3, 3) from
    their :func:`_doubled_areas`."""
    return (
        np.ascontiguousarray(v.mean(axis=1), dtype=np.float64),
        np.ascontiguousarray(cross / dbl_area[:, None], dtype=np.float32),
        np.ascontiguousarray(0.5 * dbl_area, dtype=np.float32),
    )


def patch_geometry(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centres, normals, areas) of a Scene's patches ``faces`` over ``vertices``, as
    :class:`Scene` computes them (bit for bit), for faces already known to be sound."""
    v = np.asarray(vertices, np.float64)[faces]
    return _patch_arrays(v, *_doubled_areas(v))


def _checked_albedo(value, n: int) -> np.ndarray:
    a = _as_rgb(value, n, "albedo")
    if a.min() < 0.0 or a.max() >= 1.0:
        raise InvalidInputError(
            "albedo must lie in [0, 1) (a closed scene with albedo >= 1 has no finite radiosity); "
            f"got range [{a.min():g}, {a.max():g}]"
        )
    return a


def _checked_emission(value, n: int) -> np.ndarray:
    e = _as_rgb(value, n, "emission")
    if e.min() < 0.0:
        raise InvalidInputError(f"emission must be >= 0; got minimum {e.min():g}")
    return e


def _renamed_arguments(vertices, faces, renamed: dict) -> tuple:
    """``(vertices, faces)`` from Scene's arguments, taking the names they had before they took
    trimesh's (``points=``, ``triangles=``) for one release, with a DeprecationWarning."""
    for old, new in (("points", "vertices"), ("triangles", "faces")):
        if old not in renamed:
            continue
        if (vertices if new == "vertices" else faces) is not None:
            raise InvalidInputError(f"Scene got both {new}= and its old name {old}=")
        warnings.warn(f"Scene({old}=...) is deprecated: use {new}= (trimesh's name)", DeprecationWarning, stacklevel=3)
        if new == "vertices":
            vertices = renamed.pop(old)
        else:
            faces = renamed.pop(old)
    if renamed:
        raise TypeError(f"Scene() got unexpected keyword argument(s) {', '.join(sorted(renamed))}")
    if vertices is None or faces is None:
        raise InvalidInputError("Scene needs vertices (V, 3) and faces (N, 3)")
    return vertices, faces


class Scene:
    """N triangular patches with materials.

    Zero-area triangles are dropped with a :class:`~pydynrad.geometry.DegenerateTriangleWarning`
    that counts them; everything else invalid raises :class:`~pydynrad.errors.InvalidInputError`.

    Parameters
    ----------
    vertices : (V, 3) float
        Vertex positions.
    faces : (N, 3) int
        Vertex indices of each patch, counter-clockwise seen from the front (the lit side).
        ``vertices``, ``faces`` and ``triangles`` mean what they mean in trimesh; a
        ``trimesh.Trimesh`` or ``trimesh.Scene`` becomes a Scene through :func:`~pydynrad.load`,
        and every function that takes a Scene takes one of those too.
    albedo : float, (3,), (N,) or (N, 3)
        Diffuse reflectance per patch and RGB channel, each in [0, 1).
    emission : float, (3,), (N,) or (N, 3)
        Emitted radiosity per patch and channel, >= 0.
    source_face : (N,) int, optional
        Index of the input-mesh face each patch came from (identity by default).
    name : str
        A label used in reports and file headers.
    unit : str or float
        Metres per scene unit, or a unit name ("m", "cm", "mm", "in", "ft"); ``Scene.unit`` is
        the number. Metres by default.
    up : str or (3,)
        The scene's up axis ("+y", "+z", ... or a vector); ``Scene.up`` is the unit vector. +z
        by default for a scene made from arrays (what skies and work planes assumed before
        scenes knew their up axis); :func:`~pydynrad.load` and the built-in scenes declare theirs.
    """

    #: Defaults for scenes assembled without the constructor (see :meth:`_assembled`).
    unit = 1.0
    up = np.array([0.0, 0.0, 1.0])
    materials: MaterialTable | None = None

    def __init__(
        self,
        vertices=None,
        faces=None,
        albedo=0.5,
        emission=0.0,
        source_face=None,
        name: str = "scene",
        unit="m",
        up="+z",
        **renamed,
    ) -> None:
        vertices, faces = _renamed_arguments(vertices, faces, renamed)
        self.unit = unit_metres(unit)
        self.up = _frozen(np.array(up_vector(up)))
        pts = floats(vertices, "vertices")
        tri = np.asarray(faces)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise InvalidInputError(f"vertices must have shape (V, 3); got {pts.shape}")
        if tri.size == 0:
            raise InvalidInputError("the mesh is empty: it has no faces")
        if tri.ndim != 2 or tri.shape[1] != 3:
            raise InvalidInputError(f"faces must have shape (N, 3); got {tri.shape}")
        if not np.issubdtype(tri.dtype, np.integer):
            raise InvalidInputError(f"faces must hold integer vertex indices; got dtype {tri.dtype}")
        if tri.min() < 0 or tri.max() >= len(pts):
            raise InvalidInputError(f"faces index vertices outside 0..{len(pts) - 1}")
        used = np.unique(tri)
        if not np.all(np.isfinite(pts[used])):
            raise InvalidInputError("vertices contain NaN or infinite coordinates")
        n_in = len(tri)
        albedo = _checked_albedo(albedo, n_in)
        emission = _checked_emission(emission, n_in)
        if source_face is None:
            source_face = np.arange(n_in)
        source_face = np.asarray(source_face, dtype=np.int64)
        if source_face.shape != (n_in,):
            raise InvalidInputError(f"source_face must have shape ({n_in},); got {source_face.shape}")

        v = pts[tri]
        with np.errstate(over="ignore", invalid="ignore"):
            cross, dbl_area = _doubled_areas(v)
        if not np.all(np.isfinite(dbl_area)):  # not zero-area triangles: their areas overflow
            raise InvalidInputError("patch areas overflow float64 (coordinates beyond ~1e154 units): rescale the scene")
        # Relative to the triangle's own size, so tiny but well-shaped patches survive.
        edge2 = np.max(np.sum((v - np.roll(v, 1, axis=1)) ** 2, axis=2), axis=1)
        keep = dbl_area > 1e-7 * edge2
        if not np.all(keep):
            n_bad = int(np.count_nonzero(~keep))
            if n_bad == n_in:
                raise InvalidInputError(f"the mesh is empty: all {n_in} triangles have zero area")
            warnings.warn(f"dropped {n_bad} zero-area triangle(s) of {n_in}", DegenerateTriangleWarning, stacklevel=2)
            tri, albedo, emission, source_face = tri[keep], albedo[keep], emission[keep], source_face[keep]
            cross, dbl_area = cross[keep], dbl_area[keep]

        # float64: a scene far from the origin keeps its shape; DeviceFrame makes it float32.
        self.vertices = np.array(pts, dtype=np.float64)  # copies: frozen below, never the caller's arrays
        self.faces = np.array(tri, dtype=np.int32)
        self.albedo = albedo
        self.emission = emission
        self.source_face = np.array(source_face)
        self.name = str(name)
        self.centers, self.normals, self.areas = _patch_arrays(pts[tri], cross, dbl_area)
        if not (np.all(np.isfinite(self.areas)) and self.areas.min() > 0):
            raise InvalidInputError(
                "patch areas overflow or underflow float32 (coordinates beyond ~1e18 or "
                "patches below ~1e-22 units): rescale the scene"
            )
        for a in (self.vertices, self.faces, self.source_face, self.centers, self.normals, self.areas):
            _frozen(a)
        size, diag = np.sqrt(edge2[keep]), self.scale
        if size.min() < MIN_RELATIVE_SIZE * diag:
            warnings.warn(
                f"{int(np.count_nonzero(size < MIN_RELATIVE_SIZE * diag))} patch(es) are smaller than "
                f"{MIN_RELATIVE_SIZE:g} of the scene's diagonal ({diag:g}): float32 ray casting cannot "
                "resolve them reliably",
                PrecisionWarning,
                stacklevel=2,
            )

    @classmethod
    def _assembled(
        cls, vertices, faces, albedo, emission, centers, normals, areas, name: str, bbox: np.ndarray
    ) -> Scene:
        """A Scene of arrays already sound: parts of validated scenes, moved rigidly
        (:func:`pydynrad.geometry.objects.instanced`, once per move). Not checked again: a large scene's
        checks and geometry cost a move's own work many times over
        (docs/decisions/0028-moving-objects-large-scenes.md)."""
        out = object.__new__(cls)
        out.vertices, out.faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int32)
        out.albedo, out.emission = np.asarray(albedo, np.float32), np.asarray(emission, np.float32)
        out.source_face = np.arange(len(out.faces))
        out.centers, out.normals, out.areas = centers, normals, areas
        out.name = str(name)
        for a in (
            out.vertices,
            out.faces,
            out.albedo,
            out.emission,
            out.source_face,
            out.centers,
            out.normals,
            out.areas,
        ):
            _frozen(a)
        out.__dict__["bbox"] = _frozen(np.asarray(bbox, np.float64))
        return out

    # -- sizes and views -------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.faces)

    @property
    def n_patches(self) -> int:
        return len(self.faces)

    @property
    def triangles(self) -> np.ndarray:
        """(N, 3, 3) float64 corner positions of every patch (trimesh's ``Trimesh.triangles``)."""
        return self.vertices[self.faces]

    @property
    def points(self) -> np.ndarray:
        """Deprecated name of :attr:`vertices` (V, 3), kept for one release."""
        warnings.warn(
            "Scene.points is deprecated: use Scene.vertices (trimesh's name)", DeprecationWarning, stacklevel=2
        )
        return self.vertices

    @property
    def is_grey(self) -> bool:
        """True when every albedo has equal R, G and B: one colour channel suffices for K."""
        a = self.albedo
        return bool(np.all(a[:, 0] == a[:, 1]) and np.all(a[:, 0] == a[:, 2]))

    @cached_property
    def bbox(self) -> np.ndarray:
        """(2, 3) min and max corner of the used points (cached: per-call kernels need it)."""
        p = self.vertices[np.unique(self.faces)]
        return np.stack([p.min(axis=0), p.max(axis=0)])

    @cached_property
    def triangle_boxes(self) -> np.ndarray:
        """(2, N, 3) float64: each triangle's bounding box, min and max corner (cached: a moving
        object's intersection test reads it every move)."""
        corners = self.triangles
        return np.stack([corners.min(axis=1), corners.max(axis=1)])

    @property
    def scale(self) -> float:
        """Length of the bounding-box diagonal: the yardstick for scene-relative lengths."""
        lo, hi = self.bbox.astype(np.float64)
        return float(np.linalg.norm(hi - lo)) or 1.0

    @property
    def ray_scale(self) -> float:
        """The length that rays' offsets from their surfaces are fractions of: :attr:`scale`, or
        for a scene with moving objects (:func:`~pydynrad.geometry.objects.with_objects`) the static scene's, whose device
        frame every position is in (an object moved away must not lift every static patch's
        rays off its surface: at 1e5 mm from the bench's box, 1 mm, 0.4% off the rows' sums)."""
        return self.__dict__.get("_ray_scale", self.scale)

    @property
    def emitters(self) -> np.ndarray:
        """Indices of patches with non-zero emission."""
        return np.flatnonzero(self.emission.max(axis=1) > 0)

    # -- derived structures ----------------------------------------------------------------
    @cached_property
    def frame(self) -> DeviceFrame:
        """The device frame (:class:`~pydynrad.geometry.scene.DeviceFrame`): every upload of positions goes through it."""
        lo, hi = self.bbox
        return DeviceFrame(lo, hi, metres=self.unit, up=self.up)

    @cached_property
    def bvh(self):
        """The patch BVH (in :attr:`frame`), built on first use and shared by every kernel that casts rays."""
        return BVH.build(self.frame.points(self.triangles))

    def patch_buffers(self, device, patches=None) -> tuple:
        """``(centers, normals)``: (N, 4) float32 device buffers (xyz, 0) of :attr:`centers` (in
        :attr:`frame`) and :attr:`normals`, uploaded once per device and kept beside the BVH's buffers, so kernels
        run per frame (the light pass, hemicubes) upload nothing of the scene. Scene arrays never
        change after construction, and scenes share a BVH only when they share geometry
        (:meth:`with_materials`), so a different scene never sees these buffers. With ``patches``
        (k,) indices: the same float32 rows of those patches alone, uploaded for this call."""

        def upload(idx=slice(None)):
            return tuple(device.to_device(float4(a)) for a in (self.frame.points(self.centers[idx]), self.normals[idx]))

        if patches is not None:
            return upload(np.asarray(patches, np.int64))
        return self.bvh.upload_once(device, "patch_frames", upload)

    def content_hash(self) -> str:
        """SHA-256 of geometry and materials: identifies the scene in file headers."""
        h = hashlib.sha256()
        for a in (self.vertices.astype(np.float32), self.faces, self.albedo, self.emission):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()

    def geometry_hash(self) -> str:
        """SHA-256 of geometry only: form factors depend on this and not on materials.

        Hashes the points as float32, as scenes stored them before they kept float64, so files
        and stores made then still match."""
        h = hashlib.sha256()
        for a in (self.vertices.astype(np.float32), self.faces):
            h.update(np.ascontiguousarray(a).tobytes())
        return h.hexdigest()

    def with_materials(self, albedo=None, emission=None) -> Scene:
        """A scene with the same geometry (and the same BVH, not rebuilt) and new materials."""
        out = object.__new__(Scene)
        out.__dict__.update(self.__dict__)
        if albedo is not None:
            out.albedo = _checked_albedo(albedo, len(self))
        if emission is not None:
            out.emission = _checked_emission(emission, len(self))
        return out

    @property
    def unit_name(self) -> str:
        """:attr:`unit` as a short name ("mm") where it has one."""
        return unit_name(self.unit)

    def summary(self) -> str:
        """What was read: size, unit and up axis, and per material (for a loaded scene) the patch
        count, mean albedo and emission, the textures used and what was clamped or ignored."""
        return scene_summary(self)

    def __repr__(self) -> str:
        return f"Scene({self.name!r}, {len(self)} patches, {len(self.emitters)} emitting, grey={self.is_grey})"


#: Hemicube centres sit this far off their patch, times the scene's bounding-box diagonal:
#: far above float32 rounding of coordinates (about 6e-8 of them), far below any patch size.
SURFACE_OFFSET = 1e-5
