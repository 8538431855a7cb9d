"""Sensors: illuminance at points that are not part of the scene (they cast no shadows).

``illuminance`` adds, at every point, the direct light of the analytic lights (one shadow ray
per point and light, the patch light pass's kernel), and a hemicube gather of the patches'
radiosity and the sky (``kernels/gather.cl``): emitting patches enter through their radiosity,
which includes their emission, and so does every reflected (indirect) contribution. With a
photometric scene (docs/design.md, 'Units and photometry') the result is in lux.
"""

from __future__ import annotations

import numpy as np

from ..checks import checked_sensors, floats, patch_indices
from ..checks import resolution as checked_resolution
from ..defaults import RESOLUTION
from ..errors import InvalidInputError
from ..geometry.loading import checked_scene
from ..lights.areas import checked_grid, emitter_irradiance
from ..lights.gather import gather_irradiance
from ..lights.sky import SkyLight, pack_sky
from ..lights.sources import checked_lights, point_irradiance

__all__ = ["illuminance", "auto_emitters", "EMITTER_CHOICES", "NEAR_SIZES"]

#: What ``illuminance(emitters=...)`` takes.
EMITTER_CHOICES = ("auto", "analytic", "hemicube")
#: ``emitters="auto"`` with many emitters: an emitter within this many of its sizes (the square
#: root of its area) of some sensor is integrated analytically, the others through the hemicube.
NEAR_SIZES = 10.0


def auto_emitters(scene, points, resolution: int, grid: int) -> np.ndarray:
    """The emitting patches ``emitters="auto"`` integrates analytically at ``points``: all of
    them where their shadow rays (``grid^2`` per emitter and sensor) are no more than the
    hemicube's own ``3 R^2`` (measured: 0-40% more time than the gather alone, docs/guide/
    defaults.md); otherwise those within :data:`NEAR_SIZES` sizes of some sensor."""
    em = np.asarray(scene.emitters, dtype=np.int64)
    if len(em) * grid * grid <= 3 * resolution * resolution or len(points) == 0:
        return em
    from scipy.spatial import cKDTree

    distance, _ = cKDTree(np.asarray(points, dtype=np.float64)).query(scene.centers[em].astype(np.float64))
    return em[distance <= NEAR_SIZES * np.sqrt(scene.areas[em].astype(np.float64))]


def illuminance(
    scene,
    radiosity=None,
    points=None,
    normals=None,
    lights=(),
    *,
    patches=None,
    resolution: int = RESOLUTION,
    emitters: str = "auto",
    visibility_grid: int = 4,
    device=None,
) -> np.ndarray:
    """Irradiance at sensor points (lux when the scene's light is photometric).

    Parameters
    ----------
    scene : Scene
    radiosity : (N, 3) array, optional
        Patch radiosity B (``solve(...).radiosity``, ``DynamicRadiosity.radiosity(...)``),
        gathered by a hemicube at every point: the light of emitting patches and all reflected
        light. None: the direct light of ``lights`` only.
    points : (n, 3) or (3,) float
        Sensor positions in scene units. Sensors do not occlude anything.
    normals : (n, 3) or (3,) float
        The direction each sensor faces (normalised here; zero is an error). A horizontal
        work plane faces up.
    lights : light object or sequence
        The lights the radiosity was computed with (PointLight, SpotLight, DirectionalLight,
        LuminaireLight, SkyLight): their direct light at the sensors, by shadow rays (sky: by
        the hemicube).
        Pass the same ones as to ``solve``, or the direct light is missing.
    patches : (n,) int, optional
        Instead of points: the centres of these patches, facing their normals; each hemicube
        ignores its own patch and uses that patch's row rotation, so the gather equals
        ``(F @ B)[patches]`` of a hemicube F of the same resolution.
    resolution : int
        Hemicube resolution R of the gather (3 R^2 rays per sensor).
    emitters : "auto", "analytic" or "hemicube"
        How the direct light of emitting patches is found: by the exact point-to-polygon form
        factor with ``visibility_grid^2`` shadow rays per emitter (:mod:`pydynrad.lights.areas`;
        the hemicube then gathers only the rest of their radiosity, ``B - E``), or through
        their radiosity in the hemicube, which is coarse near them (CIE 171 test 5.3 at R = 64:
        5% off 3 m below a 1 m source, 42% 20 cm below its edge; analytic: 2e-7). "auto" (the
        default): analytic for every emitter when that costs no more rays than the hemicube
        (up to 768 emitting patches at the defaults), else for those near a sensor
        (:func:`auto_emitters`); it adds the emitters' light only with ``radiosity`` (which
        holds their emission), "analytic" always.

    Returns
    -------
    (n, 3) float64
        Irradiance per colour channel (W/unit^2, or lux).
    """
    scene = checked_scene(scene)
    lights = checked_lights(lights)
    # Both checked whether or not this call uses them: a bad value is the caller's mistake either way.
    resolution, visibility_grid = checked_resolution(resolution), checked_grid(visibility_grid)
    n_patches = len(scene)
    if patches is not None:
        if points is not None or normals is not None:
            raise InvalidInputError("give sensor points and normals, or patches, not both")
        ids = patch_indices(patches, n_patches, "patches")
        points, normals = scene.centers[ids].astype(np.float64), scene.normals[ids].astype(np.float64)
        keys = own = ids
    else:
        if points is None or normals is None:
            raise InvalidInputError("illuminance needs sensor points and normals (or patches=)")
        points, normals = checked_sensors(points, normals)
        keys, own = None, None
    if radiosity is not None:
        radiosity = floats(radiosity, "radiosity")
        if radiosity.shape != (n_patches, 3):
            raise InvalidInputError(f"radiosity must have shape ({n_patches}, 3); got {radiosity.shape}")
        if not np.all(np.isfinite(radiosity)) or radiosity.min(initial=0.0) < 0:
            raise InvalidInputError("radiosity must be finite and >= 0")
    if not isinstance(emitters, str) or emitters not in EMITTER_CHOICES:
        raise InvalidInputError(f"emitters must be 'auto', 'analytic' or 'hemicube'; got {emitters!r}")
    E = point_irradiance(scene, points, normals, lights, device).astype(np.float64)
    if emitters == "analytic":
        E += emitter_irradiance(scene, points, normals, visibility_grid, device)
        if radiosity is not None:
            radiosity = radiosity - scene.emission
    elif emitters == "auto" and radiosity is not None:
        near = auto_emitters(scene, points, resolution, visibility_grid)
        if len(near):
            E += emitter_irradiance(scene, points, normals, visibility_grid, device, subset=near)
            radiosity = radiosity.copy()
            radiosity[near] -= scene.emission[near]
    has_sky = any(isinstance(light, SkyLight) for light in lights)
    if radiosity is not None or has_sky:
        E += gather_irradiance(
            scene,
            points,
            normals,
            radiosity,
            pack_sky(lights, scene.up) if has_sky else None,
            resolution,
            keys,
            own,
            device,
        )
    if not np.all(np.isfinite(E)):  # as direct_irradiance refuses it on the patches
        raise InvalidInputError(
            "the illuminance overflows float32 at some sensor (above 3.4e38): the lights are "
            "too strong for float32; scale the light intensities (and emission) down"
        )
    return E
