"""trimesh's vocabulary on Scene, and trimesh meshes wherever a Scene is taken."""

import warnings

import numpy as np
import pytest
import trimesh

import pydynrad
from pydynrad import InvalidInputError, Scene

SQUARE_VERTICES = [[0, 0, 0], [2, 0, 0], [2, 3, 0], [0, 3, 0]]
SQUARE_FACES = [[0, 1, 2], [0, 2, 3]]


def test_names_mean_what_they_mean_in_trimesh():
    mesh = trimesh.creation.box(extents=(2.0, 3.0, 4.0))
    s = Scene(mesh.vertices, mesh.faces)
    np.testing.assert_array_equal(s.vertices, mesh.vertices)  # (V, 3)
    np.testing.assert_array_equal(s.faces, mesh.faces)  # (N, 3)
    np.testing.assert_array_equal(s.triangles, mesh.triangles)  # (N, 3, 3)
    np.testing.assert_allclose(s.areas, mesh.area_faces, rtol=1e-6)
    np.testing.assert_allclose(s.normals, mesh.face_normals, atol=1e-6)
    np.testing.assert_allclose(s.centers, mesh.triangles_center, rtol=1e-12)


def test_old_names_work_for_one_release_with_a_warning():
    s = Scene(SQUARE_VERTICES, SQUARE_FACES)
    with pytest.warns(DeprecationWarning, match=r"Scene\.points is deprecated: use Scene\.vertices"):
        assert s.points is s.vertices
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        old = Scene(points=SQUARE_VERTICES, triangles=SQUARE_FACES, albedo=0.3)
    assert [str(w.message) for w in caught] == [
        "Scene(points=...) is deprecated: use vertices= (trimesh's name)",
        "Scene(triangles=...) is deprecated: use faces= (trimesh's name)",
    ]
    assert {w.category for w in caught} == {DeprecationWarning} and caught[0].filename == __file__
    np.testing.assert_array_equal(old.faces, SQUARE_FACES)
    np.testing.assert_array_equal(old.vertices, SQUARE_VERTICES)
    with pytest.raises(InvalidInputError, match="both vertices= and its old name points="):
        Scene(SQUARE_VERTICES, SQUARE_FACES, points=SQUARE_VERTICES)
    with pytest.raises(TypeError, match="unexpected keyword argument"):
        Scene(SQUARE_VERTICES, SQUARE_FACES, colour=1.0)
    with pytest.raises(InvalidInputError, match=r"needs vertices \(V, 3\) and faces"):
        Scene(SQUARE_VERTICES)


@pytest.fixture(scope="module")
def room_mesh():
    """A closed box seen from inside (faces turned inward), 1 m, each side split in 8 patches."""
    mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0)).subdivide()
    mesh.invert()
    return mesh


def test_entry_points_take_a_trimesh_mesh_as_load_reads_it(device, room_mesh, tmp_path):
    """Each entry point given the mesh gives what it gives for ``pydynrad.load(mesh)``."""
    scene = pydynrad.load(room_mesh)
    lamp = pydynrad.PointLight([0.1, 0.2, 0.3], 10.0)
    F_scene = pydynrad.form_factors(scene, resolution=16, device=device)
    F_mesh = pydynrad.form_factors(room_mesh, resolution=16, device=device)
    assert (F_mesh != F_scene).nnz == 0
    B = pydynrad.solve(scene, F_scene, lights=lamp, device=device).radiosity
    np.testing.assert_array_equal(pydynrad.solve(room_mesh, F_scene, lights=lamp, device=device).radiosity, B)
    np.testing.assert_array_equal(
        pydynrad.light_vector(room_mesh, lamp, device=device), pydynrad.light_vector(scene, lamp, device=device)
    )
    dyn = pydynrad.DynamicRadiosity(room_mesh, F_scene, local_size=8, resolution=16, device=device)
    dyn.update([0.0, 0.0, 0.0])
    ref = pydynrad.DynamicRadiosity(scene, F_scene, local_size=8, resolution=16, device=device)
    ref.update([0.0, 0.0, 0.0])
    np.testing.assert_array_equal(dyn.radiosity(lamp), ref.radiosity(lamp))
    points, normals = [[0.0, 0.0, -0.2]], [[0.0, 0.0, 1.0]]
    np.testing.assert_array_equal(
        pydynrad.illuminance(room_mesh, B, points, normals, lights=lamp, device=device),
        pydynrad.illuminance(scene, B, points, normals, lights=lamp, device=device),
    )
    camera = pydynrad.Camera([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], width=16, height=12)
    np.testing.assert_array_equal(
        pydynrad.render(room_mesh, B, camera, device=device), pydynrad.render(scene, B, camera, device=device)
    )
    np.testing.assert_array_equal(
        pydynrad.path_trace(room_mesh, camera, spp=2, lights=lamp, device=device),
        pydynrad.path_trace(scene, camera, spp=2, lights=lamp, device=device),
    )
    from pydynrad.comparison import reference_frame

    frames = [reference_frame(s, F_scene, B, camera, lights=lamp, device=device) for s in (room_mesh, scene)]
    assert frames[0].error == frames[1].error and np.array_equal(frames[0].image, frames[1].image)
    obj = pydynrad.RigidObject(room_mesh)
    np.testing.assert_array_equal(obj.scene.vertices, scene.vertices)
    pydynrad.save_form_factors(room_mesh, tmp_path / "F.npz", F_scene, resolution=16)
    assert (pydynrad.open_form_factors(scene, tmp_path / "F.npz", resolution=16) != F_scene).nnz == 0
    pydynrad.export_mesh(room_mesh, B, tmp_path / "mesh.ply")
    pydynrad.export_mesh(scene, B, tmp_path / "scene.ply")
    assert (tmp_path / "mesh.ply").read_bytes() == (tmp_path / "scene.ply").read_bytes()
    store = pydynrad.compute_store(room_mesh, tmp_path / "store", resolution=16, device=device)
    assert (store.to_csr() != F_scene).nnz == 0
    path = pydynrad.orbit([0.0, 0.0, 0.0], 0.2, 0.0, 2, width=8, height=6)
    walked = pydynrad.walk(
        room_mesh, path, form_factors=F_scene, lights=lamp, local_size=8, render=False, device=device
    )
    assert len(walked.frames) == 2


def test_not_a_scene_is_named():
    with pytest.raises(InvalidInputError, match="scene must be a pydynrad.Scene or a trimesh mesh; got PointCloud"):
        pydynrad.form_factors(trimesh.PointCloud(np.zeros((3, 3))))
