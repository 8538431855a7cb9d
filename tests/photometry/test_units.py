"""Photometric unit conversions against their integrals."""

import math

import numpy as np
import pytest

from pydynrad import InvalidInputError
from pydynrad.photometry import units


def test_grey_rgb_is_its_own_photometric_value():
    assert units.REC709_LUMINANCE.sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(units.photometric([[2.0, 2.0, 2.0], [0.0, 1.0, 0.0]]), [2.0, 0.7152])


def test_conversions_match_their_integrals():
    # Midpoint quadrature of intensity over the sphere / hemisphere gives back the flux.
    n = 20000
    theta = (np.arange(n) + 0.5) * (math.pi / n)
    dw = 2 * math.pi * np.sin(theta) * (math.pi / n)
    assert np.sum(units.isotropic_intensity(1000.0) * dw) == pytest.approx(1000.0, rel=1e-7)
    up = theta < math.pi / 2
    cosine_flux = np.sum(units.lambertian_peak_intensity(1000.0) * np.cos(theta[up]) * dw[up])
    assert cosine_flux == pytest.approx(1000.0, rel=1e-7)
    # A Lambertian surface of luminance L emits pi L per unit area (integral of L cos over the hemisphere).
    assert units.exitance_from_luminance(300.0) == pytest.approx(np.sum(300.0 * np.cos(theta[up]) * dw[up]), rel=1e-7)
    assert units.luminance_from_exitance(units.exitance_from_luminance(300.0)) == pytest.approx(300.0)


def test_negative_quantities_are_refused():
    with pytest.raises(InvalidInputError, match="flux must be finite and >= 0"):
        units.isotropic_intensity(-1.0)
    with pytest.raises(InvalidInputError, match="last axis of 3"):
        units.photometric([1.0, 2.0])
