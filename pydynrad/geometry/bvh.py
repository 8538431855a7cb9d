"""Bounding volume hierarchy over patch triangles, built natively and traversed on the device.

The builder is ``csrc/bvh.c`` (binned SAH, leaves of at most 4 triangles, the binary tree
collapsed to 4-wide nodes). This module keeps
its flattened arrays and uploads them once per OpenCL device (with the patch arrays of the same
geometry that kernels read beside them); kernels include
``kernels/bvh.cl`` and take the three buffers of :meth:`BVH.buffers` as arguments.

See docs/design.md, 'BVH'.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .. import _bvh, _raybatch
from ..checks import finite
from ..device.devices import default_device
from ..device.launch import bvh_packet, enqueue_kernel, global_size, ray_work_group
from ..errors import InvalidInputError

__all__ = ["BVH", "InstancedBVH", "cast_rays", "occluded"]

#: Deepest tree (in wide levels) that the traversal stack of kernels/bvh.cl (BVH_STACK = 96)
#: holds: a node pushes at most four children and the walk pops one, so D levels need 3 D + 1.
MAX_DEPTH = 31

#: Lanes of a wide node (csrc/bvh.c WIDTH) and float32 values per node.
WIDTH, NODE_FLOATS = 4, 32


def _children(nodes: np.ndarray) -> np.ndarray:
    """(n_nodes, 4) int32 child references of wide nodes (see :class:`BVH`)."""
    return np.ascontiguousarray(nodes[:, 24:28]).view(np.int32)


def _depth(nodes: np.ndarray) -> int:
    """Wide levels from the root to the deepest interior node."""
    children = _children(nodes)
    level, depth = np.array([0]), 0
    while len(level):
        depth += 1
        c = children[level].ravel()
        level = c[c > 0]
    return depth


def leaf_ranges(child: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, count) of the triangles (BVH order) of leaf references ``child < 0``."""
    code = ~np.asarray(child, np.int32)
    return code >> 3, (code & 7) + 1


@dataclass(eq=False)
class BVH:
    """A flattened BVH.

    Attributes
    ----------
    nodes : (n_nodes, 32) float32
        4-wide nodes, root first: ``minx[4], maxx[4], miny[4], maxy[4], minz[4], maxz[4]``
        (the children's boxes), ``child[4]`` (int32 bit-cast, see :attr:`children`), 4 floats
        of padding. A child reference > 0 is a node, 0 an empty slot (inverted box), < 0 a
        leaf (``leaf_ranges``).
    order : (N,) int32
        Patch index of each triangle in BVH order.
    tris : (N, 12) float32
        Per triangle in BVH order: its corners ``v0, 0, v1, 0, v2, 0`` as three float4, for
        the watertight test in the kernel (shared corners stay bit-identical).
    """

    nodes: np.ndarray
    order: np.ndarray
    tris: np.ndarray
    _device_buffers: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, vertices: np.ndarray) -> BVH:
        """Build over (N, 3, 3) triangle corners."""
        v = np.ascontiguousarray(vertices, dtype=np.float32)
        if v.ndim != 3 or v.shape[1:] != (3, 3) or len(v) == 0:
            raise InvalidInputError(f"BVH needs (N, 3, 3) triangle corners with N > 0; got {v.shape}")
        finite(v, "BVH input (triangle corners)")
        n = len(v)
        nodes = np.empty((n, NODE_FLOATS), dtype=np.float32)
        order = np.empty(n, dtype=np.int32)
        tris = np.empty((n, 12), dtype=np.float32)
        n_nodes = _bvh.build(v.reshape(-1), nodes, order, tris)
        nodes = nodes[:n_nodes].copy()
        # Boxes grown by 8 float32 ulps of the largest coordinate: the watertight triangle test
        # works in each ray's own frame, whose axis differs from the ray by rounding (~1e-7 rad),
        # so near an edge it can pick the triangle whose exact box the ray just misses (at grazing
        # angles, by far more than a relative margin on t would cover).
        pad = np.float32(2.0**-20 * float(np.abs(v).max()))
        boxes = nodes[:, :24].reshape(-1, 3, 2, WIDTH)  # a view: (node, axis, min/max, child)
        boxes[:, :, 0] -= pad
        boxes[:, :, 1] += pad
        depth = _depth(nodes)
        if depth > MAX_DEPTH:
            raise InvalidInputError(
                f"BVH depth {depth} exceeds the traversal stack ({MAX_DEPTH}); the geometry is pathological "
                "(e.g. millions of nested, nearly coincident triangles)"
            )
        return cls(nodes, order, tris)

    # Sizes and views computed from the packed arrays (as Scene's are from its own): read-only accessors.
    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def depth(self) -> int:
        """Wide levels from the root to the deepest interior node."""
        return _depth(self.nodes)

    @property
    def children(self) -> np.ndarray:
        """(n_nodes, 4) int32 child references."""
        return _children(self.nodes)

    def own_instances(self, patches) -> np.ndarray:
        """(len(patches),) int32: per patch, the instance its hemicube rays need not look at
        (:meth:`InstancedBVH.own_instances`); a plain tree has none, -1."""
        return np.full(len(patches), -1, np.int32)

    @property
    def boxes(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi), each (n_nodes, 4, 3) float32: the children's boxes."""
        b = self.nodes[:, :24].reshape(-1, 3, 2, WIDTH)
        return b[:, :, 0].transpose(0, 2, 1), b[:, :, 1].transpose(0, 2, 1)

    @property
    def nbytes(self) -> int:
        return self.nodes.nbytes + self.order.nbytes + self.tris.nbytes

    def buffers(self, device) -> tuple:
        """``(nodes, tris, order)`` device buffers, uploaded once per device."""
        arrays = (self.nodes, self.tris, self.order)
        return self.upload_once(device, "bvh", lambda: tuple(map(device.to_device, arrays)))

    def upload_once(self, device, name: str, upload):
        """``upload()``'s result (device buffers) under ``name``, made once per device and kept
        with the BVH's own buffers: for arrays of the geometry the BVH was built from (patch
        centres and normals, see :meth:`pydynrad.Scene.patch_buffers`), which never change."""
        # Keyed by id(); the entry keeps the device alive so the id cannot be reused.
        entry = self._device_buffers.get(id(device))
        if entry is None:
            entry = self._device_buffers[id(device)] = (device, {})
        uploads: dict[str, object] = entry[1]
        if name not in uploads:
            uploads[name] = upload()
        return uploads[name]


