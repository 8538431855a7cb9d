"""Occlusion geometry of moving objects: which rays and segments their bounds may cut.

Bounding spheres give cheap, conservative tests (solid angles, form factors of a sphere seen
from a patch, segments that pass near one); the objects' own BVHs answer the few segments
left. See docs/design.md, 'Moving objects'.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .. import _segments
from ..checks import patch_indices
from ..errors import InvalidInputError
from ..geometry.bvh import occluded
from ..host.threads import cores, map_parts, row_parts
from ..lights.sources import DirectionalLight
from .poserows import native_spans

__all__ = [
    "sphere_solid_angle",
    "sphere_form_factor",
    "shadow_rays_near",
    "refresh_order",
    "hidden_by",
    "hidden_between",
    "hidden_entries",
]


def sphere_solid_angle(points: np.ndarray, normals: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """(n,) solid angle (sr) that a sphere subtends from each point, 0 when wholly behind its plane.

    A point inside the sphere sees it over its whole hemisphere (2 pi). Conservative for the
    ranking's purpose: a patch scores 0 only when no ray of its hemicube can reach the sphere.
    """
    return _sphere_view(points, normals, center, radius)[0]


def sphere_form_factor(points: np.ndarray, normals: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """(n,) the form factor from each point to a sphere, estimated as its solid angle
    (:func:`sphere_solid_angle`) times the cosine to its centre over pi; a point inside the
    sphere counts the cosine as 1."""
    omega, cos = _sphere_view(points, normals, center, radius)
    return omega * cos / np.pi


def _sphere_view(points, normals, center, radius) -> tuple[np.ndarray, np.ndarray]:
    """(solid angle, cosine to the centre clipped at 0, 1 inside) of a sphere from each point."""
    v = np.asarray(center, np.float64) - np.asarray(points, np.float64)
    d = np.linalg.norm(v, axis=1)
    height = np.einsum("ij,ij->i", v, np.asarray(normals, np.float64))
    inside = d <= radius
    omega = 2.0 * np.pi * (1.0 - np.sqrt(np.clip(1.0 - (radius / np.maximum(d, 1e-300)) ** 2, 0.0, 1.0)))
    omega = np.where(inside, 2.0 * np.pi, omega)
    cos = np.where(inside, 1.0, np.clip(height / np.maximum(d, 1e-300), 0.0, 1.0))
    return np.where(height > -radius, omega, 0.0), cos


#: Spheres :func:`shadow_rays_near` takes in one pass (its temporaries are points x spheres x 3
#: float64: 13 MB for the 66k village at this many).
SHADOW_SPHERES = 8


def shadow_rays_near(points: np.ndarray, light, spheres) -> np.ndarray:
    """(n,) bool: whether the shadow ray from each point towards ``light`` passes within the
    radius of any of ``spheres`` [(centre, radius), ...]: the segment to a point or spot light's
    position, the ray against a directional light's direction (unbounded, so a superset of the
    kernel's, which stops past the scene). Where False, an object inside those spheres cannot
    shadow the point from the light. All spheres in one pass of arrays (n, k): a pass per
    sphere repeated every array step's overhead per sphere."""
    p = np.asarray(points, np.float64)
    if not len(spheres):
        return np.zeros(len(p), bool)
    c = np.array([s[0] for s in spheres], np.float64)  # (k, 3)
    r = np.array([s[1] for s in spheres], np.float64)  # (k,)
    if isinstance(light, DirectionalLight):
        v = np.broadcast_to(-np.asarray(light.direction, np.float64), p.shape)
        vv = None
    else:  # a point or spot light: the segment to its position
        v = np.asarray(light.position, np.float64) - p
        vv = np.maximum(np.einsum("nj,nj->n", v, v), 1e-300)[:, None]
    near = np.zeros(len(p), bool)
    for k in range(0, len(c), SHADOW_SPHERES):  # (n, k, 3) temporaries of a bounded size
        u = c[None, k : k + SHADOW_SPHERES, :] - p[:, None, :]  # from each point to each centre
        uv = np.einsum("nkj,nj->nk", u, v)
        t = np.maximum(uv, 0.0) if vv is None else np.clip(uv / vv, 0.0, 1.0)
        gap = t[:, :, None] * v[:, None, :] - u  # closest point on the ray minus the centre
        near |= np.any(np.einsum("nkj,nkj->nk", gap, gap) <= r[k : k + SHADOW_SPHERES] ** 2, axis=1)
    return near


