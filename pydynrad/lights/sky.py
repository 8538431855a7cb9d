"""Sky light: the uniform sky, the traditional CIE overcast sky and the CIE standard general skies.

A :class:`SkyLight` is a light at infinity whose luminance depends on direction. Its direct
contribution to a point is gathered by a hemicube there: every pixel whose ray leaves the
scene adds its delta form factor times pi times the sky's luminance in that direction
(``kernels/sky.h``, ``kernels/gather.cl``), so buildings, overhangs and window reveals shade
the sky as they should. Below the horizon a ray sees a uniform ground of luminance
``ground_reflectance * E_h / pi``, E_h the sky's unobstructed horizontal illuminance (the
sun's light reflected by the ground is not included: give the sun as a
:class:`~pydynrad.DirectionalLight`, which lights the scene's own ground patches).

Sky models (``kind``):

* ``"uniform"``: the same luminance everywhere, ``E_h = pi L``.
* ``"cie_overcast"``: the traditional CIE overcast sky (Moon and Spencer 1942),
  ``L(Z) = L_z (1 + 2 cos Z) / 3``, ``E_h = 7 pi / 9 L_z``; the sky of CIE 171:2006.
* ``1`` .. ``15``: the CIE standard general skies of CIE S 011 / ISO 15469,
  ``L = L_z f(chi) phi(Z) / (f(Z_s) phi(0))`` with the gradation ``phi(Z) = 1 + a exp(b / cos Z)``
  and the indicatrix ``f(chi) = 1 + c (exp(d chi) - exp(d pi / 2)) + e cos^2 chi`` (chi: the
  angle to the sun, Z_s: the sun's zenith angle). ``"overcast"`` is type 1, ``"clear"`` type 12
  (the CIE standard clear sky, low turbidity). Types with a sun-dependent indicatrix need
  ``sun_direction``.

The sky's zenith is the scene's up axis (:attr:`pydynrad.Scene.up`) unless ``up`` is given:
a sky is placed in a scene when it lights it. A sky that lights no patch at all (its zenith
pointing into the floor, say) is warned about with :class:`SkyOrientationWarning`, which says
why. :func:`sun_direction` turns a solar elevation and azimuth into a direction in a scene of
any up axis.

Units: luminance in cd/m2, illuminance in lux (see docs/guide/units.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..checks import integer, number, unit_vector
from ..checks import resolution as checked_resolution
from ..errors import InvalidInputError
from ..geometry.scene import rotation_to, up_vector

__all__ = ["SkyLight", "CIE_GENERAL_SKIES", "pack_sky", "sun_direction", "north_east", "SkyOrientationWarning"]


class SkyOrientationWarning(UserWarning):
    """A sky adds nothing to a scene, or its zenith disagrees with the scene's up axis."""


