"""Moving objects in path files: load_walk reads them as ObjectTracks, and a walk from the file
is the walk of the same tracks built in Python (truth: poses written out in plain numpy)."""

import json
import re

import numpy as np
import pytest
from helpers import pose, run_main

import pydynrad as pd
from pydynrad import InvalidInputError
from pydynrad.paths import load_path, load_walk

R = 8
LIGHTS = [pd.PointLight((278.0, 500.0, 280.0), (3e5, 3e5, 3e5))]
CAMERA = {
    "frames": 3,
    "width": 16,
    "height": 12,
    "fov_y": 40,
    "keyframes": [
        {"position": [278, 273, -300], "look_at": [278, 273, 0]},
        {"position": [278, 273, -250], "look_at": [278, 273, 0]},
    ],
}
POSE = [[1, 0, 0, 150], [0, 1, 0, 300], [0, 0, 1, 400], [0, 0, 0, 1]]


def write(tmp_path, doc, name="path.json"):
    p = tmp_path / name
    p.write_text(json.dumps(doc))
    return p


def test_a_walk_from_a_path_file_with_a_moving_block_is_the_walk_of_the_same_track(tmp_path, device):
    box = pd.scenes.cornell_box(max_edge=250.0)
    green = (0.1, 0.7, 0.1)
    doc = dict(
        CAMERA,
        objects=[
            {
                "block": {"size": 100, "subdivisions": 1},
                "albedo": green,
                "name": "crate",
                "keyframes": [
                    POSE,
                    {"position": [250, 420, 300], "rotation_deg": [0, 30, 0]},
                    {"position": [380, 420, 150], "rotation_deg": [0, 70, 0]},
                ],
            }
        ],
    )
    loaded = load_walk(write(tmp_path, doc))
    (track,) = loaded.objects
    assert track.object.name == "crate" and loaded.lights == []
    keys = [pose(0, (150, 300, 400)), pose(30, (250, 420, 300)), pose(70, (380, 420, 150))]
    np.testing.assert_allclose(track.transforms, keys, atol=1e-12)

    def walked(path, tracks):
        n = len(box) + sum(len(t.object) for t in tracks)
        dyn = pd.DynamicRadiosity(
            box,
            None,
            local_size=n,
            resolution=R,
            objects=pd.MovingObjects([t.object for t in tracks], occlusion=None),
            observer=path.camera(0).position,
            device=device,
        )
        return pd.walk(box, path, dyn, lights=LIGHTS, objects=tracks, device=device).radiosity

    by_hand = pd.walks.ObjectTrack(pd.RigidObject(pd.scenes.block(100.0, 1, albedo=green), keys[0]), keys)
    b_file, b_hand = walked(loaded.path, loaded.objects), walked(loaded.path, [by_hand])
    np.testing.assert_allclose(track.object.transform, keys[-1], atol=1e-12)
    assert b_file.shape == (len(box) + 48, 3) and b_file[len(box) :, 1].max() > 0  # the block is lit
    np.testing.assert_allclose(b_file, b_hand, rtol=1e-6)  # poses equal to 1e-16: observed bit for bit


def test_mesh_objects_are_read_relative_to_the_path_file(tmp_path):
    cube = pd.scenes.block(2.0, 0)
    sub = tmp_path / "meshes"
    sub.mkdir()
    lines = [f"v {x} {y} {z}" for x, y, z in cube.vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in cube.faces]
    (sub / "cube.obj").write_text("\n".join(lines) + "\n")
    doc = dict(
        CAMERA,
        objects=[
            {
                "mesh": "meshes/cube.obj",
                "emission": [5, 5, 4],
                "interpolation": "linear",
                "keyframes": [{"position": [1, 2, 3]}],
            }
        ],
    )
    (track,) = load_walk(write(tmp_path, doc)).objects
    obj = track.object
    assert obj.name == "cube" and len(obj) == len(cube) and track.interpolation == "linear"
    corners = obj.world_points()[obj.scene.faces]  # the loader merges shared vertices; triangles keep order
    np.testing.assert_allclose(corners, (cube.vertices + [1, 2, 3])[cube.faces], atol=1e-6)
    np.testing.assert_array_equal(obj.scene.emission, np.tile([5.0, 5.0, 4.0], (len(cube), 1)))