#: float4 per instance in the table of kernels/bvh.cl (BVH_INSTANCE): the world-to-object rows, the root.
INSTANCE_FLOAT4 = 4


def _relocated(nodes: np.ndarray, node_offset: int, tri_offset: int) -> np.ndarray:
    """A tree's nodes with child references moved to where the tree lies in a joint buffer."""
    out = nodes.copy()
    child = _children(out).copy()
    first, count = leaf_ranges(child)
    child = np.where(child > 0, child + node_offset, child)
    child = np.where(child < 0, ~(((first + tri_offset) << 3) | (count - 1)), child)
    out.view(np.int32)[:, 24:28] = child  # bit patterns, never through float arithmetic
    return out


class InstancedBVH:
    """A two-level BVH: the static tree plus one tree per rigid object, each in object space.

    The trees share the three device buffers of :meth:`buffers` (the static tree first, so
    node 0 stays the static root) and a table of the objects' world-to-object transforms after
    the nodes; kernels/bvh.cl walks the static tree, then each object's tree with the ray
    moved into object space. A move rewrites only the table (:meth:`set_transforms`), so
    nothing is rebuilt. Patch indices: the static tree's, then each object's offset by the
    patches before it.

    Parameters
    ----------
    static : BVH
        The static scene's tree (patch indices 0..N-1).
    objects : sequence of BVH
        One tree per object over its object-space triangles, each as ``(v - origin) / frame.unit``.
    transforms : sequence of (4, 4) float
        Each object's object-to-world transform (rigid; see :func:`pydynrad.geometry.objects.rigid_transform`).
    frame : DeviceFrame, optional
        The frame of the static tree (:attr:`pydynrad.Scene.frame`; default: identity). Rays come
        in it; sharing its unit, the objects' trees keep the map from it to theirs rigid.
    origins : (n_objects, 3) float, optional
        The object-space point each object's tree is centred on (default: zeros).
    convex : (n_objects,) bool, optional
        Whether each object is the whole boundary of one convex solid (default: none is); the
        hemicube rays of its own patches then skip its tree (:meth:`own_instances`).

    See docs/design.md, 'BVH' and 'Moving objects'.
    """

    def __init__(self, static: BVH, objects, transforms, frame=None, origins=None, convex=None) -> None:
        objects = list(objects)
        self.convex = np.zeros(len(objects), bool) if convex is None else np.array(convex, bool).reshape(len(objects))
        self.frame_origin = np.zeros(3) if frame is None else np.asarray(frame.origin, np.float64)
        self.frame_unit = 1.0 if frame is None else float(frame.unit)
        self.origins = (
            np.zeros((len(objects), 3)) if origins is None else np.asarray(origins, np.float64).reshape(-1, 3)
        )
        node_at = np.cumsum([static.n_nodes] + [b.n_nodes for b in objects])
        tri_at = np.cumsum([len(static.order)] + [len(b.order) for b in objects])
        self.roots = node_at[:-1].astype(np.int32)  # each object tree's root node
        parts = [static.nodes] + [_relocated(b.nodes, int(n0), int(t0)) for b, n0, t0 in zip(objects, node_at, tri_at)]
        # The table fills whole node rows so that it starts at a float4 index node 0 can name.
        table_rows = -(-len(objects) * INSTANCE_FLOAT4 * 4 // NODE_FLOATS)
        self.nodes = np.concatenate(parts + [np.zeros((table_rows, NODE_FLOATS), np.float32)])
        self._table_float4 = int(node_at[-1]) * (NODE_FLOATS // 4)
        self.nodes.view(np.int32)[0, 28:30] = (len(objects), self._table_float4)
        self.order = np.concatenate([static.order] + [b.order + int(t0) for b, t0 in zip(objects, tri_at)])
        self.patch_starts = tri_at.astype(np.int64)  # each object's first patch, then the patch count
        self.tris = np.concatenate([static.tris] + [b.tris for b in objects])
        self.n_objects = len(objects)
        self._device_buffers: dict = {}
        self.set_transforms(transforms)

    def _table(self) -> np.ndarray:
        """The (n_objects, 4, 4) float32 view of the instance table inside :attr:`nodes`."""
        flat = self.nodes.reshape(-1)[4 * self._table_float4 : 4 * self._table_float4 + 16 * self.n_objects]
        return flat.reshape(self.n_objects, INSTANCE_FLOAT4, 4)

    def set_transforms(self, transforms) -> None:
        """Put the objects at new (4, 4) object-to-world transforms, on the host and every device."""
        import pyopencl as cl

        T = np.asarray(transforms, dtype=np.float64).reshape(-1, 4, 4)
        if len(T) != self.n_objects:
            raise InvalidInputError(f"expected {self.n_objects} transforms; got {len(T)}")
        table = np.zeros((self.n_objects, INSTANCE_FLOAT4, 4), np.float32)
        Rt = T[:, :3, :3].transpose(0, 2, 1)  # the inverse of a rotation is its transpose
        # Device ray p_d = (p - c) / u into the object tree's (R^T (p - t) - o) / u: rotation R^T,
        # translation (R^T (c - t) - o) / u; lengths, so t, unchanged.
        table[:, :3, :3] = Rt
        table[:, :3, 3] = (
            np.einsum("kij,kj->ki", Rt, self.frame_origin - T[:, :3, 3]) - self.origins
        ) / self.frame_unit
        table.view(np.int32)[:, 3, 0] = self.roots
        self._table()[:] = table
        self.transforms = T.copy()
        for device, uploads in self._device_buffers.values():
            # Other uploads kept with the BVH (a scene's patch centres and normals) were of the
            # old poses: only the BVH's own buffers stay, with the table rewritten in place.
            bvh = uploads.get("bvh")
            uploads.clear()
            if bvh is not None:
                uploads["bvh"] = bvh
                cl.enqueue_copy(device.queue, bvh[0], table, dst_offset=16 * self._table_float4)

    def own_instances(self, patches) -> np.ndarray:
        """(len(patches),) int32: per patch, the object it lies on where that object is convex,
        else -1: a ray leaving a point of a convex solid's surface into the hemisphere outside
        it meets nothing of the solid, which lies wholly behind the point's plane, so its tree
        need not be walked (kernels/hemicube.cl)."""
        p = np.asarray(patches, np.int64)
        k = np.searchsorted(self.patch_starts, p, side="right") - 1  # -1: a static patch
        inside = (k >= 0) & (k < self.n_objects)
        out = np.full(len(p), -1, np.int32)
        out[inside] = np.where(self.convex[k[inside]], k[inside], -1)
        return out

    @property
    def nbytes(self) -> int:
        return self.nodes.nbytes + self.order.nbytes + self.tris.nbytes

    buffers = BVH.buffers
    upload_once = BVH.upload_once


#: Rays per launch of :func:`cast_rays` and :func:`occluded` (~5 ms on a small GPU). cast_rays
#: converts the next chunk on the host while the device traces one (see there), in buffers of
#: this size whatever the batch. A chunk this size takes several times longer to trace than to
#: check and convert, so the conversion hides behind the trace (docs/decisions/0011-ray-tracing.md).
CAST_CHUNK = 1 << 18


def _ray_arrays(origins, directions) -> tuple[np.ndarray, np.ndarray]:
    """``origins`` and ``directions`` as arrays of one shape (n, 3), not yet converted."""
    o, d = np.asarray(origins), np.asarray(directions)
    if o.ndim != 2 or o.shape[1] != 3 or d.shape != o.shape:
        raise InvalidInputError(f"origins and directions must both have shape (n, 3); got {o.shape} and {d.shape}")
    return o, d


def _rays(origins, directions, tmax, frame=None, first: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Checked float32 rays, moved into ``frame`` (a scene's DeviceFrame; t is unchanged) if
    given; ``first``: the index of the first of them in the caller's batch (for messages).

    One native pass per ray (``csrc/rays.c``), with :meth:`DeviceFrame.points` and
    :meth:`~DeviceFrame.directions`' arithmetic."""
    origins, directions = _ray_arrays(origins, directions)
    real = (
        origins.dtype if origins.dtype == directions.dtype and origins.dtype in (np.float32, np.float64) else np.float64
    )
    o, d = (np.ascontiguousarray(a, dtype=real) for a in (origins, directions))
    tm = np.asarray(tmax, dtype=np.float32)
    tm = tm.reshape(1) if tm.size == 1 else np.ascontiguousarray(np.broadcast_to(tm, (len(o),)))
    out = np.empty_like(o, np.float32), np.empty_like(d, np.float32), np.empty(len(o), np.float32)
    code, bad = _raybatch.prepare(
        o, d, tm, None if frame is None else (*map(float, frame.origin), float(frame.unit)), *out
    )
    if code == 1:
        raise InvalidInputError("ray origins or directions contain NaN or infinite values")
    if code == 2:
        raise InvalidInputError("ray directions must be non-zero")
    if code == 3:
        raise InvalidInputError(f"tmax must be > 0 (inf for unbounded rays); got {out[2][bad]} for ray {first + bad}")
    return out


def _resolve(scene_or_bvh, device):
    """(bvh, device, frame): a Scene's BVH lives in the scene's DeviceFrame, a bare BVH in the rays' own."""
    traced = (BVH, InstancedBVH)
    bvh = scene_or_bvh if isinstance(scene_or_bvh, traced) else getattr(scene_or_bvh, "bvh", None)
    if not isinstance(bvh, traced):
        raise InvalidInputError(f"expected a Scene or a BVH; got {type(scene_or_bvh).__name__}")
    return bvh, device or default_device(), None if bvh is scene_or_bvh else scene_or_bvh.frame


def cast_rays(scene_or_bvh, origins, directions, tmax=np.inf, device=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest hits of a batch of rays ``origins + t * directions``, ``0 < t < tmax``.

    Parameters
    ----------
    scene_or_bvh : Scene or BVH
    origins, directions : (n, 3) float
        Directions need not be unit length; ``t`` is measured in units of ``|direction|``.
    tmax : float or (n,) float

    Returns
    -------
    patch : (n,) int32, the patch hit (-1 on a miss)
    t : (n,) float32, the hit distance (inf on a miss)
    front : (n,) bool, True when the ray meets the patch's front (its normal's side)
    """
    import pyopencl as cl

    bvh, dev, frame = _resolve(scene_or_bvh, device)
    origins, directions = _ray_arrays(origins, directions)
    n = len(origins)
    tmax = np.asarray(tmax, dtype=np.float32)
    tmax = tmax.reshape(1) if tmax.size == 1 else np.broadcast_to(tmax, (n,))
    patch, t, front = np.empty(n, np.int32), np.empty(n, np.float32), np.empty(n, np.int8)
    if n == 0:
        return patch, t, front.astype(bool)
    chunk = min(n, CAST_CHUNK)
    mf = cl.mem_flags
    ins = [cl.Buffer(dev.context, mf.READ_ONLY, chunk * size) for size in (12, 12, 4)]
    outs = [cl.Buffer(dev.context, mf.WRITE_ONLY, chunk * a.itemsize) for a in (patch, t, front)]
    # One packet of BVH_PACKET consecutive rays per work-item (see kernels/raycast.cl).
    packet, wg = bvh_packet(dev), ray_work_group(dev)
    knl = dev.kernel("raycast.cl", "cast_closest", {"BVH_PACKET": packet})

    def prepare(a: int):
        tm = tmax if len(tmax) == 1 else tmax[a : a + chunk]
        return a, _rays(origins[a : a + chunk], directions[a : a + chunk], tm, frame, first=a)

    def launch(a: int, rays) -> None:
        for buf, host in zip(ins, rays):
            cl.enqueue_copy(dev.queue, buf, host, is_blocking=False)  # pyopencl holds host until copied
        enqueue_kernel(
            dev,
            knl,
            (global_size(-(-len(rays[0]) // packet), wg),),
            (wg,),
            *bvh.buffers(dev),
            *ins,
            np.int32(len(rays[0])),
            *outs,
        )

    # The host checks and converts chunk c + 1 (float64, one core) while the device traces chunk
    # c; then reads c back and uploads c + 1 (PoCL's reads and uploads wait for the kernels
    # queued before them, so that order keeps the host free while a chunk is traced).
    hosts: tuple[np.ndarray, ...] = (patch, t, front)  # (annotated: mypy joins their dtypes to object)
    a, rays = prepare(0)
    launch(a, rays)
    while a < n:
        following = prepare(a + chunk) if a + chunk < n else None
        for host, buf in zip(hosts, outs):
            cl.enqueue_copy(dev.queue, host[a : a + chunk], buf, is_blocking=False)
        if following is None:
            break
        a, rays = following
        launch(a, rays)
    dev.queue.finish()
    return patch, t, front.astype(bool)


def occluded(scene_or_bvh, origins, directions, tmax=np.inf, device=None) -> np.ndarray:
    """(n,) bool: True where any triangle lies on ``origins + t * directions``, ``0 < t < tmax``.

    Consecutive rays are traced as packets (``kernels/raycast.cl``, ``cast_occluded``): keep
    coherent ones (a patch's rows, neighbouring patches to a light) next to each other."""
    import pyopencl as cl

    bvh, dev, frame = _resolve(scene_or_bvh, device)
    o, d, tm = _rays(origins, directions, tmax, frame)
    n = len(o)
    out = np.zeros(n, np.int8)
    if n == 0:
        return out.astype(bool)
    nodes, tris, _ = bvh.buffers(dev)
    # A fixed work-group: left to choose, PoCL compiles the kernel anew for each new global
    # size (each compile far longer than the trace), and a move's shadow rays vary in number.
    wg = ray_work_group(dev)
    packet = bvh_packet(dev)
    knl = dev.kernel("raycast.cl", "cast_occluded", {"BVH_PACKET": packet})  # one program with cast_closest
    # Launches of at most CAST_CHUNK rays (kernels/raycast.cl's bound), a whole number of
    # packets: every packet holds the rays it holds in one launch, so the results are its own.
    chunk = min(n, max(packet, CAST_CHUNK // packet * packet))
    mf = cl.mem_flags
    ins = [cl.Buffer(dev.context, mf.READ_ONLY, chunk * size) for size in (12, 12, 4)]
    buf = cl.Buffer(dev.context, mf.WRITE_ONLY, chunk)
    for a in range(0, n, chunk):
        m = min(chunk, n - a)
        for dst, host in zip(ins, (o, d, tm)):
            cl.enqueue_copy(dev.queue, dst, host[a : a + m], is_blocking=False)  # pyopencl holds host until copied
        enqueue_kernel(
            dev,
            knl,
            (global_size(-(-m // packet), wg),),
            (wg,),
            nodes,
            tris,
            *ins,
            np.int32(m),
            buf,
        )
        cl.enqueue_copy(dev.queue, out[a : a + m], buf, is_blocking=False)
    dev.queue.finish()
    return out.astype(bool)
