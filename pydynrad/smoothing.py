"""Smooth vertices: where a patch corner's radiosity is shared with its neighbours' corners.

Patches meeting at a point join one *smoothing group* when their normals differ by less than
``crease_angle`` and their albedo and emission are equal, so light never leaks across a crease
(a wall meeting the floor) or a material border (the light's edge, a red wall meeting a white
one). Groups are the connected components of that relation, which splits every mesh vertex
into one vertex per group; a vertex's radiosity is the area-weighted mean radiosity of its
group's patches. The renderer's smooth shading and the baked meshes and lightmaps
(:mod:`pydynrad.bake`) interpolate these vertex values, so they agree.

See docs/design.md, 'Renderer'.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .checks import finite, floats, number
from .errors import InvalidInputError
from .geometry.loading import checked_scene

__all__ = ["SmoothVertices", "checked_radiosity", "smooth_vertices", "smoothing_groups"]

# Smoothing groups depend on the scene only: kept while the scene lives, so repeated
# render() calls (a walk) and bakes group the corners once.
_cache: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def smoothing_groups(scene, crease_angle: float = 30.0) -> tuple[np.ndarray, int]:
    """Split mesh vertices into smoothing groups.

    Parameters
    ----------
    scene : Scene
    crease_angle : float
        Patches meeting at a point are smoothed together only when their normals differ by
        less than this many degrees (and their materials are equal).

    Returns
    -------
    corner_group : (N, 3) int64
        Group index of each patch corner; corners with equal index share one value.
    n_groups : int
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if not (np.isfinite(crease_angle) and 0.0 <= crease_angle <= 180.0):
        raise InvalidInputError(f"crease_angle must be in [0, 180] degrees; got {crease_angle!r}")
    n = len(scene)
    # Points are identified by position, so meshes stored with duplicated vertices still smooth.
    _, point_id = np.unique(scene.vertices, axis=0, return_inverse=True)
    corner_point = point_id.reshape(-1)[scene.faces].reshape(-1)
    corner_patch = np.repeat(np.arange(n), 3)
    order = np.argsort(corner_point, kind="stable")
    sorted_point = corner_point[order]
    cos_crease = np.cos(np.radians(crease_angle)) - 1e-6
    normals, albedo, emission = scene.normals, scene.albedo, scene.emission
    rows, cols = [], []
    # Corners of one point sit next to each other after sorting: pair each with the ones
    # d places later, for d up to the largest number of patches around a point.
    d = 1
    while d < len(sorted_point):
        same = sorted_point[d:] == sorted_point[:-d]
        if not same.any():
            break
        a, b = order[:-d][same], order[d:][same]
        pa, pb = corner_patch[a], corner_patch[b]
        ok = (
            (np.einsum("ij,ij->i", normals[pa], normals[pb]) >= cos_crease)
            & np.all(np.abs(albedo[pa] - albedo[pb]) <= 1e-6, axis=1)
            & np.all(np.abs(emission[pa] - emission[pb]) <= 1e-6 * (1.0 + np.abs(emission[pa])), axis=1)
        )
        rows.append(a[ok])
        cols.append(b[ok])
        d += 1
    rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    cols = np.concatenate(cols) if cols else np.zeros(0, dtype=np.int64)
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(3 * n, 3 * n))
    n_groups, labels = connected_components(graph, directed=False)
    return labels.reshape(n, 3).astype(np.int64), int(n_groups)


FLOAT32_MAX = float(np.finfo(np.float32).max)


#: Negative radiosity down to this fraction of the largest magnitude is rounding (a float32
#: solve's, ~1e-7 of it) and is shown as 0; below it :func:`checked_radiosity` refuses the
#: values (light is not negative: a render or mesh of them would show a wrong solution as right).
NEGATIVE_RADIOSITY_TOLERANCE = 1e-5


