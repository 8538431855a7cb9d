"""Rigid objects and the two-level BVH: an instanced object is seen exactly where a static copy is.

Every ray user (hemicubes, shadow rays, primary visibility, the path tracer) is compared with
the same geometry built as one static scene .
"""

import numpy as np
import pytest

import pydynrad as pd
from pydynrad.formfactors import pixel_form_factors
from pydynrad.geometry.bvh import cast_rays
from pydynrad.geometry.objects import instanced, with_objects

R = 32


def pose(angle_deg=0.0, at=(150.0, 300.0, 400.0)):
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    T = np.eye(4)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]  # about y
    T[:3, 3] = at
    return T


@pytest.fixture(scope="module")
def brick():
    return pd.scenes.block((120.0, 80.0, 100.0), 1, albedo=(0.2, 0.6, 0.3))


def test_rigid_transform_refused(brick):
    for bad, msg in [
        (np.diag([2.0, 1, 1, 1]), "not rigid"),
        (np.diag([-1.0, 1, 1, 1]), "mirrors"),
        (np.full((4, 4), np.nan), "NaN"),
        (np.eye(3), r"\(4, 4\)"),
    ]:
        with pytest.raises(pd.InvalidInputError, match=msg):
            pd.RigidObject(brick, transform=bad)
    shear = np.eye(4)
    shear[0, 1] = 0.01
    with pytest.raises(pd.InvalidInputError, match="not rigid"):
        pd.RigidObject(brick, transform=shear)
    projective = np.eye(4)
    projective[3, 0] = 0.5
    with pytest.raises(pd.InvalidInputError, match="last row"):
        pd.RigidObject(brick, transform=projective)
    with pytest.raises(pd.InvalidInputError, match="RigidObject"):
        with_objects(pd.scenes.cornell_box(max_edge=None), [brick])
    # A pose checked once is found again by its bytes, not trusted after a change in place.
    obj, T = pd.RigidObject(brick), pose(30)
    c, r = obj.bounding_sphere(T)
    np.testing.assert_array_equal(obj.bounding_sphere(T.copy())[0], c)
    T[0, 0] = 2.0
    with pytest.raises(pd.InvalidInputError, match="not rigid"):
        obj.bounding_sphere(T)
    with pytest.raises(pd.InvalidInputError, match="not rigid"):
        obj.world_points(T)
    for k in range(20):  # more poses than it keeps: each still right
        np.testing.assert_allclose(
            obj.bounding_sphere(pose(k))[0], pose(k)[:3, :3] @ obj.bounding_sphere()[0] + pose(k)[:3, 3]
        )


def test_with_objects_numbering(cornell_384, brick):
    a, b = pd.RigidObject(brick, pose(30)), pd.RigidObject(brick, pose(0, (400.0, 450.0, 150.0)))
    both = with_objects(cornell_384, [a, b])
    n, m = len(cornell_384), len(brick)
    assert len(both) == n + 2 * m
    np.testing.assert_array_equal(both.centers[:n], cornell_384.centers)
    T = pose(0, (400.0, 450.0, 150.0))
    np.testing.assert_allclose(both.centers[n + m :], brick.centers @ T[:3, :3].T + T[:3, 3], atol=1e-3)
    np.testing.assert_allclose(both.areas[n : n + m], brick.areas, rtol=1e-5)
    np.testing.assert_array_equal(both.albedo[n : n + m], brick.albedo)


def test_with_objects_is_the_validated_scene(cornell_384, brick):
    """The combined scene is assembled from its parts without validation: every array equals,
    bit for bit, a Scene validated from the same points and triangles (static patches: the
    static scene's own arrays, as before), its bounds included; the arrays are read-only."""
    a, b = pd.RigidObject(brick, pose(30)), pd.RigidObject(brick, pose(0, (400.0, 450.0, 150.0)))
    both = with_objects(cornell_384, [a, b])
    parts = [cornell_384, brick, brick]
    checked = pd.Scene(
        both.vertices,
        both.faces,
        np.concatenate([p.albedo for p in parts]),
        np.concatenate([p.emission for p in parts]),
    )
    n = len(cornell_384)
    for name in ("vertices", "faces", "triangles", "albedo", "emission", "source_face", "bbox"):
        np.testing.assert_array_equal(getattr(both, name), getattr(checked, name), err_msg=name)
    for name in ("centers", "normals", "areas"):
        np.testing.assert_array_equal(getattr(both, name)[n:], getattr(checked, name)[n:], err_msg=name)
        np.testing.assert_array_equal(getattr(both, name)[:n], getattr(cornell_384, name), err_msg=name)
    assert both.geometry_hash() == checked.geometry_hash() and not both.centers.flags.writeable


