"""Occlusion geometry of moving objects (pydynrad.dynamic.occlusion) against numpy: hidden entries, segments near spheres and boxes, shadow rays near spheres, outside patches gathered only where objects are in view."""

import numpy as np
import pytest
from helpers import END, brute_force_hits

import pydynrad as pd
from pydynrad.geometry.objects import with_objects


@pytest.mark.parametrize("solid", [True, False], ids=["convex, clipped", "two blocks, traced"])
def test_hidden_entries_match_numpy(cornell_384, green_block, device, solid):
    """Segments between patch centres that cross the object, against Moller-Trumbore in float64:
    the block is a convex solid (its planes clip the segments), two blocks through each other
    are not (the object's tree traces them)."""
    from pydynrad.dynamic.occlusion import hidden_by

    if not solid:
        green_block = pd.Scene(
            np.vstack([green_block.vertices, green_block.vertices + (60.0, 60.0, 0.0)]),
            np.vstack([green_block.faces, green_block.faces + len(green_block.vertices)]),
            albedo=0.5,
        )
    obj = pd.RigidObject(green_block, END)
    assert (obj.solid_planes is not None) == solid
    rng = np.random.default_rng(4)
    i, j = rng.integers(0, len(cornell_384), (2, 6000))
    p0, p1 = cornell_384.centers[i].astype(np.float64), cornell_384.centers[j].astype(np.float64)
    got = hidden_by([obj], [obj.transform], p0, p1, device)
    truth = brute_force_hits(obj.world_points()[green_block.faces], p0, p1 - p0).t < 1.0  # crossing at t in (0, 1)
    assert truth.sum() > 100
    assert (got != truth).sum() <= 2  # float32 rays along a shared edge; observed 0


def test_outside_gathered_only_where_objects_are_in_view(device, monkeypatch):
    """In a scene larger than the object's reach (a small village, a 1 m block), the frame
    gathers at the poses only the outside patches whose form factor to the block's bounding
    sphere (now or at its first pose) is at least VIEW_FORM_FACTOR; those get what gathering
    every outside patch gives them, the others keep the far field's B_far; and the answer stays
    within the far field's accuracy of a full solve of the scene with the block."""
    import pydynrad.dynamic.moves as moves
    from pydynrad.comparison import radiosity_error

    village = pd.scenes.village(houses=1, detail=0.5)
    F = pd.form_factors(village, 16, device=device)
    green_block = pd.scenes.block(1.0, 0, albedo=(0.1, 0.6, 0.15))
    sun = [pd.DirectionalLight((-0.4, -1.0, -0.3), (100.0,) * 3)]

    def at(x):
        T = np.eye(4)
        T[:3, 3] = (x, 0.6, 2.5)
        return T

    def moved():
        obj = pd.RigidObject(green_block, at(3.0))
        dyn = pd.DynamicRadiosity(
            village, F, local_size=256, resolution=16, objects=[obj], observer=(1.0, 1.7, 2.5), device=device
        )
        dyn.move(obj, at(4.0))
        dyn.update((1.0, 1.7, 2.5))
        return dyn, dyn.radiosity(sun)

    dyn, B = moved()
    outside, view = ~dyn.local_mask, dyn._ff.source.in_view()
    assert 0 < (outside & view).sum() < outside.sum() // 2  # observed 1,032 of 2,994
    np.testing.assert_array_equal(B[outside & ~view], dyn.far.B_far[outside & ~view])
    monkeypatch.setattr(moves, "VIEW_FORM_FACTOR", 0.0)  # every outside patch gathered
    _, B_all = moved()
    np.testing.assert_allclose(B[outside & view], B_all[outside & view], rtol=1e-12, atol=0.0)
    world = with_objects(village, [pd.RigidObject(green_block, at(4.0))])
    truth = pd.solve(
        world, pd.form_factors(world, 16, device=device), lights=sun, tol=1e-8, dtype=np.float64, device=device
    ).radiosity
    # observed 0.26% (0.10% gathering every outside patch, 0.36% gathering none)
    assert radiosity_error(B, truth, world.areas) < 0.004


def test_shadow_rays_near_in_chunks_of_spheres(monkeypatch):
    """Many spheres in chunks of SHADOW_SPHERES give what one call per sphere gives."""
    from pydynrad.dynamic import occlusion
    from pydynrad.dynamic.occlusion import shadow_rays_near

    rng = np.random.default_rng(8)
    points = rng.uniform(-100.0, 100.0, (3000, 3))
    spheres = [(rng.uniform(-50.0, 50.0, 3), float(rng.uniform(5.0, 30.0))) for _ in range(11)]
    monkeypatch.setattr(occlusion, "SHADOW_SPHERES", 4)
    for light in (
        pd.PointLight((10.0, 150.0, 5.0), (1.0, 1.0, 1.0)),
        pd.DirectionalLight((0.3, -1.0, 0.2), (1.0, 1.0, 1.0)),
    ):
        one_by_one = np.zeros(len(points), bool)
        for sphere in spheres:
            one_by_one |= shadow_rays_near(points, light, [sphere])
        got = shadow_rays_near(points, light, spheres)
        assert 100 < got.sum() < len(points) and np.array_equal(got, one_by_one)
    assert not shadow_rays_near(points, light, []).any()


