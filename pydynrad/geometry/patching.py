"""Patching: split triangles 4-way at their edge midpoints until none exceeds a size limit.

Each split replaces a triangle (a, b, c) by (a, ab, ca), (ab, b, bc), (ca, bc, c) and
(ab, bc, ca), so every child keeps its parent's orientation and a quarter of its area.
A midpoint is created once per edge and shared by every triangle that splits that edge, in
the same round or a later one, so the patches of a mesh stay connected through shared
points. Where a triangle splits and its neighbour across an edge does not (mixed sizes),
the neighbour keeps the whole edge: a T-junction, harmless for radiosity patches.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError, OutOfMemoryError
from ..host.memory import available_host_bytes
from .scene import Scene

__all__ = ["subdivide", "subdivide_scene"]

#: Refuse to produce more patches than this: a typo in a limit should fail fast, not fill memory.
MAX_TRIANGLES = 1 << 27

#: Host bytes per patch at the peak of a subdivision and the scene built from it (measured: 325
#: for :func:`subdivide`'s rounds, its edge tables and the sort by parent, 367 with
#: :func:`subdivide_scene`'s materials): near :data:`MAX_TRIANGLES` that is 50 GB, so a
#: subdivision is refused as :class:`~pydynrad.errors.OutOfMemoryError` before it starts where
#: the process's memory (RLIMIT_AS, the cgroup, the machine) cannot hold it.
SUBDIVIDE_BYTES_PER_PATCH = 384

_EDGES = np.array([[0, 1], [1, 2], [2, 0]])


def _limit(value, name: str) -> float | None:
    if value is None:
        return None
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise InvalidInputError(f"{name} must be a positive finite number; got {value!r}")
    return v


def _too_big(p: np.ndarray, tri: np.ndarray, max_area: float | None, max_edge: float | None) -> np.ndarray:
    v = p[tri]
    big = np.zeros(len(tri), dtype=bool)
    if max_area is not None:
        big |= 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1) > max_area
    if max_edge is not None:
        big |= np.max(np.sum((v - v[:, [1, 2, 0]]) ** 2, axis=2), axis=1) > max_edge**2
    return big


def _expected_count(p: np.ndarray, tri: np.ndarray, max_area: float | None, max_edge: float | None) -> float:
    """Patches the split will make: a midpoint split gives four copies at half scale, so a
    triangle needs ceil(log4(area / max_area)) and ceil(log2(edge / max_edge)) levels."""
    if not len(tri):
        return 0.0
    v = p[tri]
    levels = np.zeros(len(tri))
    with np.errstate(divide="ignore"):
        if max_area is not None:
            area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
            levels = np.maximum(levels, np.ceil(np.log(area / max_area) / np.log(4.0)))
        if max_edge is not None:
            edge = np.sqrt(np.max(np.sum((v - v[:, [1, 2, 0]]) ** 2, axis=2), axis=1))
            levels = np.maximum(levels, np.ceil(np.log2(edge / max_edge)))
    return float(np.sum(4.0 ** np.clip(levels, 0, 40)))


def subdivide(points, triangles, max_area: float | None = None, max_edge: float | None = None):
    """Split triangles until no triangle's area exceeds ``max_area`` and no edge ``max_edge``.

    Parameters
    ----------
    points : (V, 3) float
        Vertex positions.
    triangles : (N, 3) int
        Vertex indices per triangle.
    max_area : float, optional
        Largest allowed triangle area (units of ``points`` squared).
    max_edge : float, optional
        Largest allowed edge length (units of ``points``).

    Returns
    -------
    points : (V', 3) float64
        The input points followed by the new midpoints.
    triangles : (N', 3) int32
        The patches, grouped by parent in input order.
    parent : (N',) int64
        Index of the input triangle each patch came from.

    With neither limit given the input comes back unchanged (``parent`` is the identity).
    """
    max_area = _limit(max_area, "max_area")
    max_edge = _limit(max_edge, "max_edge")
    p = np.asarray(points, dtype=np.float64)
    tri = np.asarray(triangles)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidInputError(f"points must have shape (V, 3); got {p.shape}")
    if tri.ndim != 2 or tri.shape[1] != 3 or not np.issubdtype(tri.dtype, np.integer):
        raise InvalidInputError(f"triangles must be an (N, 3) integer array; got {tri.shape} {tri.dtype}")
    if tri.size and (tri.min() < 0 or tri.max() >= len(p)):
        raise InvalidInputError(f"triangles index vertices outside 0..{len(p) - 1}")
    if tri.size and not np.all(np.isfinite(p[np.unique(tri)])):
        raise InvalidInputError("points contain NaN or infinite coordinates")
    tri = tri.astype(np.int64)
    expected = _expected_count(p, tri, max_area, max_edge)
    if expected > MAX_TRIANGLES:
        raise InvalidInputError(
            f"subdividing to max_area={max_area}, max_edge={max_edge} would make about {expected:.3g} patches "
            f"(more than {MAX_TRIANGLES})"
        )
    need, available = expected * SUBDIVIDE_BYTES_PER_PATCH, available_host_bytes()
    if need > available:
        raise OutOfMemoryError(
            f"subdividing to max_area={max_area}, max_edge={max_edge} would make about {expected:.3g} patches, "
            f"needing about {need / 2**30:.3g} GiB of host memory; {available / 2**30:.3g} GiB is available "
            "(the machine, the memory cgroup and ulimit -v): use larger limits"
        )
    try:
        return _split(p, tri, max_area, max_edge)
    except MemoryError as exc:  # the estimate is close, not a bound: numpy's bare error, named
        raise OutOfMemoryError(
            f"subdividing to max_area={max_area}, max_edge={max_edge} (about {expected:.3g} patches, "
            f"{need / 2**30:.3g} GiB estimated, {available / 2**30:.3g} GiB available) ran out of host "
            f"memory: {exc or 'numpy could not allocate'}; use larger limits"
        ) from None


def _split(p: np.ndarray, tri: np.ndarray, max_area: float | None, max_edge: float | None):
    """:func:`subdivide`'s rounds, on checked input."""
    parent = np.arange(len(tri), dtype=np.int64)
    n_points = len(p)
    # Every edge split so far, as sorted keys lo << 32 | hi, and the index of its midpoint.
    edge_keys = np.empty(0, dtype=np.int64)
    edge_mids = np.empty(0, dtype=np.int64)
    done_tri, done_parent = [], []
    while len(tri):
        big = _too_big(p, tri, max_area, max_edge)
        done_tri.append(tri[~big])
        done_parent.append(parent[~big])
        tri, parent = tri[big], parent[big]
        if not len(tri):
            break
        ends = tri[:, _EDGES]  # (S, 3, 2)
        keys = (np.minimum(ends[..., 0], ends[..., 1]) << 32) | np.maximum(ends[..., 0], ends[..., 1])
        uniq, inverse = np.unique(keys.ravel(), return_inverse=True)
        # Midpoints of edges already split in an earlier round are reused, not duplicated.
        pos = np.searchsorted(edge_keys, uniq)
        found = pos < len(edge_keys)
        found[found] = edge_keys[pos[found]] == uniq[found]
        mids = np.empty(len(uniq), dtype=np.int64)
        mids[found] = edge_mids[pos[found]]
        new = uniq[~found]
        lo, hi = new >> 32, new & 0xFFFFFFFF
        mids[~found] = n_points + np.arange(len(new))
        new_points = 0.5 * (p[lo] + p[hi])
        n_points += len(new)
        p = np.concatenate([p, new_points])
        merged = np.concatenate([edge_keys, new])
        order = np.argsort(merged, kind="stable")
        edge_keys, edge_mids = merged[order], np.concatenate([edge_mids, mids[~found]])[order]
        m = mids[inverse].reshape(-1, 3)  # midpoints of edges ab, bc, ca
        a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
        ab, bc, ca = m[:, 0], m[:, 1], m[:, 2]
        tri = np.concatenate([np.stack(t, axis=1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
        parent = np.tile(parent, 4)
    tri = np.concatenate(done_tri)
    parent = np.concatenate(done_parent)
    order = np.argsort(parent, kind="stable")
    if n_points >= 2**31:
        raise InvalidInputError(f"subdivision produced {n_points} points, more than int32 indices can address")
    return p, tri[order].astype(np.int32), parent[order]


def subdivide_scene(scene, max_area: float | None = None, max_edge: float | None = None):
    """``scene`` with its patches split by :func:`subdivide`: every child keeps its parent's
    albedo, emission and source face, so materials and file faces stay as they were."""
    points, triangles, parent = subdivide(scene.vertices, scene.faces, max_area=max_area, max_edge=max_edge)
    out = Scene(
        points,
        triangles,
        albedo=scene.albedo[parent],
        emission=scene.emission[parent],
        source_face=scene.source_face[parent],
        name=scene.name,
        unit=scene.unit,
        up=scene.up,
    )
    if scene.materials is not None:
        out.materials = scene.materials.take(parent)
    return out