@pytest.mark.parametrize("offset", [0.0, 3e6])
def test_hemicube_rows_match_static_copy(cornell_384, brick, device, offset):
    """Also far from the origin: object trees share the static scene's device frame."""
    if offset:
        cornell_384 = pd.Scene(
            cornell_384.vertices + offset, cornell_384.faces, cornell_384.albedo, cornell_384.emission, name="far box"
        )
    obj = pd.RigidObject(brick, pose(30, (150.0 + offset, 300.0 + offset, 400.0 + offset)))
    ref = pd.form_factors(with_objects(cornell_384, [obj]), R, device=device)
    inst = pd.form_factors(instanced(cornell_384, [obj]), R, device=device)
    assert ref.shape == inst.shape == (len(cornell_384) + len(brick),) * 2
    diff = abs(ref - inst)
    # Rays are moved into object space in float32, so a pixel whose ray grazes an edge may see
    # the neighbouring patch: at most a couple of pixels in all, each one pixel's weight.
    assert diff.max() <= 1.01 * pixel_form_factors(R).max()
    assert (diff > 1e-6).nnz <= 4
    assert ref[len(cornell_384) :].sum() > 0.9 * len(brick)  # the object's rows are there and see the box


def test_convex_objects_rows_skip_their_own_tree(cornell_384, brick, device):
    """The hemicube rows of a convex object's own patches do not walk its tree (nothing of a
    convex solid lies in front of its surface): the same rows bit for bit as with it walked, on
    the block at several poses. A convex solid wound inwards, and an object that is not convex
    (two blocks apart, whose facing sides see each other), keep walking their own tree, and
    their rows hold those entries."""
    obj = pd.RigidObject(brick, pose(30))
    world = instanced(cornell_384, [obj])
    n, m = len(cornell_384), len(brick)
    assert world.bvh.convex.tolist() == [True]
    own = world.bvh.own_instances(np.array([0, n - 1, n, n + m - 1]))
    assert own.tolist() == [-1, -1, 0, 0] and cornell_384.bvh.own_instances([0, 1]).tolist() == [-1, -1]
    idx = np.arange(n, n + m)
    for T in (pose(30), pose(75, (100.0, 400.0, 150.0)), pose(10, (450.0, 450.0, 120.0))):
        world = instanced(cornell_384, [obj], [T])
        skipped = pd.form_factors(world, R, rows=idx, device=device)
        world.bvh.convex[:] = False
        walked = pd.form_factors(world, R, rows=idx, device=device)
        assert skipped.nnz > 30 * m and all(
            np.array_equal(getattr(skipped, k), getattr(walked, k)) for k in ("indptr", "indices", "data")
        )
    inward = pd.Scene(brick.vertices, brick.faces[:, ::-1], brick.albedo, brick.emission, name="inward")
    world = instanced(cornell_384, [pd.RigidObject(inward, pose(30))])  # its patches face into the solid
    assert pd.RigidObject(inward).solid_planes is not None and world.bvh.convex.tolist() == [False]
    rows = pd.form_factors(world, R, rows=idx, device=device)
    assert rows[:, n:].sum() > 0.9 * m  # each sees the solid's other sides, which its tree shows
    one = pd.scenes.block(60.0, 1)
    pair = pd.Scene(
        np.vstack([one.vertices - (50.0, 0.0, 0.0), one.vertices + (50.0, 0.0, 0.0)]),
        np.vstack([one.faces, one.faces + len(one.vertices)]),
        np.vstack([one.albedo, one.albedo]),
        np.vstack([one.emission, one.emission]),
        name="pair",
    )
    world = instanced(cornell_384, [pd.RigidObject(pair, pose(20))])
    assert world.bvh.convex.tolist() == [False]
    assert (world.bvh.own_instances(np.arange(n, len(world))) == -1).all()
    rows = pd.form_factors(world, R, rows=np.arange(n, len(world)), device=device)
    assert rows[:, n:].sum() > 1.0  # the two blocks' facing sides see each other


