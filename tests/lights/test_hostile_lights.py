"""Hostile lights and sensors: values past float32, text that is not a plain number, bad files."""

import numpy as np
import pytest

import pydynrad
from pydynrad.errors import InvalidInputError
from pydynrad.renderer import Renderer

# Far from the origin and at extreme scales: the device frame (docs/design.md, 'Device frame').
SHIFT = np.array([1.0, -0.5, 0.25])


def _moved_box(scale, offset, albedo=0.5, emission=1.0):
    base = pydynrad.scenes.closed_box(subdivisions=1)
    return pydynrad.Scene(base.vertices * scale + offset * SHIFT, base.faces, albedo=albedo, emission=emission)


@pytest.mark.parametrize("scale, offset", [(1.0, 0.0), (1e-4, 1e3), (1e3, 1e7)])
def test_point_light_and_rays_in_the_users_frame(device, scale, offset):
    scene = _moved_box(scale, offset, emission=0.0)
    light = scene.bbox.mean(axis=0) + 0.1 * scale
    E = pydynrad.lights.direct_irradiance(scene, [pydynrad.PointLight(light, 5.0)], device=device)[:, 0]
    # Nothing inside a convex box occludes: E = I cos / r^2 in float64.
    to_light = light - scene.centers
    r = np.linalg.norm(to_light, axis=1)
    expected = 5.0 * np.einsum("ij,ij->i", scene.normals.astype(np.float64), to_light) / r**3
    np.testing.assert_allclose(E, expected, rtol=1e-5)
    # A ray from the light to each patch centre stops there: t = 1 for directions of that length.
    patch, t, front = pydynrad.geometry.bvh.cast_rays(
        scene, np.broadcast_to(light, to_light.shape), -to_light, device=device
    )
    np.testing.assert_allclose(t, 1.0, rtol=1e-5)
    assert front.all() and np.mean(patch == np.arange(len(scene))) > 0.99  # a centre may sit on an edge
    # Depth from the renderer in the user's unit: the box is [0, scale]^3 shifted.
    cam = pydynrad.Camera(light, light + [1.0, 0.0, 0.0], up=(0, 0, 1), fov_y=10.0, width=8, height=8)
    depth = Renderer(scene, device=device).visibility(cam).depth
    wall_x = scale + offset * SHIFT[0]
    assert np.abs(depth.min() / (wall_x - light[0]) - 1) < 1e-3  # the centre pixels are off-axis by < fov


def test_sensors_and_bakes_refuse_what_would_come_back_as_inf_or_text(tmp_path):
    from pydynrad.lights import LuminaireLight, PhotometricDistribution
    from pydynrad.photometry import illuminance

    plates = pydynrad.scenes.parallel_plates(subdivisions=1)
    # 1e39 cd is inf in the device's table (inf times a zero weight: NaN at the sensor), and 1e30
    # cd times 1e10 passes float32 at the sensor: both came back as NaN or inf with a warning.
    for lum, message in (
        (LuminaireLight((0.5, 0.5, 0.5), PhotometricDistribution.isotropic(1e39)), "candela table"),
        (
            LuminaireLight((0.5, 0.5, 0.5), PhotometricDistribution.isotropic(1e30), scale=1e10),
            "illuminance overflows float32",
        ),
    ):
        with pytest.raises(InvalidInputError, match=message):
            illuminance(plates, None, [[0.5, 0.5, 0.0]], [0, 0, 1], lights=lum)
    with pytest.raises(InvalidInputError, match="radiosity must be numbers"):
        pydynrad.bake.export_mesh(plates, np.full((len(plates), 3), "1"), tmp_path / "m.glb")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "text",
    [
        "point:pos=1,2,3;intensity=1_000",
        "point:pos=1,2,3;intensity=５",
        "point:pos=1,2,3;intensity=\u0665",
        "point:pos=0x10,2,3;intensity=5",
    ],
)
def test_light_text_takes_plain_numbers_only(text):
    # Python's float() reads "1_000" and other scripts' digits: a typo must not become a light.
    from pydynrad.lights.text import parse_light

    with pytest.raises(InvalidInputError, match="must be"):
        parse_light(text)


def test_a_sky_resolution_of_a_fraction_is_refused_not_cut():
    from pydynrad.lights.text import parse_light

    with pytest.raises(InvalidInputError, match="resolution must be an integer; got 64.5"):
        parse_light("sky:model=uniform;zenith=100;resolution=64.5")
    assert parse_light("sky:model=uniform;zenith=100;resolution=32").resolution == 32


def test_photometric_files_the_review_found_refused_still_read():
    from test_luminaires import ldt_text

    from bench.cie171_data import LM63_EXAMPLE
    from pydynrad.lights import parse_ies, parse_ldt

    # A DOS end-of-file mark after the table.
    assert parse_ies(LM63_EXAMPLE.rstrip() + "\r\n\x1a").candela.max() == parse_ies(LM63_EXAMPLE).candela.max()
    # Isym = 0 with two planes C0 and C180 goes round the circle; one plane is rotational.
    two = parse_ldt(ldt_text(0, 2, 180.0, [0.0, 90.0], [[100.0, 50.0], [80.0, 40.0]]))
    assert two.c_angles.tolist() == [0.0, 180.0, 360.0]
    assert parse_ldt(ldt_text(0, 1, 0.0, [0.0, 90.0], [[100.0, 50.0]])).c_angles.tolist() == [0.0]
