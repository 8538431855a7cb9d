"""Convex solids: which meshes bound one (pydynrad/geometry/convex.py), and the move's clipping of segments
by their planes (csrc/segments.c) against Moller-Trumbore on the mesh's triangles in float64."""

import numpy as np
import pytest
import trimesh
from helpers import brute_force_hits

import pydynrad as pd
from pydynrad import _segments
from pydynrad.geometry.convex import MAX_PLANES, solid_planes


def _mesh(m: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64)


def _cube(subdivisions: int = 1):
    s = pd.scenes.block((2.0, 1.0, 0.5), subdivisions)
    return s.vertices, s.faces


def _t_junction():
    """A cube whose top side is cut at the midpoint of one of its edges, which the side below
    does not share: a T-junction, as in bench/objects.py's 64-patch block."""
    m = trimesh.creation.box((1.0, 1.0, 1.0))
    V = np.asarray(m.vertices)
    top = m.face_normals[:, 2] > 0.5
    P, faces = list(V), [list(f) for f in m.faces[~top]]
    for f in m.faces[top]:  # each split at the midpoint of a shortest edge: one of the square's sides
        i, j, k = min(
            ((f[q], f[(q + 1) % 3], f[(q + 2) % 3]) for q in range(3)), key=lambda e: np.linalg.norm(V[e[1]] - V[e[0]])
        )
        P.append(0.5 * (V[i] + V[j]))
        faces += [[i, len(P) - 1, k], [len(P) - 1, j, k]]
    return np.array(P), np.array(faces)


def test_solids_are_found():
    P, T = _cube()
    planes = solid_planes(P, T)
    assert planes is not None and len(planes) == 6
    np.testing.assert_allclose(np.linalg.norm(planes[:, :3], axis=1), 1.0, atol=1e-15)
    # The solid is the box: |x| <= 1, |y| <= 0.5, |z| <= 0.25.
    assert sorted(np.round(planes[:, 3], 12)) == [0.25, 0.25, 0.5, 0.5, 1.0, 1.0]
    assert np.all(P @ planes[:, :3].T - planes[:, 3] <= 1e-12)
    # Moved far from the origin, in the points' own coordinates.
    shift = np.array([1e4, -3e3, 7e2])
    moved = solid_planes(P + shift, T)
    np.testing.assert_allclose(moved[:, 3] - moved[:, :3] @ shift, planes[:, 3], rtol=0, atol=1e-9)
    assert len(solid_planes(*_t_junction())) == 6  # a T-junction still covers each side whole
    assert len(solid_planes(*_mesh(trimesh.creation.icosahedron()))) == 20
    assert len(solid_planes(*_mesh(trimesh.creation.cylinder(1.0, 2.0, sections=12)))) == 14


def test_other_meshes_are_not_solids():
    P, T = _cube()
    assert solid_planes(P, T[2:]) is None  # open: a side lacks two triangles
    assert solid_planes(P, np.vstack([T, T[:1]])) is None  # a triangle twice
    assert solid_planes(P, np.vstack([T[1:], T[1:2, ::-1]])) is None  # one twice (reversed), one of its area missing
    two = trimesh.util.concatenate(
        [
            trimesh.creation.box((1, 1, 1)),
            trimesh.creation.box((1, 1, 1), trimesh.transformations.translation_matrix((3, 0, 0))),
        ]
    )
    assert solid_planes(*_mesh(two)) is None  # two solids apart: inner sides lie inside the hull
    ell = trimesh.util.concatenate(
        [
            trimesh.creation.box((2, 1, 1)),
            trimesh.creation.box((1, 1, 1), trimesh.transformations.translation_matrix((0.5, 1, 0))),
        ]
    )
    assert solid_planes(*_mesh(ell)) is None  # an L: not convex
    dent = trimesh.creation.box((1, 1, 1)).subdivide()
    V = np.array(dent.vertices)
    top_centre = np.flatnonzero(np.all(np.abs(V - (0, 0, 0.5)) < 1e-12, axis=1))
    V[top_centre, 2] = 0.4
    assert solid_planes(V, dent.faces) is None  # a dent in the top
    assert solid_planes(*_mesh(trimesh.creation.icosphere(2))) is None  # 320 sides: past MAX_PLANES
    assert MAX_PLANES < 320
    quad = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    assert solid_planes(quad, np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])) is None  # flat
    assert solid_planes(np.full((8, 3), np.nan), T[:12] % 8) is None