def refresh_order(points, normals, spheres) -> tuple[np.ndarray, np.ndarray]:
    """Patches that may see any of ``spheres`` [(centre, radius), ...], most solid angle first.

    Returns (order, score): indices into ``points`` with a positive score, and their scores.
    """
    score = sum(sphere_solid_angle(points, normals, c, r) for c, r in spheres)
    order = np.flatnonzero(score > 0)
    order = order[np.argsort(-score[order], kind="stable")]
    return order, score[order]


def hidden_by(objects, transforms, starts: np.ndarray, ends: np.ndarray, device=None) -> np.ndarray:
    """(n,) bool: the segments ``starts[i] -> ends[i]`` (world points) that cross an object's
    triangles at ``transforms`` (:func:`hidden_between` of the points as given)."""
    p0, p1 = np.asarray(starts, np.float64), np.asarray(ends, np.float64)
    n = len(p0)
    return hidden_between(objects, transforms, np.concatenate([p0, p1]), np.arange(n), np.arange(n, 2 * n), device)


#: Relative widening of the bounding spheres in :func:`_hidden_entries`'s pre-test, so that its
#: rounding never drops a segment that the tree (in float32) would report hidden.
SPHERE_MARGIN = 1e-6


#: Widening of each side of an object's box in the same pre-test, relative to its bounding
#: radius: float32 rays and triangles in the device frame may hit ~1e-7 of it outside the box.
BOX_MARGIN = 1e-4


#: The least form factor from a patch outside the local set to a moving object's bounding sphere
#: (at its pose, or where the far field's coarse level has it) for which the frame gathers the
#: patch's light at the objects' poses (:meth:`WorldRows.gather_outside`); the others keep the
#: far field's B, which the object changes by less than this share of the light around them. On a
#: large scene a small object is seen so by a small share of the patches that have it in front,
#: whose rows would be most of F to gather per frame
#: (docs/decisions/0028-moving-objects-large-scenes.md).
VIEW_FORM_FACTOR = 1e-3


#: Up to this many outside patches per local patch the frame gathers every one of them at the
#: poses (:meth:`WorldRows.gathered`): a final gather of the far field as well, which halves its
#: max error on the bench's small Cornell box (348 patches, M = 64: 0.0049 -> 0.0025 of max B),
#: for at most this many passes over rows as long as the local set's. The 66k village at
#: M = 1,024 (64 per local patch) gathers only those in view.
GATHER_ALL_OUTSIDE = 8


#: Segments from which :func:`_hidden_entries` splits its pre-test over the cores (below, a
#: thread's start costs more than it saves).
PARALLEL_SEGMENTS = 50_000


def hidden_between(objects, transforms, points: np.ndarray, a: np.ndarray, b: np.ndarray, device=None) -> np.ndarray:
    """(n,) bool: the segments ``points[a[i]] -> points[b[i]]`` that cross an object's triangles
    at ``transforms`` (:func:`_hidden_entries` with one segment per row)."""
    a, b = np.asarray(a, np.int64), patch_indices(b, len(points), "segment ends")
    ends = np.arange(1, len(a) + 1)
    return _hidden_entries(objects, transforms, points, ends - 1, ends, b.astype(np.int32), a, device)


