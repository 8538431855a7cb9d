"""Direct light of emitting patches, accurately near them (``kernels/areas.cl``).

A hemicube sees an emitter through its pixels: a few centimetres from a 1 m emitter, seen nearly
edge-on, it is off by tens of percent at any affordable resolution. Here each emitting triangle
contributes its exitance times the exact form factor from the point to the triangle (Lambert's
contour integral, the triangle first clipped to the point's half-space), times its visible
share: the form-factor integrand ``cos cos / r^2`` summed over ``grid x grid`` stratified points
on it that shadow rays reach, over the same sum for all of them. Exact for a fully visible or
fully hidden emitter; partial occlusion converges with the grid.

:func:`pydynrad.illuminance` uses it with ``emitters="analytic"``, gathering only the reflected
part ``B - E`` of the patches' radiosity by its hemicube, so nothing is counted twice.
"""

from __future__ import annotations

import numpy as np

from ..checks import integer
from ..launch import global_size
from ..lights import SHADOW_EPSILON

__all__ = ["emitter_irradiance"]


def _float4(a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32).reshape(len(a), -1)
    out = np.zeros((len(a), 4), dtype=np.float32)
    out[:, : a.shape[1]] = a
    return out


def emitter_irradiance(scene, points, normals, grid: int = 4, device=None) -> np.ndarray:
    """(n, 3) float64 irradiance at ``points`` (unit ``normals``) from the scene's emitting patches.

    ``grid``: visibility samples per emitter are ``grid^2`` shadow rays per point.
    """
    import pyopencl as cl

    from ..device import default_device

    grid = integer(grid, "grid (visibility samples per side)", 1, 64)
    n = len(points)
    em = scene.emitters
    if n == 0 or len(em) == 0:
        return np.zeros((n, 3))
    dev = device or default_device()
    corners = scene.vertices[em].astype(np.float32)
    packed = np.concatenate([corners, scene.normals[em][:, None, :]], axis=1).reshape(-1, 3)
    nodes, tris, _ = scene.bvh.buffers(dev)
    out_dev = cl.Buffer(dev.context, cl.mem_flags.WRITE_ONLY, n * 16)
    kernel = dev.kernel("areas.cl", "emitter_irradiance")
    up = dev.to_device
    kernel(dev.queue, (global_size(n),), None, up(_float4(points)), up(_float4(normals)), np.int32(n),
           up(_float4(packed)), up(_float4(scene.emission[em])), np.int32(len(em)), nodes, tris,
           np.float32(SHADOW_EPSILON * scene.scale), np.int32(grid), out_dev)
    out = np.empty((n, 4), np.float32)
    cl.enqueue_copy(dev.queue, out, out_dev)
    return out[:, :3].astype(np.float64)