@pytest.mark.parametrize(
    "objects, message",
    [
        ({"block": {"size": 1}}, "'objects' must be a list"),
        ([{"block": {"size": 1}}], "object 0: missing field 'keyframes'"),
        ([{"keyframes": [POSE]}], "object 0: give exactly one of 'mesh'"),
        ([{"mesh": "a.obj", "block": {"size": 1}, "keyframes": [POSE]}], "object 0: give exactly one of 'mesh'"),
        ([{"block": {"size": 1}, "keyframes": [POSE], "pose": POSE}], "object 0: unknown field 'pose'"),
        ([{"mesh": "nope.obj", "keyframes": [POSE]}], "object 0: 'mesh': .*nope.obj: no such file"),
        ([{"block": {"size": -1}, "keyframes": [POSE]}], "object 0: block 'size'"),
        ([{"block": {"size": 1, "subdivisions": 9}, "keyframes": [POSE]}], "object 0: block 'subdivisions'"),
        ([{"block": {"size": 1, "sides": 6}, "keyframes": [POSE]}], "object 0: block: unknown field 'sides'"),
        ([{"block": {"size": 1}, "albedo": 1.5, "keyframes": [POSE]}], "object 0: .*albedo"),
        ([{"block": {"size": 1}, "keyframes": []}], "object 0: 'keyframes' must be a non-empty list"),
        (
            [{"block": {"size": 1}, "keyframes": [POSE, np.diag([1, 1, 3, 1]).tolist()]}],
            "object 0: keyframe 1 is not rigid",
        ),
        ([{"block": {"size": 1}, "keyframes": [[1, 2, 3]]}], r"object 0: keyframe 0 must be a \(4, 4\) matrix"),
        (
            [{"block": {"size": 1}, "keyframes": [{"position": [0, 0, 0], "rotation_deg": [0, 90]}]}],
            "object 0: keyframe 0: 'rotation_deg' must be 3 finite numbers",
        ),
        (
            [{"block": {"size": 1}, "keyframes": [{"rotation_deg": [0, 90, 0]}]}],
            "object 0: keyframe 0: missing field 'position'",
        ),
        (
            [{"block": {"size": 1}, "keyframes": [{"position": [0, 0, 0], "scale": 2}]}],
            "object 0: keyframe 0: unknown field 'scale'",
        ),
        ([{"block": {"size": 1}, "keyframes": [POSE], "interpolation": "cubic"}], "interpolation must be one of"),
    ],
)
def test_bad_objects_name_the_file_the_object_and_the_field(tmp_path, objects, message):
    p = write(tmp_path, dict(CAMERA, objects=objects))
    with pytest.raises(InvalidInputError, match=message) as info:
        load_walk(p)
    assert str(p) in str(info.value) and "\n" not in str(info.value)


def test_load_path_keeps_its_return_and_refuses_to_drop_objects(tmp_path):
    path, lights = load_path(write(tmp_path, CAMERA))
    assert len(path) == 3 and lights == []
    with pytest.raises(InvalidInputError, match="has moving 'objects': read it with load_walk"):
        load_path(write(tmp_path, dict(CAMERA, objects=[{"block": {"size": 1}, "keyframes": [POSE]}])))