def checked_radiosity(radiosity, n: int) -> np.ndarray:
    """``radiosity`` of shape (n,), (n, 1) or (n, 3) as a finite (n, 3) float32 view, or
    InvalidInputError; also where a value is negative beyond rounding
    (:data:`NEGATIVE_RADIOSITY_TOLERANCE`), values negative within it read as 0. The one check
    of :func:`pydynrad.render`, :func:`pydynrad.export_mesh` and the bakes."""
    given = np.asarray(radiosity)
    if given.dtype.kind not in "fiub":  # text that spells numbers is refused (a copy only then)
        given = floats(radiosity, "radiosity")
    if np.all(np.isfinite(given)) and np.abs(given).max(initial=0.0) > FLOAT32_MAX:
        # finite in float64, inf once cast: say so, not "NaN or infinite" of values that were neither
        raise InvalidInputError(
            f"radiosity reaches {float(np.abs(given).max()):.3g}, beyond float32 (what renders "
            "and smoothed vertices hold): scale the scene's emission and lights down"
        )
    b = np.asarray(radiosity, dtype=np.float32)
    if b.ndim == 1 and b.shape == (n,):
        b = b[:, None]
    if b.ndim != 2 or b.shape[0] != n or b.shape[1] not in (1, 3):
        raise InvalidInputError(f"radiosity must have shape ({n},), ({n}, 1) or ({n}, 3); got {np.shape(radiosity)}")
    finite(b, "radiosity")
    low = float(b.min(initial=0.0))
    if low < 0.0:
        scale = float(np.abs(b).max())
        if low < -NEGATIVE_RADIOSITY_TOLERANCE * scale:
            patch, channel = np.unravel_index(int(np.argmin(b)), b.shape)
            raise InvalidInputError(
                f"radiosity is negative beyond rounding: patch {patch} (channel {channel}) holds {low:.4g}, "
                f"{-low / scale:.3g} of the largest magnitude {scale:.4g} (down to {NEGATIVE_RADIOSITY_TOLERANCE:g} "
                f"of it is read as rounding, and as 0); {int(np.count_nonzero(b < -NEGATIVE_RADIOSITY_TOLERANCE * scale))} "
                "values are: light is not negative, check the solution that made them"
            )
        b = np.maximum(b, 0.0)
    return np.broadcast_to(b, (n, 3))


@dataclass(frozen=True)
class SmoothVertices:
    """The scene's mesh split into smooth vertices (one per smoothing group).

    Attributes
    ----------
    corner_vertex : (N, 3) int64
        Smooth vertex of each patch corner; ``positions[corner_vertex]`` are the patch corners.
    positions : (V, 3) float32
        Position of each smooth vertex, in scene units.
    weight : (N * 3,) float64
        Area of the patch of each corner (flattened like ``corner_vertex``): the mean's weights.
    """

    corner_vertex: np.ndarray
    positions: np.ndarray
    weight: np.ndarray

    @property
    def n_vertices(self) -> int:
        return len(self.positions)

    def radiosity(self, radiosity) -> np.ndarray:
        """(V, 3) float64 radiosity of each smooth vertex: the area-weighted mean over its patches.

        ``radiosity`` is the patch radiosity, (N, 3), (N, 1) or (N,).
        """
        n = len(self.corner_vertex)
        b = checked_radiosity(radiosity, n).astype(np.float64)
        flat = self.corner_vertex.reshape(-1)
        values = np.stack(
            [
                np.bincount(flat, weights=self.weight * np.repeat(b[:, c], 3), minlength=self.n_vertices)
                for c in range(3)
            ],
            axis=1,
        )
        return values / self._total[:, None]

    @cached_property
    def _total(self) -> np.ndarray:
        """(V,) float64 sum of the weights at each smooth vertex: the same for every radiosity."""
        return np.bincount(self.corner_vertex.reshape(-1), weights=self.weight, minlength=self.n_vertices)


def smooth_vertices(scene, crease_angle: float = 30.0) -> SmoothVertices:
    """The :class:`SmoothVertices` of ``scene`` at ``crease_angle`` degrees, computed once per scene and angle."""
    scene = checked_scene(scene)
    per_scene = _cache.setdefault(scene, {})
    key = number(crease_angle, "crease_angle")
    found = per_scene.get(key)
    if found is None:
        groups, n_groups = smoothing_groups(scene, key)
        positions = np.zeros((n_groups, 3), dtype=np.float32)
        positions[groups.reshape(-1)] = scene.triangles.reshape(-1, 3)
        weight = np.repeat(scene.areas.astype(np.float64), 3)
        found = per_scene[key] = SmoothVertices(groups, positions, weight)
    return found
