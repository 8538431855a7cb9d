"""The Cornell Box, from the measurements published by the Cornell Program of Computer Graphics.

Geometry: https://www.graphics.cornell.edu/online/box/data.html, in millimetres, y up, the
open side at z = 0 facing the camera (published at (278, 273, -800) looking along +z). The
box is about 556 x 548.8 x 559.2 mm with slightly skewed floor and left wall, exactly as
published. The 130 x 105 mm light (x 213..343, z 227..332) is cut into the ceiling plane
y = 548.8 rather than floating below it: the ceiling is the eight rectangles around the light,
so no two patches overlap and the box has no gaps except its open front. The floor likewise
stops at the blocks' footprints (the published blocks stand on it): it is triangulated around
them, so no patch lies hidden under a block (such patches see only the blocks' backs, receive
nothing, and broke the scene's reciprocity and energy balance).

Materials are the RGB reflectances most renderers use for this scene (Mitsuba's and pbrt's
``cbox``): white (0.725, 0.71, 0.68), red (0.63, 0.065, 0.05) on the left wall (x ~ 556),
green (0.14, 0.45, 0.091) on the right wall (x = 0). The light's radiance defaults to those
renderers' (17, 12, 4) W/(sr m^2); as a Lambertian emitter its emission (radiant exitance,
the unit of radiosity) is pi times that. Form factors are dimensionless, so the millimetre
lengths do not change the radiosity's unit.

Normals face the lit side: the box's walls face its interior, the blocks' faces face out.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from ..geometry.loading import soup_scene
from ..geometry.scene import Scene

__all__ = ["cornell_box", "WHITE", "RED", "GREEN", "LIGHT_ALBEDO", "LIGHT_RADIANCE"]

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
LIGHT_ALBEDO = (0.78, 0.78, 0.78)
LIGHT_RADIANCE = (17.0, 12.0, 4.0)

_HEIGHT = 548.8
# Light rectangle in the ceiling plane: x and z extents (published vertices).
_LIGHT_X = (213.0, 343.0)
_LIGHT_Z = (227.0, 332.0)

# Published quads (x, y, z), in the data page's vertex order.
_FLOOR = [(552.8, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 559.2), (549.6, 0.0, 559.2)]
_BACK = [(549.6, 0.0, 559.2), (0.0, 0.0, 559.2), (0.0, 548.8, 559.2), (556.0, 548.8, 559.2)]
_RIGHT = [(0.0, 0.0, 559.2), (0.0, 0.0, 0.0), (0.0, 548.8, 0.0), (0.0, 548.8, 559.2)]
_LEFT = [(552.8, 0.0, 0.0), (549.6, 0.0, 559.2), (556.0, 548.8, 559.2), (556.0, 548.8, 0.0)]
_SHORT_TOP = [(130.0, 165.0, 65.0), (82.0, 165.0, 225.0), (240.0, 165.0, 272.0), (290.0, 165.0, 114.0)]
_TALL_TOP = [(423.0, 330.0, 247.0), (265.0, 330.0, 296.0), (314.0, 330.0, 456.0), (472.0, 330.0, 406.0)]

# Centre of the box: every wall faces it.
_INTERIOR = np.array([278.0, 274.4, 279.6])


def _ceiling_quads() -> tuple[np.ndarray, np.ndarray]:
    """The ceiling as a 3 x 3 grid of rectangles on the light's edges: (8 frame quads, light quad)."""
    xs = (0.0, *_LIGHT_X, 556.0)
    zs = (0.0, *_LIGHT_Z, 559.2)
    cells = [
        [
            (xs[i], _HEIGHT, zs[k]),
            (xs[i + 1], _HEIGHT, zs[k]),
            (xs[i + 1], _HEIGHT, zs[k + 1]),
            (xs[i], _HEIGHT, zs[k + 1]),
        ]
        for i in range(3)
        for k in range(3)
    ]
    return np.array(cells[:4] + cells[5:]), np.array(cells[4:5])