def test_cli_walk_moves_the_objects_of_the_path_file(tmp_path, capsys):
    doc = dict(
        CAMERA,
        frames=2,
        keyframes=CAMERA["keyframes"][:1],
        objects=[
            {
                "block": {"size": 100, "subdivisions": 0},
                "albedo": [0.1, 0.7, 0.1],
                "keyframes": [POSE, {"position": [380, 400, 150]}],
            }
        ],
    )
    code, out, err = run_main(
        [
            "walk",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "--quiet",
            "--path",
            str(write(tmp_path, doc)),
            "--local-size",
            "400",
            "--out",
            str(tmp_path / "w"),
            "--reference-frames",
            "0",
            "1",
        ],
        capsys,
    )
    assert code == 0, err
    frames = [pd.image_io.read_image(tmp_path / "w" / f"frame_{k:04d}.png") for k in (0, 1)]
    assert (
        frames[0].shape == (12, 16, 3) and np.abs(frames[0] - frames[1]).max() > 0.05
    )  # a still camera: the block moved
    # Against fresh hemicubes of the world with the block: the static F's stale rows and the
    # columns by reciprocity cost ~1% (observed 1.06% and 1.17%; the demo's is 1.4%).
    errors = [float(e) for e in re.findall(r"relative RMS error ([\d.e+-]+)%", out)]
    assert len(errors) == 2 and max(errors) < 3.0


def test_cli_stores_the_poses_of_a_path_file_and_walk_takes_them(tmp_path, capsys):
    """formfactors --poses: the rows of the path file's objects at each frame of its walk go
    into the store (the same rows as precompute_poses in memory, bit for bit); a second run
    adds none; a walk over the store reads them."""
    from pydynrad.cli.main import load_scene
    from pydynrad.rows.store import FormFactorStore

    doc = dict(
        CAMERA,
        frames=2,
        objects=[{"block": {"size": 100, "subdivisions": 0}, "keyframes": [POSE, {"position": [380, 400, 150]}]}],
    )
    path, store = write(tmp_path, doc), tmp_path / "store"
    args = [
        "formfactors",
        "cornell_box",
        "--max-edge",
        "250",
        "--resolution",
        "8",
        "--workers",
        "0",
        "--quiet",
        "-o",
        str(store),
        "--poses",
        str(path),
    ]
    code, out, err = run_main(args, capsys)
    assert code == 0, err
    assert "2 new configurations (2 in the store, 2 frames)" in out
    code, out, err = run_main(args, capsys)
    assert code == 0 and "0 new configurations (2 in the store" in out, err
    scene, loaded = load_scene("cornell_box", 250.0), load_walk(path)
    objs = [t.object for t in loaded.objects]
    configs = [[t.at(k, 2) for t in loaded.objects] for k in range(2)]
    memory = pd.precompute.precompute_poses(scene, objs, configs, resolution=R)
    opened = FormFactorStore.open(scene, store, resolution=R, patching={"max_edge": 250.0, "scene": "cornell_box"})
    stored = pd.precompute.stored_poses(scene, objs, opened, R)
    for config in configs:
        (p_mem, rows_mem), (p_st, rows_st) = memory.get(config), stored.get(config)
        np.testing.assert_array_equal(p_mem, p_st)
        assert (rows_mem != rows_st).nnz == 0
    # The walk's poses are the stored ones: a move to frame 1's takes no hemicube.
    dyn = pd.DynamicRadiosity(
        scene,
        opened,
        local_size=300,
        resolution=R,
        objects=pd.MovingObjects(objs, poses=stored),
        observer=(278.0, 273.0, -300.0),
    )
    for t in loaded.objects:
        dyn.move(t.object, t.at(1, 2))
    assert dyn.update((278.0, 273.0, -300.0)).hemicubes == 0
    code, out, err = run_main(
        [
            "walk",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "--quiet",
            "--path",
            str(path),
            "--local-size",
            "400",
            "--form-factors",
            str(store),
        ],
        capsys,
    )
    assert code == 0, err
    assert "poses: 2 configurations of the objects stored in" in out
    code, out, err = run_main(
        ["formfactors", "cornell_box", "--max-edge", "250", "-o", str(tmp_path / "f.npz"), "--poses", str(path)], capsys
    )
    assert code != 0 and "--poses apply to a store folder" in err
    still = write(tmp_path, CAMERA, "still.json")
    code, out, err = run_main(
        [
            "formfactors",
            "cornell_box",
            "--max-edge",
            "250",
            "--workers",
            "0",
            "-o",
            str(tmp_path / "other"),
            "--poses",
            str(still),
        ],
        capsys,
    )
    assert code != 0 and "the path file moves no objects" in err and not (tmp_path / "other").exists()
