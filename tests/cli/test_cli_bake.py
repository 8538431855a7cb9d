"""Lights of every kind on the command line, and `pydynrad bake`."""

import math

import numpy as np
import pytest
import trimesh
from helpers import assert_one_line_error, run_main

import pydynrad
from bench.cie171_data import LM63_EXAMPLE
from pydynrad import DirectionalLight, InvalidInputError, PointLight, SkyLight, SpotLight
from pydynrad.bake.gltf import read_glb
from pydynrad.cli.main import build_parser
from pydynrad.lights import parse_ies
from pydynrad.lights.text import parse_light
from pydynrad.renderer import Renderer

SPOT = "spot:pos=278,540,280;dir=0,-1,0.2;intensity=1e5,8e4,6e4;outer=35;inner=25"
SUN = "sun:dir=0.1,-0.2,1;irradiance=0.01"


def test_every_light_kind_reads_as_its_object():
    assert parse_light("point:pos=1,2,3;intensity=5") == PointLight((1, 2, 3), 5)
    assert parse_light(" Point : position=1,2,3 ; intensity=1,2,3 ") == PointLight((1, 2, 3), (1, 2, 3))
    assert parse_light(SPOT) == SpotLight(
        (278, 540, 280), (0, -1, 0.2), (1e5, 8e4, 6e4), math.radians(25), math.radians(35)
    )
    assert parse_light("spot:pos=0,0,0;dir=0,0,1;intensity=1;outer=10").inner_angle == math.radians(10)
    assert parse_light(SUN) == DirectionalLight((0.1, -0.2, 1), 0.01)
    assert parse_light("directional:direction=0,-1,0;irradiance=2") == DirectionalLight((0, -1, 0), 2)
    assert parse_light("278,400,280:5e4") == PointLight((278, 400, 280), 5e4)  # the older form
    assert parse_light("sky:model=cie_overcast;zenith=3000;ground=0.2") == SkyLight(
        "cie_overcast", zenith_luminance=3000.0, ground_reflectance=0.2
    )
    assert parse_light("sky:model=12;horizontal=2e4;sun=0.5,0.2,0.6;up=0,1,0;resolution=32") == SkyLight(
        12, horizontal_illuminance=2e4, sun_direction=(0.5, 0.2, 0.6), up=(0, 1, 0), resolution=32
    )


def test_a_luminaire_reads_its_file(tmp_path):
    path = tmp_path / "lamp.ies"
    path.write_text(LM63_EXAMPLE)
    lum = parse_light(f"luminaire:pos=1,2,3;file={path};nadir=0,0,-2;scale=0.5")
    assert lum.position == (1, 2, 3) and lum.nadir == (0, 0, -1) and lum.scale == (0.5, 0.5, 0.5)
    np.testing.assert_array_equal(lum.distribution.candela, parse_ies(LM63_EXAMPLE).candela)


@pytest.mark.parametrize(
    "text, needle",
    [
        ("lamp:zenith=1", "unknown light kind 'lamp'"),
        ("sky:zenith=-1", "zenith_luminance must be finite and >= 0"),
        ("sky:model=clear;zenith=1", "give sun_direction"),
        ("luminaire:pos=1,2,3;file=/no/such.ies", "cannot read '/no/such.ies'"),
        ("point:pos=1,2,3;colour=1", "unknown field 'colour'; its fields are pos, intensity"),
        ("point:pos=1,2,3", "missing intensity"),
        ("point:pos=1,2;intensity=1", "pos must be three numbers"),
        ("point:pos=1,2,3;pos=1,2,3;intensity=1", "given twice"),
        ("point:pos=1,2,3;intensity", "expected FIELD=VALUE"),
        ("sun:dir=0,0,0;irradiance=1", "non-zero"),
        ("spot:pos=0,0,0;dir=0,0,1;intensity=1;outer=10;inner=20", "inner (20 degrees) must not exceed outer"),
        ("point:pos=1,2,3;intensity=-1", ">= 0"),
        ("1,2,3", "X,Y,Z:R,G,B"),
    ],
)
def test_bad_light_text_is_named(text, needle):
    with pytest.raises(InvalidInputError) as info:
        parse_light(text)
    assert needle in str(info.value)


@pytest.mark.parametrize(
    "command",
    [
        ["render", "cornell_box", "-o", "x.png"],
        ["walk", "cornell_box", "--path", "p"],
        ["compare", "cornell_box", "-o", "x.png"],
        ["bake", "cornell_box", "-o", "x.glb"],
    ],
)
def test_render_walk_compare_and_bake_take_several_lights_of_any_kind(command):
    args = build_parser().parse_args(command + ["--light", SPOT, "--light", SUN, "--light", "1,2,3:4"])
    assert args.light == [parse_light(SPOT), parse_light(SUN), PointLight((1, 2, 3), 4)]


def test_a_bad_light_on_the_command_line_is_one_line(capsys):
    assert_one_line_error(
        *run_main(["render", "cornell_box", "-o", "x.png", "--light", "lamp:x=1"], capsys)[::2],
        "unknown light kind 'lamp'",
    )


@pytest.fixture(scope="module")
def reference(device):
    """What bake should write: the library's full solve of the 120-patch box under SPOT and SUN."""
    scene = pydynrad.scenes.cornell_box(max_edge=250.0)
    F = pydynrad.form_factors(scene, resolution=8, device=device)
    B = pydynrad.solve(scene, F, [parse_light(SPOT), parse_light(SUN)]).radiosity
    return scene, Renderer(scene, device).corner_radiosity(B)


