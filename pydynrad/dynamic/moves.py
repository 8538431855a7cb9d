"""Moving rigid objects in a dynamic solution: their rows, the rows they change, and the swap.

A move of objects O is a batched swap with I = J = the slots of O's patches plus the slots of
the local patches whose rows are refreshed (the occlusion budget): remove them with their old
rows and add them back with new ones (docs/design.md, 'Moving objects', 'Batched swap'):

* O's rows: one hemicube per patch at the new pose;
* the columns F[s, O] of the other local patches: by reciprocity, A_s F[s, o] = A_o F[o, s];
* refreshed rows: hemicubes of the local patches that see the most of O's old and new
  bounding spheres (their view of the static scene changed: O now hides or uncovers parts);
* rows left stale whose sum the new object columns would push above 1: those columns are
  scaled down to fill the row to 1 (:func:`stale_rows`); being in the objects' columns, they
  need no slot of their own in the swap. With a static F their rows at the new poses are made
  too (:meth:`WorldRows.refresh`) and B is corrected for them (:mod:`pydynrad.dynamic.stale`).

The swap size bounds one batch; larger sets go in chunks, each one exact on its own: after
chunk c the device K is that of the form factors whose entries in a row or column of the
chunks done so far are new and the rest old, which is what the next chunk removes from.
"""

from __future__ import annotations

import threading
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from ..host.colproduct import rows_product
from ..errors import InvalidInputError, PydynradError
from ..rows.sources import HemicubeRows
from .localrows import LocalRows

