"""Pictures of a radiosity solution.

Two steps: an OpenCL kernel (``kernels/render.cl``) casts one primary ray per pixel through
the scene's BVH and records the visible patch and the barycentrics of the hit; then the host
shades each pixel from the patch radiosities:

* ``"flat"``: the radiosity of the visible patch (the patches show as facets);
* ``"smooth"``: radiosity interpolated linearly over each triangle from values at its
  corners. A corner's value is the area-weighted mean radiosity of the patches around that
  point which belong to the same *smoothing group*: patches meeting at a point join a group
  when their normals differ by less than ``crease_angle`` and their albedo and emission are
  equal, so light never leaks across a crease (a wall meeting the floor) or a material
  border (the light's edge, a red wall meeting a white one). Groups are the connected
  components of that relation, which splits every mesh vertex into one vertex per group.

Pixel values are the radiosity (radiant exitance, the unit of ``Scene.emission``) of the
visible surface, linear, float32, shape (height, width, 3); divide by pi for radiance.
Patches radiate from their front side only, so a ray that meets a patch's back face shows
``backface`` (default black) and a ray that leaves the scene shows ``background``.

See docs/design.md, 'Renderer'.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from .camera import Camera
from .checks import finite, number, scene as checked_scene
from .errors import InvalidInputError
from .launch import global_size

__all__ = ["Renderer", "Visibility", "render", "smoothing_groups", "SHADINGS"]

SHADINGS = ("smooth", "flat")

# Smoothing groups depend on the scene only: kept while the scene lives, so repeated
# render() calls (a walk) group the corners once.
_group_cache: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


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


def smoothing_groups(scene, crease_angle: float = 30.0) -> tuple[np.ndarray, int]:
    """Split mesh vertices into smoothing groups.

    Parameters
    ----------
    scene : Scene
    crease_angle : float
        Patches meeting at a point are smoothed together only when their normals differ by
        less than this many degrees (and their materials are equal).

    Returns
    -------
    corner_group : (N, 3) int64
        Group index of each patch corner; corners with equal index share one value.
    n_groups : int
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if not (np.isfinite(crease_angle) and 0.0 <= crease_angle <= 180.0):
        raise InvalidInputError(f"crease_angle must be in [0, 180] degrees; got {crease_angle!r}")
    n = len(scene)
    # Points are identified by position, so meshes stored with duplicated vertices still smooth.
    _, point_id = np.unique(scene.points, axis=0, return_inverse=True)
    corner_point = point_id.reshape(-1)[scene.triangles].reshape(-1)
    corner_patch = np.repeat(np.arange(n), 3)
    order = np.argsort(corner_point, kind="stable")
    sorted_point = corner_point[order]
    cos_crease = np.cos(np.radians(crease_angle)) - 1e-6
    normals, albedo, emission = scene.normals, scene.albedo, scene.emission
    rows, cols = [], []
    # Corners of one point sit next to each other after sorting: pair each with the ones
    # d places later, for d up to the largest number of patches around a point.
    d = 1
    while d < len(sorted_point):
        same = sorted_point[d:] == sorted_point[:-d]
        if not same.any():
            break
        a, b = order[:-d][same], order[d:][same]
        pa, pb = corner_patch[a], corner_patch[b]
        ok = (
            (np.einsum("ij,ij->i", normals[pa], normals[pb]) >= cos_crease)
            & np.all(np.abs(albedo[pa] - albedo[pb]) <= 1e-6, axis=1)
            & np.all(np.abs(emission[pa] - emission[pb]) <= 1e-6 * (1.0 + np.abs(emission[pa])), axis=1)
        )
        rows.append(a[ok])
        cols.append(b[ok])
        d += 1
    rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
    cols = np.concatenate(cols) if cols else np.zeros(0, dtype=np.int64)
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(3 * n, 3 * n))
    n_groups, labels = connected_components(graph, directed=False)
    return labels.reshape(n, 3).astype(np.int64), int(n_groups)


def _as_radiosity(radiosity, n: int) -> np.ndarray:
    b = np.asarray(radiosity, dtype=np.float32)
    if b.ndim == 1 and b.shape == (n,):
        b = b[:, None]
    if b.ndim != 2 or b.shape[0] != n or b.shape[1] not in (1, 3):
        raise InvalidInputError(f"radiosity must have shape ({n},), ({n}, 1) or ({n}, 3); got {np.shape(radiosity)}")
    finite(b, "radiosity")
    return np.broadcast_to(b, (n, 3))


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
        from .device import default_device

        self.scene = checked_scene(scene)
        self.device = device or default_device()
        self.crease_angle = number(crease_angle, "crease_angle")

    @property
    def corner_groups(self) -> tuple[np.ndarray, int]:
        """Smoothing groups of the scene's corners, computed once per scene and crease angle."""
        per_scene = _group_cache.setdefault(self.scene, {})
        groups = per_scene.get(self.crease_angle)
        if groups is None:
            groups = per_scene[self.crease_angle] = smoothing_groups(self.scene, self.crease_angle)
        return groups

    def visibility(self, camera: Camera) -> Visibility:
        """Cast one primary ray per pixel of ``camera``."""
        import pyopencl as cl

        if not isinstance(camera, Camera):
            raise InvalidInputError(f"camera must be a pydynrad.Camera; got {type(camera).__name__}")
        dev = self.device
        h, w = camera.shape
        n_pix = h * w
        dirs = np.zeros((n_pix, 4), dtype=np.float32)
        dirs[:, :3] = camera.ray_directions().reshape(n_pix, 3)
        origin = np.zeros(4, dtype=np.float32)
        origin[:3] = camera.position
        nodes, tris, order = self.scene.bvh.buffers(dev)
        mf = cl.mem_flags
        d_dirs = dev.to_device(dirs)
        d_patch = cl.Buffer(dev.context, mf.WRITE_ONLY, 4 * n_pix)
        d_uvf = cl.Buffer(dev.context, mf.WRITE_ONLY, 16 * n_pix)
        d_depth = cl.Buffer(dev.context, mf.WRITE_ONLY, 4 * n_pix)
        knl = dev.kernel("render.cl", "primary_visibility")
        knl(dev.queue, (global_size(n_pix),), None, nodes, tris, order, origin, d_dirs, np.int32(n_pix), d_patch, d_uvf,
            d_depth)
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
            depth=depth.reshape(h, w),
        )

    def corner_radiosity(self, radiosity) -> np.ndarray:
        """(N, 3, 3) smoothed radiosity at each patch corner (patch, corner, channel)."""
        scene = self.scene
        b = _as_radiosity(radiosity, len(scene)).astype(np.float64)
        groups, n_groups = self.corner_groups
        weight = np.repeat(scene.areas.astype(np.float64), 3)
        flat_groups = groups.reshape(-1)
        total = np.bincount(flat_groups, weights=weight, minlength=n_groups)
        values = np.stack(
            [np.bincount(flat_groups, weights=weight * np.repeat(b[:, c], 3), minlength=n_groups) for c in range(3)],
            axis=1,
        )
        values /= total[:, None]
        return values[groups].astype(np.float32)

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
