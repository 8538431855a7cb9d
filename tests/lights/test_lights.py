"""Analytic lights: direct irradiance against the inverse-square cosine law, shadows, cones."""

import math

import numpy as np
import pytest
from helpers import plane_mesh

import pydynrad
from pydynrad import DirectionalLight, PointLight, SpotLight, light_vector
from pydynrad.lights import direct_irradiance


def plate(n=12, size=2.0, z=0.0, extra=None, albedo=0.5):
    """An n x n grid of quads (2 triangles each) on z = const, normals +z, centred on the
    origin; ``extra`` = (points, triangles) appended (e.g. a blocker)."""
    pts, tris = plane_mesh(n, size, z, origin=(-size / 2, -size / 2))
    if extra is not None:
        tris = np.vstack([tris, extra[1] + len(pts)])
        pts = np.vstack([pts, extra[0]])
    return pydynrad.Scene(pts, tris, albedo=albedo, name="plate")


def inverse_square(scene, pos, intensity):
    d = pos - scene.centers.astype(np.float64)
    r = np.linalg.norm(d, axis=1)
    cos = np.sum(d * scene.normals, axis=1) / r
    return np.maximum(cos, 0)[:, None] * np.broadcast_to(intensity, (3,)) / r[:, None] ** 2


def test_point_light_inverse_square_cosine(device):
    s = plate()
    pos = np.array([0.3, -0.2, 0.8])
    E = direct_irradiance(s, [PointLight(pos, (1.0, 2.0, 3.0))], device=device)
    assert E.dtype == np.float32 and E.shape == (len(s), 3)
    np.testing.assert_allclose(E, inverse_square(s, pos, (1.0, 2.0, 3.0)), rtol=2e-5)
    # Lights add up.
    E2 = direct_irradiance(s, [PointLight(pos, 1.0), PointLight(-pos * [1, 1, -1] + [0, 0, 1.6], 2.0)], device=device)
    truth = inverse_square(s, pos, 1.0) + inverse_square(s, -pos * [1, 1, -1] + [0, 0, 1.6], 2.0)
    np.testing.assert_allclose(E2, truth, rtol=2e-5)


def test_back_side_is_dark(device):
    s = plate()
    E = direct_irradiance(s, [PointLight((0.0, 0.0, -1.0), 5.0)], device=device)
    assert np.all(E == 0)


def test_blocker_casts_shadow(device):
    h, half = 1.0, 0.25
    # A blocker square at z = h/2 facing down (towards the plate) and a light at z = h above the origin.
    bp = np.array([[-half, -half, h / 2], [half, -half, h / 2], [half, half, h / 2], [-half, half, h / 2]])
    s = plate(n=16, extra=(bp, np.array([[0, 2, 1], [0, 3, 2]])))
    light = np.array([0.0, 0.0, h])
    E = direct_irradiance(s, [PointLight(light, 1.0)], device=device)[:-2, 0]
    c = s.centers[:-2].astype(np.float64)
    # Where the segment centre -> light crosses z = h/2: at half the centre's (x, y).
    cross = np.abs(c[:, :2] * 0.5).max(axis=1)
    law = inverse_square(pydynrad.Scene(s.vertices, s.faces[:-2]), light, 1.0)[:, 0]
    shadowed, lit = cross < half - 0.02, cross > half + 0.02
    assert shadowed.sum() > 10 and lit.sum() > 10
    assert np.all(E[shadowed] == 0)
    np.testing.assert_allclose(E[lit], law[lit], rtol=2e-5)
    # The blocker's underside faces the plate, not the light: unlit.
    assert np.all(direct_irradiance(s, [PointLight(light, 1.0)], device=device)[-2:] == 0)


def test_spot_light_cone(device):
    s = plate(n=20, size=4.0)
    pos = np.array([0.0, 0.0, 1.0])
    inner, outer = math.radians(30), math.radians(45)
    E = direct_irradiance(s, [SpotLight(pos, (0, 0, -2), 1.0, inner, outer)], device=device)[:, 0]
    c = s.centers.astype(np.float64)
    angle = np.arctan2(np.hypot(c[:, 0], c[:, 1]), 1.0)
    law = inverse_square(s, pos, 1.0)[:, 0]
    inside, outside = angle < inner - 0.01, angle > outer + 0.01
    ramp = ~inside & ~outside
    assert inside.sum() > 10 and outside.sum() > 10
    np.testing.assert_allclose(E[inside], law[inside], rtol=2e-5)
    assert np.all(E[outside] == 0)
    assert np.all((E[ramp] >= 0) & (E[ramp] <= law[ramp] * (1 + 1e-3)))