def test_segments_near_sphere_match_numpy():
    """csrc/segments.c's pre-test against the closest point of each segment in plain numpy;
    rows whose owner is -1 are skipped, a bad index is a ValueError."""
    from pydynrad import _segments

    rng = np.random.default_rng(7)
    P = rng.uniform(-1.0, 1.0, (300, 3))
    indptr = np.concatenate([[0], np.cumsum(rng.integers(0, 40, 50))]).astype(np.int64)
    indices = rng.integers(0, len(P), indptr[-1]).astype(np.int64)
    owners = rng.integers(0, len(P), 50).astype(np.int64)
    owners[::7] = -1
    c, r = np.array([0.1, -0.2, 0.3]), 0.35
    spans = indptr[:-1], indptr[1:]
    out, rays = _segments.near_sphere(P, *spans, indices.astype(np.int32), owners, tuple(c), r, None)
    out, rays = np.frombuffer(out, np.int64), np.frombuffer(rays, np.float64).reshape(-1, 6)
    row = np.repeat(np.arange(50), np.diff(indptr))
    a, b = P[owners[row]], P[indices]
    d = b - a
    t = np.clip(np.einsum("ij,ij->i", c - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    dist = np.linalg.norm(a + t[:, None] * d - c, axis=1)
    truth = np.flatnonzero((owners[row] >= 0) & (dist <= r))
    assert 50 < len(truth) < len(indices) // 2
    np.testing.assert_array_equal(out, truth)
    np.testing.assert_array_equal(rays, np.hstack([a[truth], d[truth]]))  # no box: the segments in world space
    # Rows read as spans in another order give each row's segments; spans that end before they start are refused.
    order = rng.permutation(50)
    out2 = np.frombuffer(
        _segments.near_sphere(
            P,
            indptr[:-1][order].copy(),
            indptr[1:][order].copy(),
            indices.astype(np.int32),
            owners[order].copy(),
            tuple(c),
            r,
            None,
        )[0],
        np.int64,
    )
    np.testing.assert_array_equal(np.sort(out2), truth)
    bad = indices.astype(np.int32)
    bad[3] = len(P)
    with pytest.raises(ValueError, match="out of range"):
        _segments.near_sphere(P, *spans, bad, np.zeros(50, np.int64), tuple(c), r, None)
    with pytest.raises(ValueError, match="out of range"):
        _segments.near_sphere(
            P, indptr[1:].copy(), indptr[:-1].copy(), indices.astype(np.int32), owners, tuple(c), r, None
        )


def test_segments_near_sphere_box_matches_numpy():
    """The pre-test's box (the object's bounds in its own space, by the slab test on the segment
    moved there) against numpy, on rows longer than the native pass's blocks of 512 segments
    and with segments parallel to an axis of the box, inside and outside its slab."""
    from pydynrad import _segments

    rng = np.random.default_rng(11)
    P = rng.uniform(-1.0, 1.0, (400, 3))
    P[:40, 1] = 0.05  # segments between these lie in a plane y = 0.05: parallel to the x-z slabs
    P[40:80, 1] = 0.9  # and in y = 0.9, outside the box's y slab
    indptr = np.array([0, 1300, 1300, 2000, 2040], np.int64)
    indices = rng.integers(0, len(P), indptr[-1])
    indices[2000:] = rng.integers(0, 80, 40)
    owners = np.array([5, 7, 300, 45], np.int64)
    c, r = np.array([0.05, 0.0, -0.1]), 0.6
    a_ = np.radians(30.0)
    A = np.array([[np.cos(a_), 0.0, -np.sin(a_)], [0.0, 1.0, 0.0], [np.sin(a_), 0.0, np.cos(a_)]])  # world -> object
    t = -A @ c
    lo, hi = np.array([-0.3, -0.2, -0.25]), np.array([0.3, 0.2, 0.25])
    cornell_384 = np.concatenate([A.ravel(), t, lo, hi])
    out, rays = _segments.near_sphere(
        P, indptr[:-1], indptr[1:], indices.astype(np.int32), owners, tuple(c), r, cornell_384.tolist()
    )
    out, rays = np.frombuffer(out, np.int64), np.frombuffer(rays, np.float64).reshape(-1, 6)
    row = np.repeat(np.arange(len(owners)), np.diff(indptr))
    a, b = P[owners[row]], P[indices]
    d = b - a
    s = np.clip(np.einsum("ij,ij->i", c - a, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0.0, 1.0)
    near = np.linalg.norm(a + s[:, None] * d - c, axis=1) <= r

    def to_object(x):  # in the native pass's order of operations, for the same rounding
        return np.stack([A[k, 0] * x[:, 0] + A[k, 1] * x[:, 1] + A[k, 2] * x[:, 2] + t[k] for k in range(3)], axis=1)

    oa, ob = to_object(a), to_object(b)
    od = ob - oa
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - oa) / od, (hi - oa) / od
    enter, leave = np.minimum(ta, tb), np.maximum(ta, tb)
    parallel = od == 0.0
    enter = np.where(parallel, np.where((oa < lo) | (oa > hi), np.inf, -np.inf), enter)
    leave = np.where(parallel, np.inf, leave)
    crosses = np.maximum(enter.max(axis=1), 0.0) <= np.minimum(leave.min(axis=1), 1.0)
    truth = np.flatnonzero(near & crosses)
    assert parallel[truth].any() and (near & ~crosses)[2000:].any()  # both kinds of parallel segment met
    assert len(truth) > 300 and (truth >= 1300).any() and (truth < 512).any() and (truth > 512).any()
    np.testing.assert_array_equal(out, truth)
    np.testing.assert_array_equal(rays, np.hstack([oa[truth], od[truth]]))  # in object space
