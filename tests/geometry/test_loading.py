"""Loading scenes from files and trimesh objects: materials per face, transforms, patching, errors."""

import warnings

import numpy as np
import pytest
import trimesh

import pydynrad
from pydynrad import Scene
from pydynrad.errors import InvalidInputError, SceneFileError
from pydynrad.geometry import DegenerateTriangleWarning
from pydynrad.geometry.loading import MAX_ALBEDO, AlbedoClampedWarning, MissingMaterialWarning, from_mesh

# Two unit squares and a triangle; three materials, one emitting; faces listed out of material order.
OBJ = """mtllib scene.mtl
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 0 0 2
v 1 0 2
v 0 2 3
usemtl wall
f 1 2 3
usemtl lamp
f 5 6 7
usemtl wall
f 1 3 4
usemtl floor
f 1 5 6
f 1 6 2
"""
MTL = """newmtl wall
Kd 0.6 0.1 0.1
newmtl lamp
Kd 0.2 0.2 0.2
Ke 5 4 3
newmtl floor
Kd 0.25
"""
# The file's faces (1-based vertices) with their expected (albedo, emission).
FILE_FACES = {
    (1, 2, 3): ((0.6, 0.1, 0.1), (0, 0, 0)),
    (5, 6, 7): ((0.2, 0.2, 0.2), (5, 4, 3)),
    (1, 3, 4): ((0.6, 0.1, 0.1), (0, 0, 0)),
    (1, 5, 6): ((0.25, 0.25, 0.25), (0, 0, 0)),
    (1, 6, 2): ((0.25, 0.25, 0.25), (0, 0, 0)),
}
VERTS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 2], [1, 0, 2], [0, 2, 3]], dtype=float)


def write_obj(tmp_path, obj=OBJ, mtl=MTL, name="scene"):
    (tmp_path / f"{name}.mtl").write_text(mtl)
    path = tmp_path / f"{name}.obj"
    path.write_text(obj.replace("scene.mtl", f"{name}.mtl"))
    return path


def expected_by_face(scene):
    """Expected (albedo, emission, file-face corners) of each patch, found by which file face contains it."""
    albedo, emission, corners = [], [], []
    for c in scene.centers.astype(float):
        for face, (kd, ke) in FILE_FACES.items():
            tri = VERTS[np.array(face) - 1]
            n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
            bary = np.linalg.lstsq(np.stack([tri[1] - tri[0], tri[2] - tri[0], n], axis=1), c - tri[0], rcond=None)[0]
            if abs(bary[2]) < 1e-6 and bary[0] >= -1e-6 and bary[1] >= -1e-6 and bary[:2].sum() <= 1 + 1e-6:
                albedo.append(kd), emission.append(ke), corners.append(tri)
                break
        else:
            raise AssertionError(f"patch centre {c} lies on no face of the file")
    return np.array(albedo, dtype=float), np.array(emission, dtype=float), np.array(corners)


def test_obj_mtl_materials_per_face(tmp_path):
    scene = pydynrad.load(write_obj(tmp_path))
    assert len(scene) == 5 and isinstance(scene, Scene)
    albedo, emission, _ = expected_by_face(scene)
    np.testing.assert_allclose(scene.albedo, albedo, rtol=1e-6)
    np.testing.assert_allclose(scene.emission, emission, rtol=1e-6)
    assert len(scene.emitters) == 1
    # source_face is the file's face order (its `f` lines), and the patches come in it (it
    # had followed trimesh's per-material geometries, not the file its name points to).
    faces = np.array([VERTS[np.array(face) - 1] for face in FILE_FACES])
    np.testing.assert_allclose(scene.centers, faces[scene.source_face].mean(axis=1), atol=1e-6)
    assert list(scene.source_face) == list(range(5))
    # Per-material geometries repeat vertices; the scene merges them into one mesh.
    assert len(scene.vertices) == 7