def test_bake_writes_the_solution_as_vertex_colours(reference, tmp_path, capsys):
    scene, corners = reference
    out = tmp_path / "box.glb"
    code, stdout, err = run_main(
        [
            "bake",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "-o",
            str(out),
            "--light",
            SPOT,
            "--light",
            SUN,
            "--exposure",
            "-4",
            "--quiet",
        ],
        capsys,
    )
    assert code == 0, err
    mesh = next(iter(trimesh.load(out, process=False).geometry.values()))
    np.testing.assert_allclose(np.asarray(mesh.vertex_attributes["_RADIOSITY"])[mesh.faces], corners, rtol=1e-6)
    assert read_glb(out.read_bytes())[0]["asset"]["extras"]["pydynrad"]["exposure"] == -4.0


def test_bake_with_a_lightmap_writes_the_image_and_its_uv_mesh(reference, tmp_path, capsys):
    scene, corners = reference
    out, exr = tmp_path / "box.glb", tmp_path / "box.exr"
    code, stdout, err = run_main(
        [
            "bake",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "-o",
            str(out),
            "--lightmap",
            str(exr),
            "--texels-per-unit",
            "0.2",
            "--light",
            SPOT,
            "--light",
            SUN,
            "--quiet",
        ],
        capsys,
    )
    assert code == 0, err
    doc, attributes, faces = read_glb(out.read_bytes())
    meta = doc["asset"]["extras"]["pydynrad"]["lightmap"]
    image = pydynrad.image_io.read_image(exr)
    assert image.shape == (meta["height"], meta["width"], 3) and meta["image"] == "box.exr"
    assert "TEXCOORD_1" in attributes and len(faces) == len(scene)
    np.testing.assert_allclose(attributes["_RADIOSITY"][faces], corners, rtol=1e-6)
    # Looked up at the patch centres through the file's UVs, the image holds this solution's smooth radiosity.
    from scipy.ndimage import map_coordinates

    centre = attributes["TEXCOORD_1"][faces].astype(np.float64).mean(axis=1)
    coords = [centre[:, 1] * image.shape[0] - 0.5, centre[:, 0] * image.shape[1] - 0.5]
    got = np.stack([map_coordinates(image[:, :, c], coords, order=1, mode="nearest") for c in range(3)], axis=1)
    np.testing.assert_allclose(got, corners.mean(axis=1), rtol=0, atol=2e-6 * corners.max())


@pytest.mark.parametrize(
    "extra, needle",
    [
        (["-o", "x.obj"], "must end in .glb or .ply"),
        (["-o", "x.ply", "--lightmap", "x.exr"], "must end in .glb"),
        (["-o", "x.glb", "--lightmap", "x.png"], "must end in .exr"),
        (["-o", "/no/such/folder/x.glb"], "does not exist"),
    ],
)
def test_bake_refuses_bad_targets_before_any_work(capsys, extra, needle):
    assert_one_line_error(*run_main(["bake", "cornell_box"] + extra, capsys)[::2], needle)


def test_bake_refuses_to_overwrite_its_scene_and_escapes_its_name(tmp_path, capsys):
    """`bake SRC -o SRC` had replaced the source mesh with the bake; a PLY bake of a scene named
    with non-ASCII letters had crashed after the solve (a PLY header is ASCII); a store's
    block size past any index is refused when made."""
    src = tmp_path / "caf\u00e9.ply"
    trimesh.Trimesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), [[0, 1, 2]]).export(str(src))
    before = src.read_bytes()
    light = ["--light", "point:pos=0.2,0.2,1;intensity=1"]
    code, _, err = run_main(["bake", str(src), "-o", str(src), "--resolution", "8", *light], capsys)
    assert_one_line_error(code, err, "is the scene file being baked")
    assert src.read_bytes() == before
    code, _, err = run_main(["bake", str(src), "-o", str(tmp_path / "c.ply"), "--resolution", "8", *light], capsys)
    assert code == 0, err
    assert b"comment pydynrad scene: caf\\xe9" in (tmp_path / "c.ply").read_bytes()
    code, _, err = run_main(
        [
            "formfactors",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "-o",
            str(tmp_path / "st"),
            "--workers",
            "0",
            "--block-rows",
            str(10**20),
        ],
        capsys,
    )
    assert_one_line_error(code, err, "block_rows must lie in")


def test_a_lightmap_coarser_than_its_patches_is_refused(tmp_path, capsys):
    """xatlas floors the density it packs at: 1e-9 texels per unit gave 1e-3's atlas and was
    recorded as 1e-9; below a texel for the median patch the bake is refused, before the solve."""
    code, _, err = run_main(
        [
            "bake",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "-o",
            str(tmp_path / "c.glb"),
            "--lightmap",
            str(tmp_path / "c.exr"),
            "--texels-per-unit",
            "1e-9",
        ],
        capsys,
    )
    assert_one_line_error(code, err, "gives the median patch", "texels")
    with pytest.raises(InvalidInputError, match="median patch"):
        pydynrad.bake_lightmap(pydynrad.scenes.cornell_box(max_edge=250.0), np.ones((336, 3)), 1e-3)