def north_east(up=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """Unit (north, east) directions on the horizon of a scene whose up axis is ``up``: for +y up
    (glTF) north is -z and east +x; for +z up north is +y and east +x; for any other up, those of
    +y carried by the smallest rotation from +y to ``up``."""
    r = rotation_to((0.0, 1.0, 0.0), up)  # accepts "+y", "-z", ... or a vector
    return r @ np.array([0.0, 0.0, -1.0]), r @ np.array([1.0, 0.0, 0.0])


def sun_direction(elevation: float, azimuth: float, up=(0.0, 1.0, 0.0)) -> tuple:
    """Unit vector towards the sun at ``elevation`` degrees above the horizon and ``azimuth``
    degrees clockwise from north (90 = east) seen from above, in a scene whose up axis is ``up``
    (``scene.up``; north and east as :func:`north_east` gives them). A
    :class:`~pydynrad.DirectionalLight` for that sun travels the opposite way."""
    el, az = math.radians(number(elevation, "elevation")), math.radians(number(azimuth, "azimuth"))
    if not -90.0 <= math.degrees(el) <= 90.0:
        raise InvalidInputError(f"elevation must lie in -90..90 degrees; got {elevation!r}")

    north, east = north_east(up)
    u = up_vector(up)
    d = math.cos(el) * (math.cos(az) * north + math.sin(az) * east) + math.sin(el) * u
    return tuple(map(float, d / np.linalg.norm(d)))


_GRADATION = {1: (4.0, -0.70), 2: (1.1, -0.8), 3: (0.0, -1.0), 4: (-1.0, -0.55), 5: (-1.0, -0.32), 6: (-1.0, -0.15)}
_INDICATRIX = {
    1: (0.0, -1.0, 0.0),
    2: (2.0, -1.5, 0.15),
    3: (5.0, -2.5, 0.30),
    4: (10.0, -3.0, 0.45),
    5: (16.0, -3.0, 0.30),
    6: (24.0, -2.8, 0.15),
}
#: CIE S 011 sky type -> (gradation group, indicatrix group); the parameters a, b and c, d, e are above.
_TYPES = {
    1: (1, 1),
    2: (1, 2),
    3: (2, 1),
    4: (2, 2),
    5: (3, 1),
    6: (3, 2),
    7: (3, 3),
    8: (3, 4),
    9: (4, 2),
    10: (4, 3),
    11: (4, 4),
    12: (5, 4),
    13: (5, 5),
    14: (6, 5),
    15: (6, 6),
}
#: (a, b, c, d, e) of each CIE standard general sky type 1..15.
CIE_GENERAL_SKIES = {t: _GRADATION[g] + _INDICATRIX[i] for t, (g, i) in _TYPES.items()}
_ALIASES = {"overcast": 1, "clear": 12}


@dataclass(frozen=True)
class SkyLight:
    """A sky at infinity over a uniform ground, lighting every patch and sensor it can see.

    Parameters
    ----------
    kind : str or int
        ``"uniform"``, ``"cie_overcast"`` (traditional, ``(1 + 2 cos Z) / 3``), a CIE S 011
        type 1..15, or its alias ``"overcast"`` (1) / ``"clear"`` (12).
    zenith_luminance : float, optional
        Luminance at the zenith, cd/m2 (>= 0). Give this or ``horizontal_illuminance``.
    horizontal_illuminance : float, optional
        Illuminance of the unobstructed sky on a horizontal plane, lux (>= 0).
    sun_direction : (3,), optional
        Unit vector towards the sun (normalised here); needed by types whose indicatrix
        depends on the sun (c or e non-zero), ignored otherwise.
    up : (3,), optional
        The zenith in scene coordinates (normalised here); by default the up axis of the scene
        the sky lights (:attr:`pydynrad.Scene.up`). Host-side methods of a sky not yet placed
        in a scene (:meth:`placed`) take +z.
    ground_reflectance : float
        Reflectance of the ground below the horizon, in [0, 1).
    resolution : int
        Hemicube resolution of the sky-visibility pass at every patch (3 R^2 rays each).
    """

    kind: object = "uniform"
    zenith_luminance: float | None = None
    horizontal_illuminance: float | None = None
    sun_direction: tuple | None = None
    up: tuple | None = None
    ground_reflectance: float = 0.0
    resolution: int = 64

    def __post_init__(self) -> None:
        kind = _ALIASES.get(self.kind, self.kind) if isinstance(self.kind, str) else self.kind
        if isinstance(kind, (int, np.integer)) and not isinstance(kind, bool):
            if int(kind) not in CIE_GENERAL_SKIES:
                raise InvalidInputError(f"CIE standard general sky types are 1..15; got {kind}")
            kind = int(kind)
        elif kind not in ("uniform", "cie_overcast"):
            raise InvalidInputError(
                f"sky kind must be 'uniform', 'cie_overcast', 'overcast', 'clear' or 1..15; got {self.kind!r}"
            )
        object.__setattr__(self, "kind", kind)
        if self.up is not None:
            object.__setattr__(self, "up", tuple(map(float, unit_vector(self.up, "SkyLight.up"))))
        needs_sun = isinstance(kind, int) and (CIE_GENERAL_SKIES[kind][2] != 0 or CIE_GENERAL_SKIES[kind][4] != 0)
        if self.sun_direction is None:
            if needs_sun:
                raise InvalidInputError(f"CIE sky type {kind} depends on the sun's position: give sun_direction")
        else:
            object.__setattr__(
                self, "sun_direction", tuple(map(float, unit_vector(self.sun_direction, "SkyLight.sun_direction")))
            )
            # CIE S 011 defines the sky for a sun at or above the horizon (Z_s <= 90 degrees); below
            # it, the formulas give a sky of its own, and the likely cause is a direction given
            # as the sunlight's way down (a DirectionalLight's) rather than towards the sun.
            if needs_sun and self.up is not None and float(np.dot(self.up, self.sun_direction)) < 0.0:
                raise InvalidInputError(
                    f"SkyLight.sun_direction {self.sun_direction} is below the horizon (up {self.up}): CIE sky "
                    f"type {kind} is defined for a sun at or above it; give the direction towards the sun (a "
                    "DirectionalLight's direction is the way its light travels, the opposite)"
                )
        given = [v is not None for v in (self.zenith_luminance, self.horizontal_illuminance)]
        if sum(given) != 1:
            raise InvalidInputError(
                "give a SkyLight exactly one of zenith_luminance (cd/m2) or horizontal_illuminance (lux)"
            )
        for name in ("zenith_luminance", "horizontal_illuminance"):
            value = getattr(self, name)
            if value is not None:
                value = number(value, f"SkyLight.{name}")
                if not math.isfinite(value) or value < 0:
                    raise InvalidInputError(f"SkyLight.{name} must be finite and >= 0; got {value!r}")
                object.__setattr__(self, name, value)
        rho = number(self.ground_reflectance, "SkyLight.ground_reflectance")
        if not 0.0 <= rho < 1.0:
            raise InvalidInputError(f"SkyLight.ground_reflectance must lie in [0, 1); got {rho!r}")
        object.__setattr__(self, "ground_reflectance", rho)
        object.__setattr__(self, "resolution", checked_resolution(self.resolution, "SkyLight.resolution"))

    # -- placing the sky in a scene -------------------------------------------------------------------
    @property
    def zenith_direction(self) -> tuple:
        """The zenith used on the host: ``up``, or +z for a sky not placed in a scene."""
        return self.up if self.up is not None else (0.0, 0.0, 1.0)

    @property
    def _sun(self) -> tuple:
        return self.sun_direction if self.sun_direction is not None else self.zenith_direction

    def placed(self, up) -> SkyLight:
        """This sky in a scene whose up axis is ``up``: itself where its own ``up`` is given,
        else a copy with that zenith."""
        if self.up is not None:
            return self
        from dataclasses import replace

        return replace(self, up=tuple(map(float, unit_vector(up, "up"))))

    # -- the luminance distribution, in float64 on the host ------------------------------------------
    def _parameters(self) -> tuple[float, float, float, float, float]:
        if self.kind == "uniform":
            return 0.0, 0.0, 0.0, -1.0, 0.0
        if self.kind == "cie_overcast":
            return math.nan, math.nan, math.nan, math.nan, math.nan
        return CIE_GENERAL_SKIES[self.kind]

    def _norm(self) -> float:
        """1 / (f(Z_s) phi(0)): the general sky's zenith normalisation."""
        a, b, c, d, e = self._parameters()
        chi = math.acos(max(-1.0, min(1.0, float(np.dot(self.zenith_direction, self._sun)))))
        f = 1.0 + c * (math.exp(d * chi) - math.exp(d * math.pi / 2)) + e * math.cos(chi) ** 2
        return 1.0 / (f * (1.0 + a * math.exp(b)))

    def relative_luminance(self, directions) -> np.ndarray:
        """L / L_z of the sky along unit ``directions`` (..., 3); 0 below the horizon (no ground)."""
        w = np.asarray(directions, dtype=np.float64)
        cz = w @ np.asarray(self.zenith_direction)
        above = cz > 0
        czs = np.where(above, cz, 1.0)
        if self.kind == "cie_overcast":
            rel = (1.0 + 2.0 * czs) / 3.0
        else:
            a, b, c, d, e = self._parameters()
            cchi = np.clip(w @ np.asarray(self._sun), -1.0, 1.0)
            f = 1.0 + c * (np.exp(d * np.arccos(cchi)) - math.exp(d * math.pi / 2)) + e * cchi**2
            rel = f * (1.0 + a * np.exp(b / czs)) * self._norm()
        return np.where(above, rel, 0.0)

    def horizontal_factor(self, n: int = 1024) -> float:
        """E_h / L_z: the unobstructed horizontal illuminance per unit zenith luminance (sr).

        Midpoint quadrature over (cos Z, azimuth), n x 2n cells (relative error ~1e-6 for
        the smooth CIE distributions); exactly pi for the uniform sky. The default n's value
        is computed once per sky (0.3 s).
        """
        n = integer(n, "horizontal_factor quadrature size n", 1, 4096)
        if n == 1024:
            return self._horizontal_factor
        return self._quadrature(n)

    @cached_property
    def _horizontal_factor(self) -> float:
        return self._quadrature(1024)

    def _quadrature(self, n: int) -> float:
        if self.kind == "uniform":
            return math.pi
        up = np.asarray(self.zenith_direction)
        helper = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        t = np.cross(up, helper)
        t /= np.linalg.norm(t)
        bt = np.cross(up, t)
        mu = (np.arange(n) + 0.5) / n
        az = (np.arange(2 * n) + 0.5) * (math.pi / n)
        m, a = np.meshgrid(mu, az, indexing="ij")
        s = np.sqrt(1.0 - m * m)
        w = (s * np.cos(a))[..., None] * t + (s * np.sin(a))[..., None] * bt + m[..., None] * up
        return float(np.sum(self.relative_luminance(w) * m) * (1.0 / n) * (math.pi / n))

    @property
    def zenith(self) -> float:
        """Zenith luminance L_z, cd/m2."""
        if self.zenith_luminance is not None:
            return self.zenith_luminance
        return self.horizontal_illuminance / self.horizontal_factor()

    @property
    def horizontal(self) -> float:
        """Unobstructed horizontal illuminance of the sky, lux."""
        if self.horizontal_illuminance is not None:
            return self.horizontal_illuminance
        return self.zenith_luminance * self.horizontal_factor()

    @property
    def ground_luminance(self) -> float:
        """Luminance of the ground below the horizon, cd/m2: rho_g E_h / pi."""
        return self.ground_reflectance * self.horizontal / math.pi if self.ground_reflectance else 0.0

    def luminance(self, directions) -> np.ndarray:
        """Luminance (cd/m2) along unit ``directions`` (..., 3), the ground's below the horizon."""
        w = np.asarray(directions, dtype=np.float64)
        above = w @ np.asarray(self.zenith_direction) > 0
        return np.where(above, self.zenith * self.relative_luminance(w), self.ground_luminance)

    def _packed(self) -> np.ndarray:
        mode = 2.0 if self.kind == "cie_overcast" else 1.0
        a, b, c, d, e = (0.0,) * 5 if self.kind == "cie_overcast" else self._parameters()
        norm = 0.0 if self.kind == "cie_overcast" else self._norm()
        return np.array(
            [*self.zenith_direction, mode, *self._sun, self.zenith, a, b, c, d, e, norm, self.ground_luminance, 0.0],
            dtype=np.float32,
        )


def pack_sky(lights, up=None) -> np.ndarray:
    """(4, 4) float32: the sky among ``lights`` in ``kernels/sky.h``'s packing (mode 0: none).

    ``lights`` is a checked sequence of light objects; more than one sky is an error. ``up``:
    the scene's up axis (``scene.up``), the zenith of a sky that gives none (+z without it).
    """
    skies = [light for light in lights if isinstance(light, SkyLight)]
    if len(skies) > 1:
        raise InvalidInputError(f"at most one SkyLight per call; got {len(skies)}")
    if not skies:
        return np.zeros((4, 4), dtype=np.float32)
    sky = skies[0] if up is None else skies[0].placed(up)
    return sky._packed().reshape(4, 4)
