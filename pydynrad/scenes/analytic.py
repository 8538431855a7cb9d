"""Scenes whose form factors are known in closed form: the yardsticks of the hemicube.

Each scene is built from rectangles, each rectangle from two triangles, then patched by
``subdivisions`` uniform 4-way splits of the smallest rectangle (it becomes
2 * 4**subdivisions patches; larger rectangles split until their patches are no larger) and,
if given, split further until no patch exceeds ``max_patch_area``. ``Scene.source_face``
tells which rectangle a patch belongs to: ``source_face // 2`` is the rectangle's index in
the order each function documents.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from ..geometry.patching import subdivide
from ..geometry.scene import Scene

__all__ = ["parallel_plates", "perpendicular_plates", "closed_box", "block"]


def _positive(name: str, value) -> float:
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise InvalidInputError(f"{name} must be a positive finite length; got {value!r}")
    return v


def _rectangles(corners: list[np.ndarray], subdivisions: int, max_patch_area, albedo, emission, name: str) -> Scene:
    """Corners (4, 3) per rectangle, counter-clockwise seen from its front."""
    if isinstance(subdivisions, bool) or not isinstance(subdivisions, (int, np.integer)) or not 0 <= subdivisions <= 12:
        raise InvalidInputError(f"subdivisions must be an integer in 0..12; got {subdivisions!r}")
    points = np.concatenate(corners).astype(np.float64)
    quads = np.arange(len(points)).reshape(-1, 4)
    triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], axis=1).reshape(-1, 3)
    areas = 0.5 * np.linalg.norm(
        np.cross(points[triangles[:, 1]] - points[triangles[:, 0]], points[triangles[:, 2]] - points[triangles[:, 0]]),
        axis=1,
    )
    # Uniform levels first (a regular grid of right triangles), then the area limit if any.
    points, triangles, parent = subdivide(points, triangles, max_area=areas.min() / 4**subdivisions * (1 + 1e-9))
    if max_patch_area is not None:
        points, triangles, finer = subdivide(points, triangles, max_area=max_patch_area)
        parent = parent[finer]
    # Lengths in any unit, declared metres; the plates' floors face +z, the declared up axis.
    return Scene(points, triangles, albedo=albedo, emission=emission, source_face=parent, name=name, unit="m", up="+z")


def parallel_plates(
    a: float = 1.0,
    b: float = 1.0,
    c: float = 1.0,
    subdivisions: int = 3,
    max_patch_area: float | None = None,
    albedo=0.5,
    emission=0.0,
) -> Scene:
    """Two directly opposed a x b rectangles at distance c, facing each other.

    Rectangle 0 (``source_face // 2 == 0``) spans ``[0, a] x [0, b]`` at z = 0 facing +z;
    rectangle 1 is the same at z = c facing -z. Lengths in any unit; ``albedo`` and
    ``emission`` apply to every patch (use :meth:`Scene.with_materials` to vary them).
    """
    a, b, c = (_positive(n, v) for n, v in (("a", a), ("b", b), ("c", c)))
    bottom = np.array([[0, 0, 0], [a, 0, 0], [a, b, 0], [0, b, 0]], dtype=np.float64)
    top = bottom[::-1] + [0, 0, c]
    return _rectangles([bottom, top], subdivisions, max_patch_area, albedo, emission, "parallel_plates")


def perpendicular_plates(
    a: float = 1.0,
    b: float = 1.0,
    c: float = 1.0,
    subdivisions: int = 3,
    max_patch_area: float | None = None,
    albedo=0.5,
    emission=0.0,
) -> Scene:
    """Two rectangles at a right angle sharing an edge of length a (along x).

    Rectangle 0 is horizontal, ``[0, a] x [0, b]`` at z = 0 facing +z; rectangle 1 is
    vertical, ``[0, a] x {0} x [0, c]``, facing +y (towards rectangle 0).
    """
    a, b, c = (_positive(n, v) for n, v in (("a", a), ("b", b), ("c", c)))
    floor = np.array([[0, 0, 0], [a, 0, 0], [a, b, 0], [0, b, 0]], dtype=np.float64)
    wall = np.array([[0, 0, 0], [0, 0, c], [a, 0, c], [a, 0, 0]], dtype=np.float64)
    return _rectangles([floor, wall], subdivisions, max_patch_area, albedo, emission, "perpendicular_plates")


def _box_walls(size) -> list[np.ndarray]:
    """The six walls (4, 3) of ``[0, sx] x [0, sy] x [0, sz]``, counter-clockwise seen from inside."""
    s = np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
    sx, sy, sz = (_positive(n, v) for n, v in zip(("size[0]", "size[1]", "size[2]"), s))
    walls = []
    for axis, length in enumerate((sx, sy, sz)):
        u, v = (axis + 1) % 3, (axis + 2) % 3
        ext = np.array([sx, sy, sz])
        quad = np.zeros((4, 3))
        # Counter-clockwise in (u, v) faces +axis: the inward side of the wall at 0.
        quad[:, u] = [0, ext[u], ext[u], 0]
        quad[:, v] = [0, 0, ext[v], ext[v]]
        walls.append(quad)
        far = quad[::-1].copy()
        far[:, axis] = length
        walls.append(far)
    return walls


def closed_box(
    size=(1.0, 1.0, 1.0), subdivisions: int = 2, max_patch_area: float | None = None, albedo=0.5, emission=1.0
) -> Scene:
    """A closed axis-aligned box ``[0, sx] x [0, sy] x [0, sz]`` with inward-facing walls.

    The furnace test: with uniform emission E and albedo rho every patch's radiosity is
    E / (1 - rho), since every row of F sums to 1. Walls, by ``source_face // 2``:
    0: x = 0, 1: x = sx, 2: y = 0, 3: y = sy, 4: z = 0, 5: z = sz.
    ``size`` is one length (a cube) or three.
    """
    walls = _box_walls(size)
    return _rectangles(walls, subdivisions, max_patch_area, albedo, emission, "closed_box")


def block(
    size=(1.0, 1.0, 1.0), subdivisions: int = 1, max_patch_area: float | None = None, albedo=0.5, emission=0.0
) -> Scene:
    """A solid box centred on the origin with outward-facing sides: a movable object.

    ``size`` is one length (a cube) or three; each side is cut into ``2 * 4**subdivisions``
    triangles (``subdivisions=1``: 48 patches). Sides by ``source_face // 2`` as in
    :func:`closed_box`.
    """
    walls = _box_walls(size)
    half = 0.5 * np.broadcast_to(np.asarray(size, dtype=np.float64), (3,))
    walls = [w[::-1] - half for w in walls]
    return _rectangles(walls, subdivisions, max_patch_area, albedo, emission, "block")
