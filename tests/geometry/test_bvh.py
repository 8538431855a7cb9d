"""BVH build and traversal against a brute-force numpy ray cast (float64 Moller-Trumbore)."""

import numpy as np
import pytest
import trimesh
from helpers import brute_force_hits

from pydynrad import InvalidInputError, Scene
from pydynrad.geometry.bvh import BVH, MAX_DEPTH, cast_rays, leaf_ranges, occluded


def random_triangles(rng, n, spread=10.0, size=1.0):
    c = rng.uniform(-spread, spread, (n, 1, 3))
    return c + rng.normal(scale=size, size=(n, 3, 3))


def random_rays(rng, n, spread=12.0):
    o = rng.uniform(-spread, spread, (n, 3))
    d = rng.normal(size=(n, 3))
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def check_against_brute_force(device, vertices, o, d):
    bvh = BVH.build(vertices)
    patch, t, front = cast_rays(bvh, o, d, device=device)
    bp, bt, bf, second, _, _ = brute_force_hits(vertices, o, d)
    hits = bp >= 0
    assert hits.sum() > len(o) // 10, "the test rays should hit something"
    np.testing.assert_array_equal(patch >= 0, hits)
    # Where two triangles lie at (almost) the same distance either answer is right.
    with np.errstate(invalid="ignore"):
        clear = hits & (second - bt > 1e-4 * np.maximum(bt, 1.0))
    np.testing.assert_array_equal(patch[clear], bp[clear])
    np.testing.assert_array_equal(front[clear], bf[clear])
    np.testing.assert_allclose(t[hits], bt[hits], rtol=1e-4, atol=1e-5)
    assert np.all(np.isinf(t[~hits]))
    # Any-hit with a per-ray bound: occluded exactly when the nearest hit is closer than it.
    tmax = np.random.default_rng(1).uniform(0.5, 25.0, len(o))
    away = np.abs(bt - tmax) > 1e-4 * tmax
    occ = occluded(bvh, o, d, tmax=tmax, device=device)
    np.testing.assert_array_equal(occ[away], (bt < tmax)[away])
    # The same bound on the closest-hit query.
    p2, _, _ = cast_rays(bvh, o, d, tmax=tmax, device=device)
    np.testing.assert_array_equal((p2 >= 0)[away], (bt < tmax)[away])
    return patch


@pytest.mark.parametrize("width", [16, 8, 4])
def test_random_rays_random_triangles(device, width):
    """At every packet width (BVH_PACKET 16, 8, 4 as the device's float width picks it), 3,009
    rays: a tail packet of one ray at every width."""
    rng = np.random.default_rng(0)
    v = random_triangles(rng, 400)
    o, d = random_rays(rng, 3009)
    check_against_brute_force(device.with_traits(float_width=width), v, o, d)


