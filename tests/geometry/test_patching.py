"""Patching (4-way midpoint splits) and the analytic scenes' geometry."""

import numpy as np
import pytest
import trimesh

from pydynrad import InvalidInputError
from pydynrad.geometry.patching import subdivide
from pydynrad.scenes.analytic import closed_box, parallel_plates, perpendicular_plates


def tri_areas(p, t):
    v = np.asarray(p, np.float64)[t]
    return 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)


def test_split_conserves_area_orientation_and_connectivity():
    mesh = trimesh.creation.icosphere(subdivisions=1)
    limit = mesh.area_faces.min() / 20
    p, t, parent = subdivide(mesh.vertices, mesh.faces, max_area=limit)
    a = tri_areas(p, t)
    assert a.max() <= limit
    # Children tile their parent exactly.
    np.testing.assert_allclose(np.bincount(parent, weights=a), mesh.area_faces, rtol=1e-13)
    # Normals keep their parent's direction (planar split, orientation preserved).
    v = p[t]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    assert np.all(np.sum(n * mesh.face_normals[parent], axis=1) > 0)
    # Shared midpoints: a closed mesh split uniformly stays closed, with V - E + F = 2.
    out = trimesh.Trimesh(p, t, process=False)
    assert out.is_watertight and out.euler_number == 2
    assert len(p) == len(np.unique(p.round(12), axis=0)), "no duplicated points"
    assert np.all(np.diff(parent) >= 0), "patches grouped by parent"


def test_mixed_sizes_share_midpoints_across_rounds():
    # One big and one small triangle sharing the edge (0, 1): the big one splits twice,
    # the small one once; the midpoint of the shared edge must be the same point.
    pts = np.array([[0, 0, 0], [1, 0, 0], [0.5, 2.0, 0], [0.5, -0.5, 0]], float)
    tris = np.array([[0, 1, 2], [1, 0, 3]])
    p, t, parent = subdivide(pts, tris, max_area=0.2)
    assert np.all(tri_areas(p, t) <= 0.2)
    mid = np.flatnonzero(np.all(np.isclose(p, [0.5, 0, 0]), axis=1))
    assert len(mid) == 1
    assert mid[0] in t[parent == 0] and mid[0] in t[parent == 1]


def test_max_edge_and_no_limits():
    pts = np.array([[0, 0, 0], [4, 0, 0], [0, 3, 0]], float)
    p, t, parent = subdivide(pts, [[0, 1, 2]], max_edge=1.0)
    v = p[t]
    assert np.max(np.linalg.norm(v - v[:, [1, 2, 0]], axis=2)) <= 1.0
    assert len(t) == 4**3  # hypotenuse 5 needs three halvings
    p2, t2, parent2 = subdivide(pts, [[0, 1, 2]])
    np.testing.assert_array_equal(t2, [[0, 1, 2]])
    np.testing.assert_array_equal(parent2, [0])


def test_large_output_is_vectorised():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    p, t, parent = subdivide(pts, [[0, 1, 2]], max_area=0.5 / 4**10 * 1.0001)
    assert len(t) == 4**10 and t.dtype == np.int32
    # A regular grid: V = (n+1)(n+2)/2 with n = 2^10 segments per side.
    assert len(p) == (2**10 + 1) * (2**10 + 2) // 2


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(max_area=0.0), "max_area"),
        (dict(max_area=np.nan), "max_area"),
        (dict(max_edge=-1.0), "max_edge"),
        (dict(max_area=1e-12), "more than"),
    ],
)
def test_bad_limits(kwargs, match):
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    with pytest.raises(InvalidInputError, match=match):
        subdivide(pts, [[0, 1, 2]], **kwargs)


def test_bad_mesh():
    with pytest.raises(InvalidInputError, match="outside"):
        subdivide(np.zeros((3, 3)), [[0, 1, 3]], max_area=1.0)
    with pytest.raises(InvalidInputError, match="NaN"):
        subdivide([[0, 0, 0], [1, 0, 0], [0, np.nan, 0]], [[0, 1, 2]], max_area=1.0)
    with pytest.raises(InvalidInputError, match=r"\(V, 3\)"):
        subdivide(np.zeros((3, 2)), [[0, 1, 2]], max_area=1.0)


def test_parallel_plates_geometry():
    s = parallel_plates(2.0, 3.0, 0.5, subdivisions=2)
    assert len(s) == 2 * 2 * 16
    plate = s.source_face // 2
    for k, (z, nz) in enumerate(((0.0, 1.0), (0.5, -1.0))):
        assert s.areas[plate == k].sum() == pytest.approx(6.0, rel=1e-6)
        np.testing.assert_allclose(s.centers[plate == k, 2], z)
        np.testing.assert_allclose(s.normals[plate == k], [[0, 0, nz]] * np.sum(plate == k), atol=1e-7)
    assert np.ptp(s.areas) < 1e-6, "uniform patches"


def test_perpendicular_plates_geometry():
    s = perpendicular_plates(1.0, 2.0, 0.5, subdivisions=1)
    plate = s.source_face // 2
    assert s.areas[plate == 0].sum() == pytest.approx(2.0) and s.areas[plate == 1].sum() == pytest.approx(0.5)
    np.testing.assert_allclose(s.normals[plate == 0], np.tile([0, 0, 1.0], (np.sum(plate == 0), 1)), atol=1e-7)
    np.testing.assert_allclose(s.normals[plate == 1], np.tile([0, 1.0, 0], (np.sum(plate == 1), 1)), atol=1e-7)
    assert s.areas.max() <= 0.5 / 8 * (1 + 1e-6)  # the larger plate split to the smaller one's patch size


def test_closed_box_is_closed_and_inward():
    cube = closed_box(2.0, subdivisions=2)
    mesh = trimesh.Trimesh(cube.vertices, cube.faces, process=True)
    assert mesh.is_watertight
    # Inward normals: the mesh's signed volume is negative.
    assert mesh.volume == pytest.approx(-8.0)
    s = closed_box((1.0, 2.0, 3.0), subdivisions=1, albedo=0.7, emission=2.0)
    centre = np.array([0.5, 1.0, 1.5])
    assert np.all(np.sum((centre - s.centers) * s.normals, axis=1) > 0)
    assert s.areas.sum() == pytest.approx(2 * (2 + 3 + 6))
    np.testing.assert_array_equal(np.unique(s.source_face // 2), np.arange(6))
    assert np.all(s.albedo == np.float32(0.7)) and np.all(s.emission == 2.0)
    s2 = closed_box(1.0, subdivisions=0, max_patch_area=0.1)
    assert s2.areas.max() <= 0.1 and s2.areas.sum() == pytest.approx(6.0)


@pytest.mark.parametrize("fn", [parallel_plates, perpendicular_plates])
def test_bad_scene_parameters(fn):
    with pytest.raises(InvalidInputError, match="c must be"):
        fn(1.0, 1.0, 0.0)
    with pytest.raises(InvalidInputError, match="subdivisions"):
        fn(subdivisions=-1)
    with pytest.raises(InvalidInputError, match="albedo"):
        fn(albedo=1.0)
    with pytest.raises(InvalidInputError, match="size"):
        closed_box((1.0, np.inf, 1.0))
