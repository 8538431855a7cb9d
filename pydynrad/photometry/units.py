"""Photometric units: what the library's numbers mean when a user gives lighting quantities.

pydynrad is linear and unit-agnostic: it propagates whatever light quantity the inputs carry.
Give geometry in metres and light photometrically, and every result is photometric:

============================  =================================  ===========================
input                         unit                               where
============================  =================================  ===========================
lengths                       m                                  ``Scene`` points, positions
point / spot intensity        cd (lm/sr)                         ``PointLight.intensity``
directional light             lx on a surface facing it          ``DirectionalLight.irradiance``
sky                           cd/m2 (zenith) or lx (horizontal)  ``SkyLight``
emitting patch                lm/m2 (luminous exitance, pi L)    ``Scene(emission=...)``
============================  =================================  ===========================

Outputs are then: irradiance (``illuminance``, ``direct_irradiance``) in lux, radiosity B in
lm/m2 (a diffuse surface's luminance is B / pi cd/m2), light vectors in lm/m2. With lengths in
another unit u, read "m" as u (illuminance in lm/u^2).

Colour: the three channels are three independent copies of the same linear transport. For
photometry use one grey channel (give scalar intensities: they fill R = G = B). No luminous
efficacy is assumed anywhere: the channels carry lumens directly, never watts converted at
683 lm/W. When RGB values must be reduced to one photometric number, :func:`photometric`
weighs them with the Rec. 709 luminance coefficients, which sum to 1, so a grey triple gives
back its value.

See docs/design.md, 'Units and photometry'.
"""

from __future__ import annotations

import math

import numpy as np

from ..checks import floats
from ..errors import InvalidInputError

__all__ = [
    "REC709_LUMINANCE",
    "photometric",
    "exitance_from_luminance",
    "luminance_from_exitance",
    "isotropic_intensity",
    "lambertian_peak_intensity",
]

#: Weights of R, G and B in the luminance Y of linear Rec. 709 / sRGB primaries (sum 1).
REC709_LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def _non_negative(value, what: str) -> np.ndarray:
    a = floats(value, what)
    if not np.all(np.isfinite(a)) or a.min(initial=0.0) < 0:
        raise InvalidInputError(f"{what} must be finite and >= 0")
    return a


def photometric(rgb) -> np.ndarray:
    """One photometric value per RGB triple (..., 3) -> (...): the Rec. 709 luminance weighting."""
    a = floats(rgb, "rgb")
    if a.shape[-1:] != (3,):
        raise InvalidInputError(f"rgb must have a last axis of 3; got shape {a.shape}")
    return a @ REC709_LUMINANCE


def exitance_from_luminance(luminance):
    """Luminous exitance (lm/m2, a patch's ``emission``) of a Lambertian surface of luminance (cd/m2): pi L."""
    return math.pi * _non_negative(luminance, "luminance")


def luminance_from_exitance(exitance):
    """Luminance (cd/m2) of a Lambertian surface of exitance or radiosity (lm/m2): M / pi."""
    return _non_negative(exitance, "exitance") / math.pi


def isotropic_intensity(flux):
    """Intensity (cd) of an isotropic point source of luminous flux (lm): Phi / (4 pi)."""
    return _non_negative(flux, "flux") / (4.0 * math.pi)


def lambertian_peak_intensity(flux):
    """Peak intensity I0 (cd) of a cosine (Lambertian) point source of flux (lm) into a hemisphere: Phi / pi."""
    return _non_negative(flux, "flux") / math.pi
