"""Moving rigid objects: a scene of patches carried by a 4x4 transform.

A :class:`RigidObject` holds its geometry and materials in object space (a :class:`Scene`)
and a rigid object-to-world transform. Next to a static scene of N patches, the objects'
patches are numbered N.. in the order the objects are given. Two views of the same world:

* :func:`with_objects` : a plain static Scene of the combined geometry
  at the current poses, with a BVH built over all of it (full solves, references, tests);
* :func:`instanced`: the same patches, traced through a two-level :class:`~pydynrad.geometry.bvh.InstancedBVH`
  (the static tree plus each object's tree, built once), so a move rewrites one small table
  instead of rebuilding anything.

See docs/design.md, 'Moving objects'.
"""

from __future__ import annotations

import warnings
from functools import cached_property

import numpy as np

from ..checks import floats
from ..errors import InvalidInputError
from .bvh import BVH, InstancedBVH, occluded
from .convex import solid_planes
from .loading import load
from .scene import SURFACE_OFFSET, Scene, patch_geometry

__all__ = ["RigidObject", "ObjectIntersectionWarning", "rigid_transform", "with_objects", "instanced"]

#: Tolerance of the rigidity test: |R^T R - I| and |det R - 1| (float32 rounding of a composed
#: rotation stays far below it; a 0.1% scale does not).
RIGID_TOL = 1e-5


class ObjectIntersectionWarning(UserWarning):
    """An object's triangles cut through the static scene's (allowed: light then leaks there)."""


#: How far from the static scene's centre, in its diagonals, an object may reach (its bounding
#: sphere's far side): there float32 rounds a position by 2^-24 sqrt(3) of its distance, a tenth of
#: the rays' offset SURFACE_OFFSET from their surface (:func:`check_reach`).
MAX_REACH = SURFACE_OFFSET / (10 * 2.0**-24 * 3**0.5)


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def rigid_transform(value, what: str = "transform") -> np.ndarray:
    """A validated (4, 4) float64 rigid transform: a proper rotation and a translation.

    Raises :class:`~pydynrad.errors.InvalidInputError` for a wrong shape, NaN or infinite
    entries, a last row other than (0, 0, 0, 1), or a linear part that scales, shears or
    mirrors (radiosity would need new form factors for a deformed object, and a mirror turns
    its patches inside out).
    """
    T = floats(value, what)
    if T.shape != (4, 4):
        raise InvalidInputError(f"{what} must be a (4, 4) matrix; got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InvalidInputError(f"{what} contains NaN or infinite values")
    # Compared directly: np.allclose's overhead was half of this check, and a move checks its
    # poses about ten times (every bounding sphere of a held pose).
    if float(np.abs(T[3] - _LAST_ROW).max()) > RIGID_TOL:
        raise InvalidInputError(f"{what} must have last row (0, 0, 0, 1) (no projection); got {T[3]}")
    R = T[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > RIGID_TOL:
        raise InvalidInputError(f"{what} is not rigid: its 3x3 part scales or shears (|R^T R - I| = {err:.3g})")
    if np.linalg.det(R) < 0:
        raise InvalidInputError(f"{what} mirrors (det = -1): a rigid object's transform must be a proper rotation")
    out = T.copy()
    out[3] = (0.0, 0.0, 0.0, 1.0)
    return out


#: Poses per object whose check :meth:`RigidObject._pose` keeps.
CHECKED_POSES = 8


class RigidObject:
    """Patches that move rigidly: geometry and materials in object space, and a pose.

    Parameters
    ----------
    mesh_or_scene : Scene, or anything :func:`pydynrad.load` accepts
        The object's patches in object space (albedo and emission as in any scene: an emitting
        object is a lamp carried around).
    transform : (4, 4) float, optional
        Object-to-world pose (identity by default): a rotation and a translation only.
    name : str, optional
    **load_kw
        Passed to :func:`pydynrad.load` when ``mesh_or_scene`` is not a Scene.
    """

    def __init__(self, mesh_or_scene, transform=None, name: str | None = None, **load_kw) -> None:
        if isinstance(mesh_or_scene, Scene):
            if load_kw:
                raise InvalidInputError(f"load options {sorted(load_kw)} apply to a mesh or path, not to a Scene")
            scene = mesh_or_scene
        else:
            scene = load(mesh_or_scene, **load_kw)
        self.scene = scene
        self.name = str(name if name is not None else scene.name)
        self.transform = np.eye(4) if transform is None else transform

    @property
    def transform(self) -> np.ndarray:
        """(4, 4) float64 object-to-world pose."""
        return self._transform.copy()

    @transform.setter
    def transform(self, value) -> None:
        self._transform = rigid_transform(value)

    def __len__(self) -> int:
        return len(self.scene)

    def device_bvh(self, unit: float):
        """(BVH, origin): the object-space tree over ``(v - origin) / unit`` (origin: the centre
        of the object's bounds), built once per ``unit`` (a world's device frame): moving never
        rebuilds it."""
        cache = self.__dict__.setdefault("_device_bvhs", {})
        if unit not in cache:
            origin = self._bound_object[0]
            cache[unit] = (BVH.build((self.scene.triangles.astype(np.float64) - origin) / unit), origin)
        return cache[unit]

    @cached_property
    def _bound_object(self) -> tuple[np.ndarray, float]:
        lo, hi = self.scene.bbox.astype(np.float64)
        return 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))

    @cached_property
    def solid_planes(self) -> np.ndarray | None:
        """(k, 4) float64 rows (n, d) of the solid ``n . x <= d`` in object space where the object
        is the whole boundary of one convex solid of few faces (a box), else None
        (:func:`pydynrad.geometry.convex.solid_planes`): a move then finds the segments it hides by
        clipping them, without tracing them."""
        return solid_planes(self.scene.vertices, self.scene.faces)

    @cached_property
    def faces_out(self) -> bool:
        """Whether the object is one convex solid (:attr:`solid_planes`) whose every patch faces
        out of it: a hemicube ray of its own patches then meets nothing of it
        (:meth:`pydynrad.geometry.bvh.InstancedBVH.own_instances`). A patch wound inwards faces into the
        solid and sees its other sides, so such an object is not taken as one."""
        if self.solid_planes is None:
            return False
        inside = self.scene.triangles.astype(np.float64).reshape(-1, 3).mean(axis=0)  # a convex solid holds it
        towards = inside - self.scene.centers.astype(np.float64)
        return bool(np.all(np.einsum("ij,ij->i", self.scene.normals.astype(np.float64), towards) < 0.0))

    def bounding_sphere(self, transform=None) -> tuple[np.ndarray, float]:
        """(centre (3,), radius) of a sphere holding the object at ``transform`` (default: its pose)."""
        T = self._pose(transform)
        c, r = self._bound_object
        return T[:3, :3] @ c + T[:3, 3], r

    def world_points(self, transform=None) -> np.ndarray:
        """(V, 3) float64 points of the object at ``transform`` (default: its pose)."""
        T = self._pose(transform)
        return self.scene.vertices.astype(np.float64) @ T[:3, :3].T + T[:3, 3]

    def _pose(self, transform) -> np.ndarray:
        """``transform`` checked (:func:`rigid_transform`), read-only; the pose for None. A move
        asks for the spheres and points of the same few poses about ten times, and the checks
        added up to a visible share of a moving frame (docs/decisions/0026-moving-frame-cost.md): (4, 4)
        float64 poses checked are found again by their bytes, up to :data:`CHECKED_POSES` of them
        (then all are forgotten at once)."""
        if transform is None:
            return self._transform
        key = (
            transform.tobytes()
            if isinstance(transform, np.ndarray) and transform.shape == (4, 4) and transform.dtype == np.float64
            else None
        )
        checked = self.__dict__.setdefault("_checked", {})
        if key in checked:
            return checked[key]
        T = rigid_transform(transform)
        T.flags.writeable = False
        if key is not None:
            if len(checked) >= CHECKED_POSES:  # a new dict, not one changed under another thread
                checked = self.__dict__["_checked"] = {}
            checked[key] = T
        return T

    def __repr__(self) -> str:
        return f"RigidObject({self.name!r}, {len(self)} patches)"