def test_shadow_follows_object(cornell_384, brick, device):
    """A point light's shadow of the object on the floor moves with it, exactly."""
    light = [pd.PointLight((278.0, 540.0, 280.0), (1e6, 1e6, 1e6))]
    floor = np.flatnonzero(cornell_384.normals[:, 1] > 0.99)
    floor = floor[cornell_384.centers[floor, 1] < 1.0]
    shadows = []
    for T in (pose(0, (200.0, 300.0, 300.0)), pose(45, (380.0, 250.0, 150.0))):
        obj = pd.RigidObject(brick, T)
        ref, inst = with_objects(cornell_384, [obj]), instanced(cornell_384, [obj])
        E_ref = pd.lights.direct_irradiance(ref, light, device=device)
        E_inst = pd.lights.direct_irradiance(inst, light, device=device)
        np.testing.assert_array_equal(E_inst, E_ref)
        # Independent truth: a floor centre is shadowed where the segment to the light crosses
        # the object's triangles, tested in numpy (Moller-Trumbore in float64).
        v = obj.world_points()[brick.faces]
        p = cornell_384.centers[floor].astype(np.float64)
        d = np.asarray(light[0].position) - p
        e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
        pv = np.cross(d[:, None], e2[None])
        det = np.einsum("tk,ntk->nt", e1, pv)
        s = p[:, None] - v[None, :, 0]
        u = np.einsum("ntk,ntk->nt", s, pv) / det
        q = np.cross(s, e1[None])
        w = np.einsum("nk,ntk->nt", d, q) / det
        t = np.einsum("tk,ntk->nt", e2, q) / det
        blocked = np.any((u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0) & (t < 1), axis=1)
        lit = E_inst[floor].max(axis=1) > 0
        assert blocked.any() and (~blocked).any()
        # The static box shadows nothing on the floor at these centres except its own blocks.
        static_lit = pd.lights.direct_irradiance(cornell_384, light, device=device)[floor].max(axis=1) > 0
        np.testing.assert_array_equal(lit, static_lit & ~blocked)
        shadows.append(lit)
    assert (shadows[0] != shadows[1]).any()


def test_rays_and_render_match_static_copy(cornell_384, brick, device):
    obj = pd.RigidObject(brick, pose(60, (280.0, 420.0, 300.0)))
    ref, inst = with_objects(cornell_384, [obj]), instanced(cornell_384, [obj])
    cam = pd.Camera(position=(278.0, 273.0, -800.0), look_at=(278.0, 273.0, 280.0), fov_y=40, width=48, height=40)
    B = np.random.default_rng(1).random((len(ref), 3))
    img_ref = pd.render(ref, B, cam, device=device)
    img_inst = pd.render(inst, B, cam, device=device)
    bad = np.any(np.abs(img_ref - img_inst) > 1e-5, axis=2)
    assert bad.sum() <= 2  # a ray along a shared edge may pick the other triangle
    hit_obj = pd.render(
        inst, np.r_[np.zeros((len(cornell_384), 3)), np.ones((len(brick), 3))], cam, shading="flat", device=device
    )
    assert hit_obj.max() == 1.0  # the object is in view

    rng = np.random.default_rng(2)
    o = np.tile([278.0, 273.0, 100.0], (500, 1)) + rng.normal(0, 20, (500, 3))
    d = rng.normal(size=(500, 3))
    p_ref, t_ref, f_ref = cast_rays(ref, o, d, device=device)
    p_inst, t_inst, f_inst = cast_rays(inst, o, d, device=device)
    same = p_ref == p_inst
    assert same.mean() > 0.99 and np.isin(p_inst, np.arange(len(cornell_384), len(ref))).any()
    np.testing.assert_allclose(t_inst[same], t_ref[same], rtol=1e-4)
    np.testing.assert_array_equal(f_inst[same], f_ref[same])
    for width in (16, 8, 4):  # any-hit packets through the instance at every packet width
        dev = device.with_traits(float_width=width)
        np.testing.assert_array_equal(
            pd.geometry.bvh.occluded(inst, o, d, 300.0, device=dev),
            pd.geometry.bvh.occluded(ref, o, d, 300.0, device=dev),
        )


