"""A scene's unit and up axis: skies, suns, luminaires, sensors and exports use them."""

import warnings

import numpy as np
import pytest
import trimesh

import pydynrad
from pydynrad import DirectionalLight, InvalidInputError, LuminaireLight, SkyLight
from pydynrad.geometry.scene import rotation_to, unit_metres, up_vector
from pydynrad.lights.ies import parse_ies
from pydynrad.lights.sky import SkyOrientationWarning, sun_direction
from pydynrad.photometry import illuminance, work_plane

# A small IES LM-63 file: a rotationally symmetric downlight (cd at gamma 0..90).
IES = """IESNA:LM-63-2002
[TEST] units and up axis
TILT=NONE
1 1000 1 7 1 1 2 0.1 0.1 0
1 1 100
0 15 30 45 60 75 90
0
800 780 700 560 380 170 0
"""


def _yard(up="+y"):
    """An open yard: a 4 x 4 m floor with a 2 m wall and a 1 m box on it (y up), lit from outside."""
    quads = []

    def quad(a, b, c, d):
        quads.append([a, b, c, d])

    quad((0, 0, 0), (0, 0, 4), (4, 0, 4), (4, 0, 0))  # floor, facing +y
    quad((0, 0, 0), (4, 0, 0), (4, 2, 0), (0, 2, 0))  # wall at z = 0 facing +z
    x0, x1, z0, z1, h = 1.5, 2.5, 1.5, 2.5, 1.0
    quad((x0, h, z0), (x0, h, z1), (x1, h, z1), (x1, h, z0))  # box top
    quad((x0, 0, z1), (x1, 0, z1), (x1, h, z1), (x0, h, z1))  # box side facing +z
    quad((x1, 0, z0), (x1, h, z0), (x1, h, z1), (x1, 0, z1))  # box side facing +x
    pts = np.array(quads, float).reshape(-1, 3)
    tris = np.array(
        [[4 * k, 4 * k + 1, 4 * k + 2] for k in range(len(quads))]
        + [[4 * k, 4 * k + 2, 4 * k + 3] for k in range(len(quads))]
    )
    r = rotation_to("+y", up)
    scene = pydynrad.Scene(pts @ r.T, tris, albedo=0.5, name="yard", up=up)
    return pydynrad.geometry.patching.subdivide_scene(scene, max_edge=0.5)