def _crossings(P, T, a, b):
    """(n,) bool: segment a -> b crosses a triangle at t in (0, 1) (Moller-Trumbore, float64)."""
    return brute_force_hits(P[T], a, b - a, chunk=1024).t < 1.0


def _clipped(P, T, a, b, pose=None):
    """The segments a[i] -> b[i] (world) the native pass keeps for the solid of mesh (P, T) at
    ``pose``: one segment per row, a sphere holding everything, the box of the solid."""
    pose = np.eye(4) if pose is None else pose
    planes = solid_planes(P, T)
    A, t = pose[:3, :3].T, -pose[:3, :3].T @ pose[:3, 3]
    lo, hi = P.min(axis=0) - 1e-9, P.max(axis=0) + 1e-9
    pts = np.concatenate([a, b])
    n = len(a)
    ends = np.arange(1, n + 1, dtype=np.int64)
    out, rays = _segments.near_sphere(
        pts,
        ends - 1,
        ends,
        np.arange(n, 2 * n, dtype=np.int32),
        np.arange(n, dtype=np.int64),
        tuple(pose[:3, 3]),
        1e9,
        np.concatenate([A.ravel(), t, lo, hi]).tolist(),
        planes.ravel().tolist(),
    )
    assert rays == b""  # decided in the pass: no rays to trace
    kept = np.zeros(n, bool)
    kept[np.frombuffer(out, np.int64)] = True
    return kept


@pytest.mark.parametrize("shape", ["cube", "icosahedron", "t-junction"])
def test_clipping_matches_crossing_triangles(shape):
    """Random segments, many with an end inside the solid or both: the pass keeps exactly those
    that cross a triangle (a segment wholly inside crosses none)."""
    P, T = {"cube": _cube, "icosahedron": lambda: _mesh(trimesh.creation.icosahedron()), "t-junction": _t_junction}[
        shape
    ]()
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-1.5, 1.5, (2, 20000, 3))
    a[:3000] *= 0.3  # inside, most of them
    b[:1500] *= 0.3
    angle = np.radians(40.0)
    pose = np.eye(4)
    pose[:3, :3] = [[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]]
    pose[:3, 3] = (5.0, -2.0, 1.0)
    truth = _crossings(P, T, a, b)
    assert 3000 < truth.sum() < 17000 and (~truth[:1500]).sum() > 100  # both ends inside: no crossing
    np.testing.assert_array_equal(
        _clipped(P, T, a @ pose[:3, :3].T + pose[:3, 3], b @ pose[:3, :3].T + pose[:3, 3], pose), truth
    )


def test_clipping_at_the_boundary():
    """Segments that only touch the box [-1, 1] x [-0.5, 0.5] x [-0.25, 0.25] (in a side's plane,
    starting or ending on a side from outside, between two of its edges through the inside) cross
    none of its triangles at t in (0, 1) and are not kept; those through it or from inside out are."""
    P, T = _cube()
    seg = np.array(
        [
            [(-3, -0.5, 0), (3, -0.5, 0)],  # along the bottom side, in its plane
            [(-3, 0, 0.25), (3, 0, 0.25)],  # along the top side (z), in its plane
            [(0, 0.5, 0), (0, 2, 0)],  # starts on a side, leaves
            [(-2, 0, 0), (-1, 0, 0)],  # ends on a side
            [(-2, -1, 0.25), (0, 1, 0.25)],  # through the solid's top side plane: along it, touching
            [(-3, 0, 0), (3, 0, 0)],  # through: crosses two sides
            [(0, 0, 0), (3, 0, 0)],  # from the centre out: crosses one
            [(0.5, 0, 0), (-0.5, 0.1, 0.1)],  # inside: crosses none
            [(-1, -0.5, 0), (1, 0.5, 0)],  # corner edge to corner edge, through the inside: from a boundary point in
        ],
        np.float64,
    )
    kept = _clipped(P, T, seg[:, 0], seg[:, 1])
    assert kept.tolist() == [False, False, False, False, False, True, True, False, False]