def _inside_convex(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(n,) bool: 2-D ``points`` strictly inside the convex ``polygon`` (either winding)."""
    edge = np.roll(polygon, -1, axis=0) - polygon
    rel = points[:, None, :] - polygon[None]
    side = edge[None, :, 0] * rel[..., 1] - edge[None, :, 1] * rel[..., 0]
    return np.all(side > 1e-9, axis=1) | np.all(side < -1e-9, axis=1)


#: Largest gap (mm) between the points the floor is triangulated on, whatever the patching:
#: triangles of about this size around the footprints, split further by max_edge.
FLOOR_SPACING = 70.0


def _floor_triangles(spacing: float = FLOOR_SPACING) -> np.ndarray:
    """(T, 3, 3) triangles of the floor minus the blocks' footprints.

    ``spacing`` (mm) is the largest gap between the points it is triangulated on. A conforming Delaunay triangulation in the floor plane (x, z): every footprint edge is split
    at its midpoint until it is an edge of the triangulation, then the triangles inside the
    footprints are dropped. The floor's outline is convex, so its edges are hull edges. Smallest
    triangle quality 0.54 (4 sqrt(3) area / sum of squared edges; 1 for equilateral).
    """
    holes = [np.asarray(top)[:, [0, 2]] for top in (_SHORT_TOP, _TALL_TOP)]
    outline = np.asarray(_FLOOR)[:, [0, 2]]
    # Points every <= ``spacing`` mm along the outline and the footprints, and on a grid inside,
    # kept half a spacing clear of both: the Delaunay triangles come out well shaped (long
    # slivers make poor hemicube patches and unreadable lightmap texels).
    points, segments = [], []
    for ring, closed_ring in ((outline, False), *((h, True) for h in holes)):
        start = len(points)
        for k in range(4):
            a, b = ring[k], ring[(k + 1) % 4]
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing)))
            points += [a + (b - a) * i / n for i in range(n)]
        count = len(points) - start
        if closed_ring:
            segments += [(start + i, start + (i + 1) % count) for i in range(count)]
    g = np.stack(
        np.meshgrid(np.arange(0.5, 556.0 / spacing) * spacing, np.arange(0.5, 559.2 / spacing) * spacing), -1
    ).reshape(-1, 2)
    boundary = np.asarray(points)
    clear = np.min(np.linalg.norm(g[:, None] - boundary[None], axis=2), axis=1) > 0.5 * spacing
    clear &= _inside_convex(g, outline) & ~_inside_convex(g, holes[0]) & ~_inside_convex(g, holes[1])
    points += list(g[clear])
    while True:
        tri = Delaunay(np.asarray(points)).simplices
        edges = {tuple(sorted(e)) for t in tri for e in ((t[0], t[1]), (t[1], t[2]), (t[2], t[0]))}
        missing = [s for s in segments if tuple(sorted(s)) not in edges]
        if not missing:
            break
        for a, b in missing:
            points.append(0.5 * (points[a] + points[b]))
            m = len(points) - 1
            segments.remove((a, b))
            segments += [(a, m), (m, b)]
    points = np.asarray(points)
    centroids = points[tri].mean(axis=1)
    keep = ~(_inside_convex(centroids, holes[0]) | _inside_convex(centroids, holes[1]))
    flat = points[tri[keep]]
    return np.stack([flat[..., 0], np.zeros(flat.shape[:2]), flat[..., 1]], axis=-1)


def _block_sides(top) -> np.ndarray:
    """The four vertical sides of a block standing on the floor under its top quad."""
    top = np.asarray(top)
    bottom = top * np.array([1.0, 0.0, 1.0])
    nxt = np.roll(np.arange(4), -1)
    return np.stack([bottom, bottom[nxt], top[nxt], top], axis=1)


def _oriented_triangles(quads: np.ndarray, facing: np.ndarray, inward: bool) -> np.ndarray:
    """(2Q, 3, 3) triangles of quads, wound so each faces (``inward``) or faces away from ``facing``.

    Quads are split along their 0-2 diagonal; the published walls are not all planar (the
    left wall is skewed), so each triangle is oriented on its own.
    """
    return _oriented(np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]]), facing, inward)


def _oriented(tri: np.ndarray, facing: np.ndarray, inward: bool) -> np.ndarray:
    """Triangles (T, 3, 3) rewound so each faces (``inward``) or faces away from ``facing``."""
    tri = tri.copy()
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    side = np.einsum("ij,ij->i", normal, facing - tri[:, 0])
    flip = side < 0 if inward else side > 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri


def cornell_box(
    max_patch_area: float | None = None, max_edge: float | None = 100.0, light_radiance=LIGHT_RADIANCE
) -> Scene:
    """The Cornell Box as a patched :class:`~pydynrad.Scene` (lengths in mm).

    Parameters
    ----------
    max_patch_area : float, optional
        Largest patch area in mm^2.
    max_edge : float, optional
        Longest patch edge in mm. The default (100 mm) gives 1,128 patches, coarse enough for
        quick form factors; pass ``max_edge=None`` (and no area) for the 186 triangles it is
        built from (the floor triangulated around the blocks' footprints).
    light_radiance : (3,) float
        Radiance of the ceiling light; its emission is ``pi * light_radiance``.
    """
    frame, light = _ceiling_quads()
    box_parts = [
        (_floor_triangles(), WHITE),
        (frame, WHITE),
        (np.array([_BACK]), WHITE),
        (np.array([_RIGHT]), GREEN),
        (np.array([_LEFT]), RED),
        (light, LIGHT_ALBEDO),
    ]
    tris, albedo = [], []
    for part, rgb in box_parts:
        t = (
            _oriented(part, _INTERIOR, inward=True)
            if part.shape[1] == 3
            else _oriented_triangles(part, _INTERIOR, inward=True)
        )
        tris.append(t)
        albedo.append(np.tile(rgb, (len(t), 1)))
    for top in (_SHORT_TOP, _TALL_TOP):
        quads = np.concatenate([np.array([top]), _block_sides(top)])
        centroid = np.mean(top, axis=0) * np.array([1.0, 0.5, 1.0])
        t = _oriented_triangles(quads, centroid, inward=False)
        tris.append(t)
        albedo.append(np.tile(WHITE, (len(t), 1)))
    emission = [np.zeros((len(t), 3)) for t in tris]
    emission[5][:] = np.pi * np.asarray(light_radiance, dtype=np.float64)
    return soup_scene(
        np.concatenate(tris),
        np.concatenate(albedo),
        np.concatenate(emission),
        max_patch_area=max_patch_area,
        max_edge=max_edge,
        name="cornell_box",
        unit="mm",
        up="+y",
    )