def test_unit_and_up_parsing():
    assert unit_metres("mm") == 0.001 and unit_metres("ft") == 0.3048 and unit_metres(0.25) == 0.25
    np.testing.assert_array_equal(up_vector("-z"), [0, 0, -1])
    for bad in ("parsec", -1.0, 0, True):
        with pytest.raises(InvalidInputError):
            unit_metres(bad)
    with pytest.raises(InvalidInputError):
        up_vector((0, 0, 0))
    r = rotation_to("+z", "+y")
    np.testing.assert_allclose(r @ [0, 0, 1], [0, 1, 0], atol=1e-15)
    assert np.linalg.det(r) == pytest.approx(1.0)
    # Defaults: built-ins declare theirs; a file is metres, +y unless told.
    box = pydynrad.scenes.cornell_box(max_edge=None)
    assert box.unit == 0.001 and box.unit_name == "mm" and tuple(box.up) == (0, 1, 0)
    assert pydynrad.scenes.village(houses=1, detail=0.25).up.tolist() == [0, 1, 0]
    assert pydynrad.scenes.parallel_plates(subdivisions=0).up.tolist() == [0, 0, 1]
    # North is -z with y up, +y with z up (the same direction, rotated): east +x in both.
    np.testing.assert_allclose(sun_direction(0, 0, "+y"), [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(sun_direction(0, 90, "+z"), [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(
        rotation_to("+y", "+z") @ sun_direction(30, 135, "+y"), sun_direction(30, 135, "+z"), atol=1e-15
    )


def test_a_rotated_scene_gets_the_same_sky_and_sun(device):
    solutions = []
    for up in ("+y", "+z"):
        scene = _yard(up)
        sun = DirectionalLight(-np.asarray(sun_direction(40, 135, scene.up)), 50000.0)
        sky = SkyLight("cie_overcast", horizontal_illuminance=10000.0, resolution=32)
        F = pydynrad.form_factors(scene, resolution=32, device=device)
        with warnings.catch_warnings():
            warnings.simplefilter("error", SkyOrientationWarning)
            solutions.append(pydynrad.solve(scene, F, lights=[sky, sun], device=device).radiosity)
    # The hemicubes of a rotated patch turn with it only up to their in-plane orientation: to
    # rounding on most patches, within the hemicube's discretisation on all.
    np.testing.assert_allclose(solutions[1], solutions[0], rtol=2e-2)
    assert np.median(np.abs(solutions[1] / solutions[0] - 1)) < 1e-3
    assert solutions[0].min() > 0


def test_the_sky_lights_the_y_up_cornell_box(device):
    box = pydynrad.scenes.cornell_box(max_edge=200.0)
    sky = SkyLight("cie_overcast", horizontal_illuminance=10000.0, resolution=16)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SkyOrientationWarning)
        E = pydynrad.lights.direct_irradiance(box, [sky], device=device)
    floor = box.normals[:, 1] > 0.99
    assert E[floor].max() > 0
    # The old default zenith, +z in a y-up box, sees nothing but the black ground: said, not silent.
    with pytest.warns(SkyOrientationWarning) as said:
        pydynrad.lights.direct_irradiance(
            box, [SkyLight(horizontal_illuminance=1e4, up=(0, 0, 1), resolution=8)], device=device
        )
    messages = [str(w.message) for w in said]
    assert any("lights no patch" in m for m in messages) and any(
        "90 degrees from the scene's up" in m for m in messages
    )


def test_a_millimetre_room_and_a_metre_room_read_the_same_lux(device):
    lamp = parse_ies(IES)
    room_m = pydynrad.scenes.closed_box((4.0, 3.0, 2.5), subdivisions=2, albedo=0.5)
    room_mm = pydynrad.Scene(
        room_m.vertices * 1000.0, room_m.faces, albedo=0.5, emission=room_m.emission, unit="mm", up="+z"
    )
    plane_m = work_plane([[0, 0], [4, 0], [4, 3], [0, 3]], 0.75, scene=room_m)
    plane_mm = work_plane([[0, 0], [4000, 0], [4000, 3000], [0, 3000]], 750.0, scene=room_mm)
    np.testing.assert_allclose(plane_mm.points, plane_m.points * 1000.0)  # EN 12464-1's spacing, in metres
    lux = []
    for room, plane, k in ((room_m, plane_m, 1.0), (room_mm, plane_mm, 1000.0)):
        light = [LuminaireLight(np.array([2.0, 1.5, 2.4]) * k, lamp)]  # nadir: down the scene's up axis
        F = pydynrad.form_factors(room, resolution=32, device=device)
        B = pydynrad.solve(room, F, lights=light, device=device).radiosity
        lux.append(illuminance(room, B, plane.points, plane.normals, lights=light, resolution=32, device=device))
    np.testing.assert_allclose(lux[1], lux[0], rtol=1e-4)
    # Under the lamp: at least its direct 800 cd / (1.65 m)^2.
    assert lux[0][:, 0].max() > 800 / 1.65**2


def test_an_exported_glb_is_metres_y_up(tmp_path, device):
    box = pydynrad.scenes.cornell_box(max_edge=250.0)
    B = pydynrad.solve(box, pydynrad.form_factors(box, resolution=16, device=device), device=device).radiosity
    path = pydynrad.export_mesh(box, B, tmp_path / "box.glb")
    mesh = trimesh.load(path, process=False)
    mesh = next(iter(mesh.geometry.values())) if isinstance(mesh, trimesh.Scene) else mesh
    np.testing.assert_allclose(mesh.bounds, box.bbox * 0.001, rtol=1e-6, atol=1e-7)  # metres
    assert mesh.extents[1] == pytest.approx(0.5488, rel=1e-6)  # the box's height along +y
    # A z-up scene is turned on write: its height comes out along +y.
    room = pydynrad.scenes.closed_box((4.0, 3.0, 2.5), subdivisions=0, albedo=0.5)
    room_b = np.ones((len(room), 3))
    m2 = trimesh.load(pydynrad.export_mesh(room, room_b, tmp_path / "room.glb"), process=False)
    m2 = next(iter(m2.geometry.values())) if isinstance(m2, trimesh.Scene) else m2
    np.testing.assert_allclose(m2.extents, [4.0, 2.5, 3.0], rtol=1e-6)
    pygltflib = pytest.importorskip("pygltflib")
    gltf = pygltflib.GLTF2().load(str(path))
    prim = gltf.meshes[0].primitives[0]
    acc = gltf.accessors[prim.attributes.POSITION]
    np.testing.assert_allclose(acc.max, box.bbox[1] * 0.001, rtol=1e-6)
    assert prim.attributes.COLOR_0 is not None
    ply = pydynrad.export_mesh(box, B, tmp_path / "box.ply")
    np.testing.assert_allclose(trimesh.load(ply, process=False).bounds, box.bbox * 0.001, rtol=1e-6, atol=1e-7)


def test_load_declares_unit_and_up(tmp_path):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1000 0 0\nv 0 0 -1000\nf 1 2 3\n")
    scene = pydynrad.load(tmp_path / "t.obj", unit="mm", up="+y")
    assert scene.unit == 0.001 and scene.up.tolist() == [0, 1, 0]
    assert pydynrad.load(tmp_path / "t.obj").unit == 1.0
    scene = pydynrad.load(tmp_path / "t.obj", up="+z", max_edge=400.0)
    assert scene.up.tolist() == [0, 0, 1] and scene.unit == 1.0  # kept through patching
    with pytest.raises(pydynrad.errors.SceneFileError, match="unknown length unit"):
        pydynrad.load(tmp_path / "t.obj", unit="furlong")