def _objects(objects) -> list[RigidObject]:
    try:
        objs = [objects] if isinstance(objects, RigidObject) else list(objects)
    except TypeError:
        raise InvalidInputError(
            f"objects must be a RigidObject or a list of them; got {type(objects).__name__}"
        ) from None
    for o in objs:
        if not isinstance(o, RigidObject):
            raise InvalidInputError(f"objects must be RigidObject instances; got {type(o).__name__}")
    if len({id(o) for o in objs}) != len(objs):
        raise InvalidInputError("the same RigidObject is given twice")
    return objs


def _combined(scene, objs: list[RigidObject], transforms=None):
    """The static scene and the objects at ``transforms`` (default: their poses) as one Scene.

    Assembled from the parts, not validated again (:meth:`Scene._assembled`): the static
    patches keep their own arrays bit for bit (so their rows match those of the static scene
    wherever no object is in view), and each object's centres, normals and areas come from its
    points at the pose as a Scene would compute them (:func:`pydynrad.geometry.scene.patch_geometry`).
    Its rays leave their surfaces by the static scene's :attr:`~pydynrad.geometry.scene.Scene.ray_scale`,
    wherever the objects are."""
    transforms = [o.transform for o in objs] if transforms is None else transforms
    for o, T in zip(objs, transforms):  # a reference the device cannot resolve is no reference
        check_reach(scene, o, T)
    points, tris, geometry, corners = [scene.vertices], [scene.faces], [], [scene.bbox]
    base = len(scene.vertices)
    for o, T in zip(objs, transforms):
        p = o.world_points(T)
        points.append(p)
        tris.append(o.scene.faces + base)
        geometry.append(patch_geometry(p, o.scene.faces))
        used = p[np.unique(o.scene.faces)]
        corners.append(np.stack([used.min(axis=0), used.max(axis=0)]))
        base += len(p)
    parts = [scene] + [o.scene for o in objs]
    centers, normals, areas = [
        np.concatenate([getattr(scene, name)] + [g[k] for g in geometry])
        for k, name in enumerate(("centers", "normals", "areas"))
    ]
    boxes = np.stack(corners)
    out = Scene._assembled(
        np.concatenate(points),
        np.concatenate(tris),
        np.concatenate([p.albedo for p in parts]),
        np.concatenate([p.emission for p in parts]),
        centers,
        normals,
        areas,
        name="+".join([scene.name] + [o.name for o in objs]),
        bbox=np.stack([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)]),
    )
    out.__dict__["_ray_scale"] = scene.ray_scale  # the static patches' rays as in the static scene
    out.unit, out.up = scene.unit, scene.up  # the static scene's unit and up axis
    return out


