"""Bounding volume hierarchy over patch triangles, built natively and traversed on the device.

The builder is ``csrc/bvh.c`` (binned SAH, leaves of at most 4 triangles). This module keeps
its flattened arrays and uploads them once per OpenCL device; kernels include
``kernels/bvh.cl`` and take the three buffers of :meth:`BVH.buffers` as arguments.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _bvh
from .errors import InvalidInputError

__all__ = ["BVH"]

#: Traversal stack size in kernels/bvh.cl (BVH_STACK); the near-first walk never holds more
#: entries than the tree is deep.
MAX_DEPTH = 64


def _depth(nodes: np.ndarray) -> int:
    offsets, counts = nodes[:, 3].view(np.int32), nodes[:, 7].view(np.int32)
    level, depth = np.array([0]), 0
    while len(level):
        depth += 1
        inner = level[counts[level] == 0]
        level = np.concatenate([offsets[inner], offsets[inner] + 1])
    return depth


@dataclass(eq=False)
class BVH:
    """A flattened BVH.

    Attributes
    ----------
    nodes : (n_nodes, 8) float32
        ``bmin.xyz, offset, bmax.xyz, count`` per node; ``offset`` and ``count`` are int32
        bit-cast into the float slots (see :attr:`offsets`, :attr:`counts`).
    order : (N,) int32
        Patch index of each triangle in BVH order.
    tris : (N, 12) float32
        Per triangle in BVH order: ``v0, 0, e1, 0, e2, 0`` (e1 = v1 - v0, e2 = v2 - v0),
        laid out as three float4 for the Moller-Trumbore test in the kernel.
    """

    nodes: np.ndarray
    order: np.ndarray
    tris: np.ndarray
    _device_buffers: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, vertices: np.ndarray) -> "BVH":
        """Build over (N, 3, 3) triangle corners."""
        v = np.ascontiguousarray(vertices, dtype=np.float32)
        if v.ndim != 3 or v.shape[1:] != (3, 3) or len(v) == 0:
            raise InvalidInputError(f"BVH needs (N, 3, 3) triangle corners with N > 0; got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise InvalidInputError("BVH input contains NaN or infinite coordinates")
        n = len(v)
        nodes = np.empty((max(1, 2 * n - 1), 8), dtype=np.float32)
        order = np.empty(n, dtype=np.int32)
        n_nodes = _bvh.build(v.reshape(-1), nodes, order)
        nodes = nodes[:n_nodes].copy()
        depth = _depth(nodes)
        if depth > MAX_DEPTH:
            raise InvalidInputError(
                f"BVH depth {depth} exceeds the traversal stack ({MAX_DEPTH}); the geometry is pathological "
                "(e.g. millions of nested, nearly coincident triangles)"
            )
        tv = v[order].astype(np.float64)
        tris = np.zeros((n, 3, 4), dtype=np.float32)
        tris[:, 0, :3] = tv[:, 0]
        tris[:, 1, :3] = tv[:, 1] - tv[:, 0]
        tris[:, 2, :3] = tv[:, 2] - tv[:, 0]
        return cls(nodes, order, tris.reshape(n, 12))

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def offsets(self) -> np.ndarray:
        return self.nodes[:, 3].view(np.int32)

    @property
    def counts(self) -> np.ndarray:
        return self.nodes[:, 7].view(np.int32)

    @property
    def nbytes(self) -> int:
        return self.nodes.nbytes + self.order.nbytes + self.tris.nbytes

    def buffers(self, device) -> tuple:
        """``(nodes, tris, order)`` device buffers, uploaded once per device."""
        # Keyed by id(); the entry keeps the device alive so the id cannot be reused.
        entry = self._device_buffers.get(id(device))
        if entry is None:
            bufs = (device.to_device(self.nodes), device.to_device(self.tris), device.to_device(self.order))
            entry = self._device_buffers[id(device)] = (device, bufs)
        return entry[1]
