"""Luminaires: point sources with a measured intensity distribution I(C, gamma), oriented in the scene.

A :class:`PhotometricDistribution` is a table of intensities (cd) on the C-gamma system of
photometry: gamma is the angle from the luminaire's nadir axis (0..180 degrees), C the
azimuth about it (0..360 degrees, C = 0 along the luminaire's C0 axis, C = 90 along
``nadir-up x C0``). Tables come from IES LM-63 files (:func:`~pydynrad.lights.ies.read_ies`),
EULUMDAT files (:func:`~pydynrad.lights.ldt.read_ldt`) or the closed forms
:meth:`PhotometricDistribution.lambertian` and :meth:`~PhotometricDistribution.isotropic`.
Symmetric tables are expanded to the full C range when read, so the kernel sees one layout.

Between table angles the intensity is bilinear in (C, gamma), on the host
(:meth:`PhotometricDistribution.intensity`) and on the device (``kernels/lights.h``) alike;
outside the table's gamma range it is 0.

A :class:`LuminaireLight` places a distribution at a position with its nadir and C0 axes,
times an RGB ``scale``; it is accepted wherever lights are (one shadow ray per point).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..checks import floats, integer, number, rgb_tuple, unit_vector, vec3_tuple
from ..errors import InvalidInputError

__all__ = ["PhotometricDistribution", "LuminaireLight"]


@dataclass(frozen=True, eq=False)
class PhotometricDistribution:
    """Intensities ``candela[c, g]`` (cd) at C angles ``c_angles`` and gamma angles ``gamma_angles`` (degrees).

    ``c_angles`` increase from 0 and either hold one angle (a rotationally symmetric
    distribution) or span 0..360 (both ends included); ``gamma_angles`` increase within
    0..180. ``name`` and ``lumens`` (the lamps' rated flux, if the file gave one) are kept for
    reports.
    """

    c_angles: np.ndarray
    gamma_angles: np.ndarray
    candela: np.ndarray
    name: str = ""
    lumens: float | None = None
    source: str = field(default="", repr=False)

    def __post_init__(self) -> None:
        c = floats(self.c_angles, "c_angles").ravel()
        g = floats(self.gamma_angles, "gamma_angles").ravel()
        cd = floats(self.candela, "candela")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(g))):  # NaN passes every order test below
            raise InvalidInputError("c_angles and gamma_angles must be finite")
        if len(g) < 2 or np.any(np.diff(g) <= 0) or g[0] < 0 or g[-1] > 180:
            raise InvalidInputError("gamma_angles must be >= 2 increasing angles within 0..180 degrees")
        if len(c) == 0 or np.any(np.diff(c) <= 0) or c[0] != 0 or (len(c) > 1 and c[-1] != 360):
            raise InvalidInputError("c_angles must increase from 0 to 360 degrees (or be the single angle 0)")
        if cd.shape != (len(c), len(g)):
            raise InvalidInputError(
                f"candela must have shape ({len(c)}, {len(g)}) (C planes, gamma angles); got {cd.shape}"
            )
        if not np.all(np.isfinite(cd)) or cd.min() < 0:
            raise InvalidInputError("candela values must be finite and >= 0")
        if len(c) > 1 and not np.array_equal(cd[0], cd[-1]):  # one direction, two intensities
            raise InvalidInputError(
                "candela at C = 360 must equal those at C = 0 (the same half-plane); they differ "
                f"by up to {np.abs(cd[-1] - cd[0]).max():g} cd"
            )
        for name, a in (("c_angles", c), ("gamma_angles", g), ("candela", cd)):
            a = np.array(a, dtype=np.float64)
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    # -- closed forms ---------------------------------------------------------------------------------
    @classmethod
    def lambertian(cls, peak: float, step: float = 0.25) -> PhotometricDistribution:
        """A cosine source: ``I = peak cos(gamma)`` below the horizon (gamma <= 90), 0 above.

        Sampled every ``step`` degrees (linear interpolation of the cosine: relative error
        below ``(step in radians)^2 / 8`` of the peak, 2.4e-6 at 0.25 degrees).
        """
        step = number(step, "lambertian step (degrees)")
        steps = 90.0 / step if step > 0 else 0.0
        # A step that divides 90 samples the horizon, where the cosine's kink is.
        if not (0 < step <= 90 and abs(steps - round(steps)) <= 1e-9 * steps and steps <= 360_000):
            raise InvalidInputError(f"lambertian step must divide 90 degrees, at least 90 / 360000; got {step!r}")
        g = np.linspace(0.0, 180.0, 2 * int(round(steps)) + 1)
        return cls(
            [0.0], g, [np.maximum(np.cos(np.radians(g)), 0.0) * number(peak, "lambertian peak (cd)")], name="lambertian"
        )

    @classmethod
    def isotropic(cls, intensity: float) -> PhotometricDistribution:
        """The same intensity (cd) in every direction."""
        return cls([0.0], [0.0, 180.0], [[number(intensity, "isotropic intensity (cd)")] * 2], name="isotropic")

    # -- evaluation -----------------------------------------------------------------------------------
    def intensity(self, c, gamma) -> np.ndarray:
        """Intensity (cd) at C angles ``c`` and gamma angles ``gamma`` (degrees, broadcast), bilinear."""
        c, gamma = floats(c, "C angles"), floats(gamma, "gamma angles")
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(gamma))):  # no direction has them
            raise InvalidInputError("C and gamma angles must be finite")
        c = np.mod(c, 360.0)
        g = self.gamma_angles
        inside = (gamma >= g[0]) & (gamma <= g[-1])
        j = np.clip(np.searchsorted(g, gamma, side="right") - 1, 0, len(g) - 2)
        tg = np.clip((gamma - g[j]) / (g[j + 1] - g[j]), 0.0, 1.0)
        cd = self.candela
        if len(self.c_angles) == 1:
            out = np.broadcast_to(cd[0, j] * (1 - tg) + cd[0, j + 1] * tg, np.broadcast_shapes(c.shape, gamma.shape))
        else:
            ca = self.c_angles
            i = np.clip(np.searchsorted(ca, c, side="right") - 1, 0, len(ca) - 2)
            tc = np.clip((c - ca[i]) / (ca[i + 1] - ca[i]), 0.0, 1.0)
            lo = cd[i, j] * (1 - tg) + cd[i, j + 1] * tg
            hi = cd[i + 1, j] * (1 - tg) + cd[i + 1, j + 1] * tg
            out = lo * (1 - tc) + hi * tc
        return np.where(inside, out, 0.0)

    def flux(self, n: int = 720) -> float:
        """Luminous flux (lm) of the interpolated distribution: midpoint quadrature on an n x 2n (gamma, C) grid."""
        n = integer(n, "flux quadrature size n", 1, 4096)
        gamma = (np.arange(n) + 0.5) * (180.0 / n)
        c = (np.arange(2 * n) + 0.5) * (180.0 / n)
        I = self.intensity(c[None, :], gamma[:, None])
        dw = np.sin(np.radians(gamma))[:, None] * (math.pi / n) ** 2
        return float(np.sum(I * dw))

    def table(self) -> np.ndarray:
        """The device table: nC, nG, C angles and gamma angles (radians), intensities C-major, float32
        (candela beyond float32 come out inf: the lights' packing refuses them)."""
        with np.errstate(over="ignore"):
            return np.concatenate(
                [
                    [len(self.c_angles), len(self.gamma_angles)],
                    np.radians(self.c_angles),
                    np.radians(self.gamma_angles),
                    self.candela.ravel(),
                ]
            ).astype(np.float32)


@dataclass(frozen=True, eq=False)
class LuminaireLight:
    """A point source with an intensity distribution.

    Parameters
    ----------
    position : (3,)
        Scene units (the light's irradiance is per square metre in a scene of any unit: the
        scene's ``unit`` converts).
    distribution : PhotometricDistribution
        Intensities in cd.
    nadir : (3,), optional
        Direction of gamma = 0 (normalised here); by default straight down in the scene it
        lights (``-scene.up``: a ceiling luminaire). Host-side methods of a luminaire not yet
        placed in a scene (:meth:`placed`) take (0, 0, -1).
    c0 : (3,)
        Direction of the C = 0 half-plane (made perpendicular to ``nadir`` here); C = 90 lies
        along ``-nadir x c0``, as in the C-gamma system seen from above. Where it is parallel to
        a default nadir, +z (for a nadir along x) is used instead.
    scale : float or (3,)
        RGB factor on the intensities (1: the table's candela in every channel).
    """

    position: tuple
    distribution: PhotometricDistribution
    nadir: tuple | None = None
    c0: tuple = (1.0, 0.0, 0.0)
    scale: tuple = (1.0, 1.0, 1.0)

    def placed(self, up) -> LuminaireLight:
        """This luminaire in a scene whose up axis is ``up``: itself where its nadir is given,
        else a copy pointing down ``-up``."""
        if self._given_nadir:
            return self
        nadir = -unit_vector(up, "up")
        c0 = np.asarray(self._given_c0, np.float64)
        if np.linalg.norm(c0 - nadir * float(c0 @ nadir)) < 1e-6 * np.linalg.norm(c0):
            c0 = np.array([0.0, 0.0, 1.0])
        return LuminaireLight(self.position, self.distribution, tuple(nadir), tuple(c0), self.scale)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_given_nadir", self.nadir is not None)
        object.__setattr__(
            self, "_given_c0", tuple(np.asarray(self.c0, np.float64).ravel()) if np.size(self.c0) == 3 else self.c0
        )
        if self.nadir is None:
            object.__setattr__(self, "nadir", (0.0, 0.0, -1.0))

        if not isinstance(self.distribution, PhotometricDistribution):
            raise InvalidInputError(
                "LuminaireLight.distribution must be a PhotometricDistribution "
                "(read_ies, read_ldt, PhotometricDistribution.lambertian)"
            )
        object.__setattr__(self, "position", vec3_tuple(self.position, "LuminaireLight.position"))
        nadir = unit_vector(self.nadir, "LuminaireLight.nadir")
        c0 = unit_vector(self.c0, "LuminaireLight.c0")
        c0 = c0 - nadir * float(c0 @ nadir)
        if np.linalg.norm(c0) < 1e-6:
            raise InvalidInputError("LuminaireLight.c0 must not be parallel to nadir")
        object.__setattr__(self, "nadir", tuple(map(float, nadir)))
        object.__setattr__(self, "c0", tuple(map(float, c0 / np.linalg.norm(c0))))
        object.__setattr__(self, "scale", rgb_tuple(self.scale, "LuminaireLight.scale"))

    @property
    def c90(self) -> tuple:
        """Direction of the C = 90 half-plane: -nadir x c0."""
        return tuple(np.cross(-np.asarray(self.nadir), self.c0))

    def intensity_towards(self, directions) -> np.ndarray:
        """Intensity (cd, grey: before ``scale``) along unit ``directions`` (..., 3) from the luminaire."""
        d = np.asarray(directions, dtype=np.float64)
        gamma = np.degrees(np.arccos(np.clip(d @ np.asarray(self.nadir), -1.0, 1.0)))
        c = np.degrees(np.arctan2(d @ np.asarray(self.c90), d @ np.asarray(self.c0)))
        return self.distribution.intensity(c, gamma)

    def _table(self) -> np.ndarray:
        return np.concatenate([np.asarray(self.c0), self.c90, self.distribution.table()]).astype(np.float32)

    def _packed(self, offset: int) -> list:
        return [*self.position, 3.0, *self.nadir, float(offset), *self.scale, 0.0]
