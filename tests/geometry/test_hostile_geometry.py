"""Hostile geometry: float32-sized patches, frozen arrays, overflowing values, OBJ lines trimesh drops."""

import numpy as np
import pytest

import pydynrad
from pydynrad.errors import InvalidInputError


def test_patches_too_small_for_float32_warn():
    base = pydynrad.scenes.closed_box(subdivisions=0)
    tiny = np.array([[0.5, 0.5, 0.5], [0.5 + 1e-7, 0.5, 0.5], [0.5, 0.5 + 1e-7, 0.5]])
    points = np.concatenate([base.vertices, tiny])
    triangles = np.concatenate([base.faces, [[len(base.vertices), len(base.vertices) + 1, len(base.vertices) + 2]]])
    with pytest.warns(pydynrad.geometry.scene.PrecisionWarning, match="1 patch"):
        pydynrad.Scene(points, triangles)


def test_scene_arrays_are_read_only_and_overflowing_values_are_refused(closed_box_48, device):
    with pytest.raises(ValueError, match="read-only"):
        closed_box_48.albedo[:] = 1.0  # main: solve then iterated 10,000 times before failing
    with pytest.raises(ValueError, match="read-only"):
        closed_box_48.vertices[0, 0] = 5.0
    points = np.array(closed_box_48.vertices)
    pydynrad.Scene(points, closed_box_48.faces)
    points[0, 0] = 0.25  # the caller's own array stays writable: the scene copied it
    with pytest.raises(InvalidInputError, match=r"emission exceeds float32's range"):
        pydynrad.Scene(closed_box_48.vertices, closed_box_48.faces, emission=1e39)  # main: stored as inf
    with pytest.raises(InvalidInputError, match="direct irradiance overflows float32"):
        pydynrad.light_vector(closed_box_48, [pydynrad.PointLight([0.5, 0.5, 0.5], 3e38)], device=device)  # main: inf


def test_obj_and_mtl_lines_trimesh_drops_are_named(tmp_path):
    from pydynrad.geometry.loading import MalformedLineWarning

    (tmp_path / "m.mtl").write_text("newmtl wall\nKd x y z\n")
    (tmp_path / "s.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl wall\nf 1 2 3\nf 2 4\n")
    with pytest.warns(MalformedLineWarning) as record:
        scene = pydynrad.load(tmp_path / "s.obj")
    messages = " | ".join(str(w.message) for w in record)
    assert "line 8 'f 2 4' (a face needs 3 corners)" in messages  # main: dropped without a word
    assert "line 2 'Kd x y z' (not numbers)" in messages
    assert len(scene) == 1