def test_directional_light(device):
    s = plate()
    d = np.array([1.0, 0.0, -1.0])
    E = direct_irradiance(s, [DirectionalLight(d, (2.0, 1.0, 0.5))], device=device)
    np.testing.assert_allclose(E, np.tile([2.0, 1.0, 0.5], (len(s), 1)) * math.cos(math.pi / 4), rtol=1e-6)


def test_light_vector_is_emission_plus_reflected_direct_light(device):
    s = plate(albedo=(0.2, 0.4, 0.6)).with_materials(emission=0.1)
    lights = [PointLight((0, 0, 1.0), 1.0)]
    L = light_vector(s, lights, device=device)
    assert L.shape == (len(s), 3) and L.dtype == np.float64
    np.testing.assert_allclose(L, 0.1 + s.albedo * direct_irradiance(s, lights, device=device), rtol=1e-6)
    np.testing.assert_array_equal(light_vector(s), s.emission)


def test_light_validation():
    with pytest.raises(pydynrad.InvalidInputError, match="finite"):
        PointLight((0, np.nan, 0), 1.0)
    with pytest.raises(pydynrad.InvalidInputError, match=">= 0"):
        PointLight((0, 0, 0), (1, -1, 1))
    with pytest.raises(pydynrad.InvalidInputError, match="non-zero"):
        DirectionalLight((0, 0, 0), 1.0)
    with pytest.raises(pydynrad.InvalidInputError, match="inner_angle"):
        SpotLight((0, 0, 0), (0, 0, 1), 1.0, 0.5, 0.2)
    with pytest.raises(pydynrad.InvalidInputError, match="inner_angle"):
        SpotLight((0, 0, 0), (0, 0, 1), 1.0, 0.0, 4.0)
    with pytest.raises(pydynrad.InvalidInputError, match="not a light"):
        light_vector(plate(n=2), ["sun"])
    spot = SpotLight((0, 0, 0), (0, 0, 3), 1.0, 0.1, 0.2)
    assert spot.direction == (0.0, 0.0, 1.0)
    # A light whose intensity rounds to zero in float32 on the device (1e-48 W/sr over the box's
    # device unit squared, (1024 mm)^2 = 1.05 m^2 now that the box declares millimetres (issue
    # 41), is below the smallest subnormal) would light nothing: refused, not a dark answer.
    # Subnormal intensities light as they should.
    box = pydynrad.scenes.cornell_box(max_edge=250.0)
    with pytest.raises(pydynrad.InvalidInputError, match="underflows float32"):
        light_vector(box, [PointLight((278, 540, 280), 1e-48)])
    with pytest.raises(pydynrad.InvalidInputError, match="underflows float32"):
        light_vector(box, [DirectionalLight((0, -1, 0), (1e-46,) * 3)])
    faint, normal = (
        pydynrad.lights.direct_irradiance(box, [PointLight((278, 540, 280), I)]).astype(np.float64) / I
        for I in (1e-39, 1.0)
    )
    lit = normal > 1e-3 * normal.max()
    np.testing.assert_allclose(faint[lit], normal[lit], rtol=1e-2)  # subnormal on the device: few bits
    light_vector(box, [DirectionalLight((0, -1, 0), (1.0, 1e-50, 1.0))])  # one negligible channel: fine
    with pytest.raises(AttributeError):
        spot.intensity = (2, 2, 2)  # frozen


def test_pack_lights_layout():
    # The three float4 per light that kernels/lights.h reads, written out by hand.
    spot = SpotLight((1, 2, 3), (0, 0, 2), (0.5, 0.25, 1.0), 0.1, 0.3)
    sun = DirectionalLight((0, -1, 0), 2.0)
    packed = pydynrad.lights.pack_lights([spot, sun])
    assert packed.shape == (2, 12) and packed.dtype == np.float32
    slope = 1.0 / (math.cos(0.1) - math.cos(0.3))
    np.testing.assert_allclose(packed[0], [1, 2, 3, 1, 0, 0, 1, slope, 0.5, 0.25, 1.0, math.cos(0.3)], rtol=1e-6)
    np.testing.assert_array_equal(packed[1, :8], [0, 0, 0, 2, 0, -1, 0, 1])
    np.testing.assert_array_equal(packed[1, 8:11], [2, 2, 2])
    np.testing.assert_array_equal(pydynrad.lights.pack_lights(PointLight((4, 5, 6), 1.0))[0, :4], [4, 5, 6, 0])
    assert pydynrad.lights.pack_lights([]).shape == (0, 12)
    with pytest.raises(pydynrad.InvalidInputError, match="not a light"):
        pydynrad.lights.pack_lights([spot, "lamp"])
