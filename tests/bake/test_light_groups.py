"""Light groups: per-group solutions combined with weights equal a solve with weighted lights."""

import numpy as np
import pytest

import pydynrad
from pydynrad import DirectionalLight, InvalidInputError, PointLight, SpotLight
from pydynrad.bake import LightGroups

WEIGHTS = {"emission": 0.5, "lamp": (1.0, 0.5, 0.2), "spots": 2.0}


@pytest.fixture(scope="module")
def cornell_lights(device):
    scene = pydynrad.scenes.cornell_box(max_edge=200.0)
    F = pydynrad.form_factors(scene, resolution=16, device=device)
    lamp = PointLight(
        (278, 450, 280), 0.04
    )  # W/sr in the millimetre box, irradiance per m^2: what 1e6 times more had lit per mm^2
    spot = SpotLight((100, 500, 100), (0.3, -1, 0.4), (0.03, 0.02, 0.01), 0.3, 0.6)
    sun = DirectionalLight((0.2, -0.3, 1.0), 0.02)  # through the open side
    groups = LightGroups(scene, {"lamp": [lamp], "spots": [spot, sun]}, device=device)
    return scene, F, groups, (lamp, spot, sun)


def _weighted(scene, lights):
    """The same scene and lights with every intensity scaled by hand: the truth to compare with."""
    lamp, spot, sun = lights
    rgb = np.asarray(WEIGHTS["lamp"])
    scaled = [
        PointLight(lamp.position, np.asarray(lamp.intensity) * rgb),
        SpotLight(spot.position, spot.direction, np.asarray(spot.intensity) * 2.0, spot.inner_angle, spot.outer_angle),
        DirectionalLight(sun.direction, np.asarray(sun.irradiance) * 2.0),
    ]
    return scene.with_materials(emission=scene.emission * 0.5), scaled


def test_combined_dense_solves_equal_a_solve_with_weighted_lights(cornell_lights):
    scene, F, groups, lights = cornell_lights
    combined = groups.solve(F, method="dense").combine(WEIGHTS)
    scene2, scaled = _weighted(scene, lights)
    truth = pydynrad.solve(scene2, F, scaled, method="dense").radiosity
    # Direct light is computed in float32 per light: linearity holds to its rounding.
    np.testing.assert_allclose(combined, truth, rtol=1e-6, atol=1e-9 * truth.max())
    # The groups' lights sum to the light vector of all of them.
    np.testing.assert_allclose(groups.light(), pydynrad.light_vector(scene, list(lights)), rtol=1e-6)


def test_combined_iterative_solves_equal_to_the_tolerance(cornell_lights):
    scene, F, groups, lights = cornell_lights
    combined = groups.solve(F, dtype=np.float64, tol=1e-10).combine(WEIGHTS)
    scene2, scaled = _weighted(scene, lights)
    truth = pydynrad.solve(scene2, F, scaled, method="dense").radiosity
    np.testing.assert_allclose(combined, truth, rtol=0, atol=1e-8 * truth.max())


def test_combined_multibounce_and_dynamic_equal_weighted_lights(cornell_lights, device):
    scene, F, groups, lights = cornell_lights
    scene2, scaled = _weighted(scene, lights)
    L = pydynrad.light_vector(scene2, scaled, device)
    K = pydynrad.multibounce(scene, F, dtype=np.float64, device=device)
    truth = pydynrad.multibounce_radiosity(scene, K, light=L)
    np.testing.assert_allclose(groups.multibounce(K).combine(WEIGHTS), truth, rtol=1e-6, atol=1e-9 * truth.max())
    dyn = pydynrad.DynamicRadiosity(scene, F, local_size=120, storage="fp64", far_field=False, device=device)
    dyn.update((278, 273, -200))
    truth = dyn.radiosity(light=L)
    np.testing.assert_allclose(groups.dynamic(dyn).combine(WEIGHTS), truth, rtol=1e-6, atol=1e-9 * truth.max())
    # The far field shares each cluster's indirect light by the patches' first bounce, which is
    # not linear in L: groups combine to its answer for the weighted lights within 1e-3 of the
    # maximum (observed 2.4e-4, PoCL; its error against the full solve is 1.1%).
    dyn = pydynrad.DynamicRadiosity(scene, F, local_size=120, storage="fp64", device=device)
    dyn.update((278, 273, -200))
    truth = dyn.radiosity(light=L)
    np.testing.assert_allclose(groups.dynamic(dyn).combine(WEIGHTS), truth, rtol=0, atol=1e-3 * truth.max())


def test_groups_refuse_bad_input(cornell_lights, device):
    scene, F, groups, lights = cornell_lights
    per_group = groups.multibounce(pydynrad.multibounce(scene, F, device=device))
    with pytest.raises(InvalidInputError, match="unknown light group.*'sky'"):
        per_group.combine({"sky": 1.0})
    with pytest.raises(InvalidInputError, match="one weight per light group"):
        per_group.combine([1.0, 2.0])
    with pytest.raises(InvalidInputError, match="finite"):
        per_group.combine({"lamp": np.nan})
    with pytest.raises(InvalidInputError, match="given twice"):
        LightGroups(scene, {"emission": [lights[0]]})
    with pytest.raises(InvalidInputError, match=r"shape \(384, 3\)"):
        LightGroups(scene, {"baked": np.ones((10, 3))})
    with pytest.raises(InvalidInputError, match="not a light"):
        LightGroups(scene, {"lamp": ["bright"]})
    with pytest.raises(InvalidInputError, match="map group names"):
        LightGroups(scene, [lights[0]])
    with pytest.raises(InvalidInputError, match="list one per group"):  # once: a raw TypeError
        per_group.combine(0.5)
    for value in (None, 3):
        with pytest.raises(InvalidInputError, match="not a light or a sequence of lights"):
            LightGroups(scene, {"lamp": value})
    other = pydynrad.scenes.cornell_box(max_edge=300.0)
    dyn = pydynrad.DynamicRadiosity(
        other, pydynrad.form_factors(other, resolution=8, device=device), local_size=16, device=device
    )
    dyn.update((278, 273, -200))
    with pytest.raises(InvalidInputError, match="another scene"):
        groups.dynamic(dyn)
    # After a move the world is another scene: the message says so and what to do.
    poses = [np.eye(4), np.eye(4)]
    poses[0][:3, 3], poses[1][:3, 3] = (150.0, 420.0, 420.0), (250.0, 420.0, 380.0)  # clear of the box's blocks
    block = pydynrad.RigidObject(pydynrad.scenes.block(100.0, 0), poses[0])
    moving = pydynrad.DynamicRadiosity(
        scene, F, local_size=64, objects=[block], observer=(278, 273, -200), device=device
    )
    at_first = LightGroups(moving.scene, {"lamp": [lights[0]]}, device=device)
    at_first.dynamic(moving)
    moving.move(block, poses[1])
    moving.update((278, 273, -200))
    with pytest.raises(InvalidInputError, match="objects moved since.*from dynamic.scene"):
        at_first.dynamic(moving)
