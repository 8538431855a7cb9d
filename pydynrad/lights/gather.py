"""Irradiance gathered by hemicubes at arbitrary points (``kernels/gather.cl``).

One hemicube per point, laid out and weighted exactly as the form-factor rows are
(``kernels/hemicube.h``, ``pydynrad.formfactors.pixel_form_factors``): each pixel's ray
adds its delta form factor times the radiosity of the patch it meets from the front, or pi
times the sky's luminance when it leaves the scene. Points are processed in blocks, so memory
stays bounded whatever their number. At a patch centre with the patch's own key and index,
the rays are the ones of that patch's row of F, so ``F @ B`` and the gather agree to rounding.
"""

from __future__ import annotations

import numpy as np

from ..checks import resolution as checked_resolution
from ..device.devices import default_device
from ..device.launch import bvh_packet, enqueue_kernel, float4, global_size, ray_work_group
from ..formfactors import pixel_form_factors
from ..geometry.scene import SURFACE_OFFSET

__all__ = ["gather_irradiance"]

#: Added to a free sensor's index to make its rotation key (patch keys are the patch indices).
_SENSOR_KEY_OFFSET = 0x9E3779B9

#: Points per kernel launch: bounds the partial-sum buffer (3R float4 per point) and a launch's length.
BLOCK_POINTS = 4096


def gather_irradiance(
    scene, points, normals, radiosity=None, sky=None, resolution: int = 64, keys=None, own=None, device=None
) -> np.ndarray:
    """(n, 3) float64 irradiance at ``points`` from the patches' radiosity and the sky.

    Parameters
    ----------
    scene : Scene
    points, normals : (n, 3) float, or None
        Positions (scene units, moved into ``scene.frame`` for the device) and unit normals,
        already checked; None: the patch centres and normals (``Scene.patch_buffers``).
    radiosity : (N, 3), optional
        Patch radiosity B gathered from the patches; none (0) by default.
    sky : (4, 4) float32, optional
        A packed sky (:func:`pydynrad.lights.sky.pack_sky`); no sky by default.
    resolution : int
        Hemicube resolution R (3 R^2 rays per point).
    keys : (n,) int, optional
        Rotation key of each point's hemicube (default: its index in ``points`` plus a fixed
        offset, so no sensor gets the unrotated, axis-aligned hemicube of key 0).
    own : (n,) int, optional
        The patch each point lies on, which its hemicube ignores (default: none, -1).
    """
    import pyopencl as cl

    dev = device or default_device()
    R = checked_resolution(resolution)
    n = len(scene) if points is None else len(points)
    if n == 0:
        return np.zeros((0, 3))
    S = 3 * R
    up = dev.to_device
    nodes, tris, order = scene.bvh.buffers(dev)
    if points is None:
        points_dev, normals_dev = scene.patch_buffers(dev)
    else:
        points_dev, normals_dev = up(float4(scene.frame.points(points))), up(float4(normals))
    B = np.zeros((len(scene), 4), np.float32) if radiosity is None else float4(radiosity)
    sky = np.zeros((4, 4), np.float32) if sky is None else np.ascontiguousarray(sky, np.float32)
    if keys is None:  # offset by the golden ratio's bits: key 0 would hash to angle 0, aligned with the axes
        keys = ((np.arange(n, dtype=np.uint64) + _SENSOR_KEY_OFFSET) % 2**32).astype(np.uint32).view(np.int32)
    own = np.full(n, -1, np.int32) if own is None else own
    keys_dev, own_dev = up(np.asarray(keys, np.int32)), up(np.asarray(own, np.int32))
    weights, B_dev, sky_dev = up(pixel_form_factors(R).astype(np.float32)), up(B), up(sky)
    kernel = dev.kernel("gather.cl", "hemicube_gather", {"HC_RES": R, "BVH_PACKET": bvh_packet(dev)})
    block = min(n, BLOCK_POINTS)
    partial_dev = cl.Buffer(dev.context, cl.mem_flags.WRITE_ONLY, block * S * 16)
    eps = np.float32(scene.frame.length(SURFACE_OFFSET * scene.ray_scale))
    out = np.empty((n, 3))
    for first in range(0, n, block):
        b = min(block, n - first)
        enqueue_kernel(
            dev,
            kernel,
            (global_size(b * S),),
            (ray_work_group(dev),),  # an item traces a hemicube scanline
            nodes,
            tris,
            order,
            points_dev,
            normals_dev,
            keys_dev,
            own_dev,
            np.int32(first),
            np.int32(b),
            eps,
            weights,
            B_dev,
            sky_dev,
            partial_dev,
        )
        partial = np.empty((b * S, 4), np.float32)
        cl.enqueue_copy(dev.queue, partial, partial_dev)
        out[first : first + b] = partial.reshape(b, S, 4)[..., :3].astype(np.float64).sum(axis=1)
    return out
