"""Hemicube form factors by ray casting through the patch BVH (kernels/hemicube.cl).

Patch i's row of F comes from hemicubes on it: every pixel casts one ray, and the pixel's
delta form factor (its exact cosine-weighted solid angle, computed once per resolution on the
host) goes to the nearest patch the ray meets from the front. A back face occludes and
receives nothing; a ray that leaves the scene takes its share with it, so rows sum to 1 in
closed scenes and to less in open ones.

F[i, j] is the area average over patch i of the point-to-patch factor; one hemicube at the
centre is a one-point rule for that average, biased where the factor is peaked (under a small
source, the centre sees more of it than the patch does on average). ``samples`` > 1 averages
that many hemicubes, one at the centroid of each stratum of the patch's midpoint subdivision
(equal areas), each at resolution R / sqrt(samples): the same rays per row.

Rows are computed in blocks: the device writes each scanline's pixels run-length encoded
(patch, weight: the difference of the pixel weights' prefix sums at the run's ends), the host
sums duplicates into CSR. Memory stays bounded by the block, whatever N.

See docs/design.md, 'Hemicube form factors'.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.sparse as sp

from . import _runs
from .checks import integer, patch_indices
from .checks import resolution as checked_resolution
from .defaults import RESOLUTION
from .device.devices import device_or_default
from .device.launch import enqueue_kernel, float4, global_size, hemicube_tiles, ray_work_group
from .errors import InvalidInputError, OutOfMemoryError
from .geometry.loading import checked_scene
from .geometry.scene import SURFACE_OFFSET
from .host.memory import available_host_bytes
from .progress import progress_bar

__all__ = [
    "checked_samples",
    "form_factors",
    "hemicube_blocks",
    "hemicube_runs",
    "pixel_form_factors",
    "sample_points",
    "stack_blocks",
    "CLUSTER_RESOLUTION",
]


#: Bytes of run buffers of the two blocks in flight (8 bytes per pixel slot); bounds memory for any N.
BLOCK_BYTES = 128 * 2**20
#: Blocks a run is cut into at least (when each keeps MIN_BLOCK_ROWS patches): the host's CSR
#: work on one block overlaps the device's tracing of the next.
OVERLAP_BLOCKS = 8
MIN_BLOCK_ROWS = 64

#: The default hemicube resolution of the far field's patch-to-cluster form factors G: the lowest
#: whose own error stays well inside the far field's 1% target (one step lower comes too close to
#: it), for a small share of F's rays; see docs/decisions/0021-far-field-without-f.md.
CLUSTER_RESOLUTION = 24

#: Peak host memory of :func:`pixel_form_factors` per R^2, rounded up: 708 bytes measured at
#: R = 1024 and 2048 (the pixels' corner polygons in float64), so R = 4096 needs 11 GiB.
PIXEL_WEIGHT_BYTES_PER_R2 = 720


def _polygon_form_factor(corners: np.ndarray) -> np.ndarray:
    """Form factor from a differential area at the origin, normal +z, to polygons.

    ``corners``: (..., K, 3) polygon vertices in order. Lambert's contour formula:
    F = 1/(2 pi) |sum_k angle(r_k, r_k+1) * z.(r_k x r_k+1) / |r_k x r_k+1||, exact.
    """
    r = corners / np.linalg.norm(corners, axis=-1, keepdims=True)
    r_next = np.roll(r, -1, axis=-2)
    cross = np.cross(r, r_next)
    sin = np.linalg.norm(cross, axis=-1)
    angle = np.arctan2(sin, np.sum(r * r_next, axis=-1))
    return np.abs(np.sum(angle * cross[..., 2] / sin, axis=-1)) / (2 * np.pi)


@lru_cache(maxsize=16)
def pixel_form_factors(resolution: int) -> np.ndarray:
    """(3R, R) float64 delta form factors of the hemicube's pixels, in the kernel's layout.

    Rows 0..R-1 are the top face's scanlines, then R/2 scanlines per side face (see
    kernels/hemicube.h). Normalised to sum to 1 (analytically they already do, to rounding).
    """
    R, H = resolution, resolution // 2
    need, have = PIXEL_WEIGHT_BYTES_PER_R2 * R * R, available_host_bytes()
    if need > have:
        raise OutOfMemoryError(
            f"hemicube resolution {R} needs about {need / 2**30:.1f} GiB of host memory for its "
            f"pixel weights; {have / 2**30:.1f} GiB is available. Use a lower resolution"
        )
    edges = -1.0 + 2.0 * np.arange(R + 1) / R  # pixel boundaries across a face
    heights = 2.0 * np.arange(H + 1) / R  # pixel boundaries up a side face
    u0, u1 = edges[:-1], edges[1:]
    # Top face: pixel (x, s) spans [u0[x], u1[x]] x [u0[s], u1[s]] at z = 1.
    uu0, vv0 = np.meshgrid(u0, u0)
    uu1, vv1 = np.meshgrid(u1, u1)
    one = np.ones_like(uu0)
    top = np.stack([np.stack(c, -1) for c in ((uu0, vv0, one), (uu1, vv0, one), (uu1, vv1, one), (uu0, vv1, one))], -2)
    # Side face 0, (1, a, h): pixel (x, r) spans a in [u0[x], u1[x]], h in [heights[r], heights[r+1]].
    aa0, hh0 = np.meshgrid(u0, heights[:-1])
    aa1, hh1 = np.meshgrid(u1, heights[1:])
    one = np.ones_like(aa0)
    side = np.stack([np.stack(c, -1) for c in ((one, aa0, hh0), (one, aa1, hh0), (one, aa1, hh1), (one, aa0, hh1))], -2)
    # The four sides are rotations of side 0 about z, so their pixels weigh the same.
    w = np.concatenate([_polygon_form_factor(top)] + [_polygon_form_factor(side)] * 4)
    return w / w.sum()


@lru_cache(maxsize=8)
def _stratum_centroids(levels: int) -> np.ndarray:
    """(4**levels, 3) barycentric centroids of a triangle's midpoint subdivision, ``levels`` deep."""
    tris = np.eye(3)[None]  # (T, corner, barycentric)
    for _ in range(levels):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
        tris = np.concatenate([np.stack(t, 1) for t in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    return tris.mean(axis=1)


def _sample_levels(samples) -> int:
    """L for ``samples`` = 4**L hemicubes per row (the strata of L levels of midpoint subdivision)."""
    k = integer(samples, "samples", 1, 4**6)
    levels = int(round(np.log(k) / np.log(4)))
    if 4**levels != k:
        raise InvalidInputError(
            f"samples must be a power of 4 (1, 4, 16, ...: the strata of a triangle's midpoint subdivision); got {k}"
        )
    return levels


def checked_samples(samples, resolution: int) -> int:
    """Hemicubes per row: 4**L, with R / 2**L an even resolution (each sample's hemicube).

    The one rule for ``samples`` wherever it is given (form factors, files, stores, rows on
    demand, the CLI): InvalidInputError naming the problem otherwise.
    """
    levels = _sample_levels(samples)
    k = 4**levels
    if resolution % (2 << levels):
        raise InvalidInputError(
            f"samples={k} splits resolution {resolution} into {k} hemicubes of resolution "
            f"{resolution} / {2**levels}, which must be an even integer"
        )
    return k


def sample_points(scene, rows, samples: int = 1) -> np.ndarray:
    """(len(rows), samples, 3) float64 hemicube origins of patches ``rows``, in the scene's frame.

    The patch centre for one sample; else the centroids of the 4**L triangles of the patch's
    midpoint subdivision L levels deep (equal areas), in :func:`_stratum_centroids`' order.
    ``samples`` must be a power of 4 and ``rows`` patch indices (InvalidInputError otherwise).
    """
    levels = _sample_levels(samples)
    scene = checked_scene(scene)
    rows = patch_indices(rows, len(scene), "rows")
    if levels == 0:
        return scene.centers[rows][:, None]
    return np.einsum("mc,rcx->rmx", _stratum_centroids(levels), scene.triangles[rows])


def _runs_to_csr(patch, weight, count, n_cols: int) -> sp.csr_matrix:
    """Sum each row's runs into a CSR block: patch/weight (B, K 3R, R), count (B, K 3R) for K
    hemicubes per row.

    Native (``csrc/runs.c``): only the runs are read, not the whole (B, K 3R, R) buffers (a
    scanline holds ~15 runs of 64 pixels in the village), and duplicates (a patch seen on
    several scanlines) are summed in float64 in the order the runs come: up to 2^16 columns in a
    dense row whose columns a bitmap lists in order, beyond it each row's runs sorted by column
    with a stable radix sort and runs of one column summed where they meet.
    """
    B, S, R = patch.shape
    count = np.ascontiguousarray(count, np.int32)
    most = int(count.sum())  # entries at most: one per run
    indptr, indices, data = np.empty(B + 1, np.int64), np.empty(most, np.int32), np.empty(most)
    nnz = _runs.to_csr(
        np.ascontiguousarray(patch, np.int32),
        np.ascontiguousarray(weight, np.float32),
        count,
        R,
        int(n_cols),
        indptr,
        indices,
        data,
    )
    return sp.csr_matrix((data[:nnz].copy(), indices[:nnz].copy(), indptr), shape=(B, n_cols))


def hemicube_blocks(
    scene,
    resolution: int,
    rows,
    device=None,
    progress: bool | None = None,
    *,
    desc: str = "form factors",
    clusters: tuple[np.ndarray, np.ndarray, int] | None = None,
    samples: int = 1,
):
    """Rows of hemicube form factors in bounded blocks: yields one float64 CSR block at a time.

    The one block loop behind :func:`form_factors` and
    :func:`pydynrad.farfield.gather.cluster_form_factors`. Without ``clusters`` a block is
    (b, N): F's rows. With ``clusters = (labels, scale, C)`` (per patch: its column in [0, C)
    or -1, and its weight) the device records ``labels[patch]`` instead of the patch and weighs
    each pixel by ``scale[patch]``, so a block is (b, C): rows of F Pr for the prolongation
    Pr[i, labels[i]] = scale[i]. Each row averages ``samples`` hemicubes of resolution
    R / sqrt(samples) (see the module's docstring). ``rows``, ``resolution`` and ``samples``
    are checked here, and the first block is queued on the device before this returns (as
    :func:`hemicube_runs`).
    """
    scene = checked_scene(scene)
    n_cols = len(scene) if clusters is None else clusters[2]
    runs = hemicube_runs(scene, resolution, rows, device, progress, desc=desc, clusters=clusters, samples=samples)
    return (_runs_to_csr(*r, n_cols) for r in runs)


def hemicube_runs(
    scene,
    resolution: int,
    rows,
    device=None,
    progress: bool | None = None,
    *,
    desc: str = "form factors",
    clusters: tuple[np.ndarray, np.ndarray, int] | None = None,
    samples: int = 1,
):
    """The device's side of :func:`hemicube_blocks`: an iterator of each block's run-length
    scanlines ``(patch, weight, count)`` as read back, (b, K 3R, R) int32 and float32 and
    (b, K 3R) int32 for K = ``samples`` hemicubes per row (see kernels/hemicube.cl), before any
    host work. Block b + 1 is traced while the caller works on block b. The first block is
    queued before this returns: a caller may queue it from one thread and read it from another
    (a moving object's hemicubes, queued beside the frame's other host work)."""
    import pyopencl as cl

    dev = device_or_default(device)
    R_total = checked_resolution(resolution)
    K = checked_samples(samples, R_total)
    R = R_total // int(round(np.sqrt(K)))  # each sample's hemicube
    if 3 * R_total * R_total * 4 > dev.max_alloc_bytes:
        raise InvalidInputError(
            f"resolution {R_total} needs more memory per hemicube than {dev.name} allows in one buffer"
        )
    scene = checked_scene(scene)
    n = len(scene)
    rows = np.arange(n, dtype=np.int32) if rows is None else patch_indices(rows, n, "rows").astype(np.int32)
    if len(rows) == 0:
        return iter(())
    S = 3 * R
    per_row = K * S * R * 8
    # Two blocks in flight (see below), each at most half of BLOCK_BYTES, and about
    # OVERLAP_BLOCKS blocks in all so that even a small scene overlaps host and device work.
    block = int(
        max(1, min(len(rows), BLOCK_BYTES // (2 * per_row), max(MIN_BLOCK_ROWS, -(-len(rows) // OVERLAP_BLOCKS))))
    )
    tiles, wg = hemicube_tiles(dev), ray_work_group(dev)
    defines, extra = tiles.defines(R), []
    if K > 1:
        defines["HC_SAMPLES"] = K
    # A row's K hemicubes are K * S scanlines of one block row; each weighs 1 / K.
    weights = pixel_form_factors(R) / K
    if clusters is None:
        # Prefix sums along each of a hemicube's 3R scanlines, in float64, then float32 for the
        # device, which differences them at each run's ends.
        weights_cum = np.zeros((S, R + 1))
        np.cumsum(weights, axis=1, out=weights_cum[:, 1:])
        extra = [dev.to_device(weights_cum.astype(np.float32))]
    else:
        labels, scale, _ = clusters
        defines["HC_CLUSTERS"] = 1
        extra = [
            dev.to_device(np.ascontiguousarray(a, dtype=t))
            for a, t in ((labels, np.int32), (scale, np.float32), (weights, np.float32))
        ]
    nodes, tris, order = scene.bvh.buffers(dev)
    normals = scene.patch_buffers(dev)[1]
    mf = cl.mem_flags
    # Two sets of output buffers: block b + 1 traces on the device while the host turns block
    # b's runs into CSR (numpy, one core), instead of each side waiting for the other. Row
    # indices go through preallocated buffers too (a buffer made from host memory waited for
    # the queue to drain on PoCL), and the read-back of block b + 1 is enqueued only after
    # block b's host work: PoCL's reads wait for the kernel before them even when not blocking.
    buffers = [
        tuple(cl.Buffer(dev.context, mf.WRITE_ONLY, block * K * S * w) for w in (R * 4, R * 4, 4)) for _ in range(2)
    ]
    # Each block's rows, then the instance each row's rays skip (BVH.own_instances), in one copy.
    idx_bufs = [cl.Buffer(dev.context, mf.READ_ONLY, 2 * block * 4) for _ in range(2)]
    org_bufs = [cl.Buffer(dev.context, mf.READ_ONLY, block * K * 16) for _ in range(2)]
    # Each block's origins and rows live until the next copy into the same buffer.
    org_host, idx_host = [None, None], [None, None]
    eps = np.float32(scene.frame.length(SURFACE_OFFSET * scene.ray_scale))

    def launch(first: int, k: int) -> int:
        idx = np.ascontiguousarray(rows[first : first + block])
        org_host[k] = float4(scene.frame.points(sample_points(scene, idx, K).reshape(-1, 3)))
        idx_host[k] = np.concatenate([idx, scene.bvh.own_instances(idx)]).astype(np.int32)
        cl.enqueue_copy(dev.queue, idx_bufs[k], idx_host[k], is_blocking=False)
        cl.enqueue_copy(dev.queue, org_bufs[k], org_host[k], is_blocking=False)
        # The first block is launched by the caller's thread, later ones by the thread that reads
        # the blocks: a kernel object per thread (Device.kernel), its arguments its own.
        knl = dev.kernel("hemicube.cl", "hemicube_runs", defines)
        enqueue_kernel(
            dev,
            knl,
            (global_size(len(idx) * K * tiles.bands(R), wg),),
            (wg,),
            nodes,
            tris,
            order,
            org_bufs[k],
            normals,
            idx_bufs[k],
            np.int32(len(idx)),
            eps,
            *buffers[k],
            *extra,
        )
        return len(idx)

    def read(b: int, k: int):
        host = (np.empty((b, K * S, R), np.int32), np.empty((b, K * S, R), np.float32), np.empty((b, K * S), np.int32))
        for h, d in zip(host, buffers[k]):
            cl.enqueue_copy(dev.queue, h, d)
        return host

    def blocks(b: int):
        with progress_bar(progress, total=len(rows), unit="patch", desc=f"{desc} R={R}") as bar:
            runs = read(b, 0)
            for k, first in enumerate(range(0, len(rows), block)):
                following = launch(first + block, (k + 1) % 2) if first + block < len(rows) else 0
                yield runs
                bar.update(b)
                if following:
                    b, runs = following, read(following, (k + 1) % 2)

    return blocks(launch(0, 0))


def stack_blocks(blocks, n_cols: int) -> sp.csr_matrix:
    """Blocks from :func:`hemicube_blocks` as one float32 CSR matrix with sorted indices."""
    parts = list(blocks)
    if not parts:
        return sp.csr_matrix((0, n_cols), dtype=np.float32)
    m = sp.vstack(parts, format="csr").astype(np.float32)
    m.sort_indices()
    return m


def form_factors(
    scene, resolution: int = RESOLUTION, rows=None, device=None, progress: bool | None = None, samples: int = 1
) -> sp.csr_matrix:
    """Gathering form factors F[i, j] of a scene by hemicubes.

    Parameters
    ----------
    scene : Scene
    resolution : int
        Hemicube resolution R (even, 2..4096: :func:`pydynrad.checks.resolution`): top face R x R, sides R x R/2, 3 R^2 rays per patch.
    rows : sequence of int, optional
        Patches whose rows to compute; all by default.
    device : Device, optional
        The OpenCL device (default: :func:`pydynrad.default_device`).
    progress : bool, optional
        Show a tqdm bar; None: once the run has taken two seconds (:mod:`pydynrad.progress`).
    samples : int
        Hemicubes per row (1, 4, 16, ...): each row averages hemicubes at the centroids of
        ``samples`` equal strata of its patch, each of resolution R / sqrt(samples), so the rays
        per row stay 3 R^2. Removes the centre point's bias where a patch is large against its
        distance to what it sees (see the module's docstring).

    Returns
    -------
    scipy.sparse.csr_matrix, float32, shape (len(rows), N)
        Row k holds patch ``rows[k]``'s form factors to every patch (fraction of the energy
        leaving it that arrives at each). ``F[i, i] = 0``.
    """
    scene = checked_scene(scene)
    n = len(scene)
    return stack_blocks(hemicube_blocks(scene, resolution, rows, device, progress, samples=samples), n)