def test_obj_patching_keeps_materials_and_area(tmp_path):
    path = write_obj(tmp_path)
    coarse = pydynrad.load(path)
    fine = pydynrad.load(path, max_patch_area=0.05)
    assert fine.areas.max() <= 0.05 and len(fine) > 20 * len(coarse)
    assert fine.areas.sum() == pytest.approx(coarse.areas.sum(), rel=1e-6)
    albedo, emission, corners = expected_by_face(fine)
    np.testing.assert_allclose(fine.albedo, albedo, rtol=1e-6)
    np.testing.assert_allclose(fine.emission, emission, rtol=1e-6)
    # Each patch's source face is the coarse face that contains it, with the same normal.
    np.testing.assert_allclose(coarse.centers[fine.source_face], corners.mean(axis=1), atol=1e-6)
    np.testing.assert_allclose(fine.normals, coarse.normals[fine.source_face], atol=1e-5)
    by_edge = pydynrad.load(path, max_edge=0.3)
    v = by_edge.triangles.astype(float)
    assert np.linalg.norm(v - np.roll(v, 1, axis=1), axis=2).max() <= 0.3 + 1e-6


def test_mtl_values_clamped_expanded_or_rejected(tmp_path):
    path = write_obj(tmp_path, mtl=MTL.replace("Kd 0.6 0.1 0.1", "Kd 1 1 1"))
    with pytest.warns(AlbedoClampedWarning, match="2 face"):
        scene = pydynrad.load(path)
    assert scene.albedo.max() == pytest.approx(MAX_ALBEDO)
    with pytest.raises(SceneFileError, match=r"bright\.obj: albedo must lie in \[0, 1\)"):
        pydynrad.load(write_obj(tmp_path, mtl=MTL.replace("Kd 0.25", "Kd 1.5"), name="bright"))
    grey = pydynrad.load(write_obj(tmp_path, mtl=MTL.replace("Ke 5 4 3", "Ke 2"), name="grey"))
    np.testing.assert_allclose(grey.emission[grey.emitters], [[2.0, 2.0, 2.0]])
    with pytest.raises(SceneFileError, match=r"emission"):
        pydynrad.load(write_obj(tmp_path, mtl=MTL.replace("Ke 5 4 3", "Ke -1 0 0"), name="negative"))
    with pytest.raises(SceneFileError, match=r"Ke"), pytest.warns(UserWarning, match="line 5 'Ke five 4 3'"):
        pydynrad.load(write_obj(tmp_path, mtl=MTL.replace("Ke 5 4 3", "Ke five 4 3"), name="words"))


def test_obj_without_its_mtl_warns_and_uses_defaults(tmp_path):
    path = write_obj(tmp_path)
    (tmp_path / "scene.mtl").unlink()
    with pytest.warns(MissingMaterialWarning, match=r"scene\.obj: 5 face"):
        scene = pydynrad.load(path, default_albedo=0.3)
    np.testing.assert_allclose(scene.albedo, 0.3, rtol=1e-6)
    assert scene.emission.max() == 0


def _coloured_box():
    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    rng = np.random.default_rng(0)
    box.visual.face_colors = np.column_stack([rng.integers(0, 255, (12, 3)), np.full(12, 255)]).astype(np.uint8)
    return box


def test_ply_face_colours(tmp_path):
    box = _coloured_box()
    box.export(tmp_path / "box.ply")
    scene = pydynrad.load(tmp_path / "box.ply")
    np.testing.assert_array_equal(scene.source_face, np.arange(12))
    np.testing.assert_allclose(scene.albedo, box.visual.face_colors[:, :3] / 255.0, rtol=1e-6)
    np.testing.assert_allclose(scene.centers, box.triangles_center, atol=1e-6)
    assert scene.emission.max() == 0
    assert scene.areas.sum() == pytest.approx(2 * (1 * 2 + 2 * 3 + 1 * 3), rel=1e-6)


def test_ply_vertex_colours_are_averaged_per_face(tmp_path):
    box = trimesh.creation.box()
    colours = np.column_stack([np.arange(8) * 30, 200 - np.arange(8) * 20, np.full(8, 7), np.full(8, 255)]).astype(
        np.uint8
    )
    box.visual.vertex_colors = colours
    box.export(tmp_path / "vbox.ply")
    scene = pydynrad.load(tmp_path / "vbox.ply")
    expected = colours[box.faces][:, :, :3].astype(float).mean(axis=1) / 255.0
    np.testing.assert_allclose(scene.albedo, expected, rtol=1e-6)