def test_path_tracer_sees_object(cornell_384, brick, device):
    """Same seed, same paths: the path tracer's image of the instanced scene is the static copy's."""
    obj = pd.RigidObject(brick, pose(20, (280.0, 420.0, 300.0)))
    ref, inst = with_objects(cornell_384, [obj]), instanced(cornell_384, [obj])
    cam = pd.Camera(position=(278.0, 273.0, -800.0), look_at=(278.0, 273.0, 280.0), fov_y=40, width=16, height=12)
    a = pd.path_trace(ref, cam, spp=2, seed=3, device=device)
    b = pd.path_trace(inst, cam, spp=2, seed=3, device=device)
    close = np.all(np.abs(a - b) <= 1e-3 * (1 + np.abs(a)), axis=2)
    assert close.mean() > 0.97  # a path that grazes an edge diverges from there on


def test_move_rewrites_table_only(cornell_384, brick, device):
    obj = pd.RigidObject(brick, pose(0))
    first = instanced(cornell_384, [obj])
    bvh = first.bvh
    nodes_before = bvh.nodes.copy()
    pd.form_factors(first, 8, rows=[0], device=device)  # uploads the buffers
    obj.transform = pose(45, (380.0, 250.0, 150.0))
    moved = instanced(cornell_384, [obj], bvh=bvh)
    assert moved.bvh is bvh
    changed = np.flatnonzero(np.any(nodes_before.view(np.int32) != bvh.nodes.view(np.int32), axis=1))
    assert len(changed) and changed.min() * 8 >= bvh._table_float4  # only the instance table
    ref = pd.form_factors(
        with_objects(cornell_384, [obj]), R, rows=np.arange(len(cornell_384), len(moved)), device=device
    )
    got = pd.form_factors(moved, R, rows=np.arange(len(cornell_384), len(moved)), device=device)
    assert (abs(ref - got) > 1e-6).nnz <= 4


def test_intersection_warned(cornell_384, brick):
    with pytest.warns(pd.geometry.ObjectIntersectionWarning, match="intersects"):
        instanced(cornell_384, [pd.RigidObject(brick, pose(0, (350.0, 200.0, 330.0)))])  # through the tall block


def test_intersection_warned_exactly_where_edges_cross(cornell_384, brick, device):
    """The warning's shortcut (no ray where no static triangle's box meets the object's bounding
    sphere) warns at the same poses as tracing every edge: poses in a grid across the box,
    through its walls and blocks and clear of them."""
    import warnings

    from pydynrad.geometry.bvh import occluded

    warned = []
    for x in (40.0, 200.0, 350.0, 520.0):
        for y in (45.0, 200.0, 420.0):
            for z in (40.0, 300.0):
                obj = pd.RigidObject(brick, pose(30, (x, y, z)))
                corners = obj.world_points()[brick.faces]
                crosses = bool(
                    occluded(
                        cornell_384,
                        corners.reshape(-1, 3),
                        (corners[:, [1, 2, 0]] - corners).reshape(-1, 3),
                        np.float32(1.0),
                        device=device,
                    ).any()
                )
                with warnings.catch_warnings(record=True) as w:
                    warnings.simplefilter("always")
                    instanced(cornell_384, [obj])
                said = any(issubclass(m.category, pd.geometry.ObjectIntersectionWarning) for m in w)
                assert said == crosses, (x, y, z)
                warned.append(said)
    assert 0 < sum(warned) < len(warned)
