"""Analytic lights and the light vector L that the radiosity solvers propagate.

Lights are frozen, validated dataclasses. Their direct irradiance at every patch centre is
computed per call by a shadow-ray kernel through the scene's BVH (``kernels/lights.cl``), so
moving or recolouring a light costs one light pass plus one matrix-vector product with the
multibounce matrix (``B = L + P K L``), never a rebuild:

    K = pydynrad.multibounce(scene, F)                  # once
    L = pydynrad.light_vector(scene, [PointLight(...)]) # per light change
    B = pydynrad.multibounce_radiosity(scene, K, light=L)

Every function that takes lights names them the same way: ``lights=`` for light objects
(the emission is always included), ``light=`` for a precomputed light vector L (N, 3).

Units: positions in scene units; a point or spot light's intensity in W/sr, or cd
photometrically; irradiance falls off as intensity * cos(theta) / (d * unit)^2, with
``unit = scene.unit`` the scene's metres per unit, so it is per square metre (lux) in a scene
of any unit; a directional light's irradiance in W/m^2 (lux) on a surface facing it; see
docs/guide/units.md. Only the front side of a patch (its normal's side) receives light.
A :class:`~pydynrad.lights.SkyLight` is accepted wherever lights are: its direct light
comes from a hemicube per patch (sky visibility), not from shadow rays.

See docs/design.md, 'Lights'.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..checks import ROW_SUM_SLACK, checked_sensors, floats, number, rgb_tuple, unit_tuple, vec3_tuple
from ..device.devices import default_device
from ..device.launch import WG, enqueue_kernel, float4, global_size
from ..errors import InvalidInputError
from ..geometry.loading import checked_scene
from ..geometry.scene import SURFACE_OFFSET
from .gather import gather_irradiance
from .luminaires import LuminaireLight
from .sky import SkyLight, SkyOrientationWarning, pack_sky

__all__ = [
    "PointLight",
    "SpotLight",
    "DirectionalLight",
    "direct_irradiance",
    "point_irradiance",
    "light_vector",
    "pack_lights",
    "pack_light_tables",
    "pack_lights_and_tables",
    "checked_lights",
    "checked_light_vector",
    "check_radiosity_range",
    "resolve_light",
]

#: Most shadow rays (points x analytic lights) one ``direct_irradiance`` launch traces: ~84 ms
#: on a small GPU at ~50 M rays/s (the bound in ``kernels/lights.cl``'s header).
LIGHT_RAYS_PER_LAUNCH = 1 << 22

#: Shadow-ray origins sit this fraction of the scene's bounding-box diagonal off the surface.
SHADOW_EPSILON = 1e-4


# Each light is a frozen dataclass whose __post_init__ runs one validator per field and whose _packed
# gives the kernel's 16-float record (kernels/lights.h): the classes share that shape, not code.
@dataclass(frozen=True)
class PointLight:
    """An isotropic point light: position (3,), intensity RGB in W/sr or cd (scalar = grey)."""

    position: tuple
    intensity: tuple

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", vec3_tuple(self.position, "PointLight.position"))
        object.__setattr__(self, "intensity", rgb_tuple(self.intensity, "PointLight.intensity"))

    def _packed(self) -> list:
        return [*self.position, 0.0, 0.0, 0.0, 1.0, 0.0, *self.intensity, -2.0]


@dataclass(frozen=True)
class SpotLight:
    """A point light restricted to a cone.

    position (3,); direction (3,), the cone axis (normalised here); intensity RGB W/sr (cd) on the
    axis; full intensity within ``inner_angle`` of the axis, smoothly falling to 0 at
    ``outer_angle`` (radians, 0 <= inner <= outer <= pi, outer > 0).
    """

    position: tuple
    direction: tuple
    intensity: tuple
    inner_angle: float
    outer_angle: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", vec3_tuple(self.position, "SpotLight.position"))
        object.__setattr__(self, "direction", unit_tuple(self.direction, "SpotLight.direction"))
        object.__setattr__(self, "intensity", rgb_tuple(self.intensity, "SpotLight.intensity"))
        inner = number(self.inner_angle, "SpotLight.inner_angle")
        outer = number(self.outer_angle, "SpotLight.outer_angle")
        if not (0.0 <= inner <= outer <= math.pi and outer > 0.0):
            raise InvalidInputError(
                f"SpotLight angles must satisfy 0 <= inner_angle <= outer_angle <= pi, outer_angle > 0 (radians); "
                f"got inner={inner!r}, outer={outer!r}"
            )
        object.__setattr__(self, "inner_angle", inner)
        object.__setattr__(self, "outer_angle", outer)

    def _packed(self) -> list:
        width = math.cos(self.inner_angle) - math.cos(self.outer_angle)
        slope = 1.0 / width if width > 1e-7 else 1e30
        return [*self.position, 1.0, *self.direction, slope, *self.intensity, math.cos(self.outer_angle)]


@dataclass(frozen=True)
class DirectionalLight:
    """A light at infinity (the sun): direction (3,) it travels in (normalised here), irradiance RGB
    W/unit^2 (lux) on a surface facing it."""

    direction: tuple
    irradiance: tuple

    def __post_init__(self) -> None:
        object.__setattr__(self, "direction", unit_tuple(self.direction, "DirectionalLight.direction"))
        object.__setattr__(self, "irradiance", rgb_tuple(self.irradiance, "DirectionalLight.irradiance"))

    def _packed(self) -> list:
        return [0.0, 0.0, 0.0, 2.0, *self.direction, 1.0, *self.irradiance, -2.0]


#: The lights of this module that analytic_irradiance (kernels/lights.h) evaluates with one
#: shadow ray each; photometry's LuminaireLight is the fourth (see _shadow_ray_lights).
LIGHT_TYPES = (PointLight, SpotLight, DirectionalLight)
_LIGHT_NAMES = "PointLight, SpotLight, DirectionalLight, LuminaireLight or SkyLight"


def checked_lights(lights) -> list:
    """``lights`` (one light object or a sequence) as a list, or InvalidInputError."""
    kinds = (*LIGHT_TYPES, LuminaireLight, SkyLight)
    if isinstance(lights, np.ndarray):
        raise InvalidInputError(
            f"lights= takes light objects ({_LIGHT_NAMES}); pass a precomputed light vector as light=L"
        )
    if isinstance(lights, kinds):
        lights = [lights]
    try:
        lights = list(lights)
    except TypeError:  # None, a number: not a sequence of lights
        raise InvalidInputError(f"not a light or a sequence of lights: {lights!r}; use {_LIGHT_NAMES}") from None
    for light in lights:
        if not isinstance(light, kinds):
            raise InvalidInputError(f"not a light: {light!r}; use {_LIGHT_NAMES}")
    return lights


def pack_lights(lights, frame=None) -> np.ndarray:
    """(n_lights, 12) float32: the point, spot, directional and luminaire lights among ``lights``.

    Three float4 per light, the layout ``kernels/lights.h`` documents; a luminaire's record
    points into :func:`pack_light_tables` (a sky is packed apart, by
    :func:`pydynrad.lights.sky.pack_sky`). Raises InvalidInputError for anything that is
    not a light. With ``frame`` (a :class:`pydynrad.geometry.scene.DeviceFrame`) positions are moved
    into it and the intensities (a luminaire's: its scale on the table) divided by the square of
    its unit in metres (its unit times the scene's metres per unit), so that the kernels'
    I / r^2 over device distances gives the irradiance per square metre; a luminaire without
    a nadir points down the frame's up axis.
    """
    return pack_lights_and_tables(lights, frame)[0]


def pack_light_tables(lights) -> np.ndarray:
    """(n,) float32: the luminaires' intensity tables, one after another in ``lights``' order
    (the offsets :func:`pack_lights` records); one zero when there is no luminaire."""
    return pack_lights_and_tables(lights)[1]


def pack_lights_and_tables(lights, frame=None) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`pack_lights`, :func:`pack_light_tables`) in one pass, for a kernel that takes both."""
    return _packed(checked_lights(lights), frame)


def _packed(lights: list, frame=None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pack_lights` and :func:`pack_light_tables` of checked ``lights``, in one pass."""
    packed, tables, offset = [], [], 0
    up = getattr(frame, "up", None)
    for light in lights:
        if isinstance(light, LIGHT_TYPES):
            packed.append(light._packed())
        elif isinstance(light, LuminaireLight):
            light = light.placed(up if up is not None else (0.0, 0.0, 1.0))
            packed.append(light._packed(offset))
            tables.append(light._table())
            offset += len(tables[-1])
    packed = np.asarray(packed, dtype=np.float64).reshape(len(packed), 12)
    if frame is not None:
        positional = packed[:, 3] != 2.0  # every light but the directional (type 2) has a position
        packed[positional, :3] = frame.points(packed[positional, :3])
        packed[positional, 8:11] /= (frame.unit * getattr(frame, "metres", 1.0)) ** 2
    with np.errstate(over="ignore"):
        out = packed.astype(np.float32)
    if not np.all(np.isfinite(out)):
        raise InvalidInputError(
            "a light's position or intensity overflows float32 on the device "
            "(beyond ~3e38 once the scene is scaled to its own size)"
        )
    # A light whose every channel rounds to zero in float32 (below ~1.4e-45, the smallest
    # subnormal, once the scene is scaled to its own size) would go dark without a word.
    if np.any(np.any(packed[:, 8:11] != 0, axis=1) & ~np.any(out[:, 8:11] != 0, axis=1)):
        raise InvalidInputError(
            "a light's intensity underflows float32 on the device (below ~1.4e-45 once the "
            "scene is scaled to its own size) and would light nothing; scale the light "
            "intensities (and emission) up"
        )
    with np.errstate(over="ignore"):
        table = np.concatenate(tables).astype(np.float32) if tables else np.zeros(1, np.float32)
    if not np.all(np.isfinite(table)):  # inf candela times a zero weight is NaN on the device
        raise InvalidInputError("a luminaire's candela table overflows float32 on the device (beyond ~3.4e38 cd)")
    return out, table


def point_irradiance(scene, points, normals, lights, device=None) -> np.ndarray:
    """(n, 3) float32 irradiance at ``points`` (normals ``normals``) from the analytic lights.

    One shadow ray per point and point, spot, directional or luminaire light, traced through
    ``scene.bvh`` on the device from the point offset along its normal; a sky is not included.
    ``points = normals = None``: the patch centres (``Scene.patch_buffers``, uploaded once).
    Otherwise points (n, 3) and normals (n, 3) or one (3,) for all, checked (the kernel reads
    a normal per point).
    """
    if points is not None or normals is not None:
        points, normals = checked_sensors(points, normals)
    return _point_irradiance(scene, points, normals, checked_lights(lights), device)


def _point_irradiance(scene, points, normals, lights: list, device, patches=None, queued: bool = False):
    """:func:`point_irradiance` of checked ``lights``; with ``points = normals = None``, at the
    patch centres, or at those of ``patches`` (k,) alone (each the same value as in a pass
    over all of them: the same float32 centre and normal, the same ray). ``queued``: a callable
    that waits for the result and returns it, the rays queued on the device but not waited for
    (so that work queued after them does not delay them)."""
    import pyopencl as cl

    if patches is not None and points is not None:
        raise InvalidInputError("_point_irradiance takes sensor points or patches, not both")
    packed, tables = _packed(lights, scene.frame)
    n = len(scene) if points is None else len(points)
    if patches is not None:
        n = len(patches)
    if not len(packed) or not n:
        zero = np.zeros((n, 3), dtype=np.float32)
        return (lambda: zero) if queued else zero
    device = device or default_device()
    nodes, tris, _ = scene.bvh.buffers(device)
    if points is None:
        centers, normals, outside = *scene.patch_buffers(device, patches), 0.0
        offset = SHADOW_EPSILON
    else:
        # A sensor is a point, not a patch of the mesh: its shadow rays leave it by the offset of
        # the sky's gather at it (a sensor 1 cm under a desk in a 141 m scene had been lifted
        # above the desk by 1e-4 of the diagonal, and lit).

        offset = SURFACE_OFFSET
        p = np.asarray(points, np.float64)
        lo, hi = scene.bbox.astype(np.float64)
        # Sensors may lie outside the scene's box: directional shadow rays must reach past it from there.
        outside = float(np.max(np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)))
        centers, normals = device.to_device(float4(scene.frame.points(p))), device.to_device(float4(normals))
    out_dev = cl.Buffer(device.context, cl.mem_flags.WRITE_ONLY, n * 16)
    kernel = device.kernel("lights.cl", "direct_irradiance")
    # Directional shadow rays need only reach past the scene: twice its diagonal (plus the
    # farthest sensor's distance outside it).
    lights_dev, tables_dev = device.to_device(packed), device.to_device(tables)
    eps = np.float32(scene.frame.length(offset * scene.ray_scale))
    far = np.float32(scene.frame.length(2.0 * scene.scale + outside))
    # Launches of at most LIGHT_RAYS_PER_LAUNCH shadow rays (one per point and light): points
    # a .. end, the kernel's guard count the chunk's end. Each point is one work-item's, so
    # the chunks' results are the one launch's, bit for bit.
    chunk = max(1, LIGHT_RAYS_PER_LAUNCH // len(packed))
    for a in range(0, n, chunk):
        end = min(n, a + chunk)
        enqueue_kernel(
            device,
            kernel,
            (global_size(end - a),),
            (WG,),
            np.int32(end),
            centers,
            normals,
            np.int32(len(packed)),
            lights_dev,
            tables_dev,
            nodes,
            tris,
            eps,
            far,
            out_dev,
            offset=(a,),
        )
    out = np.empty((n, 4), dtype=np.float32)
    read = cl.enqueue_copy(device.queue, out, out_dev, is_blocking=not queued)
    if not queued:
        return np.ascontiguousarray(out[:, :3])

    def result() -> np.ndarray:
        read.wait()
        return np.ascontiguousarray(out[:, :3])

    return result


def direct_irradiance(scene, lights, device=None) -> np.ndarray:
    """(N, 3) float32 irradiance at each patch centre from ``lights``, with shadows.

    Point, spot and directional lights: one shadow ray per patch and light. A sky: a hemicube
    at each patch centre whose escaping rays see it (sky visibility, the sky's resolution).
    """
    return _direct_irradiance(scene, checked_lights(lights), device)


def _direct_irradiance(scene, lights: list, device) -> np.ndarray:
    """:func:`direct_irradiance` of checked ``lights``."""

    scene = checked_scene(scene)
    E = _point_irradiance(scene, None, None, lights, device)
    skies = [light for light in lights if isinstance(light, SkyLight)]
    if skies:
        ids = np.arange(len(scene))
        sky_light = gather_irradiance(
            scene,
            None,
            None,
            sky=pack_sky(lights, scene.up),
            resolution=skies[0].resolution,
            keys=ids,
            own=ids,
            device=device,
        )
        check_sky_orientation(scene, skies[0], sky_light)
        E = E + sky_light
    with np.errstate(over="ignore"):
        E = np.asarray(E, dtype=np.float32)
    if not np.all(np.isfinite(E)):
        raise InvalidInputError(
            "the direct irradiance overflows float32 (above 3.4e38 at some patch): the lights "
            "are too strong for float32; scale the light intensities (and emission) down"
        )
    return E


def check_sky_orientation(scene, sky: SkyLight, lit) -> None:
    """Warn (:class:`~pydynrad.lights.sky.SkyOrientationWarning`) where ``sky`` lights no patch of
    ``scene`` (``lit``: the sky's irradiance at the patches) or its own ``up`` points away from
    the scene's: a sky adding nothing is almost always a zenith pointing into the floor."""
    import warnings

    zenith = np.asarray(sky.placed(scene.up).up)
    agree = float(zenith @ np.asarray(scene.up, np.float64))
    if sky.up is not None and agree < 0.5:
        warnings.warn(
            f"the sky's zenith {tuple(round(float(x), 4) for x in zenith)} is {np.degrees(np.arccos(np.clip(agree, -1, 1))):.0f} "
            f"degrees from the scene's up axis {tuple(round(float(x), 4) for x in scene.up)}: leave SkyLight.up "
            "out to use the scene's",
            SkyOrientationWarning,
            stacklevel=4,
        )
    if sky.horizontal > 0 and not np.any(np.asarray(lit) > 0):
        facing = int(np.count_nonzero(scene.normals.astype(np.float64) @ zenith > 1e-6))
        warnings.warn(
            f"the sky (zenith {tuple(round(float(x), 4) for x in zenith)}) lights no patch of {scene.name!r}: "
            f"{facing} of {len(scene)} patches face its upper half and none sees it past the scene "
            f"(scene.up is {tuple(round(float(x), 4) for x in scene.up)}; a closed room is lit by a sky only "
            "through openings)",
            SkyOrientationWarning,
            stacklevel=4,
        )


def light_vector(scene, lights=(), device=None) -> np.ndarray:
    """L (N, 3) float64: emission plus the albedo-weighted direct irradiance of ``lights``."""
    scene = checked_scene(scene)
    L = scene.emission.astype(np.float64)
    lights = checked_lights(lights)
    if lights:
        L = L + scene.albedo.astype(np.float64) * _direct_irradiance(scene, lights, device)
    return L


def checked_light_vector(L, n: int) -> np.ndarray:
    """``L`` as a finite, non-negative (n, 3) float64 light vector, or InvalidInputError."""
    L = floats(L, "the light vector")
    if L.shape != (n, 3):
        raise InvalidInputError(f"the light vector must have shape ({n}, 3); got {L.shape}")
    if not np.all(np.isfinite(L)) or L.min(initial=0.0) < 0:
        raise InvalidInputError("the light vector must be finite and >= 0")
    return L


def check_radiosity_range(L: np.ndarray, albedo: np.ndarray, dtype=np.float32) -> None:
    """InvalidInputError where the radiosity of light vector ``L`` could overflow ``dtype``, before
    any pass computes it: F's rows sum to at most 1 + ROW_SUM_SLACK (what the checks allow), so
    max B <= max L / (1 - max albedo (1 + ROW_SUM_SLACK)).

    Near an albedo of 1 (which a Scene allows) that product reaches 1 and bounds nothing, and
    refusing every light there would refuse scenes the solvers answer (a closed box at 0.9995:
    333.8 by the dense solve); from an albedo of about 0.998 the bound is 2 max L / (1 - max
    albedo) instead, twice the bound of rows that sum to 1."""
    top, albedo_max = float(np.max(L, initial=0.0)), float(np.max(albedo, initial=0.0))
    # The slack's factor, or half the albedo's own distance from 1 where that is smaller (from
    # an albedo of 1 / (1 + 2 slack) ~ 0.998 up): finite below 1, and growing with the albedo.
    rho = min(albedo_max * (1.0 + ROW_SUM_SLACK), 0.5 * (1.0 + albedo_max))
    bound = top / (1.0 - rho) if rho < 1.0 else np.inf
    if top > 0 and bound > float(np.finfo(dtype).max):
        raise InvalidInputError(
            f"the radiosity may reach {bound:.3g} (max L {top:.3g} / (1 - {rho:g}), the largest "
            f"albedo times F's largest row sum), "
            f"beyond {np.dtype(dtype).name}: scale the emission and the lights down"
        )


def resolve_light(scene, lights=(), light=None, device=None) -> np.ndarray:
    """L (N, 3) float64 from light objects (``lights``) or a precomputed vector (``light``), not both."""
    if light is None:
        return light_vector(scene, lights, device)
    if len(checked_lights(lights)):
        raise InvalidInputError("give lights= (light objects) or light= (a light vector L), not both")
    scene = checked_scene(scene)
    return checked_light_vector(light, len(scene))
