"""Reference path tracer: the ground truth radiosity results are measured against.

Two estimators share one OpenCL kernel file (``kernels/pathtrace.cl``) and the scene's BVH:

* :func:`path_trace` renders the image a :class:`~pydynrad.Camera` sees, one ray per pixel
  through the pixel centre (the ray ``render`` casts), so a radiosity image and a path-traced
  image compare pixel by pixel;
* :func:`path_trace_patches` estimates patch radiosities directly by gathering at patch
  centres: ``B_i = E_i + rho_i * H_i`` with the irradiance ``H_i`` estimated by cosine-weighted
  hemisphere sampling, to compare with :func:`pydynrad.solve` patch by patch.

The transport model is the radiosity model: one-sided Lambertian patches, emission only from
the front, analytic lights as deltas with shadow rays. Direct light from emitting patches is
sampled both by next-event estimation (emitters picked proportionally to power) and by the
bounce rays, combined by multiple importance sampling; see the kernel's header. Russian roulette keeps
long paths unbiased. Samples are accumulated in passes (one kernel launch each, so a progress
bar and a time limit work); random numbers depend only on ``(seed, pixel or patch, sample)``,
so a result is reproducible bit for bit.

See docs/design.md, 'Path tracer'.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .checks import integer, patch_indices
from .device.devices import default_device
from .device.launch import enqueue_kernel, float4, global_size, ray_work_group
from .errors import InvalidInputError
from .geometry.camera import Camera, check_image_memory
from .geometry.loading import checked_scene
from .geometry.scene import Scene
from .lights.sky import pack_sky
from .lights.sources import SHADOW_EPSILON, checked_lights, pack_lights_and_tables
from .progress import progress_bar

__all__ = ["path_trace", "path_trace_patches"]

#: Peak host memory of :func:`path_trace` per pixel, rounded up: 66 bytes measured (a 1500 x 1500
#: image, PoCL CPU).
PATH_TRACE_BYTES_PER_PIXEL = 80

#: Largest number of samples per item in one kernel launch (keeps launches short on GPUs).
_MAX_PASS = 16
#: Most rays one pass's launch traces (by the estimate of :meth:`_Tracer.rays_per_path`): ~84 ms
#: on a small GPU at ~50 M rays/s (the bound in ``kernels/pathtrace.cl``'s header). A pass is
#: split into launches over ranges of its items (pixels or patches), each item's samples in one.
PATH_RAYS_PER_LAUNCH = 1 << 22
#: Bounces per path the launch bound counts (Russian roulette ends most paths well before).
_BOUNCES_ESTIMATE = 6
#: Most samples per item (pixel or patch) one call takes. Each item's sum is float32, one pass of
#: :data:`_MAX_PASS` samples added at a time: at 2^24 samples a pass adds 1e-6 of the sum, ~8
#: ulps, rounded by up to half of one (6% of what it adds), so more samples buy rounding, not
#: accuracy (average calls with other seeds instead); and the sample index is a uint32.
MAX_SPP = 2**24


class _Tracer:
    """A scene's and its lights' device buffers (the kernels' SCENE_ARGS) and the bounce limit."""

    def __init__(self, scene: Scene, lights, max_depth: int, device) -> None:
        scene = checked_scene(scene)
        integer(max_depth, "max_depth", 1, 2**31 - 1)  # the kernel's int bounce counter
        self.device = device = device or default_device()
        self.defines = {"MAX_DEPTH": int(max_depth)}
        self.max_depth = int(max_depth)
        em = scene.emitters
        # Areas in the device frame, where the kernel measures distances: the pdf per device area.
        power = scene.emission[em].astype(np.float64).mean(axis=1) * (scene.areas[em] / scene.frame.unit**2)
        if len(em):
            inv_power = 1.0 / power.sum()  # the kernel turns this into each emitter's area pdf
            cdf = np.cumsum(power * inv_power)
            cdf[-1] = 1.0 + 1e-6  # every u in [0, 1) finds an emitter despite rounding
            v = scene.frame.points(scene.triangles[em]).astype(np.float64)
            tri = np.stack([v[:, 0], v[:, 1] - v[:, 0], v[:, 2] - v[:, 0], np.zeros_like(v[:, 0])], axis=1)
            tri = float4(tri.reshape(-1, 3))
            tri.reshape(len(em), 4, 4)[:, 3, :3] = scene.normals[em]
        else:
            inv_power, cdf = 0.0, np.zeros(1)
            tri = np.zeros((4, 4), np.float32)
        lights = checked_lights(lights)
        packed, tables = pack_lights_and_tables(lights, scene.frame)
        n_lights = len(packed)
        self.n_lights = n_lights
        if not n_lights:
            packed = np.zeros((1, 12), np.float32)  # a buffer cannot be empty; the kernel reads none
        up = device.to_device
        nodes, tris, order = scene.bvh.buffers(device)
        normals = scene.patch_buffers(device)[1]
        # Materials are uploaded per tracer: scenes that share geometry (and so these cached
        # buffers) may differ in albedo and emission.
        self.args = (
            nodes,
            tris,
            order,
            normals,
            up(float4(scene.albedo)),
            up(float4(scene.emission)),
            np.int32(len(em)),
            up(tri),
            up(float4(scene.emission[em]) if len(em) else np.zeros((1, 4), np.float32)),
            up(cdf.astype(np.float32)),
            np.float32(inv_power),
            np.int32(n_lights),
            up(packed),
            up(tables),
            up(pack_sky(lights, scene.up)),
            np.float32(scene.frame.length(SHADOW_EPSILON * scene.ray_scale)),
            np.float32(scene.frame.length(2.0 * scene.scale)),  # directional shadow rays need only leave the scene
        )

    def rays_per_path(self) -> int:
        """Rays one path traces, for the launch bound: per bounce one shadow ray per analytic
        light, one towards an emitter and the bounce ray, over at most :data:`_BOUNCES_ESTIMATE`
        bounces."""
        return (2 + self.n_lights) * min(self.max_depth, _BOUNCES_ESTIMATE)

    def accumulate(
        self, kernel_name: str, items: tuple, n_items: int, spp: int, seed: int, progress, time_limit: float | None
    ) -> tuple[np.ndarray, int]:
        """Run passes until ``spp`` samples (or the time limit); return (sum (n, 3), samples)."""
        import pyopencl as cl

        kernel = self.device.kernel("pathtrace.cl", kernel_name, self.defines)
        queue = self.device.queue
        accum = cl.Buffer(self.device.context, cl.mem_flags.READ_WRITE, size=max(1, n_items) * 16)
        cl.enqueue_fill_buffer(queue, accum, np.float32(0), 0, max(1, n_items) * 16)
        local = (ray_work_group(self.device),)  # an item traces n paths
        done, size = 0, 1
        start = time.perf_counter()
        bar = progress_bar(progress, total=spp, unit="spp", desc=f"path tracing ({kernel_name})")
        with bar:
            while done < spp:
                n = min(size, spp - done)
                # Items a .. end - 1 per launch (a global offset; the guard count the chunk's
                # end): each item's sum is its own work-item's, so the image is the one
                # launch's, bit for bit.
                chunk = max(1, PATH_RAYS_PER_LAUNCH // (n * self.rays_per_path()))
                for a in range(0, n_items, chunk):
                    end = min(n_items, a + chunk)
                    enqueue_kernel(
                        self.device,
                        kernel,
                        (global_size(end - a),),
                        local,
                        *items,
                        np.int32(end),
                        accum,
                        np.uint32(seed),
                        np.uint32(done),
                        np.int32(n),
                        *self.args,
                        offset=(a,),
                    )
                queue.finish()
                done += n
                bar.update(n)
                # A fixed doubling schedule: pass boundaries (and so the float sums) depend on
                # spp alone, which keeps results bit-reproducible.
                size = min(2 * size, _MAX_PASS)
                if time_limit is not None and time.perf_counter() - start > time_limit:
                    break
        out = np.empty((max(1, n_items), 4), dtype=np.float32)
        cl.enqueue_copy(queue, out, accum)
        return out[:n_items, :3], done


def _check_common(spp, seed, time_limit) -> None:
    integer(spp, "spp (samples per item)", 1, MAX_SPP)
    integer(seed, "seed", 0, 2**32 - 1)
    if time_limit is not None and (
        isinstance(time_limit, bool) or not isinstance(time_limit, (int, float, np.number)) or not time_limit > 0
    ):
        raise InvalidInputError(f"time_limit must be positive seconds or None; got {time_limit!r}")


def path_trace(
    scene: Scene,
    camera,
    spp: int = 64,
    lights=(),
    seed: int = 0,
    max_depth: int = 256,
    device=None,
    progress: bool | None = None,
    time_limit: float | None = None,
) -> np.ndarray:
    """Path-trace the image ``camera`` sees.

    Parameters
    ----------
    scene : Scene
    camera : pydynrad.Camera
        The renderer's camera; its pixel-centre rays are used, so pixels match ``render``.
    spp : int
        Samples per pixel (paths started from each pixel's visible point).
    lights : sequence of PointLight, SpotLight, DirectionalLight, SkyLight
        Lights in addition to the scene's emitting patches; bounce rays that leave the scene
        see the sky (camera rays that miss show 0, ``render``'s background).
    seed : int
        Random seed in [0, 2**32); the same seed gives the same image bit for bit.
    max_depth : int
        Bounce limit; Russian roulette ends most paths long before it.
    progress : bool, optional
        Show a tqdm bar over the samples; None: once tracing has taken two seconds
        (:mod:`pydynrad.progress`).
    time_limit : float, optional
        Stop after the pass that exceeds this many seconds (the image averages the samples done).

    Returns
    -------
    (H, W, 3) float32
        Linear pixel values in ``render``'s convention: radiosity (pi times the radiance
        towards the camera), so a diffuse surface of radiosity B shows B. Pixels whose ray
        escapes or reaches a patch's back are 0 (``render``'s default background and backface).
    """
    _check_common(spp, seed, time_limit)
    scene = checked_scene(scene)
    tracer = _Tracer(scene, lights, max_depth, device)
    if not isinstance(camera, Camera):
        raise InvalidInputError(f"camera must be a pydynrad.Camera; got {type(camera).__name__}")
    check_image_memory(camera, PATH_TRACE_BYTES_PER_PIXEL, "path tracing")
    h, w = camera.shape
    origin = np.zeros(4, dtype=np.float32)
    origin[:3] = scene.frame.points(camera.position)
    directions = tracer.device.to_device(float4(camera.ray_directions().reshape(-1, 3)))
    total, done = tracer.accumulate(
        "trace_pixels", (origin, directions), h * w, int(spp), int(seed), progress, time_limit
    )
    # The kernel returns radiance; pi * radiance is the radiosity of a diffuse surface.
    return (total * (math.pi / done)).reshape(h, w, 3).astype(np.float32)


def path_trace_patches(
    scene: Scene,
    patches=None,
    spp: int = 256,
    lights=(),
    seed: int = 0,
    max_depth: int = 256,
    device=None,
    progress: bool | None = None,
    time_limit: float | None = None,
) -> np.ndarray:
    """Estimate patch radiosities by gathering at patch centres.

    ``B_i = E_i + rho_i * H_i`` with the irradiance ``H_i`` at patch i's centre estimated from
    ``spp`` paths (next-event estimation at every vertex). Compare with the radiosity of
    :func:`pydynrad.solve`: that is an area average, this is a point value at the centre, so
    the two differ by the variation of B across a patch (small for fine patches). Parameters
    other than ``patches`` are as in :func:`path_trace`.

    Parameters
    ----------
    patches : (n,) int, optional
        Patch indices (default: every patch).

    Returns
    -------
    (n, 3) float32 radiosity (the scene's emission units).
    """
    _check_common(spp, seed, time_limit)
    scene = checked_scene(scene)
    ids = np.arange(len(scene)) if patches is None else patch_indices(patches, len(scene), "patches")
    if len(ids) == 0:
        return np.zeros((0, 3), dtype=np.float32)
    tracer = _Tracer(scene, lights, max_depth, device)
    ids_dev = tracer.device.to_device(ids.astype(np.int32))
    centers = scene.patch_buffers(tracer.device)[0]
    total, done = tracer.accumulate(
        "gather_patches", (ids_dev, centers), len(ids), int(spp), int(seed), progress, time_limit
    )
    return (scene.emission[ids] + total / done).astype(np.float32)
