"""The reference path tracer against analytic truths.

The furnace: a closed box with uniform albedo rho and uniform emission E has radiosity
B = E / (1 - rho) everywhere (B = E + rho B, since every hemisphere sees only the box).
"""

import numpy as np
import pytest
from helpers import plane_mesh

import pydynrad
from pydynrad import Camera, Scene, path_trace
from pydynrad.pathtracer import path_trace_patches


@pytest.fixture(scope="module")
def furnace():
    return pydynrad.scenes.closed_box(1.0, subdivisions=1, albedo=0.6, emission=[1.0, 0.5, 2.0])


def test_furnace_patches_converge_to_analytic(furnace, device):
    rho, e = 0.6, np.array([1.0, 0.5, 2.0])
    b = path_trace_patches(furnace, spp=1024, seed=1, device=device)
    assert b.shape == (len(furnace), 3) and b.dtype == np.float32
    truth = e / (1 - rho)
    # Each patch is an independent estimate: the mean over the patches has std err ~ std / sqrt(24).
    stderr = b.std(axis=0) / np.sqrt(len(b))
    assert np.all(np.abs(b.mean(axis=0) - truth) < 4 * stderr + 1e-3 * truth)
    assert np.all(np.abs(b - truth) < 0.25 * truth)


def test_furnace_image_matches_analytic(furnace, device):
    cam = Camera((0.5, 0.5, 0.9), (0.5, 0.5, 0.0), fov_y=60, width=16, height=12)
    img = path_trace(furnace, cam, spp=128, seed=2, device=device)
    assert img.shape == (12, 16, 3) and img.dtype == np.float32
    truth = np.array([1.0, 0.5, 2.0]) / 0.4
    stderr = img.reshape(-1, 3).std(axis=0) / np.sqrt(img.shape[0] * img.shape[1])
    assert np.all(np.abs(img.reshape(-1, 3).mean(axis=0) - truth) < 4 * stderr + 1e-3 * truth)


def test_emission_only_scene_shows_emission(device):
    """Albedo 0: the image is exactly the emission of the visible patch (no noise at all)."""
    box = pydynrad.scenes.closed_box(1.0, subdivisions=0)
    emission = np.linspace(0.5, 3.0, len(box))[:, None] * np.ones(3)
    scene = box.with_materials(albedo=0.0, emission=emission)
    cam = Camera((0.5, 0.5, 0.5), (0.5, 0.5, 0.0), fov_y=80, width=9, height=7)
    img = path_trace(scene, cam, spp=3, device=device)
    vis = pydynrad.render(scene, emission, cam, shading="flat", device=device)
    np.testing.assert_allclose(img, vis, rtol=1e-5)
    np.testing.assert_allclose(path_trace_patches(scene, spp=2, device=device), emission, rtol=1e-6)


def test_single_bounce_between_plates_matches_form_factor(device):
    """A receiver of albedo rho under a black emitting plate gathers B(x) = rho * E * F(x -> emitter);
    its area average is rho * E * F_12 with F_12 of two coaxial parallel unit squares at
    distance 1 in closed form (Howell's catalogue, C-11)."""
    x = y = 1.0  # side / distance
    xs, ys = np.sqrt(1 + x * x), np.sqrt(1 + y * y)
    f = (
        2
        / (np.pi * x * y)
        * (
            np.log(np.sqrt((1 + x * x) * (1 + y * y) / (1 + x * x + y * y)))
            + x * ys * np.arctan(x / ys)
            + y * xs * np.arctan(y / xs)
            - x * np.arctan(x)
            - y * np.arctan(y)
        )
    )
    plates = pydynrad.scenes.parallel_plates(1.0, 1.0, 1.0, subdivisions=3)
    top = plates.source_face // 2 == 1  # the emitter, facing the receiver below
    scene = plates.with_materials(albedo=np.where(top, 0.0, 0.5), emission=np.where(top, 1.0, 0.0))
    k = int(np.count_nonzero(~top))
    assert np.array_equal(np.flatnonzero(~top), np.arange(k))
    b = path_trace_patches(scene, patches=np.arange(k), spp=256, seed=5, device=device)
    mean = float(np.average(b[:, 0], weights=scene.areas[:k]))
    assert abs(mean - 0.5 * f) < 0.02 * 0.5 * f