__all__ = ["PoseRows", "precompute_poses", "stored_poses", "WorldRows", "sphere_solid_angle", "sphere_form_factor",
           "shadow_rays_near", "refresh_order", "stale_rows", "hidden_by", "hidden_between", "hidden_entries",
           "native_spans", "reciprocal_columns", "at_pose", "Since", "PoseDifference", "difference_at_pose",
           "kept_slots", "stacked_rows", "swap_chunks"]


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
    sphere was 0.4 ms of a move's relight on the bench's Cornell box."""
    from ..lights.sources import DirectionalLight

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
        u = c[None, k:k + SHADOW_SPHERES, :] - p[:, None, :]  # from each point to each centre
        uv = np.einsum("nkj,nj->nk", u, v)
        t = np.maximum(uv, 0.0) if vv is None else np.clip(uv / vv, 0.0, 1.0)
        gap = t[:, :, None] * v[:, None, :] - u  # closest point on the ray minus the centre
        near |= np.any(np.einsum("nkj,nkj->nk", gap, gap) <= r[k:k + SHADOW_SPHERES] ** 2, axis=1)
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
#: far field's B, which the object changes by less than this share of the light around them. On
#: the 66k village a 1 m block is seen so by 2,816 patches (1.4M entries of F) where 44,402 have
#: it in front (35M entries of F to gather per frame: 0.5-2.3 s; AMD EPYC Zen 3, 2026-12-02).
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
    from ..checks import patch_indices

    a, b = np.asarray(a, np.int64), patch_indices(b, len(points), "segment ends")
    ends = np.arange(1, len(a) + 1)
    return _hidden_entries(objects, transforms, points, ends - 1, ends, b.astype(np.int32), a, device)


def native_spans(m: sp.csr_matrix, select: np.ndarray | None = None):
    """(starts, ends, indices, data) of CSR ``m``'s rows ``select`` (all by default) read where
    they lie: int64 spans of its int32 indices and float64 data, as ``csrc/segments.c`` and
    ``csrc/poserows.c`` read them (no copy of the entries where they already are so)."""
    from ..checks import patch_indices

    indptr = np.asarray(m.indptr)
    rows = np.arange(m.shape[0]) if select is None else patch_indices(select, m.shape[0], "rows to select")
    _, indices, data = native_csr(m)
    return (indptr[rows].astype(np.int64), indptr[rows + 1].astype(np.int64), indices, data)


def _hidden_entries(objects, transforms, points: np.ndarray, starts: np.ndarray, ends: np.ndarray,
                    indices: np.ndarray, owners: np.ndarray, device=None) -> np.ndarray:
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
    from .. import _segments
    from ..geometry.bvh import occluded
    from ..host.threads import cores, map_parts, row_parts

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
        args = (tuple(float(v) for v in c), r * (1.0 + SPHERE_MARGIN), box.tolist(),
                None if planes is None else planes.ravel().tolist())
        found = map_parts(lambda k: _segments.near_sphere(P, starts[k[0]:k[1]], ends[k[0]:k[1]], indices,
                                                          owners[k[0]:k[1]], *args), parts)
        near = np.frombuffer(b"".join(f[0] for f in found), np.int64)
        if planes is not None:  # decided in the pass: the segments that cross the solid
            out[near] = True
            continue
        rays = np.frombuffer(b"".join(f[1] for f in found), np.float64).reshape(-1, 6)
        keep = ~out[near]
        if keep.any():
            if not keep.all():  # an earlier object hid some: a copy of the rest (35k rays: 0.5 ms)
                rays, near = rays[keep], near[keep]
            out[near] = occluded(o.scene, rays[:, :3], rays[:, 3:], np.float32(1.0), device=device)
    return out


def hidden_entries(rows: sp.csr_matrix, row_patches: np.ndarray, centers: np.ndarray, normals: np.ndarray, objects,
                   transforms, device=None, select: np.ndarray | None = None) -> np.ndarray:
    """(nnz,) bool over the entries of static ``rows`` (CSR), True where the objects hide F[s, x],
    the segment between the centres of s and x crossing one (:func:`_hidden_entries`): a
    patch-centre estimate of the occlusion a hemicube at the pose would see, for no hemicube.
    ``select``: the rows to test (all by default; the others' entries are False), read in place,
    of patches ``row_patches`` (one per row tested). Rows of patches whose front sees no object's
    bounding sphere have none (nothing in front of them can be hidden)."""
    row_patches = np.asarray(row_patches, np.int64)
    starts, ends, indices, _ = native_spans(rows, select)
    if len(row_patches) != len(starts):
        raise InvalidInputError(f"hidden_entries needs one patch per row tested ({len(starts)}); got {len(row_patches)}")
    # Only whether a front can see a sphere (it is not wholly behind the patch's plane), not
    # the ranking's solid angles and sort (line-profiled in a move: 1.4 ms, now 0.3).
    P, n = np.asarray(centers, np.float64)[row_patches], np.asarray(normals, np.float64)[row_patches]
    sees = np.zeros(len(row_patches), bool)
    for o, T in zip(objects, transforms):
        c, r = o.bounding_sphere(T)
        sees |= np.einsum("ij,ij->i", c - P, n) > -r
    owners = np.where(sees, row_patches, -1)
    return _hidden_entries(objects, transforms, centers, starts, ends, indices, owners, device)


def reciprocal_columns(row_patches: np.ndarray, object_rows: sp.csr_matrix, object_patches: np.ndarray,
                       areas: np.ndarray, n_cols: int) -> sp.csr_matrix:
    """(len(row_patches), n_cols): the columns ``object_patches`` of the rows of ``row_patches``
    by reciprocity, F[s, o] = A_o F[o, s] / A_s, from the objects' rows ``object_rows``
    (len(object_patches), N); zero elsewhere."""
    A = np.asarray(areas, np.float64)
    row_patches = np.asarray(row_patches, np.int64)
    # The objects' columns as rows (a transpose held by column, converted once), then the rows
    # wanted: a column slice of the objects' rows cost a third more. Scaled on the entries:
    # broadcast sparse products copy the matrix per factor.
    recip = sp.csr_matrix(object_rows).T.tocsr()[row_patches]
    recip.sort_indices()
    data = recip.data * A[object_patches][recip.indices] * np.repeat(1.0 / A[row_patches], np.diff(recip.indptr))
    return sp.csr_matrix((data, np.asarray(object_patches, np.int64)[recip.indices], recip.indptr),
                         shape=(len(row_patches), n_cols))


def at_pose(rows: sp.csr_matrix, hidden: np.ndarray, recip: sp.csr_matrix,
            select: np.ndarray | None = None) -> sp.csr_matrix:
    """Static ``rows`` (CSR, no entries in the object columns; its rows ``select``, read in
    place, all by default) at the objects' poses, shaped as ``recip``: without their entries
    ``hidden`` ((rows.nnz,) bool, :func:`hidden_entries`), with the object columns ``recip``
    (one row per row taken, :func:`reciprocal_columns`), and capped: where a row then sums
    above 1 (the centre segments missed part of what an object hides), its static entries are
    scaled so that it sums to 1, clipped at zero; where the object columns alone sum above 1,
    they are scaled to 1 and the static entries go. No row sums above 1. One native pass
    (``csrc/poserows.c``); zeros dropped."""
    from .. import _poserows

    starts, ends, indices, data, hidden, recip = _pose_spans("at_pose", rows, hidden, recip, select)
    n = int((ends - starts).sum()) + recip.nnz
    indptr, out_indices, out_data = np.empty(len(starts) + 1, np.int64), np.empty(n, np.int32), np.empty(n)
    # One thread: in two parts (their outputs then stacked) it took 1.25 ms against 0.70 for a
    # move's 450k entries on the bench's Cornell box (AMD EPYC Zen 4, 2026-12-06): a pass that
    # writes every entry once is bound by memory, not by a core.
    nnz = _poserows.assemble(starts, ends, indices, data, hidden, *native_csr(recip),
                             indptr, out_indices, out_data)
    return sp.csr_matrix((out_data[:nnz], out_indices[:nnz], indptr), shape=recip.shape)


def _pose_spans(caller: str, rows: sp.csr_matrix, hidden: np.ndarray, recip: sp.csr_matrix, select) -> tuple:
    """(starts, ends, indices, data, hidden as uint8, recip as CSR): the checked inputs of
    :func:`at_pose` and :func:`difference_at_pose` as ``csrc/poserows.c`` reads them."""
    if not (sp.issparse(rows) and rows.format == "csr"):
        raise InvalidInputError(f"{caller} needs the rows as CSR (hidden is over their entries); got {type(rows).__name__}")
    recip = sp.csr_matrix(recip)
    starts, ends, indices, data = native_spans(rows, select)
    if len(starts) != recip.shape[0] or rows.shape[1] > recip.shape[1]:
        raise InvalidInputError(f"{len(starts)} rows of {rows.shape[1]} columns and their object columns {recip.shape} "
                                f"do not match")
    if np.shape(hidden) != (rows.nnz,):
        raise InvalidInputError(f"hidden must have one flag per entry of the rows ({rows.nnz}); got {np.shape(hidden)}")
    return starts, ends, indices, data, _mask_bytes(hidden), recip


def _mask_bytes(mask: np.ndarray) -> np.ndarray:
    """A mask over a CSR matrix's entries as the uint8 flags ``csrc/poserows.c`` reads. A bool
    mask is read as bytes in place: it spans all of F's entries when rows are picked out of F
    (a uint8 copy of the village's 35M was 87 ms a move)."""
    mask = np.ascontiguousarray(mask)
    return (mask if mask.dtype == np.bool_ else mask != 0).view(np.uint8)


def kept_slots(slots: np.ndarray, n_rows: int, n_kept: int) -> np.ndarray:
    """``slots`` as contiguous int64, checked to name one of ``n_kept`` kept rows for each of
    ``n_rows`` rows (:func:`difference_at_pose`, :func:`~pydynrad.dynamic.stale.rows_minus`)."""
    slots = np.ascontiguousarray(slots, np.int64)
    if slots.shape != (n_rows,):
        raise InvalidInputError(f"slots must name one kept row per row ({n_rows}); got shape {slots.shape}")
    if len(slots) and (slots.min() < 0 or slots.max() >= n_kept):
        raise InvalidInputError(f"slots must lie in [0, {n_kept}) (the kept rows); got {slots.min()}..{slots.max()}")
    return slots


class Since(NamedTuple):
    """What :func:`difference_at_pose` may start from for some of its rows: their rows at the
    last pose, made from the same static rows, and their D then.

    ``rows`` (r,) bool: the rows whose row at the last pose was made with the mask ``hidden``
    ((nnz,) bool over the static rows' entries, as :func:`hidden_entries` gave it then) and not
    capped, and whose D then holds against the same kept rows: row ``last_row[i]`` of ``last``
    (CSR of N columns; -1: an empty row); ``row_sums`` (r,) float64: each static row's sum;
    ``first_object``: the first object column (every static column lies below it)."""

    rows: np.ndarray
    hidden: np.ndarray
    row_sums: np.ndarray
    last: sp.csr_matrix
    last_row: np.ndarray
    first_object: int


class PoseDifference(NamedTuple):
    """:func:`difference_at_pose`'s answer: ``delta`` (r, N) CSR, D; ``capped`` (r,) bool, where
    the row at the pose was scaled or capped (:func:`at_pose`)."""

    delta: sp.csr_matrix
    capped: np.ndarray


def difference_at_pose(rows: sp.csr_matrix, hidden: np.ndarray, recip: sp.csr_matrix, kept: sp.csr_matrix,
                       slots: np.ndarray, select: np.ndarray | None = None, since: Since | None = None) -> PoseDifference:
    """``at_pose(rows, hidden, recip, select) - kept[slots]`` (r, N) CSR, exact zeros dropped,
    without the rows at the pose: each is merged with its kept row as it is made, value for
    value as :func:`at_pose` makes it (``csrc/poserows.c``, ``moved_difference``). ``kept``
    (M, N) CSR, ``slots`` (r,) rows of it; the rest as for :func:`at_pose`. Where a kept row is
    out of column order, the kept rows are sorted first (a copy). In parts of about equal entries
    on the cores at once from :data:`~pydynrad.dynamic.stale.PARALLEL_ENTRIES` entries.

    ``since``: for the rows it names whose row at the pose is not capped either, D is their
    last D with the entries whose presence changed since (hidden then and not now, or the
    reverse) made again, and the object columns: the same values bit for bit, reading a flag
    or two per entry instead of the static and kept rows whole (:class:`Since`). Used where both
    ``rows`` and ``kept`` are in canonical order (scipy's cached ``has_canonical_format``)."""
    from .. import _poserows
    from ..host.threads import cores, map_parts, row_parts
    from .stale import PARALLEL_ENTRIES

    starts, ends, indices, data, hidden, recip = _pose_spans("difference_at_pose", rows, hidden, recip, select)
    # Not wrapped again where it is CSR: a new wrapper forgets scipy's cached order flags.
    kept = kept if sp.issparse(kept) and kept.format == "csr" else sp.csr_matrix(kept)
    if recip.shape[1] != kept.shape[1]:
        raise InvalidInputError(f"object columns {recip.shape} and kept rows {kept.shape} do not match")
    slots = kept_slots(slots, len(starts), kept.shape[0])
    r_indptr, r_indices, r_data = native_csr(recip)
    flags, p_starts, p_ends, p_indices, p_data, hidden_prev, row_sums, first = \
        _since_inputs(since, rows, hidden, len(starts), kept.shape[1])
    capped = np.zeros(len(starts), np.uint8)

    def part(task):
        (a, z), (k_indptr, k_indices, k_data), use = task
        ra, rz, sl = r_indptr[a], r_indptr[z], slots[a:z]
        n = int((ends[a:z] - starts[a:z]).sum()) + int(rz - ra) + int((k_indptr[sl + 1] - k_indptr[sl]).sum()) \
            + int((p_ends[a:z] - p_starts[a:z]).sum())
        # Only D's entries are written (no page of the rest of the bound faulted in).
        indptr, out_indices, out_data = np.empty(z - a + 1, np.int64), np.empty(n, np.int32), np.empty(n)
        nnz = _poserows.moved_difference(starts[a:z], ends[a:z], indices, data, hidden, r_indptr[a:z + 1] - ra,
                                         r_indices[ra:rz], r_data[ra:rz], k_indptr, k_indices, k_data, sl,
                                         use[a:z], hidden_prev, row_sums[a:z], p_starts[a:z], p_ends[a:z],
                                         p_indices, p_data, first, indptr, out_indices, out_data, capped[a:z])
        return (indptr, out_indices[:nnz], out_data[:nnz]) if nnz >= 0 else a - 1 - nnz  # the row out of order

    work = np.concatenate([[0], np.cumsum(ends - starts)])
    parts = row_parts(work, cores() if work[-1] >= PARALLEL_ENTRIES else 1)
    for attempt in range(2):
        k_csr = native_csr(kept)
        # The last D is read only against kept rows in canonical order (it was made against them).
        use = flags if kept.has_canonical_format else np.zeros_like(flags)
        done = map_parts(part, [(p, k_csr, use) for p in parts])
        bad = [d for d in done if not isinstance(d, tuple)]
        if not bad:
            return PoseDifference(stacked_rows(done, recip.shape[1]), capped.view(bool))
        if attempt or np.any(np.diff(indices[starts[bad[0]]:ends[bad[0]]]) <= 0):
            break  # a static row out of order: at_pose's rows must be in order too
        kept = kept.copy()
        kept.sum_duplicates()  # scipy leaves sums of CSR matrices unsorted
    raise InvalidInputError(f"row {bad[0]}'s static columns are out of increasing order: difference_at_pose reads "
                            "sorted rows")


def _since_inputs(since: Since | None, rows: sp.csr_matrix, hidden: np.ndarray, r: int, n_cols: int) -> tuple:
    """(flags uint8 (r,), the last D's spans (starts, ends int64 (r,)), indices and data, the last
    mask uint8, row sums float64 (r,), first object column): :func:`difference_at_pose`'s
    "since" inputs, checked, or none to use."""
    empty = np.zeros(r, np.int64)
    none = (np.zeros(r, np.uint8), empty, empty, np.zeros(0, np.int32), np.zeros(0), np.zeros(0, np.uint8),
            np.zeros(r), 0)
    if since is None:
        return none
    flags, at = np.ascontiguousarray(since.rows, bool), np.asarray(since.last_row, np.int64)
    last = since.last
    if flags.shape != (r,) or at.shape != (r,) or np.shape(since.row_sums) != (r,) \
            or np.shape(since.hidden) != hidden.shape or not (sp.issparse(last) and last.format == "csr") \
            or last.shape[1] != n_cols or (r and (at.min() < -1 or at.max() >= last.shape[0])):
        raise InvalidInputError(f"since must give a flag, a row sum and a row of its last D (CSR, {n_cols} columns, "
                                f"or -1) for each of the {r} rows, and a mask of the same entries as hidden")
    if not (flags.any() and rows.has_canonical_format):
        return none
    indptr, indices, data = native_csr(last)
    held = flags & (at >= 0)
    starts, ends = np.where(held, indptr[at], 0), np.where(held, indptr[at + 1], 0)
    return (flags.view(np.uint8), starts, ends, indices, data, _mask_bytes(since.hidden),
            np.ascontiguousarray(since.row_sums, np.float64), int(since.first_object))


def stacked_rows(parts: list, n_cols: int) -> sp.csr_matrix:
    """One CSR matrix of ``n_cols`` columns from row parts ``[(indptr from 0, indices, data)]``
    stacked in order: one part as it is, more in one copy of their entries (scipy's vstack of
    the parts' matrices took 0.24 ms of a move's 2 ms merge on the bench's Cornell box)."""
    if len(parts) == 1:
        indptr, indices, data = parts[0]
        return sp.csr_matrix((data, indices, indptr), shape=(len(indptr) - 1, n_cols))
    first = np.cumsum([0] + [len(p[1]) for p in parts])
    indptr = np.concatenate([[0]] + [p[0][1:] + f for p, f in zip(parts, first)])
    return sp.csr_matrix((np.concatenate([p[2] for p in parts]), np.concatenate([p[1] for p in parts]), indptr),
                         shape=(len(indptr) - 1, n_cols))


def native_csr(m: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indptr int64, indices int32, data float64) of CSR ``m``, contiguous, as ``csrc/poserows.c``
    reads them (no copy where they already are: scipy's int32 indices for fewer than 2^31 columns)."""
    if m.shape[1] >= 2**31:
        raise InvalidInputError(f"rows of {m.shape[1]} columns need 64-bit column indices")
    return (np.ascontiguousarray(m.indptr, np.int64), np.ascontiguousarray(m.indices, np.int32),
            np.ascontiguousarray(m.data, np.float64))


def stale_rows(local: sp.csr_matrix, fresh_slots: np.ndarray, S: np.ndarray, moved_slots: np.ndarray,
               moved: np.ndarray, areas: np.ndarray) -> sp.csr_matrix:
    """The kept rows (M, N) after a move, for the slots not given fresh rows.

    ``local`` already holds the fresh rows of ``fresh_slots`` (the moved objects' patches, in
    ``moved_slots``, among them). The other rows that see a moved object, before or after,
    get its columns by reciprocity; where those would push a row's sum above 1 (it still sees
    what the object now hides), the object columns alone are scaled down to fill the row to 1.
    Only entries in the moved objects' columns change, so these rows need no slot of their
    own in the swap, and a pose that comes back gives back the same rows.
    """
    M, N = local.shape
    fresh = np.zeros(M, bool)
    fresh[fresh_slots] = True
    is_moved = np.zeros(N, bool)
    is_moved[moved] = True
    slot_of = np.full(N, -1)
    slot_of[S] = np.arange(M)
    A = np.asarray(areas, np.float64)
    # The moved objects' fresh rows give, by reciprocity, F[s, o] = A_o F[o, s] / A_s for every
    # other local s they see.
    obj = sp.csr_matrix(local[moved_slots])
    o_row = np.repeat(np.arange(len(moved_slots)), np.diff(obj.indptr))
    at = slot_of[obj.indices]
    use = (at >= 0) & ~fresh[np.maximum(at, 0)]
    r_row, r_col = at[use], moved[o_row[use]]
    r_val = A[r_col] * obj.data[use] / A[S[r_row]]
    # The stale rows' old entries in the moved columns go: a mask over the entries, cleared on
    # the fresh rows' runs, so that no row index per entry is formed (three times faster at
    # M = 1024, 426k entries); the kept rows' sums are the same sequential sums as before.
    indptr = local.indptr
    drop = is_moved[local.indices]
    fs = np.flatnonzero(fresh)
    lens = indptr[fs + 1] - indptr[fs]
    drop[np.repeat(indptr[fs] - (np.cumsum(lens) - lens), lens) + np.arange(lens.sum())] = False
    drop_row = np.searchsorted(indptr, np.flatnonzero(drop), side="right") - 1
    if not len(drop_row) and not len(r_row):
        return local
    keep = ~drop
    gone = np.zeros(M + 1, np.int64)
    np.cumsum(np.bincount(drop_row, minlength=M), out=gone[1:])
    kept = sp.csr_matrix((local.data[keep], local.indices[keep], indptr - gone), shape=(M, N))
    others = kept @ np.ones(N)
    objects = np.bincount(r_row, weights=r_val, minlength=M)
    scale = np.ones(M)
    over = (others + objects > 1.0) & (objects > 0)
    scale[over] = np.maximum(1.0 - others[over], 0.0) / objects[over]
    out = sp.csr_matrix(kept + sp.csr_matrix((r_val * scale[r_row], (r_row, r_col)), shape=(M, N)))
    out.eliminate_zeros()
    return out


class PoseRows:
    """Rows precomputed for poses of the objects known in advance (the paper's section 3.2).

    Keyed by the objects' transforms together (a row of a static patch depends on every
    object): for each configuration, the rows of the object patches and of the static patches
    that may see an object there (:func:`refresh_order`). A move to a stored configuration
    takes those rows from here instead of hemicubes. Made by :func:`precompute_poses`; held in
    memory, or read from a form-factor store's per-pose part (``store``, each file verified on
    read) with the last configuration read kept.
    """

    def __init__(self, n_patches: int, resolution: int, geometry: tuple[str, tuple[str, ...]], store=None) -> None:
        self.n_patches, self.resolution = int(n_patches), int(resolution)
        # (the static scene's geometry hash, each object's): rows of other geometry with the same
        # patch counts would be taken as these (:meth:`check`).
        self.geometry = (str(geometry[0]), tuple(map(str, geometry[1])))
        self.store = store
        self._rows: dict[bytes, tuple[np.ndarray, sp.csr_matrix]] = {}
        self._last: tuple[bytes, tuple | None] | None = None  # (key, entry) last read from the store
        # A move asks from two threads at once (the objects' rows on a pool thread, the static
        # rows here): one of them reads and verifies the file, the other waits for it.
        self._reading = threading.Lock()

    @staticmethod
    def geometry_of(scene, objects) -> tuple[str, tuple[str, ...]]:
        """The fingerprint :attr:`geometry` of rows made for static ``scene`` and ``objects``."""
        return scene.geometry_hash(), tuple(o.scene.geometry_hash() for o in objects)

    def check(self, scene, objects, resolution: int) -> None:
        """Raise InvalidInputError unless these rows are of ``scene`` with ``objects`` at ``resolution``."""
        n = len(scene) + sum(len(o) for o in objects)
        if self.n_patches != n or self.resolution != resolution:
            raise InvalidInputError(f"poses= holds rows of {self.n_patches} patches at R = {self.resolution}; this "
                                    f"scene with its objects has {n} patches at R = {resolution}")
        static, objs = self.geometry_of(scene, objects)
        if static != self.geometry[0]:
            raise InvalidInputError(f"poses= holds rows made for another static scene than {scene.name!r} (its "
                                    "geometry differs): precompute them for this one")
        if objs != self.geometry[1]:
            raise InvalidInputError(f"poses= holds rows made for other objects than {[o.name for o in objects]} (their "
                                    "geometry differs): precompute them for these")

    @staticmethod
    def key(transforms) -> bytes:
        return np.ascontiguousarray(np.asarray(transforms, np.float64)).tobytes()

    def add(self, transforms, patches: np.ndarray, rows: sp.csr_matrix) -> None:
        order = np.argsort(patches)
        patches, rows = np.asarray(patches, np.int64)[order], sp.csr_matrix(rows)[order]
        if self.store is None:
            self._rows[self.key(transforms)] = (patches, rows)
        else:
            self.store.write_pose(transforms, patches, rows)

    def get(self, transforms):
        """(sorted patch indices, their rows) stored for these transforms, or None."""
        key = self.key(transforms)
        if self.store is None:
            return self._rows.get(key)
        with self._reading:
            if self._last is None or self._last[0] != key:
                self._last = (key, self.store.read_pose(transforms))
            return self._last[1]

    def __contains__(self, transforms) -> bool:
        return self.key(transforms) in self._rows if self.store is None else self.store.has_pose(transforms)

    def __len__(self) -> int:
        return len(self._rows) if self.store is None else len(self.store.pose_files())

    @property
    def nbytes(self) -> int:
        """Host bytes of the rows held in memory (0 for a store's: read per configuration)."""
        return sum(p.nbytes + r.data.nbytes + r.indices.nbytes + r.indptr.nbytes for p, r in self._rows.values())


def _configurations(objs, poses):
    """Each configuration of ``poses`` as a list of validated transforms, one per object."""
    from ..geometry.objects import rigid_transform

    from ..checks import floats

    try:
        poses = list(poses)
    except TypeError:
        raise InvalidInputError(f"poses must be a sequence of configurations; got {type(poses).__name__}") from None
    for config in poses:
        config = floats(config, "a configuration of poses")
        transforms = [rigid_transform(t) for t in (config[None] if config.ndim == 2 else config)]
        if len(transforms) != len(objs):
            raise InvalidInputError(f"a configuration needs one transform per object ({len(objs)}); got {len(transforms)}")
        yield transforms


def stored_poses(scene, objects, store, resolution: int = 128) -> PoseRows:
    """The per-pose rows in form-factor ``store`` (a :class:`~pydynrad.FormFactorStore` of the
    static ``scene``) as :class:`PoseRows` for ``DynamicRadiosity(poses=...)``. Raises
    :class:`~pydynrad.rows.store.StoreMismatchError` for a store of another scene, or whose
    poses are of other objects or another resolution."""
    from ..checks import resolution as checked_resolution
    from ..geometry.objects import _objects
    from ..rows.store import StoreMismatchError

    objs = _objects(objects)
    if store.header["geometry_hash"] != scene.geometry_hash() or store.n_patches != len(scene):
        raise StoreMismatchError(f"form-factor store {store.path} is of another scene than {scene.name!r}")
    R = checked_resolution(resolution)
    store.check_pose_objects(objs, resolution=R)
    return PoseRows(len(scene) + sum(len(o) for o in objs), R, PoseRows.geometry_of(scene, objs), store=store)


def precompute_poses(scene, objects, poses, resolution: int = 128, device=None, store=None) -> PoseRows:
    """The rows of each configuration in ``poses`` for :class:`pydynrad.DynamicRadiosity`'s ``poses=``.

    ``poses``: a sequence of configurations, each a (4, 4) transform per object (a single
    (4, 4) per entry for one object): a keyframed path. Costs one hemicube per object patch
    and per static patch that may see an object, per configuration. With ``store`` (a
    :class:`~pydynrad.FormFactorStore` of ``scene``) the rows go into the store's per-pose part
    (a file per configuration; configurations already there are kept, so an interrupted run
    resumes) and the result reads them from there.
    """
    from ..checks import resolution as checked_resolution
    from ..formfactors import form_factors
    from ..geometry.objects import _objects, instanced

    objs = _objects(objects)
    R = checked_resolution(resolution)
    n_static = len(scene)
    if store is None:
        out = PoseRows(n_static + sum(len(o) for o in objs), R, PoseRows.geometry_of(scene, objs))
    else:
        store.set_pose_objects(objs, resolution=R)
        out = stored_poses(scene, objs, store, R)
    for transforms in _configurations(objs, poses):
        world = instanced(scene, objs, transforms)
        if world.bvh.transforms in out:
            continue
        spheres = [o.bounding_sphere(T) for o, T in zip(objs, transforms)]
        seeing, _ = refresh_order(world.centers[:n_static], world.normals[:n_static], spheres)
        patches = np.concatenate([seeing, np.arange(n_static, len(world))])
        out.add(world.bvh.transforms, patches, form_factors(world, R, rows=patches, device=device))
    return out


class WorldRows:
    """Rows of F for a static scene with objects (a :class:`~pydynrad.rows.sources.RowSource`).

    Object patches' rows are hemicubes of the current world scene (or stored in ``poses``).
    Static rows come from ``static_ff`` (the static scene's (N, N) F or row source) with the
    entries the objects hide dropped (:func:`hidden_entries`), their object columns by
    reciprocity from the objects' current rows, and capped to a sum of 1 (:func:`at_pose`),
    except those ``poses`` holds for the current configuration (hemicubes of the world there);
    with ``static_ff=None`` they are hemicubes of the world too, and exact at the current poses.
    """

    def __init__(self, world, n_static: int, objects, static_ff, static_scene, resolution: int,
                 device, poses: PoseRows | None = None) -> None:
        if poses is not None:
            if not isinstance(poses, PoseRows):
                raise InvalidInputError(f"poses= must be PoseRows (precompute_poses, stored_poses); got "
                                        f"{type(poses).__name__}")
            poses.check(static_scene, objects, resolution)
        self.poses = poses
        self.hemicubes = HemicubeRows(world, resolution, device)
        self.device = device
        self.n_patches = len(world)
        self.n_static = int(n_static)
        self.objects_moving = list(objects)
        self.object_patches = np.arange(self.n_static, self.n_patches)
        self.static = None if static_ff is None else LocalRows(static_scene, static_ff, resolution, device)
        self.object_rows: sp.csr_matrix | None = None  # rows of object_patches at the current poses
        self._tracing = None  # a Future of fresh(object_patches) while refresh() traces them (objects() waits)
        self._meanwhile = None  # refresh()'s work to run before objects() first waits for that trace
        self._at_pose: tuple[np.ndarray, sp.csr_matrix] | None = None  # rows made at the current poses (:meth:`_at`)
        self._outside: tuple[np.ndarray, sp.csr_matrix] | None = None  # (patches, their rows) last gathered
        # Where the objects were when the far field's coarse level was made (the first poses).
        self._first_spheres = [o.bounding_sphere() for o in self.objects_moving]
        self._in_view: np.ndarray | None = None  # (N,) bool, per pose: :meth:`in_view`
        self._first_view: np.ndarray | None = None  # its part for the first poses
        self.pose = 0  # moves so far: the number of the poses the world is at
        # (pose, hidden over the static F's entries, capped (n_static,) bool) of the last pass of
        # :meth:`differences` over the pre-test: what the next pose's differences start from
        # (a byte per entry of F held between moves: 0.45 MB on the bench's box, 35 MB on the village).
        self._made: tuple[int, np.ndarray, np.ndarray] | None = None
        self._row_sums: np.ndarray | None = None  # (n_static,) the static F's row sums, once

    @property
    def world(self):
        return self.hemicubes.scene

    def move(self, world) -> None:
        """The objects moved: later rows are of ``world`` (the objects' own rows are hemicubes
        when first needed, unless set in :attr:`object_rows`)."""
        self.hemicubes.scene = world
        self.object_rows = None
        self._at_pose, self._outside, self._in_view = None, None, None
        self.pose += 1

    def in_view(self) -> np.ndarray:
        """(N,) bool: the static patches whose view an object changes, by a form factor of at
        least :data:`VIEW_FORM_FACTOR` to its bounding sphere at its current pose or at its
        first (where the far field's coarse level has it; computed once per pose)."""
        if self._first_view is None:  # the first poses' part, once
            self._first_view = self._seeing(self._first_spheres)
        if self._in_view is None:
            self._in_view = self._first_view | self._seeing([o.bounding_sphere(T) for o, T in
                                                             zip(self.objects_moving, self.world.bvh.transforms)])
        return self._in_view

    def _seeing(self, spheres) -> np.ndarray:
        """(N,) bool: static patches with a form factor (:func:`sphere_form_factor`) of at least
        :data:`VIEW_FORM_FACTOR` to one of ``spheres`` [(centre, radius), ...]."""
        world = self.world
        P, n = world.centers[: self.n_static], world.normals[: self.n_static]
        view = np.zeros(self.n_patches, bool)
        for c, r in spheres:
            view[: self.n_static] |= sphere_form_factor(P, n, c, r) >= VIEW_FORM_FACTOR
        return view

    def gather_outside(self, outside: np.ndarray, L: np.ndarray, B: np.ndarray) -> np.ndarray:
        """(len(outside), 3) B on the patches ``outside`` the local set: ``L + P F B`` with their
        rows at the current poses (:meth:`rows`) for those :meth:`gathered` chooses (every one,
        or in a large scene those whose view an object changes, :meth:`in_view`), so the far
        field's patches see the objects where they are, their light and their shadows; ``B`` as
        given (the far field's) for the others, which the objects change by less than
        :data:`VIEW_FORM_FACTOR` of the light around them, as the coarse level's own error does."""
        outside = np.asarray(outside, np.int64)
        chosen = self.gathered(outside)
        near = outside[chosen]
        if self._outside is None or not np.array_equal(self._outside[0], near):
            rows = self.rows(near) if len(near) else sp.csr_matrix((0, self.n_patches))
            self._outside = (near.copy(), rows)
        out = B[outside].copy()
        out[chosen] = L[near] + self.world.albedo[near].astype(np.float64) * rows_product(self._outside[1], B)
        return out

    def gathered(self, outside: np.ndarray) -> np.ndarray:
        """(len(outside),) bool: which of the patches ``outside`` the local set
        :meth:`gather_outside` gathers at the poses. Every one while they are at most
        :data:`GATHER_ALL_OUTSIDE` times the local set (the gather is then a final gather of
        the far field too, cheap beside the frame), else those :meth:`in_view`."""
        outside = np.asarray(outside, np.int64)
        if len(outside) <= GATHER_ALL_OUTSIDE * (self.n_patches - len(outside)):
            return np.ones(len(outside), bool)
        return self.in_view()[outside]

    def objects(self) -> sp.csr_matrix:
        """The objects' rows at the current poses (computed once per pose)."""
        if self._tracing is not None:
            meanwhile, self._meanwhile = self._meanwhile, None
            if meanwhile is not None:
                meanwhile()
            tracing, self._tracing = self._tracing, None
            self.object_rows = tracing.result()[0]
        if self.object_rows is None:
            self.object_rows = self.fresh(self.object_patches)[0]
        return self.object_rows

    def fresh(self, idx) -> tuple[sp.csr_matrix, int]:
        """Rows ``idx`` of the world as it is: from ``poses`` where it holds them for the current
        transforms, else hemicubes; and how many hemicubes that took."""
        return self.fresh_queued(idx)()

    def fresh_queued(self, idx):
        """:meth:`fresh` with its hemicubes queued on the device now: a callable (to call once,
        from any thread) that waits for them and returns what :meth:`fresh` does."""
        idx = np.asarray(idx, np.int64)
        stored = self._stored()
        miss = idx if stored is None else idx[~np.isin(idx, stored[0])]
        made = self.hemicubes.queued(miss) if len(miss) else lambda: sp.csr_matrix((0, self.n_patches))
        return lambda: self._stored_or(idx, lambda _: sp.csr_matrix(made(), dtype=np.float64), stored)

    def _stored(self):
        """(patches, rows) that ``poses`` holds for the current transforms, or None."""
        return None if self.poses is None else self.poses.get(self.world.bvh.transforms)

    def _stored_or(self, idx: np.ndarray, make, stored) -> tuple[sp.csr_matrix, int]:
        """Rows ``idx``: those ``stored`` (``poses``'s rows for the current transforms, or None)
        holds from there, the others by ``make(missing indices)``; and how many ``make`` made."""
        if stored is None:
            return make(idx), len(idx)
        patches, rows = stored  # patches sorted (PoseRows.add)
        have = np.isin(idx, patches)
        held = rows[np.searchsorted(patches, idx[have])]
        if have.all():
            return sp.csr_matrix(held, dtype=np.float64), 0
        miss = idx[~have]
        return _in_order(held, make(miss), have), len(miss)

    def _at(self, idx: np.ndarray, make, also: np.ndarray | None = None) -> sp.csr_matrix:
        """Rows ``idx``, each made once per pose by ``make(missing indices)`` and kept until the
        next move; rows ``also`` missing are made in the same call, for later. The rows returned
        may share memory with those kept (every caller copies before it changes them)."""
        if self._at_pose is None:
            self._at_pose = (np.full(self.n_patches, -1), sp.csr_matrix((0, self.n_patches)))
        where, held = self._at_pose
        wanted = idx if also is None else np.concatenate([idx, also])
        missing = wanted[where[wanted] < 0]
        if len(missing):
            # In the order asked (first occurrences): the first call after a move then takes its
            # rows as one run of what it made, not a copy through an index.
            miss = missing[np.sort(np.unique(missing, return_index=True)[1])]
            made = sp.csr_matrix(make(miss))  # before the index: a make() that raises leaves it as it was
            where[miss] = held.shape[0] + np.arange(len(miss))
            held = made if not held.shape[0] else sp.vstack([held, made], format="csr")
            self._at_pose = (where, held)
        at = where[idx]
        if len(at) and np.array_equal(at, np.arange(at[0], at[0] + len(at))):  # a view (scipy's slice copies)
            a, z = held.indptr[at[0]], held.indptr[at[0] + len(at)]
            indptr = held.indptr[at[0]: at[0] + len(at) + 1]
            return sp.csr_matrix((held.data[a:z], held.indices[a:z], indptr - a if a else indptr),
                                 shape=(len(at), held.shape[1]))
        return held[at]

    def _static_rows(self, s: np.ndarray) -> sp.csr_matrix:
        """Rows of static patches ``s`` at the current poses: those ``poses`` holds for them
        (hemicubes of the world there: no estimate, and no pass over their entries), the others
        from the static F (:meth:`_from_static`: patches that cannot see an object there, whose
        pre-test finds nothing to hide)."""
        return self._stored_or(np.asarray(s, np.int64), self._from_static, self._stored())[0]

    def _from_static(self, s: np.ndarray) -> sp.csr_matrix:
        """Rows of static patches ``s`` at the current poses, from the static F (class docstring)."""
        return at_pose(*self._pose_inputs(s))

    def _pose_inputs(self, s: np.ndarray) -> tuple:
        """(rows, hidden, object columns, select): :func:`at_pose`'s inputs for static patches
        ``s``, their rows of the static F read where they lie in an F held in memory (a copy of
        them was 1.2 ms of a move at 426k entries), else fetched from its source."""
        F, select = (self.static.csr, s) if self.static.csr is not None else (self.static.rows(s), np.arange(len(s)))
        world = self.world
        hidden = hidden_entries(F, s, world.centers, world.normals, self.objects_moving, world.bvh.transforms,
                                self.device, select)
        return F, hidden, reciprocal_columns(s, self.objects(), self.object_patches, world.areas, self.n_patches), select

    def differences(self, s: np.ndarray, kept: sp.csr_matrix, at: np.ndarray, also: np.ndarray | None = None,
                    held=None) -> sp.csr_matrix:
        """(len(s), N) CSR: the rows of static patches ``s`` at the current poses (:meth:`rows`)
        minus ``kept[at]`` (``kept`` (M, N), ``at`` (len(s),) its rows). From the static F they
        are never made: :func:`difference_at_pose` merges each with its kept row as it is made
        (writing a move's ~450k entries at the pose, then reading them back to merge them, was
        2.4-3.9 ms of the bench's moving frame; AMD EPYC Zen 4, 2026-12-06). Rows ``also``
        missing at the pose are made in the same pass (one pre-test of both) and kept for the
        pose, as :meth:`rows` keeps them (distinct patches). Rows ``poses`` holds come from
        there, merged.

        ``held``: the stale rows (:class:`~pydynrad.dynamic.stale.StaleRows`) whose D, where put
        at the last pose by this pass and held since against the same kept rows, the pass starts
        from (:class:`Since`): it then reads the rows' hidden flags then and now, not their
        entries."""
        from .stale import rows_minus

        s, at = np.asarray(s, np.int64), np.asarray(at, np.int64)
        also = np.empty(0, np.int64) if also is None else np.asarray(also, np.int64)
        if len(np.unique(also)) != len(also):
            raise InvalidInputError("differences() needs distinct patches in also")
        if self._stored() is not None:
            return rows_minus(self._at(s, self._static_rows, also), kept, at)
        if self._at_pose is not None:  # rows already made at this pose are not made again
            also = also[self._at_pose[0][also] < 0]
        both = np.concatenate([s, also])
        F, hidden, recip, select = self._pose_inputs(both)
        if len(also):
            def made(miss):
                # _at() asks for all of them, in order: distinct, none at the pose yet (a dict from
                # patch to place in both, for any order, was 0.2 ms a move).
                if not np.array_equal(miss, also):
                    raise PydynradError("differences(): the outside rows asked for are not those made")
                return at_pose(F, hidden, recip[len(s):], select[len(s):])

            self._at(also, made)
        since = self._since(s, at, held) if F is self.static.csr else None
        D, capped = difference_at_pose(F, hidden, recip[: len(s)], kept, at, select[: len(s)], since)
        if F is self.static.csr:
            flags = np.ones(self.n_static, bool)  # rows not made here: never started from
            flags[s] = capped
            self._made = (self.pose, hidden, flags)
        return D

    def _since(self, s: np.ndarray, at: np.ndarray, held) -> Since | None:
        """What :meth:`differences` at this pose starts from for static patches ``s`` in slots
        ``at``: their D that ``held`` put at the last pose, where that pose's pass made their
        rows uncapped."""
        made = self._made  # over the same static F's entries as this pose's mask
        if held is None or made is None or made[0] != self.pose - 1:
            return None
        flags, last, last_row = held.since(at, made[0])
        flags &= ~made[2][s]
        if not flags.any():
            return None
        if self._row_sums is None:
            self._row_sums = np.asarray(self.static.csr.sum(axis=1), np.float64).ravel()
        return Since(flags, made[1], self._row_sums[s], last, last_row, self.n_static)

    def rows(self, idx) -> sp.csr_matrix:
        idx = np.asarray(idx, np.int64)
        if self.static is None:
            return self._at(idx, lambda miss: self.fresh(miss)[0])
        obj = idx >= self.n_static
        static = self._at(idx[~obj], self._static_rows)
        if not obj.any():
            return static
        return _in_order(static, self.objects()[idx[obj] - self.n_static], ~obj)

    def refresh(self, moved: np.ndarray, candidates: np.ndarray, slots: np.ndarray, kept: sp.csr_matrix, spheres,
                budget: int | None, weight: np.ndarray | None, correct: bool = False,
                outside: np.ndarray | None = None, meanwhile=None,
                held=None) -> tuple[np.ndarray, sp.csr_matrix, int, tuple | None]:
        """Which of the static ``candidates`` (patch indices in ``slots``; ``kept`` the local
        set's rows (M, N) in slot order, so theirs are ``current = kept[slots]``, sliced only
        when the budget ranks them) to refresh after a move, and the new rows of ``moved``
        (object patches) and of those.

        Hemicube rows (no static F): the ``budget`` candidates that see the most of the objects'
        old and new bounding ``spheres`` (:func:`refresh_order`), by hemicube. With a static F:
        every candidate that may see a sphere gets its row at the new poses from the static F
        (:meth:`rows`, no hemicube; kept for the pose), and the ``budget`` whose gathered light
        that changes most relative to their own are kept (a shortlist by solid angle first
        loses: 6.6% mean pixel error at 32 rows against 4.5%, bench/objects.py's scene): ``A_s rho_s |(new_s - current_s) w| / w_s`` with
        ``w`` (N,) the last radiosity summed over channels (ones before any), the row's share of
        the mean relative error over the surface. At budget 0 only when ``correct``, and then
        only their differences from their kept rows are made, not the rows (:meth:`differences`).
        Returns (indices into ``candidates``, rows of ``moved`` then of those, hemicubes
        computed, left): with ``correct``, ``left`` is (indices into ``candidates``, D) for the
        candidates made but not kept (with a static F and a budget that leaves some): their rows
        at the new poses minus their kept rows ``kept[slots[...]]``, for
        :class:`~pydynrad.dynamic.stale.StaleRows`; else None.
        ``outside``: patches whose rows the frame will gather at the new poses
        (:meth:`gather_outside`): with a static F made in the same pass as the candidates'.
        ``meanwhile``: a callable run once while the objects' hemicubes trace on the device,
        after the static rows' pre-test on the host (with hemicube rows: before they are
        made), so that the host's work of the caller overlaps the trace. ``held``: the stale
        rows the differences at budget 0 may start from (:meth:`differences`)."""
        from .stale import rows_minus

        world = self.world
        if self.static is None:
            order, _ = refresh_order(world.centers[candidates], world.normals[candidates], spheres)
            order = order[:budget]
            if meanwhile is not None:
                meanwhile()
            rows, hemicubes = self.fresh(np.concatenate([moved, candidates[order]]))
            return order, rows, hemicubes, None
        tracing = None
        try:
            if self.object_rows is None:
                # The objects' hemicubes trace on the device while this thread runs the static
                # rows' pre-test on the host; a pool thread waits for them, and their reciprocal
                # columns for it (objects()). The CPU device left ~0.35 of 2 cores idle while
                # tracing them alone: 1.5 ms of a move (t_move median 20.8-22.4 -> 18.7-20.1 ms,
                # Cornell box, 2-core Xeon). Queued by this thread, first: the pool thread only
                # waits, and takes the interpreter's lock once they are traced (queued by it, both
                # threads had wanted the lock for small numpy steps at once: refresh_order took 3
                # ms instead of 0.3, and the trace started after it; Zen 4, 2026-12-06).
                from ..host.threads import pool

                tracing = self._tracing = pool().submit(self.fresh_queued(self.object_patches))
                self._meanwhile = meanwhile
            elif meanwhile is not None:
                meanwhile()
            order, _ = refresh_order(world.centers[candidates], world.normals[candidates], spheres)
            # Objects that did not move are seen by those that did: their rows, new anyway, go in too.
            still = np.flatnonzero(candidates >= self.n_static)
            order = order[candidates[order] < self.n_static] if budget != 0 or correct else order[:0]
            also = None if outside is None else outside[self.gathered(outside)]
            if budget == 0:  # every row made is left stale: only their differences are wanted
                left = (order, self.differences(candidates[order], kept, slots[order], also, held))
                order, new = order[:0], sp.csr_matrix((0, self.n_patches))
            else:
                new, left = self._at(candidates[order], self._static_rows, also), None
        except BaseException:
            self._meanwhile = None  # the refresh failed: no work of the caller's to overlap
            raise
        finally:
            try:
                if self._tracing is not None:  # never a trace left running past the call (nor its meanwhile not run)
                    self.objects()
            finally:
                self._meanwhile = None
        hemicubes = 0 if tracing is None else tracing.result()[1]
        if budget != 0 and budget is not None and len(order) > budget:
            w = np.ones(self.n_patches) if weight is None else np.asarray(weight, np.float64)
            keep = np.ones(self.n_patches)
            keep[self.object_patches] = 0.0
            change = np.abs((new - kept[slots[order]]) @ (keep * w))
            p = candidates[order]
            rho = world.albedo[p].astype(np.float64).mean(axis=1)
            score = world.areas[p] * rho * change / np.maximum(w[p], 1e-3 * max(float(w.mean()), 1e-300))
            best = np.argsort(-score, kind="stable")[:budget]
            best = best[score[best] > 0]
            rest = np.setdiff1d(np.arange(len(order)), best)
            left = (order[rest], rows_minus(new[rest], kept, slots[order[rest]])) if correct else None
            order, new = order[best], new[best]
        rows = self.object_rows[np.concatenate([moved, candidates[still]]) - self.n_static]
        return np.concatenate([still, order]), sp.vstack([rows, new], format="csr"), hemicubes, left if correct else None


def _in_order(first: sp.csr_matrix, second: sp.csr_matrix, in_first: np.ndarray) -> sp.csr_matrix:
    """One float64 CSR of rows asked for in order: row i the next of ``first`` where
    ``in_first[i]``, else the next of ``second``."""
    order = np.argsort(np.concatenate([np.flatnonzero(in_first), np.flatnonzero(~in_first)]), kind="stable")
    return sp.csr_matrix(sp.vstack([first, second], format="csr")[order], dtype=np.float64)


def swap_chunks(slots: np.ndarray, size: int) -> list[np.ndarray]:
    """``slots`` cut into batches of at most ``size`` (the swap size of the device kernels)."""
    if size < 1:
        raise InvalidInputError(f"swap size must be >= 1; got {size}")
    return [slots[i:i + size] for i in range(0, len(slots), size)]
