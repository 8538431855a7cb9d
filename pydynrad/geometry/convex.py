"""Whether a triangle mesh is the whole boundary of one convex solid, and that solid's planes.

A moving object that is a convex solid with few faces (a box, a prism, a wedge) hides the
segment between two patch centres exactly where the segment crosses the solid's boundary, and
clipping the segment by the solid's face planes decides that without tracing it
(``csrc/segments.c``; docs/design.md, 'Moving objects'). Any other object keeps the trace.

The test, on the mesh's own points (no new geometry): the convex hull of the points has at
most :data:`MAX_PLANES` distinct face planes; every triangle lies in one of them; and the
triangles on each plane cover exactly the hull's face there (their areas sum to its area, to
:data:`AREA_TOL`), with no triangle given twice. A mesh with a hole, a missing face, a dent, a
part outside another, or an open side fails one of them. What it cannot see is a face with
overlapping triangles that also lacks a piece of exactly their overlap's area: such a mesh
would be read as closed.
"""

from __future__ import annotations

import numpy as np

__all__ = ["solid_planes", "MAX_PLANES", "PLANE_TOL", "AREA_TOL"]

#: The most distinct face planes a solid may have for the planes test: it runs them all per
#: segment near the object, and past a few dozen the object's tree traces a segment faster.
MAX_PLANES = 32
#: Distance from a plane, relative to the points' bounding radius, within which a point lies in
#: it: the points are float64, but often float32 data (rounding ~6e-8 of the radius).
PLANE_TOL = 1e-6
#: Relative difference allowed between a face's area and that of the triangles on it.
AREA_TOL = 1e-6


def _triangle_areas(corners: np.ndarray) -> np.ndarray:
    """Areas of triangles ``corners`` (T, 3, 3)."""
    return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)


def solid_planes(points: np.ndarray, triangles: np.ndarray) -> np.ndarray | None:
    """(k, 4) float64 rows (n, d), ``|n| = 1``, of the solid ``dot(n, x) <= d`` (all k at once) whose
    whole boundary the triangles are (module docstring), in the points' own coordinates; None
    where they are not the boundary of one convex solid of at most :data:`MAX_PLANES` faces.

    ``points`` (V, 3) float; ``triangles`` (T, 3) int indices into them."""
    from scipy.spatial import ConvexHull, QhullError

    P = np.asarray(points, np.float64)
    tri = np.asarray(triangles, np.int64)
    if tri.ndim != 2 or tri.shape[1] != 3 or len(tri) < 4 or not np.all(np.isfinite(P)):
        return None
    used = P[np.unique(tri)]
    lo, hi = used.min(axis=0), used.max(axis=0)
    centre, radius = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    if not radius > 0.0:
        return None
    try:  # about the centre and in radii, so the tolerances are relative
        hull = ConvexHull((used - centre) / radius)
    except (QhullError, ValueError):  # flat, or too few distinct points: no solid
        return None
    normals, offsets = hull.equations[:, :3], hull.equations[:, 3]  # n . x + offset <= 0 inside
    # qhull splits each face into triangles: one plane for those that agree to the tolerance.
    planes: list[int] = []
    face = np.empty(len(normals), np.int64)
    for f in range(len(normals)):
        for k, g in enumerate(planes):
            if np.abs(normals[f] - normals[g]).max() <= PLANE_TOL and abs(offsets[f] - offsets[g]) <= PLANE_TOL:
                face[f] = k
                break
        else:
            if len(planes) == MAX_PLANES:
                return None
            face[f] = len(planes)
            planes.append(f)
    N, off = normals[planes], offsets[planes]
    hull_area = np.bincount(face, _triangle_areas(hull.points[hull.simplices]), minlength=len(planes))
    corners = (P[tri] - centre) / radius
    on = np.all(np.abs(corners @ N.T + off) <= PLANE_TOL, axis=1)  # (T, k): every corner in plane k
    if not on.any(axis=1).all():
        return None  # a triangle inside the hull (a dent, an inner wall) or across it
    if len(np.unique(np.sort(tri, axis=1), axis=0)) != len(tri):
        return None  # a triangle given twice
    mesh_area = np.bincount(on.argmax(axis=1), _triangle_areas(corners), minlength=len(planes))
    if np.any(np.abs(mesh_area - hull_area) > AREA_TOL * hull_area.sum()):
        return None  # a hole, an open side, or triangles over one another
    # Back to the points' coordinates: n . (x - c) / r + offset <= 0  <=>  n . x <= n . c - offset r.
    return np.column_stack([N, N @ centre - off * radius])