def test_analytic_lights_match_direct_irradiance(device):
    """A single lit plane of albedo rho with a black occluder above: no light returns to the
    plane, so B = rho * direct irradiance exactly, as lights.direct_irradiance computes it
    (point, spot and directional lights, shadows included)."""
    from pydynrad.lights.sources import DirectionalLight, PointLight, SpotLight, direct_irradiance

    floor, up = plane_mesh(6)
    blocker = np.array([[0.1, 0.1, 0.5], [0.4, 0.1, 0.5], [0.4, 0.4, 0.5]])
    k = len(up)
    scene = Scene(
        np.vstack([floor, blocker]),
        np.vstack([up, [[len(floor), len(floor) + 1, len(floor) + 2]]]),
        albedo=np.append(np.full(k, 0.7), 0.0),
    )
    lights = [
        PointLight((0.3, 0.3, 1.0), (1.0, 2.0, 0.5)),
        SpotLight((0.7, 0.7, 0.8), (0, 0, -1), 3.0, 0.2, 0.6),
        DirectionalLight((0.3, -0.2, -1.0), 0.4),
    ]
    truth = 0.7 * direct_irradiance(scene, lights, device=device)[:k]
    assert (truth[:, 1] == 0).any() and (truth[:, 1] > 0).sum() > k // 2  # some shadowed, most lit
    b = path_trace_patches(scene, patches=np.arange(k), spp=3, lights=lights, device=device)
    np.testing.assert_allclose(b, truth, rtol=1e-5)  # observed 1.1e-7; shadowed patches exactly 0


def test_seed_determinism_and_pass_independence(furnace, device):
    a = path_trace_patches(furnace, spp=5, seed=7, device=device)
    b = path_trace_patches(furnace, spp=5, seed=7, device=device)
    c = path_trace_patches(furnace, spp=5, seed=8, device=device)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    # Patch subsets draw the same random numbers per patch as the full run.
    sub = path_trace_patches(furnace, patches=[3, 0], spp=5, seed=7, device=device)
    np.testing.assert_allclose(sub, a[[3, 0]], rtol=1e-6)


def test_time_limit_stops_early(furnace, device):
    b = path_trace_patches(furnace, spp=10**6, seed=0, time_limit=0.2, device=device)
    assert np.all(np.isfinite(b)) and b.min() > 0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"spp": 0}, "spp"),
        ({"spp": 2.5}, "spp"),
        ({"spp": 2**24 + 1}, r"spp .* 1\.\.16777216"),
        ({"seed": -1}, "seed"),
        ({"max_depth": 0}, "max_depth"),
        ({"max_depth": 2**31}, r"max_depth .* 1\.\.2147483647"),
        ({"patches": [0, 99]}, "patch indices"),
        ({"patches": [[0]]}, "1-D"),
        ({"lights": [object()]}, "not a light"),
        ({"time_limit": 0}, "time_limit"),
        ({"time_limit": "1"}, "time_limit"),
        ({"time_limit": True}, "time_limit"),
    ],
)
def test_bad_input_is_rejected(furnace, kwargs, match):
    with pytest.raises(pydynrad.InvalidInputError, match=match):
        path_trace_patches(furnace, **kwargs)


def test_bad_camera_is_rejected(furnace):
    with pytest.raises(pydynrad.InvalidInputError, match="Camera"):
        path_trace(furnace, camera="front")


def _cornell_vs_radiosity(device, max_edge, resolution, spp):
    """Path-traced patch radiosities of the Cornell box vs the full radiosity solution:
    (relative RMS difference, the path tracer's own relative RMS noise, scene, solution)."""
    from pydynrad.comparison import radiosity_error

    scene = pydynrad.scenes.cornell_box(max_edge=max_edge)
    F = pydynrad.form_factors(scene, resolution=resolution, device=device)
    b = pydynrad.solve(scene, F, device=device).radiosity
    # Two independent halves: their difference measures the noise of their mean.
    h1 = path_trace_patches(scene, spp=spp // 2, seed=1, device=device)
    h2 = path_trace_patches(scene, spp=spp // 2, seed=2, device=device)
    noise = 0.5 * radiosity_error(h1, h2, scene.areas)
    return radiosity_error(b, 0.5 * (h1 + h2), scene.areas), noise, scene, b


def test_cornell_box_agrees_with_full_radiosity(device):
    err, noise, scene, b = _cornell_vs_radiosity(device, max_edge=150.0, resolution=32, spp=64)
    # Within twice the Monte Carlo noise, plus 1% for what separates the two models at this
    # patching (centre point vs patch average, hemicube aliasing at R = 32).
    assert err < np.hypot(2 * noise, 0.01), (err, noise)
    # Pixel by pixel: the path-traced image and the flat-shaded radiosity image see the same
    # patches through the same rays; their mean values agree within the noise.
    cam = Camera((278.0, 273.0, -800.0), (278.0, 273.0, 0.0), fov_y=39.3, width=32, height=24)
    img = path_trace(scene, cam, spp=64, device=device)
    ref = pydynrad.render(scene, b, cam, shading="smooth", device=device)
    assert np.array_equal(img > 0, ref > 0)  # identical coverage: same rays, same visibility
    np.testing.assert_allclose(img.mean(axis=(0, 1)), ref.mean(axis=(0, 1)), rtol=0.03)


@pytest.mark.slow
def test_cornell_box_agrees_with_full_radiosity_finely_patched(device):
    err, noise, _, _ = _cornell_vs_radiosity(device, max_edge=60.0, resolution=128, spp=1024)
    assert err < np.hypot(2 * noise, 0.005), (err, noise)
