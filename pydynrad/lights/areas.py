"""Direct light of emitting patches, accurately near them (``kernels/areas.cl``).

A hemicube sees an emitter through its pixels: a few centimetres from a 1 m emitter, seen nearly
edge-on, it is off by tens of percent at any affordable resolution. Here each emitting triangle
contributes its exitance times the exact form factor from the point to the triangle (Lambert's
contour integral, the triangle first clipped to the point's half-space), times its visible
share: the form-factor integrand ``cos cos / r^2`` summed over ``grid x grid`` stratified points
on it that shadow rays reach, over the same sum for all of them. Exact for a fully visible or
fully hidden emitter; partial occlusion converges with the grid.

:func:`pydynrad.illuminance` uses it with ``emitters="analytic"``, gathering only the reflected
part ``B - E`` of the patches' radiosity by its hemicube, so nothing is counted twice; ``solve``
and ``DynamicRadiosity.radiosity`` with ``emitters="analytic"`` solve for ``B - E`` with
:func:`reflected_light_vector` (see docs/design.md, 'Area emitters').
"""

from __future__ import annotations

import weakref

import numpy as np

from ..checks import checked_sensors, integer
from ..device.devices import default_device
from ..device.launch import enqueue_kernel, float4, global_size, ray_work_group
from ..errors import InvalidInputError
from .sources import SHADOW_EPSILON, direct_irradiance, resolve_light

__all__ = [
    "emitter_irradiance",
    "reflected_light_vector",
    "analytic_emitter_light",
    "EMITTER_MODES",
    "MAX_GRID",
    "checked_grid",
]

#: How the direct light of emitting patches reaches a receiver: through the hemicube (F or the
#: sensor's own), or by the contour integral here.
EMITTER_MODES = ("hemicube", "analytic")

# The emitters' irradiance at the patch centres depends on the scene alone (its arrays are
# read-only), not on the lights: kept while the scene lives, so a relit solve or every frame of
# DynamicRadiosity.radiosity(emitters="analytic") traces its shadow rays once.
_at_patches: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


#: Most shadow rays (points x emitters x grid^2) one ``emitter_irradiance`` launch traces: ~84 ms
#: on a small GPU at ~50 M rays/s (the bound in ``kernels/areas.cl``'s header).
EMITTER_RAYS_PER_LAUNCH = 1 << 22

#: Most visibility samples per side of an emitter (``grid``): 4,096 shadow rays per point and emitter.
MAX_GRID = 64


def checked_grid(grid) -> int:
    """``grid`` (visibility samples per side of an emitter) as an int in 1..:data:`MAX_GRID`."""
    return integer(grid, "grid (visibility samples per side)", 1, MAX_GRID)


def emitter_irradiance(scene, points, normals, grid: int = 4, device=None, subset=None) -> np.ndarray:
    """(n, 3) float64 irradiance at ``points`` (n, 3; unit ``normals`` (n, 3) or one (3,) for
    all, checked: the kernel reads a normal per point) from the scene's emitting patches.

    ``grid``: visibility samples per emitter are ``grid^2`` shadow rays per point. A point on
    an emitter's plane (its own patch, a coplanar neighbour) receives nothing from it.
    ``subset``: patch indices of the emitters to count (default: all of ``scene.emitters``).
    """
    import pyopencl as cl

    points, normals = checked_sensors(points, normals)
    grid = checked_grid(grid)
    n = len(points)
    em = scene.emitters if subset is None else np.asarray(subset, dtype=np.int64).reshape(-1)
    if n == 0 or len(em) == 0:
        return np.zeros((n, 3))
    dev = device or default_device()
    corners = scene.frame.points(scene.triangles[em])  # the device frame, as the BVH (form factors are scale-free)
    packed = np.concatenate([corners, scene.normals[em][:, None, :]], axis=1).reshape(-1, 3)
    nodes, tris, _ = scene.bvh.buffers(dev)
    out_dev = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE, n * 16)
    kernel = dev.kernel("areas.cl", "emitter_irradiance")
    up = dev.to_device
    args = (
        up(float4(scene.frame.points(points))),
        up(float4(normals)),
        up(float4(packed)),
        up(float4(scene.emission[em])),
        nodes,
        tris,
        np.float32(scene.frame.length(SHADOW_EPSILON * scene.ray_scale)),
        np.int32(grid),
    )
    # Launches of at most EMITTER_RAYS_PER_LAUNCH shadow rays: emitters j0 .. j1 - 1 (a later
    # range adds to each point's sum, in the one launch's order), points a .. end - 1 (the
    # kernel's guard count the chunk's end). Bit for bit the one launch's result.
    per_pair = grid * grid
    emitters = max(1, min(len(em), EMITTER_RAYS_PER_LAUNCH // per_pair))
    for j0 in range(0, len(em), emitters):
        j1 = min(len(em), j0 + emitters)
        chunk = max(1, EMITTER_RAYS_PER_LAUNCH // ((j1 - j0) * per_pair))
        for a in range(0, n, chunk):
            end = min(n, a + chunk)
            enqueue_kernel(
                dev,
                kernel,
                (global_size(end - a),),
                (ray_work_group(dev),),  # an item loops over every emitter's shadow rays
                args[0],
                args[1],
                np.int32(end),
                args[2],
                args[3],
                np.int32(j1),
                *args[4:],
                np.int32(j0),
                out_dev,
                offset=(a,),
            )
    out = np.empty((n, 4), np.float32)
    cl.enqueue_copy(dev.queue, out, out_dev)
    return out[:, :3].astype(np.float64)


def reflected_light_vector(scene, lights=(), grid: int = 4, device=None) -> np.ndarray:
    """(N, 3) float64 ``rho (H_lights + H_emitters)`` at the patch centres, H_emitters by
    :func:`emitter_irradiance`: the light vector of the reflected radiosity ``B_r = B - E``.

    Since ``F (B - E) = F B_r``, ``B_r`` solves the usual equation ``B_r = L_r + P F B_r`` with
    this ``L_r`` and the same F, so F's (coarse) entries towards emitters never carry their
    emission; ``solve`` and ``DynamicRadiosity.radiosity`` do this with ``emitters="analytic"``
    and add E back.
    """
    dev = device or default_device()
    per_scene = _at_patches.setdefault(scene, {})
    key = (checked_grid(grid), id(dev))
    if key not in per_scene:  # the device is kept beside its value, so its id is not reused
        per_scene[key] = (dev, emitter_irradiance(scene, scene.centers, scene.normals, key[0], dev))
    H = direct_irradiance(scene, lights, dev).astype(np.float64) + per_scene[key][1]
    return scene.albedo.astype(np.float64) * H


def analytic_emitter_light(scene, lights, light, emitters: str, device=None):
    """For a solver's ``emitters=`` option: ``(L_r, E)`` to solve for ``B - E`` with and add E to
    afterwards, or ``(L, None)`` for ``"hemicube"`` (the usual light vector)."""
    if emitters not in EMITTER_MODES:
        raise InvalidInputError(f"emitters must be one of {EMITTER_MODES}; got {emitters!r}")
    if emitters == "hemicube":
        return resolve_light(scene, lights, light, device), None
    if light is not None:
        raise InvalidInputError(
            "emitters='analytic' builds its own light vector from lights=; "
            "a precomputed light= cannot be split into emission and reflected light"
        )
    return reflected_light_vector(scene, lights, device=device), scene.emission.astype(np.float64)