def _hidden_entries(
    objects,
    transforms,
    points: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    indices: np.ndarray,
    owners: np.ndarray,
    device=None,
) -> np.ndarray:
    """(m,) bool over ``indices`` (m,) int32: entry j of row k (``starts[k] <= j < ends[k]``, as
    :func:`native_spans` gives) is the segment ``points[owners[k]] -> points[indices[j]]`` (rows
    with ``owners[k] < 0`` are skipped, as are the entries of no row: False), True where it
    crosses an object's triangles at ``transforms``. Only segments passing within an object's
    bounding sphere are traced, each in the object's own space against its own tree (the static
    scene is not looked at).

    The pre-test is one pass over the entries (``csrc/segments.c``): with u = p - c for the
    sphere's centre c, |u_a + t (u_b - u_a)|^2 is a quadratic in t whose coefficients are
    |u_a|^2, |u_b|^2 (per point, not per segment) and u_a . u_b; a segment near the sphere is
    then moved into object space and kept only if it crosses the object's box (slab test), and
    comes out as the ray the object's tree traces. An object that is one convex solid
    (:attr:`~pydynrad.geometry.objects.RigidObject.solid_planes`) is not traced: the same pass clips each
    segment by the solid's planes, which decides exactly whether it crosses the boundary."""

    P = np.ascontiguousarray(points, np.float64)
    starts, ends = np.ascontiguousarray(starts, np.int64), np.ascontiguousarray(ends, np.int64)
    indices, owners = np.ascontiguousarray(indices, np.int32), np.ascontiguousarray(owners, np.int64)
    out = np.zeros(len(indices), bool)
    # The rows in a part per core, of about equal entries, the native pass run on each at once
    # (it releases the GIL).
    work = np.concatenate([[0], np.cumsum(ends - starts)])
    parts = row_parts(work, cores() if work[-1] >= PARALLEL_SEGMENTS else 1)
    for o, T in zip(objects, transforms):
        c, r = o.bounding_sphere(T)
        Rt = T[:3, :3].T  # world to object space: x -> R^T (x - t)
        lo, hi = o.scene.bbox.astype(np.float64)
        box = np.concatenate([Rt.ravel(), -Rt @ T[:3, 3], lo - BOX_MARGIN * r, hi + BOX_MARGIN * r])
        planes = o.solid_planes
        args = (
            tuple(float(v) for v in c),
            r * (1.0 + SPHERE_MARGIN),
            box.tolist(),
            None if planes is None else planes.ravel().tolist(),
        )
        found = map_parts(
            lambda k: _segments.near_sphere(
                P, starts[k[0] : k[1]], ends[k[0] : k[1]], indices, owners[k[0] : k[1]], *args
            ),
            parts,
        )
        near = np.frombuffer(b"".join(f[0] for f in found), np.int64)
        if planes is not None:  # decided in the pass: the segments that cross the solid
            out[near] = True
            continue
        rays = np.frombuffer(b"".join(f[1] for f in found), np.float64).reshape(-1, 6)
        keep = ~out[near]
        if keep.any():
            if not keep.all():  # an earlier object hid some: a copy of the rest (only then)
                rays, near = rays[keep], near[keep]
            out[near] = occluded(o.scene, rays[:, :3], rays[:, 3:], np.float32(1.0), device=device)
    return out


def hidden_entries(
    rows: sp.csr_matrix,
    row_patches: np.ndarray,
    centers: np.ndarray,
    normals: np.ndarray,
    objects,
    transforms,
    device=None,
    select: np.ndarray | None = None,
) -> np.ndarray:
    """(nnz,) bool over the entries of static ``rows`` (CSR), True where the objects hide F[s, x],
    the segment between the centres of s and x crossing one (:func:`_hidden_entries`): a
    patch-centre estimate of the occlusion a hemicube at the pose would see, for no hemicube.
    ``select``: the rows to test (all by default; the others' entries are False), read in place,
    of patches ``row_patches`` (one per row tested). Rows of patches whose front sees no object's
    bounding sphere have none (nothing in front of them can be hidden)."""
    row_patches = np.asarray(row_patches, np.int64)
    starts, ends, indices, _ = native_spans(rows, select)
    if len(row_patches) != len(starts):
        raise InvalidInputError(
            f"hidden_entries needs one patch per row tested ({len(starts)}); got {len(row_patches)}"
        )
    # Only whether a front can see a sphere (it is not wholly behind the patch's plane), not
    # the ranking's solid angles and sort (several times the cost, line-profiled in a move).
    P, n = np.asarray(centers, np.float64)[row_patches], np.asarray(normals, np.float64)[row_patches]
    sees = np.zeros(len(row_patches), bool)
    for o, T in zip(objects, transforms):
        c, r = o.bounding_sphere(T)
        sees |= np.einsum("ij,ij->i", c - P, n) > -r
    owners = np.where(sees, row_patches, -1)
    return _hidden_entries(objects, transforms, centers, starts, ends, indices, owners, device)