def test_rays_inside_a_closed_mesh_hit_its_inside(device):
    """A real scene: rays from inside a sphere plus a box hit back faces of the sphere."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=5.0)
    box = trimesh.creation.box(extents=(2.0, 1.0, 3.0))
    mesh = trimesh.util.concatenate([sphere, box])
    scene = Scene(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(2)
    o = rng.uniform(-2.5, 2.5, (2000, 3))  # inside the sphere (inradius > 4.5)
    inside_box = np.all(np.abs(o) < [1.0, 0.5, 1.5], axis=1)
    o = o[~inside_box]
    d = rng.normal(size=o.shape)
    patch = check_against_brute_force(device, scene.triangles, o, d)
    assert np.all(patch >= 0), "nothing escapes a closed sphere"
    p, _, front = cast_rays(scene, o, d, device=device)
    on_sphere = p < len(sphere.faces)
    assert np.all(~front[on_sphere]), "rays from inside meet the sphere's back faces"
    assert np.all(front[~on_sphere]), "rays from outside the box meet its front faces"


def test_axis_aligned_rays_and_coincident_centroids(device):
    """Directions with zero components and many triangles sharing one centroid."""
    rng = np.random.default_rng(3)
    base = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    stack = np.stack([base * (1 + 0.01 * k) + [0, 0, 0.1 * k] for k in range(40)])
    v = np.concatenate([stack, random_triangles(rng, 200, spread=5.0)])
    o = rng.uniform(-0.5, 0.5, (1500, 3)) + [0, 0, -2.0]
    d = np.zeros_like(o)
    d[:, 2] = 1.0
    d[::3] = [1.0, 0.0, 0.0]
    check_against_brute_force(device, v, o, d)


def test_build_is_a_valid_hierarchy():
    rng = np.random.default_rng(4)
    v = random_triangles(rng, 5000, spread=50.0).astype(np.float32)
    bvh = BVH.build(v)
    assert np.array_equal(np.sort(bvh.order), np.arange(len(v)))
    assert bvh.depth <= MAX_DEPTH
    children = bvh.children
    lo, hi = bvh.boxes
    # Every node but the root is referenced exactly once; empty slots come last in a node.
    inner = children[children > 0]
    assert np.array_equal(np.sort(inner), np.arange(1, bvh.n_nodes))
    assert np.all(np.diff((children == 0).astype(int), axis=1) >= 0)
    assert np.all(lo[children == 0] == np.inf) and np.all(hi[children == 0] == -np.inf)
    # Leaves cover every triangle exactly once, at most 4 each, inside their box.
    first, count = leaf_ranges(children[children < 0])
    assert count.max() <= 4
    covered = np.zeros(len(v), int)
    for f, c, blo, bhi in zip(first, count, lo[children < 0], hi[children < 0]):
        covered[f : f + c] += 1
        tv = v[bvh.order[f : f + c]].reshape(-1, 3)
        assert np.all(tv >= blo) and np.all(tv <= bhi)
    assert np.all(covered == 1)
    # A child node's own children lie inside the box its parent holds for it.
    parent, slot = np.nonzero(children > 0)
    node = children[parent, slot]
    full = children[node] != 0
    assert np.all((lo[node] >= lo[parent, slot][:, None]) | ~full[..., None])
    assert np.all((hi[node] <= hi[parent, slot][:, None]) | ~full[..., None])
    # Collapsing to 4 wide leaves few slots empty: nodes are at least 3/4 full on average.
    assert np.mean(children != 0) > 0.75
    # The packed triangles are the input corners in BVH order, bit for bit (the watertight test needs it).
    tris = bvh.tris.reshape(-1, 3, 4)[:, :, :3]
    np.testing.assert_array_equal(tris, v[bvh.order].astype(np.float32))


def test_tiny_trees(device):
    """One triangle (the root holds a single leaf) and a handful (the root's slots part empty)."""
    rng = np.random.default_rng(7)
    for n in (1, 2, 5):
        v = random_triangles(rng, n, spread=0.5, size=2.0)
        bvh = BVH.build(v)
        if n == 1:
            assert bvh.n_nodes == 1 and np.count_nonzero(bvh.children) == 1
        o, d = random_rays(rng, 500, spread=3.0)
        bp = brute_force_hits(v, o, d).patch
        patch, t, _ = cast_rays(bvh, o, d, device=device)
        np.testing.assert_array_equal(patch, bp)
        np.testing.assert_array_equal(occluded(bvh, o, d, device=device), bp >= 0)


@pytest.mark.parametrize(
    "vertices, match",
    [
        (np.zeros((0, 3, 3)), "N > 0"),
        (np.zeros((4, 3)), r"\(N, 3, 3\)"),
        (np.full((2, 3, 3), np.nan), "NaN"),
        (np.full((2, 3, 3), np.inf), "infinite"),
    ],
)
def test_bad_geometry(vertices, match):
    with pytest.raises(InvalidInputError, match=match):
        BVH.build(vertices)


def test_bad_rays(device):
    bvh = BVH.build(random_triangles(np.random.default_rng(5), 10))
    o = np.zeros((2, 3))
    with pytest.raises(InvalidInputError, match="shape"):
        cast_rays(bvh, o, np.ones((3, 3)), device=device)
    with pytest.raises(InvalidInputError, match="non-zero"):
        cast_rays(bvh, o, np.zeros((2, 3)), device=device)
    with pytest.raises(InvalidInputError, match="NaN"):
        cast_rays(bvh, [[np.nan, 0, 0], [0, 0, 0]], np.ones((2, 3)), device=device)
    with pytest.raises(InvalidInputError, match="tmax"):
        occluded(bvh, o, np.ones((2, 3)), tmax=0.0, device=device)
    with pytest.raises(InvalidInputError, match="Scene or a BVH"):
        cast_rays("scene", o, np.ones((2, 3)), device=device)


@pytest.mark.parametrize("real", [np.float32, np.float64])
def test_rays_move_into_the_device_frame_as_numpy_moves_them(real):
    """The native ray pass (csrc/rays.c) gives DeviceFrame.points / directions' float32 bit for
    bit, magnitudes from 1e-40 to 1e30 (float32's subnormals included), and the rays' own
    rounding without a frame."""
    from pydynrad.geometry.bvh import _rays
    from pydynrad.geometry.scene import DeviceFrame

    rng = np.random.default_rng(9)
    size = 10.0 ** rng.integers(-40, 31, (5000, 1))
    o, d = (rng.normal(size=(5000, 3)) * size).astype(real), (rng.normal(size=(5000, 3)) * size).astype(real)
    for frame in (DeviceFrame(np.array([-3.0, 1e3, 7.0]), np.array([40.0, 1e3 + 2.0, 9.5])), None):
        got = _rays(o, d, 2.5, frame)
        want = (o.astype(np.float32), d.astype(np.float32)) if frame is None else (frame.points(o), frame.directions(d))
        for g, w in zip(got, want + (np.full(len(o), 2.5, np.float32),)):
            assert g.dtype == np.float32 and np.array_equal(g.view(np.uint32), w.view(np.uint32))


def test_packet_lanes_are_independent(device):
    """cast_rays packs consecutive rays into one traversal; a ray's answer must not depend on its
    neighbours, on where the batch ends (spare lanes of a tail packet) or on the batch size."""
    rng = np.random.default_rng(6)
    bvh = BVH.build(random_triangles(rng, 300))
    o, d = random_rays(rng, 70)
    tmax = rng.uniform(1.0, 30.0, len(o))
    whole = cast_rays(bvh, o, d, tmax=tmax, device=device)
    for start, stop in ((0, 1), (5, 22), (33, 70), (69, 70)):
        part = cast_rays(bvh, o[start:stop], d[start:stop], tmax=tmax[start:stop], device=device)
        for a, b in zip(part, whole):
            np.testing.assert_array_equal(a, b[start:stop])
    # Each ray alone, in reverse order: neighbours of every kind.
    single = [cast_rays(bvh, o[k : k + 1], d[k : k + 1], tmax=tmax[k], device=device) for k in range(len(o))[::-1]]
    np.testing.assert_array_equal(np.concatenate([s[0] for s in single[::-1]]), whole[0])


@pytest.mark.parametrize("chunk", [7, 32, 69])
def test_chunks_give_the_whole_batch(device, monkeypatch, chunk):
    """cast_rays in launches of `chunk` rays (pydynrad.geometry.bvh.CAST_CHUNK: chunks ending inside a
    packet, on one, and a one-ray tail) returns what one launch does, bit for bit; a bad tmax
    in a later chunk is reported by its index in the whole batch."""
    import pydynrad.geometry.bvh as bvh_module

    rng = np.random.default_rng(8)
    bvh = BVH.build(random_triangles(rng, 300))
    o, d = random_rays(rng, 70)
    tmax = rng.uniform(1.0, 30.0, len(o))
    whole = cast_rays(bvh, o, d, tmax=tmax, device=device)
    monkeypatch.setattr(bvh_module, "CAST_CHUNK", chunk)
    for a, b in zip(cast_rays(bvh, o, d, tmax=tmax, device=device), whole):
        np.testing.assert_array_equal(a, b)
    tmax[66] = -1.0
    with pytest.raises(InvalidInputError, match="for ray 66"):
        cast_rays(bvh, o, d, tmax=tmax, device=device)


def _depth_recursive(children, node=0):
    inner = [c for c in children[node] if c > 0]
    return 1 + max((_depth_recursive(children, c) for c in inner), default=0)


def test_depth_guard(monkeypatch):
    """The wide depth that sizes the kernels' stack, and the refusal of trees deeper than it holds."""
    # Triangles at x = 2^k: each binned split peels off only a few, so the tree is deep.
    x = np.ldexp(1.0, np.arange(100))[:, None, None]
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])[None] + x * [1.0, 0, 0]
    bvh = BVH.build(v)
    assert bvh.depth == _depth_recursive(bvh.children) > 10
    monkeypatch.setattr("pydynrad.geometry.bvh.MAX_DEPTH", bvh.depth - 1)
    with pytest.raises(InvalidInputError, match=f"depth {bvh.depth} exceeds"):
        BVH.build(v)
