"""illuminance: sensors agree with the patches they sit on, cast no shadows, and refuse bad input."""

import numpy as np
import pytest
from helpers import ceiling_lit_box

import pydynrad
from pydynrad import InvalidInputError, PointLight
from pydynrad.photometry import illuminance


@pytest.fixture(scope="module")
def lit_box(device):
    """A closed box, lit by its emitting top wall and a point light, solved with R = 16 rows."""
    scene = ceiling_lit_box(albedo=0.6)
    light = PointLight([0.3, 0.6, 0.5], 2.0)
    F = pydynrad.form_factors(scene, 16, device=device)
    B = pydynrad.solve(scene, F, lights=[light], tol=1e-9, device=device).radiosity
    return scene, F, B, light


def test_sensors_on_patches_gather_exactly_their_rows(lit_box, device):
    scene, F, B, light = lit_box
    ids = np.arange(len(scene))
    E = illuminance(scene, B, lights=light, patches=ids, resolution=16, emitters="hemicube", device=device)
    direct = pydynrad.lights.direct_irradiance(scene, [light], device)
    # The same rays as F's rows: equal to float32 summation (4e-8 observed).
    np.testing.assert_allclose(E - direct, F @ B, rtol=1e-6)
    # And the radiosity equation itself: B = E + rho H.
    np.testing.assert_allclose(scene.emission + scene.albedo * E, B, rtol=1e-6)


def test_free_sensors_agree_with_patches_they_coincide_with(lit_box, device):
    scene, F, B, light = lit_box
    ids = np.arange(0, len(scene), 5)
    at_patch = illuminance(scene, B, lights=[light], patches=ids, resolution=32, device=device)
    free = illuminance(scene, B, scene.centers[ids], scene.normals[ids], lights=[light], resolution=32, device=device)
    # Differently rotated hemicubes of the same point: 0.16% RMS, 0.43% at most at R = 32.
    rel = (free - at_patch) / at_patch
    assert np.sqrt(np.mean(rel**2)) < 0.005
    assert np.abs(rel).max() < 0.015


def test_sensors_cast_no_shadows(device):
    # A column of sensors under a point light above a floor: each sees the light as if alone.
    pts = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float)
    scene = pydynrad.Scene(pts, [[0, 1, 2], [0, 2, 3]], albedo=0.5)
    light = PointLight([0.0, 0.0, 3.0], 100.0)
    z = np.linspace(0.0, 2.5, 6)
    points = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    E = illuminance(scene, None, points, [0, 0, 1], lights=light, device=device)
    np.testing.assert_allclose(E[:, 0], 100.0 / (3.0 - z) ** 2, rtol=1e-6)
    # and the floor below them still receives the light in full (it is the scene's patch).
    H = pydynrad.lights.direct_irradiance(scene, [light], device)
    d2 = np.sum((scene.centers - light.position) ** 2, axis=1)
    np.testing.assert_allclose(H[:, 0], 100.0 * 3.0 / d2**1.5, rtol=1e-6)


def test_bad_sensors_are_refused(lit_box):
    scene, _, B, _ = lit_box
    with pytest.raises(InvalidInputError, match=r"normals\[1\] is zero"):
        illuminance(scene, B, [[0.5, 0.5, 0.5]] * 2, [[0, 0, 1], [0, 0, 0]])
    with pytest.raises(InvalidInputError, match=r"points\[0\] is not finite"):
        illuminance(scene, B, [[np.nan, 0.5, 0.5]], [0, 0, 1])
    with pytest.raises(InvalidInputError, match="shape"):
        illuminance(scene, B[:3], [0.5, 0.5, 0.5], [0, 0, 1])
    with pytest.raises(InvalidInputError, match="not both"):
        illuminance(scene, B, [0.5, 0.5, 0.5], [0, 0, 1], patches=[0])
    with pytest.raises(InvalidInputError, match="radiosity must be finite"):
        illuminance(scene, -B, [0.5, 0.5, 0.5], [0, 0, 1])
    # Refused whether or not the call uses them (no radiosity and no sky: no gather; hemicube
    # emitters: no visibility grid).
    with pytest.raises(InvalidInputError, match=r"resolution must lie in 2\.\.4096; got 1"):
        illuminance(scene, None, [0.5, 0.5, 0.5], [0, 0, 1], resolution=1)
    with pytest.raises(InvalidInputError, match=r"visibility samples per side\) must lie in 1\.\.64; got 0"):
        illuminance(scene, B, [0.5, 0.5, 0.5], [0, 0, 1], visibility_grid=0)


def test_sensors_far_from_the_origin(device):
    # The device frame re-centres sensor points with the scene: a floor lit by a point light
    # and its emitting square, 1e6 m away, reads the same as at the origin.
    emitter = np.array([[-0.5, -0.5, 2.0], [-0.5, 0.5, 2.0], [0.5, 0.5, 2.0], [0.5, -0.5, 2.0]])
    floor = np.array([[-5, -5, 0], [5, -5, 0], [5, 5, 0], [-5, 5, 0]], float)
    tris = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    points = np.array([[0.3, 0.2, 0.5], [2.0, -1.0, 1.0]])
    results = []
    for shift in (np.zeros(3), np.array([1e6, -2e6, 5e5])):
        scene = pydynrad.Scene(
            np.vstack([emitter, floor]) + shift, tris, albedo=0.5, emission=np.array([50.0, 50.0, 0.0, 0.0])
        )
        light = PointLight(shift + [1.0, 1.0, 3.0], 100.0)
        B = pydynrad.light_vector(scene, [light], device)
        results.append(
            [
                illuminance(scene, B, points + shift, [0, 0, 1], lights=light, emitters=mode, device=device)
                for mode in ("hemicube", "analytic")
            ]
        )
    # The same float32 device positions either way (the frame's shift is exact in float64):
    # equal bit for bit observed; float32 rounding would be ~1e-7.
    np.testing.assert_allclose(results[1], results[0], rtol=1e-7)


def test_a_sensor_just_under_a_desk_is_in_its_shadow(device):
    """A sensor 1 cm under a 1 m desk top in a 141 m scene: shadow rays leave free sensors by the
    sky gather's offset (1e-5 of the diagonal), not a patch's (1e-4, 1.4 cm: above the desk)."""
    v = np.array(
        [
            [-50, -50, 0],
            [50, -50, 0],
            [50, 50, 0],
            [-50, 50, 0],
            [-0.5, -0.5, 0.75],
            [0.5, -0.5, 0.75],
            [0.5, 0.5, 0.75],
            [-0.5, 0.5, 0.75],
        ],
        float,
    )
    scene = pydynrad.Scene(v, [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], albedo=0.0)
    for light in (pydynrad.DirectionalLight((0, 0, -1), 1000.0), PointLight((0, 0, 3), 100.0)):
        under, beside = illuminance(
            scene, None, [[0, 0, 0.74], [2, 0, 0.74]], [[0, 0, 1]] * 2, lights=[light], device=device
        )
        assert under.max() == 0.0 and beside.min() > 0.0, light
    # The sky it sees past the desk's edges, within 1.2 degrees of the horizon: of order
    # pi L (0.01 / 0.5)^2 = 1.3 lx of the open 3142 (observed 2.5, the square's corners more).
    sky = pydynrad.SkyLight(zenith_luminance=1000.0, up=(0, 0, 1), resolution=32)
    under, beside = illuminance(scene, None, [[0, 0, 0.74], [2, 0, 0.74]], [[0, 0, 1]] * 2, lights=[sky], device=device)
    assert under.max() < 1e-3 * beside.min()