def check_reach(scene, obj: RigidObject, transform) -> None:
    """Refuse a pose where the device cannot place the object's rays: every position goes to the
    device as float32 in the static scene's frame (:class:`~pydynrad.geometry.scene.DeviceFrame`), rounded
    by up to 2^-24 sqrt(3) of its distance from the frame's centre, and rays leave their patches
    :data:`~pydynrad.formfactors.SURFACE_OFFSET` of the static scene's diagonal above them
    (:attr:`~pydynrad.geometry.scene.Scene.ray_scale`). Beyond :data:`MAX_REACH` diagonals the rounding
    exceeds a tenth of that offset, and an object's hemicube rays may start inside it; further
    out its patches collapse (a 100 mm block at 1e18 mm: zero-length rays). A pose is asked for
    per frame, and an object there is wrong as a whole, so it is an error
    (:class:`~pydynrad.errors.InvalidInputError`), not a warning."""
    c, r = obj.bounding_sphere(transform)
    reach = float(np.linalg.norm(c - scene.frame.origin)) + r
    limit = MAX_REACH * scene.ray_scale
    if reach > limit:
        raise InvalidInputError(
            f"object {obj.name!r} at this pose reaches {reach:.3g} from the static scene's centre (its bounding "
            f"sphere's far side), beyond {limit:.3g} ({MAX_REACH:.3g} of the scene's diagonals), where float32 device "
            "coordinates round its rays' origins by more than a tenth of their offset from its surface: keep it "
            "within that (an object is hidden by a pose just outside the scene)"
        )


def _warn_intersections(scene, objs: list[RigidObject], transforms) -> None:
    """Warn when an object's edges cross static triangles (checked by rays, once per pose, where
    a static triangle's box comes within the object's bounding sphere: elsewhere its edges can
    cross none, and a move of the bench's block skips the device's round trip)."""
    lo, hi = scene.triangle_boxes
    for o, T in zip(objs, transforms):
        c, r = o.bounding_sphere(T)
        gap = np.maximum(np.maximum(lo - c, c - hi), 0.0)  # per axis, from the sphere's centre to each box
        if not np.any(np.einsum("ij,ij->i", gap, gap) <= (r * (1.0 + 1e-6)) ** 2):
            continue
        corners = o.world_points(T)[o.scene.faces]  # (T, 3, 3)
        start, end = corners.reshape(-1, 3), corners[:, [1, 2, 0]].reshape(-1, 3)
        d = end - start
        hit = occluded(scene, start, d, np.float32(1.0))
        if hit.any():
            warnings.warn(
                f"object {o.name!r} intersects the static scene ({int(hit.sum())} of its edges cross static "
                "triangles): light leaks through the cut",
                ObjectIntersectionWarning,
                stacklevel=3,
            )


def with_objects(scene, objects):
    """A plain static Scene: ``scene``'s N patches, then each object's at its current pose.

    Its BVH is built over the combined geometry on first use; form factors, solves and renders
    of it are the references a moving object is compared against.
    """
    return _combined(scene, _objects(objects))


def instanced(scene, objects, transforms=None, bvh=None):
    """The combined Scene of :func:`with_objects`, traced through a two-level BVH.

    Patch arrays (centres, normals, points) are those at ``transforms`` (default: the objects'
    poses); the returned scene's ``bvh`` is an :class:`~pydynrad.geometry.bvh.InstancedBVH` holding
    those poses: ``bvh`` when given (one made by an earlier call with the same objects, moved
    in place, so an earlier view's BVH moves with it), else a new one. Warns
    :class:`ObjectIntersectionWarning` when an object cuts through the static scene.
    """
    objs = _objects(objects)
    transforms = [o.transform for o in objs] if transforms is None else [rigid_transform(t) for t in transforms]
    out = _combined(scene, objs, transforms)  # reach checked first: a far object breaks the test's rays
    _warn_intersections(scene, objs, transforms)
    if bvh is None:
        trees = [o.device_bvh(scene.frame.unit) for o in objs]
        bvh = InstancedBVH(
            scene.bvh,
            [t for t, _ in trees],
            transforms,
            scene.frame,
            [c for _, c in trees],
            convex=[o.faces_out for o in objs],
        )
    else:
        bvh.set_transforms(transforms)
    # The static scene's device frame, the one its tree and every upload of positions are in.
    out.__dict__["frame"] = scene.frame
    out.__dict__["bvh"] = bvh
    return out