def test_glb_colours_and_pbr_material(tmp_path):
    # glTF stores vertex colours: unmerged corners keep each face's colour exact.
    box = _coloured_box()
    box.unmerge_vertices()
    box.export(tmp_path / "box.glb")
    scene = pydynrad.load(tmp_path / "box.glb")
    np.testing.assert_allclose(scene.albedo, box.visual.face_colors[:, :3] / 255.0, atol=1e-6)
    assert len(scene.vertices) == 8  # coincident corners are merged again
    lamp = trimesh.creation.box()
    material = trimesh.visual.material.PBRMaterial(
        baseColorFactor=[0.5, 0.25, 0.75, 1.0], emissiveFactor=[1.0, 0.5, 0.0]
    )
    lamp.visual = trimesh.visual.TextureVisuals(material=material)
    lamp.export(tmp_path / "lamp.glb")
    scene = pydynrad.load(tmp_path / "lamp.glb")
    np.testing.assert_allclose(
        scene.albedo, np.tile(np.round(np.array([0.5, 0.25, 0.75]) * 255) / 255, (12, 1)), rtol=1e-6
    )
    np.testing.assert_allclose(scene.emission, np.tile([1.0, 0.5, 0.0], (12, 1)), rtol=1e-6)


def test_stl_gets_default_albedo_and_merged_points(tmp_path):
    trimesh.creation.box().export(tmp_path / "box.stl")
    scene = pydynrad.load(tmp_path / "box.stl", default_albedo=(0.3, 0.4, 0.5))
    np.testing.assert_allclose(scene.albedo, np.tile([0.3, 0.4, 0.5], (12, 1)), rtol=1e-6)
    assert len(scene.vertices) == 8
    assert not scene.is_grey


def test_scene_graph_transforms_and_mirrors():
    box = trimesh.creation.box()  # outward normals
    graph = trimesh.Scene()
    shift = trimesh.transformations.translation_matrix([5.0, 0.0, 0.0])
    mirror = trimesh.transformations.scale_matrix(-1.0) @ trimesh.transformations.translation_matrix([3.0, 1.0, 0.0])
    graph.add_geometry(box, node_name="a", geom_name="box")
    graph.add_geometry(box, node_name="b", geom_name="box", transform=shift)
    graph.add_geometry(box, node_name="c", geom_name="box", transform=mirror)
    scene = pydynrad.load(graph)
    assert len(scene) == 36
    centres = {"a": np.zeros(3), "b": np.array([5.0, 0, 0]), "c": np.array([-3.0, -1.0, 0])}
    owner = np.argmin([np.linalg.norm(scene.centers - c, axis=1) for c in centres.values()], axis=0)
    assert np.bincount(owner).tolist() == [12, 12, 12]
    for k, c in enumerate(centres.values()):
        mine = owner == k
        # Every face of every instance still faces out of its own box, mirrored or not.
        assert np.all(np.einsum("ij,ij->i", scene.normals[mine], scene.centers[mine] - c) > 0)
    assert scene.areas.sum() == pytest.approx(3 * 6.0, rel=1e-6)


def test_from_mesh_matches_scene_from_mesh_and_rejects_other_types():
    box = trimesh.creation.box()
    a, b = from_mesh(box, max_edge=0.4), pydynrad.load(box, max_edge=0.4)
    assert a.content_hash() == b.content_hash()
    with pytest.raises(InvalidInputError, match="trimesh"):
        from_mesh(np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match="empty"):
        from_mesh(trimesh.Scene())


