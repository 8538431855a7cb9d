"""Pictures of a radiosity solution.

Two steps: an OpenCL kernel (``kernels/render.cl``) casts one primary ray per pixel through
the scene's BVH and records the visible patch and the barycentrics of the hit; then the host
shades each pixel from the patch radiosities:

* ``"flat"``: the radiosity of the visible patch (the patches show as facets);
* ``"smooth"``: radiosity interpolated linearly over each triangle from values at its
  corners, the radiosity of the corner's smooth vertex (:mod:`pydynrad.smoothing`): the
  area-weighted mean over the patches around that point in the same smoothing group, so
  light never leaks across a crease or a material border.

Pixel values are the radiosity (radiant exitance, the unit of ``Scene.emission``) of the
visible surface, linear, float32, shape (height, width, 3); divide by pi for radiance.
Patches radiate from their front side only, so a ray that meets a patch's back face shows
``backface`` (default black) and a ray that leaves the scene shows ``background``.

See docs/design.md, 'Renderer'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import number
from .device.devices import default_device
from .device.launch import WG, enqueue_kernel, global_size
from .errors import InvalidInputError
from .geometry.camera import Camera, check_image_memory
from .geometry.loading import checked_scene
from .smoothing import checked_radiosity as _as_radiosity
from .smoothing import smooth_vertices, smoothing_groups

__all__ = ["Renderer", "Visibility", "render", "smoothing_groups", "SHADINGS"]

SHADINGS = ("smooth", "flat")

#: Peak host memory of :meth:`Renderer.render` per pixel, rounded up: 109 bytes measured
#: (a 3000 x 3000 smooth render, PoCL CPU, whose device buffers are host memory too).
RENDER_BYTES_PER_PIXEL = 128


@dataclass
class Visibility:
    """What every pixel sees.

    Attributes
    ----------
    patch : (H, W) int32
        Visible patch index, -1 where the ray leaves the scene.
    barycentric : (H, W, 3) float32
        Weights of the patch's three corners at the hit point (zeros for a miss).
    front : (H, W) bool
        True where the ray hits the patch's front (lit) side.
    depth : (H, W) float32
        Distance from the camera along the ray, in scene units (inf for a miss).
    """

    patch: np.ndarray
    barycentric: np.ndarray
    front: np.ndarray
    depth: np.ndarray


def _as_colour(value, what: str) -> np.ndarray:
    c = np.broadcast_to(np.asarray(value, dtype=np.float32), (3,))
    if not np.all(np.isfinite(c)):
        raise InvalidInputError(f"{what} must be finite; got {value!r}")
    return c


class Renderer:
    """Renders one scene repeatedly (a walk): the smoothing groups and the BVH upload are
    computed once, each :meth:`render` only casts rays and shades.

    Parameters
    ----------
    scene : Scene
    device : Device, optional
        OpenCL device; the process default when omitted.
    crease_angle : float
        Degrees; see :func:`smoothing_groups`.
    """

    def __init__(self, scene, device=None, crease_angle: float = 30.0) -> None:
        self.scene = checked_scene(scene)
        self.device = device or default_device()
        self.crease_angle = number(crease_angle, "crease_angle")

    def visibility(self, camera: Camera) -> Visibility:
        """Cast one primary ray per pixel of ``camera``."""
        import pyopencl as cl

        if not isinstance(camera, Camera):
            raise InvalidInputError(f"camera must be a pydynrad.Camera; got {type(camera).__name__}")
        check_image_memory(camera, RENDER_BYTES_PER_PIXEL, "rendering")
        dev = self.device
        h, w = camera.shape
        n_pix = h * w
        dirs = np.zeros((n_pix, 4), dtype=np.float32)
        dirs[:, :3] = camera.ray_directions().reshape(n_pix, 3)
        origin = np.zeros(4, dtype=np.float32)
        origin[:3] = self.scene.frame.points(camera.position)  # unit directions: t in device units
        nodes, tris, order = self.scene.bvh.buffers(dev)
        mf = cl.mem_flags
        d_dirs = dev.to_device(dirs)
        d_patch = cl.Buffer(dev.context, mf.WRITE_ONLY, 4 * n_pix)
        d_uvf = cl.Buffer(dev.context, mf.WRITE_ONLY, 16 * n_pix)
        d_depth = cl.Buffer(dev.context, mf.WRITE_ONLY, 4 * n_pix)
        knl = dev.kernel("render.cl", "primary_visibility")
        enqueue_kernel(
            dev,
            knl,
            (global_size(n_pix),),
            (WG,),
            nodes,
            tris,
            order,
            origin,
            d_dirs,
            np.int32(n_pix),
            d_patch,
            d_uvf,
            d_depth,
        )
        patch = np.empty(n_pix, dtype=np.int32)
        uvf = np.empty((n_pix, 4), dtype=np.float32)
        depth = np.empty(n_pix, dtype=np.float32)
        cl.enqueue_copy(dev.queue, patch, d_patch)
        cl.enqueue_copy(dev.queue, uvf, d_uvf)
        cl.enqueue_copy(dev.queue, depth, d_depth, is_blocking=True)
        hit = patch >= 0
        bary = np.zeros((n_pix, 3), dtype=np.float32)
        bary[hit, 1:] = uvf[hit, :2]
        bary[hit, 0] = 1.0 - uvf[hit, 0] - uvf[hit, 1]
        return Visibility(
            patch=patch.reshape(h, w),
            barycentric=bary.reshape(h, w, 3),
            front=(uvf[:, 2] > 0.5).reshape(h, w) & hit.reshape(h, w),
            depth=(depth * np.float32(self.scene.frame.unit)).reshape(h, w),
        )

    def warm_up(self) -> None:
        """Trace an 8 x 8 image once, so that the first :meth:`render` of a frame loop does not
        wait for PoCL to compile the visibility kernel (compiled at its first launch, per
        local size: every launch uses the same one)."""
        corners = self.scene.triangles.reshape(-1, 3)
        lo, hi = corners.min(axis=0), corners.max(axis=0)
        centre = 0.5 * (lo + hi)
        self.visibility(Camera(centre + (hi - lo), centre, width=8, height=8))

    def corner_radiosity(self, radiosity) -> np.ndarray:
        """(N, 3, 3) smoothed radiosity at each patch corner (patch, corner, channel)."""
        smooth = smooth_vertices(self.scene, self.crease_angle)
        return smooth.radiosity(radiosity)[smooth.corner_vertex].astype(np.float32)

    def shade(self, vis: Visibility, radiosity, shading: str = "smooth", background=0.0, backface=0.0) -> np.ndarray:
        """(H, W, 3) float32 image from a :class:`Visibility` and patch radiosities (N, 3)."""
        if shading not in SHADINGS:
            raise InvalidInputError(f"shading must be one of {', '.join(SHADINGS)}; got {shading!r}")
        b = _as_radiosity(radiosity, len(self.scene))
        h, w = vis.patch.shape
        img = np.empty((h, w, 3), dtype=np.float32)
        img[:] = _as_colour(background, "background")
        img[vis.patch >= 0] = _as_colour(backface, "backface")
        front = vis.front
        patches = vis.patch[front]
        if shading == "flat":
            img[front] = b[patches]
        else:
            corners = self.corner_radiosity(b)[patches]  # (P, 3 corners, 3 channels)
            img[front] = np.einsum("pk,pkc->pc", vis.barycentric[front], corners)
        return img

    def render(self, radiosity, camera: Camera, shading: str = "smooth", background=0.0, backface=0.0) -> np.ndarray:
        """Render ``radiosity`` (N, 3) seen by ``camera``: (H, W, 3) float32, linear."""
        b = _as_radiosity(radiosity, len(self.scene))
        return self.shade(self.visibility(camera), b, shading, background, backface)


def render(
    scene,
    radiosity,
    camera: Camera,
    shading: str = "smooth",
    *,
    background=0.0,
    backface=0.0,
    crease_angle: float = 30.0,
    device=None,
) -> np.ndarray:
    """Render a radiosity solution.

    Parameters
    ----------
    scene : Scene
    radiosity : (N, 3) or (N,) float
        Radiosity of every patch (e.g. ``pydynrad.solve(...).radiosity``).
    camera : Camera
    shading : "smooth" or "flat"
        See the module docstring.
    background, backface : float or RGB
        Value of pixels that see nothing, and of pixels that see a patch from behind.
    crease_angle : float
        Degrees; smooth shading never averages across a sharper angle.
    device : Device, optional

    Returns
    -------
    (camera.height, camera.width, 3) float32 linear image.
    """
    return Renderer(scene, device, crease_angle).render(radiosity, camera, shading, background, backface)