def test_zero_area_faces_are_dropped_and_counted(tmp_path):
    obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\nf 2 2 3\n"
    path = tmp_path / "flat.obj"
    path.write_text(obj)
    with pytest.warns(DegenerateTriangleWarning, match="dropped 2 zero-area"):
        scene = pydynrad.load(path, max_patch_area=0.1)
    assert np.all(scene.source_face == 0) and scene.areas.sum() == pytest.approx(0.5)


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("garbage.obj", bytes(range(256)) * 8, "OBJ"),
        ("garbage.ply", bytes(range(256)) * 8, "PLY"),
        ("garbage.glb", b"glTF" + bytes(60), "GLB"),
        ("empty.obj", b"# no geometry\n", "empty"),
        ("points.obj", b"v 0 0 0\nv 1 0 0\n", "empty"),
        ("nan.obj", b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "NaN"),
        ("scene.xyz", b"0 0 0\n", "unsupported format"),
    ],
)
def test_bad_files_raise_errors_naming_file_and_problem(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(SceneFileError, match=message) as info:
            pydynrad.load(path)
    assert name in str(info.value)
    assert isinstance(info.value, ValueError)


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(SceneFileError, match=r"nothere\.obj: no such file"):
        pydynrad.load(tmp_path / "nothere.obj")
    with pytest.raises(SceneFileError, match="not a regular file"):
        pydynrad.load(tmp_path)


def _gltf_two_materials(strength):
    """A glTF of two triangles: a lamp (emissive 1, KHR_materials_emissive_strength ``strength``)
    and a grey wall, as Blender writes an emission above 1."""
    import base64

    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [0, 1, 1]], np.float32).tobytes()
    idx = np.array([0, 1, 2], np.uint32).tobytes()
    idx2 = np.array([3, 4, 5], np.uint32).tobytes()
    blob = pos + idx + idx2
    lamp = {
        "name": "lamp",
        "emissiveFactor": [1.0, 0.5, 0.25],
        "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": strength}},
    }
    wall = {"name": "wall", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0]}}
    return {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [
            {
                "primitives": [
                    {"attributes": {"POSITION": 0}, "indices": 1, "material": 0},
                    {"attributes": {"POSITION": 0}, "indices": 2, "material": 1},
                ]
            }
        ],
        "materials": [lamp, wall],
        "extensionsUsed": ["KHR_materials_emissive_strength"],
        "buffers": [
            {"byteLength": len(blob), "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}
        ],
        "bufferViews": [
            {"buffer": 0, "byteLength": 72},
            {"buffer": 0, "byteOffset": 72, "byteLength": 12},
            {"buffer": 0, "byteOffset": 84, "byteLength": 12},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 6, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 1]},
            {"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR"},
            {"bufferView": 2, "componentType": 5125, "count": 3, "type": "SCALAR"},
        ],
    }


def test_gltf_emissive_strength_and_face_indices(tmp_path):
    """KHR_materials_emissive_strength multiplies the emission (trimesh drops it: Blender's lamps
    had come out 100 times too dim), in .gltf and .glb; a PLY face indexing past its vertices,
    or below them (-1 had wrapped to the last vertex), is refused by name."""
    import json

    for suffix in ("gltf", "glb"):
        path = tmp_path / f"lamp.{suffix}"
        if suffix == "gltf":
            path.write_text(json.dumps(_gltf_two_materials(100.0)))
        else:
            doc = json.dumps(_gltf_two_materials(100.0)).encode()
            doc += b" " * (-len(doc) % 4)
            path.write_bytes(
                b"glTF"
                + (2).to_bytes(4, "little")
                + (20 + len(doc)).to_bytes(4, "little")
                + len(doc).to_bytes(4, "little")
                + b"JSON"
                + doc
            )
        scene = pydynrad.load(path)
        lamp = scene.emission.max(axis=1) > 0
        assert lamp.sum() == 1
        np.testing.assert_allclose(scene.emission[lamp][0], [100.0, 50.0, 25.0], rtol=1e-6)
        np.testing.assert_allclose(scene.albedo[~lamp][0], [0.5, 0.5, 0.5], atol=1 / 255)
    for face, message in (("3 0 1 5", "face 0 indexes vertex"), ("3 0 1 -1", "face 0 indexes vertex")):
        ply = tmp_path / "bad.ply"
        ply.write_text(
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
            "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
            f"0 0 0\n1 0 0\n0 1 0\n1 1 0\n{face}\n"
        )
        with pytest.raises(SceneFileError, match=message):
            pydynrad.load(ply)
