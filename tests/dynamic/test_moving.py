"""Moving objects in DynamicRadiosity: a move is an exact batched swap of the objects' patches
and of the rows it changes most; with every changed row refreshed, K is a fresh build's.

Truths: a full solve of the world at the final pose from scratch (fresh hemicubes, float64),
and the same F with the rows a limited budget leaves stale, solved densely in numpy."""

import numpy as np
import pytest
from helpers import END, MIDDLE, START, dense_K, dense_radiosity, pose, rel
from helpers import MOVING_LIGHTS as LIGHTS
from helpers import MOVING_OBSERVER as OBSERVER
from helpers import MOVING_R as R
from helpers import moving_full_solve as full_solve

import pydynrad as pd
from pydynrad.dynamic.occlusion import sphere_solid_angle
from pydynrad.geometry.objects import instanced, with_objects


@pytest.fixture(scope="module")
def lamp():
    return pd.scenes.block(40.0, 0, albedo=0.5, emission=(30.0, 30.0, 20.0))


def test_light_vector_after_moves_relights_only_what_they_shadow(cornell_384, green_block, lamp, device, monkeypatch):
    """Each move lights again only the objects' patches and the static patches whose shadow rays
    pass near a moved object (old or new pose), in update() while the objects' hemicubes trace
    when the lights were steady (the last frame's those of the frame before), so that
    radiosity(lights) with the same lights traces nothing: the light vector is that of the same
    world built afresh (its own BVH), bit for bit, for point, spot and directional lights, with
    one object moved or two. Lights new in the last frame are relit in radiosity() instead (the
    move does not guess), other lights are lit whole there, as is a sky."""
    import pydynrad.dynamic.radiosity as radiosity_module
    import pydynrad.lights.sources as lights_module
    from pydynrad.lights import SkyLight

    traced = []
    real = radiosity_module._point_irradiance

    def counting(scene, points, normals, lights, device, patches=None, queued=False):
        traced.append(len(scene) if patches is None else len(patches))
        return real(scene, points, normals, lights, device, patches, queued)

    def fresh(lights):  # the world at the objects' poses, BVH and uploads of its own
        return pd.light_vector(instanced(cornell_384, dyn.objects), lights, device=device)

    monkeypatch.setattr(radiosity_module, "_point_irradiance", counting)  # a relight after a move
    monkeypatch.setattr(lights_module, "_point_irradiance", counting)  # a light vector traced whole
    lights = [
        pd.PointLight((278.0, 500.0, 280.0), (0.3, 0.3, 0.3)),
        pd.SpotLight((100.0, 540.0, 100.0), (0.3, -1.0, 0.4), (0.2, 0.2, 0.1), 0.3, 0.8),
        pd.DirectionalLight((0.0, -1.0, 0.0), (40.0, 40.0, 40.0)),
    ]
    obj, carried = pd.RigidObject(green_block, START), pd.RigidObject(lamp, pose(0, (400.0, 300.0, 120.0)))
    dyn = pd.DynamicRadiosity(
        cornell_384,
        None,
        local_size=len(cornell_384) // 2,
        resolution=R,
        objects=pd.MovingObjects([obj, carried], occlusion=0),
        observer=OBSERVER,
        device=device,
    )
    dyn.radiosity(lights)
    dyn.radiosity(lights)  # steady
    for T, U in ((MIDDLE, None), (END, pose(30, (350.0, 150.0, 200.0))), (START, None)):
        dyn.move(obj, T)
        if U is not None:
            dyn.move(carried, U)
        traced.clear()
        dyn.update(OBSERVER)
        assert len(traced) == 1 and len(green_block) + len(lamp) <= traced[0] < len(dyn.scene)
        dyn.radiosity(lights)
        assert len(traced) == 1
        np.testing.assert_array_equal(dyn._held_light.L, fresh(lights))
    dimmer = [pd.PointLight((278.0, 500.0, 280.0), (0.1, 0.1, 0.1))]
    traced.clear()
    dyn.radiosity(dimmer)
    assert traced == [len(dyn.scene)]
    np.testing.assert_array_equal(dyn._held_light.L, fresh(dimmer))
    dyn.move(obj, MIDDLE)  # the lights changed in the last frame: the move leaves them to radiosity()
    traced.clear()
    dyn.update(OBSERVER)
    assert traced == []
    dyn.radiosity(dimmer)
    assert len(traced) == 1 and len(green_block) + len(lamp) <= traced[0] < len(dyn.scene)
    np.testing.assert_array_equal(dyn._held_light.L, fresh(dimmer))
    sky = [SkyLight(zenith_luminance=1.0, up=(0.0, 1.0, 0.0), resolution=8)]
    dyn.radiosity(sky)
    dyn.move(obj, MIDDLE)
    dyn.update(OBSERVER)
    traced.clear()
    dyn.radiosity(sky)
    assert traced == [len(dyn.scene)]
    np.testing.assert_array_equal(dyn._held_light.L, fresh(sky))


def test_unlimited_budget_equals_full_solve(cornell_384, green_block, lamp, device):
    """Two objects (one emitting), moved twice, in chunks of 8 swaps: B is the full solve's."""
    obj, carried = pd.RigidObject(green_block, START), pd.RigidObject(lamp, pose(0, (400.0, 300.0, 120.0)))
    n = len(cornell_384) + len(green_block) + len(lamp)
    dyn = pd.DynamicRadiosity(
        cornell_384,
        None,
        local_size=n,
        resolution=R,
        objects=pd.MovingObjects([obj, carried], occlusion=None),
        max_swaps_per_frame=8,
        observer=OBSERVER,
        device=device,
    )
    assert len(dyn.scene) == n and dyn.scene.n_patches == n
    for T, U in ((MIDDLE, pose(10, (300.0, 200.0, 100.0))), (END, pose(45, (150.0, 250.0, 150.0)))):
        dyn.move(obj, T)
        dyn.move(carried, U)
        st = dyn.update(OBSERVER)
        assert st.moved == 2 and st.rows_refreshed > 0 and st.t_move > 0
    world, F, B_ref = full_solve(cornell_384, [obj, carried], device)
    B = dyn.radiosity(LIGHTS)
    assert rel(B, B_ref) < 2e-6  # fp32 K; observed 3e-8 (PoCL, Xeon)
    np.testing.assert_allclose(dyn.matrix.to_host(), dense_K(world, F, dyn.local_patches), atol=1e-6, rtol=0)
    # Against the static copy (one BVH over everything): a grazing hemicube pixel may see the
    # neighbouring patch, so the two F differ in a few pixels' worth.
    ref = with_objects(cornell_384, [obj, carried])
    F_flat = pd.form_factors(ref, R, device=device)
    assert rel(B, dense_radiosity(ref, F_flat, pd.light_vector(ref, LIGHTS, device=device))) < 3e-3
    # The objects receive light and reflect it: green bleeds onto the floor next to the block.
    n_box = len(cornell_384)
    assert B[n_box : n_box + len(green_block)].max() > 0
    floor = np.flatnonzero((cornell_384.normals[:, 1] > 0.99) & (cornell_384.centers[:, 1] < 1.0))
    without = dense_radiosity(
        cornell_384, pd.form_factors(cornell_384, R, device=device), pd.light_vector(cornell_384, LIGHTS, device=device)
    )
    near = floor[np.argsort(np.linalg.norm(cornell_384.centers[floor] - END[:3, 3], axis=1))[:4]]

    def green(b):
        return b[near, 1] / b[near].sum(axis=1)

    assert np.all(green(B) > green(without))


def test_budget_trades_error(cornell_384, green_block, device):
    """One move with a row budget: B is exactly the dense solve of the F that budget leaves
    (stale rows for the patches not refreshed, object columns by reciprocity), and the error
    against the full solve falls as the budget rises."""
    n_box = len(cornell_384)
    n = n_box + len(green_block)
    start = pd.RigidObject(green_block, START)
    F0 = pd.form_factors(instanced(cornell_384, [start]), R, device=device).toarray().astype(np.float64)
    end = pd.RigidObject(green_block, END)
    world, F1, B_ref = full_solve(cornell_384, [end], device)
    F1 = F1.toarray().astype(np.float64)
    L = pd.light_vector(world, LIGHTS, device=device)
    score = sum(
        sphere_solid_angle(cornell_384.centers, cornell_384.normals, *o.bounding_sphere()) for o in (start, end)
    )
    ranked = np.argsort(-score, kind="stable")
    A = world.areas.astype(np.float64)
    recip = (F1[n_box:, :n_box] * A[n_box:, None]).T / A[:n_box, None]
    stale = F1.copy()
    stale[:n_box, :n_box] = F0[:n_box, :n_box]
    stale[:n_box, n_box:] = recip
    # Rows summing above 1 with the block's columns: those columns fill them to 1.
    over = np.flatnonzero((stale[:n_box].sum(axis=1) > 1.0) & (recip.sum(axis=1) > 0))
    stale[over, n_box:] *= (np.maximum(1.0 - F0[over, :n_box].sum(axis=1), 0.0) / recip[over].sum(axis=1))[:, None]
    errors = []
    for budget in (0, 64, 160, None):
        obj = pd.RigidObject(green_block, START)
        dyn = pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=n,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=budget),
            observer=OBSERVER,
            device=device,
        )
        dyn.move(obj, END)
        st = dyn.update(OBSERVER)
        B = dyn.radiosity(LIGHTS)
        k = int((score > 0).sum()) if budget is None else budget
        assert st.rows_refreshed == k
        model = stale.copy()
        model[ranked[:k]] = F1[ranked[:k]]
        assert rel(B, dense_radiosity(world, model, L)) < 2e-6  # observed <= 7e-8
        errors.append(rel(B[:n_box], B_ref[:n_box]))
    assert errors[0] > errors[1] > errors[2] > errors[3]
    assert errors[0] < 0.03 and errors[3] < 2e-6  # observed 0.0086, 0.0085, 0.0080, 3e-8 (PoCL, Xeon)


@pytest.mark.parametrize("budget", [0, None])
def test_away_and_back_restores_K(cornell_384, green_block, device, budget):
    obj = pd.RigidObject(green_block, START)
    dyn = pd.DynamicRadiosity(
        cornell_384,
        None,
        local_size=len(cornell_384) + len(green_block),
        resolution=R,
        objects=pd.MovingObjects([obj], occlusion=budget),
        observer=OBSERVER,
        device=device,
    )
    # From the first move on, the rows a budget leaves stale are the same at every pose (the
    # built ones) and the objects' own rows and columns are those of the pose.
    dyn.move(obj, END)
    dyn.update(OBSERVER)
    K_end = dyn.matrix.to_host()
    for T in (MIDDLE, START, END):
        dyn.move(obj, T)
        dyn.update(OBSERVER)
    np.testing.assert_allclose(dyn.matrix.to_host(), K_end, atol=2e-6, rtol=0)  # observed 1e-7


def test_static_form_factors_with_objects(cornell_384, green_block, device):
    """A precomputed static F: object rows by hemicube, their columns by reciprocity; M < N
    keeps every object patch local while the observer moves."""
    F_static = pd.form_factors(cornell_384, R, device=device)
    obj = pd.RigidObject(green_block, START)
    M = len(green_block) + 100
    dyn = pd.DynamicRadiosity(
        cornell_384,
        F_static,
        local_size=M,
        resolution=R,
        objects=pd.MovingObjects([obj], occlusion=16),
        observer=OBSERVER,
        device=device,
    )
    objects = np.arange(len(cornell_384), len(cornell_384) + len(green_block))
    assert np.isin(objects, dyn.local_patches).all()
    dyn.move(obj, END)
    dyn.update((278.0, 100.0, 500.0))
    stale = dict(zip(dyn._stale.slots.tolist(), dyn.local_patches[dyn._stale.slots].tolist()))
    assert stale  # rows the move left stale, corrected in radiosity()
    before = dyn.local_patches
    st = dyn.update((100.0, 400.0, 500.0))
    assert np.isin(objects, dyn.local_patches).all()
    # A slot the walk refilled holds its entering patch's current row: it is no longer stale;
    # the others still are, for the same patches.
    refilled = np.flatnonzero(before != dyn.local_patches)
    assert st.swaps == len(refilled) > 0 and not np.isin(refilled, dyn._stale.slots).any()
    assert set(dyn._stale.slots.tolist()) == set(stale) - set(refilled.tolist())
    assert all(dyn.local_patches[s] == stale[s] for s in dyn._stale.slots.tolist())
    # K is a fresh build over the kept rows: the update is exact whatever the rows are.
    S = dyn.local_patches
    Fs = dyn._ff.square(S).toarray()
    K = np.stack([np.linalg.solve(np.eye(M) - Fs * dyn.scene.albedo[S, c][None, :], Fs) for c in range(3)])
    assert rel(dyn.matrix.to_host(), K) < 2e-6
    B = dyn.radiosity(LIGHTS)
    assert np.all(np.isfinite(B)) and B[objects].max() > 0


def test_bad_input(cornell_384, green_block, device):
    obj = pd.RigidObject(green_block, START)
    dyn = pd.DynamicRadiosity(
        cornell_384, None, local_size=len(cornell_384), resolution=R, objects=[obj], observer=OBSERVER, device=device
    )
    with pytest.raises(pd.InvalidInputError, match="not rigid"):
        dyn.move(obj, np.diag([1.0, 2.0, 1.0, 1.0]))
    with pytest.raises(pd.InvalidInputError, match="NaN"):
        dyn.move(obj, np.full((4, 4), np.nan))
    with pytest.raises(pd.InvalidInputError, match="never added"):
        dyn.move(pd.RigidObject(green_block), END)
    with pytest.raises(pd.InvalidInputError, match="more than local_size"):
        pd.DynamicRadiosity(cornell_384, None, local_size=len(green_block) - 1, objects=[obj], device=device)
    with pytest.raises(pd.InvalidInputError, match="update='exact'"):
        pd.DynamicRadiosity(
            cornell_384, None, local_size=len(cornell_384), objects=[obj], update="paper", device=device
        )
    with pytest.raises(pd.InvalidInputError, match="occlusion"):
        pd.DynamicRadiosity(
            cornell_384, None, local_size=len(cornell_384), objects=pd.MovingObjects([obj], occlusion=-1), device=device
        )
    with pytest.raises(pd.InvalidInputError, match="occlusion_correction"):
        pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=len(cornell_384),
            objects=pd.MovingObjects([obj], occlusion_correction="yes"),
            device=device,
        )
    with pytest.raises(pd.InvalidInputError, match="'auto'"):
        pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=len(cornell_384),
            objects=pd.MovingObjects([obj], occlusion="some"),
            device=device,
        )
    dyn.move(obj, pose(0, (350.0, 200.0, 330.0)))  # through the tall block: allowed, warned
    with pytest.warns(pd.geometry.ObjectIntersectionWarning):
        dyn.update(OBSERVER)


def test_a_pose_the_device_cannot_resolve_is_refused_before_anything_moves(cornell_384, green_block, device):
    """float32 device coordinates round a position d from the scene's centre by up to 2^-24
    sqrt(3) d: an object reaching beyond MAX_REACH diagonals (where that passes a tenth of the
    rays' surface offset) is refused by move() with nothing queued, at construction, by
    with_objects and by a walk before its first frame. Just inside, behind the back wall, the static patches' rows
    of the world are the box's own, bit for bit, and the block is dark: their rays leave their surfaces by the static
    scene's offset (Scene.ray_scale), not by one grown with the world (it had been 0.4% off the
    rows' sums at 1e5 mm). At 1e18 mm a move had crashed in the intersection test's rays."""
    from pydynrad.geometry.objects import MAX_REACH

    obj = pd.RigidObject(green_block, START)
    dyn = pd.DynamicRadiosity(
        cornell_384, None, local_size=len(cornell_384), resolution=R, objects=[obj], observer=OBSERVER, device=device
    )
    B = dyn.radiosity(LIGHTS)
    centre, radius = cornell_384.frame.origin, obj.bounding_sphere()[1]
    behind = lambda reach: pose(0, centre + (0.0, 0.0, reach - radius))  # noqa: E731  (+z: behind the back wall)
    limit = MAX_REACH * cornell_384.ray_scale
    for reach in (1.01 * limit, 1e18):
        with pytest.raises(pd.InvalidInputError, match=r"float32 .* keep it within"):
            dyn.move(obj, behind(reach))
        with pytest.raises(pd.InvalidInputError, match="float32"):
            pd.DynamicRadiosity(
                cornell_384,
                None,
                local_size=len(cornell_384),
                resolution=R,
                objects=[pd.RigidObject(green_block, behind(reach))],
                device=device,
            )
    with pytest.raises(pd.InvalidInputError, match="float32"):
        with_objects(cornell_384, [pd.RigidObject(green_block, behind(1e18))])
    track = pd.walks.ObjectTrack(obj, [START, behind(1.01 * limit)], interpolation="linear")
    with pytest.raises(pd.InvalidInputError, match="float32"):
        pd.walk(cornell_384, pd.orbit(centre, 300.0, 0.0, 3, width=8, height=6), dyn, objects=[track], device=device)
    dyn.update(OBSERVER)  # nothing was queued: the same answer
    np.testing.assert_array_equal(dyn.radiosity(LIGHTS), B)
    far = behind(0.95 * limit)
    world = instanced(cornell_384, [pd.RigidObject(green_block, far)])
    assert world.ray_scale == cornell_384.ray_scale < world.scale / 5
    n = len(cornell_384)
    F_world, F_box = (
        pd.form_factors(world, R, rows=np.arange(n), device=device),
        pd.form_factors(cornell_384, R, device=device),
    )
    assert F_world[:, n:].nnz == 0
    np.testing.assert_array_equal(F_world[:, :n].toarray(), F_box.toarray())
    dyn.move(obj, far)
    dyn.update(OBSERVER)
    B = dyn.radiosity(LIGHTS)
    assert np.all(np.isfinite(B)) and B[:n].max() > 0
    assert not B[n:].any()  # behind the back wall no light of the box reaches it


def test_object_track_and_walk(cornell_384, green_block, device):
    """walk with a keyframed block: each frame moves it, renders the world as it is, and the
    reference frames' full solves (fresh hemicubes of that world) agree with dynamic radiosity."""
    obj = pd.RigidObject(green_block, START)
    straight = pd.walks.ObjectTrack(obj, [START, END], interpolation="linear")
    np.testing.assert_array_equal(straight.at(0, 3), START)
    np.testing.assert_array_equal(straight.at(2, 3), END)
    half = straight.at(1, 3)
    np.testing.assert_allclose(half[:3, 3], 0.5 * (START[:3, 3] + END[:3, 3]), atol=1e-9)
    np.testing.assert_allclose(half[:3, :3], pose(35, (0, 0, 0))[:3, :3], atol=1e-12)  # halfway between 0 and 70 deg
    track = pd.walks.ObjectTrack(obj, [START, MIDDLE, END])  # three frames: one on each keyframe
    path = pd.fly_through([(278.0, 273.0, -300.0), (278.0, 273.0, -250.0)], frames=3, fov_y=40, width=24, height=18)
    n = len(cornell_384) + len(green_block)
    dyn = pd.DynamicRadiosity(
        cornell_384,
        None,
        local_size=n,
        resolution=R,
        objects=pd.MovingObjects([obj], occlusion=None),
        observer=path.camera(0).position,
        device=device,
    )
    result = pd.walk(cornell_384, path, dyn, lights=LIGHTS, objects=[track], reference_frames=[0, 2], device=device)
    np.testing.assert_array_equal(obj.transform, END)
    errors = [f.error for f in result.frames if f.error is not None]
    assert len(errors) == 2 and max(errors) < 2e-5  # fp32 K vs the walk's float32 full solve; observed 3.6e-6
    with pytest.raises(pd.InvalidInputError, match="ObjectTrack"):
        pd.walk(cornell_384, path, dyn, objects=[obj], device=device)
    with pytest.raises(pd.InvalidInputError, match="not rigid"):
        pd.walks.ObjectTrack(obj, [START, np.diag([1.0, 1.0, 3.0, 1.0])])


def test_static_form_factors_budget_trades_error(cornell_384, green_block, device):
    """A precomputed static F with the far field: rows at the new pose from it (hidden entries
    dropped, object columns by reciprocity) for the budget's rows, the outside gathered at the
    pose; uncorrected, the error against the full solve falls with the budget; corrected (the
    default), every budget is about as close as refreshing every row."""
    F_static = pd.form_factors(cornell_384, R, device=device)
    world, _, B_ref = full_solve(cornell_384, [pd.RigidObject(green_block, END)], device)
    errors = {}
    for budget, correct in ((0, False), (32, False), (None, False), (0, True), (32, True)):
        obj = pd.RigidObject(green_block, START)
        dyn = pd.DynamicRadiosity(
            cornell_384,
            F_static,
            local_size=len(world) - 40,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=budget, occlusion_correction=correct),
            observer=OBSERVER,
            device=device,
        )
        for T in (MIDDLE, END):
            dyn.move(obj, T)
            st = dyn.update(OBSERVER)
            dyn.radiosity(LIGHTS)
            assert st.hemicubes == len(green_block)  # the rows refreshed come from F
        errors[budget, correct] = rel(dyn.radiosity(LIGHTS), B_ref)
    assert errors[0, False] > errors[32, False] > errors[None, False]
    # observed 0.0118, 0.0104, 0.0026 (PoCL, Xeon); the rest is the patch-centre
    # occlusion estimate and the far field's coarse level of the first pose
    assert errors[None, False] < 0.01
    for budget in (0, 32):  # observed within 2e-8 of the refresh of every row (PoCL, EPYC)
        assert abs(errors[budget, True] - errors[None, False]) < 1e-4


def test_default_budget_follows_the_rows(cornell_384, green_block, device):
    """occlusion="auto": 0 with a static F and the correction (every budget gives the same
    error there, see test_stale_rows_corrected), DEFAULT_OCCLUSION where a refresh buys
    accuracy (hemicube rows, or no correction)."""
    from pydynrad.dynamic.radiosity import DEFAULT_OCCLUSION

    F_static = pd.form_factors(cornell_384, R, device=device)

    def budget(form_factors, **kw):
        return pd.DynamicRadiosity(
            cornell_384,
            form_factors,
            local_size=64,
            resolution=R,
            objects=pd.MovingObjects([pd.RigidObject(green_block, START)], **kw),
            far_field=False,
            observer=OBSERVER,
            device=device,
        ).occlusion

    assert budget(F_static) == 0
    assert budget(F_static, occlusion_correction=False) == DEFAULT_OCCLUSION == 32
    assert budget(None) == DEFAULT_OCCLUSION
    assert budget(F_static, occlusion=5) == 5


def test_a_move_that_fails_is_not_half_applied(cornell_384, green_block, device, monkeypatch):
    """A relight that fails inside the move (the light's guess while the objects trace) does not
    fail the move: radiosity() lights the world itself. A trace that fails leaves the world at
    the poses K and the stale rows are of, the move still queued: the next update applies it.
    Either way B is then the same move's without a failure (budget 0, static F)."""
    import pydynrad.dynamic.moves as moves_module
    import pydynrad.dynamic.radiosity as radiosity_module

    F_static = pd.form_factors(cornell_384, R, device=device)
    n = len(cornell_384) + len(green_block)

    def made():
        obj = pd.RigidObject(green_block, START)
        dyn = pd.DynamicRadiosity(
            cornell_384,
            F_static,
            local_size=n,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=0),
            observer=OBSERVER,
            device=device,
        )
        dyn.radiosity(LIGHTS)
        dyn.radiosity(LIGHTS)  # steady lights: the move brings them along
        return dyn, obj

    ok, obj = made()
    ok.move(obj, MIDDLE)
    ok.update(OBSERVER)
    truth = ok.radiosity(LIGHTS)

    def broken(*args, **kwargs):
        raise RuntimeError("clEnqueueNDRangeKernel failed: OUT_OF_RESOURCES")

    dyn, obj = made()
    real = radiosity_module._point_irradiance
    monkeypatch.setattr(radiosity_module, "_point_irradiance", broken)
    dyn.move(obj, MIDDLE)
    dyn.update(OBSERVER)  # the guess failed, the move did not
    with pytest.raises(RuntimeError, match="OUT_OF_RESOURCES"):
        dyn.radiosity(LIGHTS)  # where the caller asked for the light
    monkeypatch.setattr(radiosity_module, "_point_irradiance", real)
    np.testing.assert_array_equal(dyn.radiosity(LIGHTS), truth)

    # The objects' hemicubes fail as they are queued, or as they are waited for on a pool thread.
    from pydynrad.rows.sources import HemicubeRows

    for owner, name, failing in (
        (moves_module.WorldRows, "fresh_queued", broken),
        (HemicubeRows, "queued", lambda *args: broken),
    ):
        dyn, obj = made()
        before = dyn.scene
        monkeypatch.setattr(owner, name, failing)
        dyn.move(obj, MIDDLE)
        with pytest.raises(RuntimeError, match="OUT_OF_RESOURCES"):
            dyn.update(OBSERVER)
        np.testing.assert_array_equal(dyn.scene.bvh.transforms[0], START)
        np.testing.assert_array_equal(dyn.scene.centers, before.centers)
        np.testing.assert_array_equal(obj.transform, START)
        monkeypatch.undo()
        assert dyn.update(OBSERVER).moved == 1  # still queued
        np.testing.assert_array_equal(obj.transform, MIDDLE)
        np.testing.assert_array_equal(dyn.radiosity(LIGHTS), truth)
    # A queue that fails once: the failed move does not trace them again in its cleanup.
    real_queued, calls = HemicubeRows.queued, []

    def once(self, idx):
        calls.append(len(idx))
        if len(calls) == 1:
            raise RuntimeError("clEnqueueNDRangeKernel failed: OUT_OF_RESOURCES")
        return real_queued(self, idx)

    dyn, obj = made()
    monkeypatch.setattr(HemicubeRows, "queued", once)
    dyn.move(obj, MIDDLE)
    with pytest.raises(RuntimeError, match="OUT_OF_RESOURCES"):
        dyn.update(OBSERVER)
    assert calls == [len(green_block)]
    assert dyn.update(OBSERVER).moved == 1 and calls == [len(green_block)] * 2
    np.testing.assert_array_equal(dyn.radiosity(LIGHTS), truth)
    assert dyn._ff.source.fresh([])[0].shape == (0, len(dyn.scene))  # no rows asked, none made


def test_budget_zero_moves_then_walk_swaps(cornell_384, green_block, device, monkeypatch):
    """After budget-0 moves (nothing swapped into K) the walk's swaps keep K and its kept rows
    consistent: B equals what refresh() (every stale row swapped in) gives. With the correction
    capped at one iteration a call stops unconverged, returns an evaluated iterate, and later
    calls go on from it to the same answer."""
    from pydynrad.dynamic import stale

    F_static = pd.form_factors(cornell_384, R, device=device)
    n = len(cornell_384) + len(green_block)

    def walked():
        obj = pd.RigidObject(green_block, START)
        dyn = pd.DynamicRadiosity(
            cornell_384,
            F_static,
            local_size=n - 150,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=0),
            max_swaps_per_frame=16,
            observer=OBSERVER,
            device=device,
        )
        dyn.radiosity(LIGHTS)
        for T in (MIDDLE, END):
            dyn.move(obj, T)
            dyn.update(OBSERVER)
            dyn.radiosity(LIGHTS)
        swaps = sum(dyn.update(np.add(OBSERVER, (0.0, 0.0, 50.0 * k))).swaps for k in range(1, 6))
        assert swaps > 20  # observed 47
        return dyn

    dyn = walked()
    B = dyn.radiosity(LIGHTS, far_field=False)
    assert dyn._stale.converged and len(dyn._stale) > 100
    dyn.refresh()
    truth = dyn.radiosity(LIGHTS, far_field=False)
    # The correction stops at an estimated error of 2e-4 (CORRECTION_TOLERANCE); observed 3.5e-5.
    assert rel(B, truth) < 1e-4
    monkeypatch.setattr(stale, "CORRECTION_ITERATIONS", 1)
    capped = walked()
    capped.radiosity(LIGHTS, far_field=False)
    assert not capped._stale.converged
    for _ in range(30):
        B = capped.radiosity(LIGHTS, far_field=False)
        if capped._stale.converged:
            break
    # Observed: converged at the 2nd call, 7.6e-7 (the 6th, 5.9e-6, without the Gauss-Seidel step).
    assert capped._stale.converged and rel(B, truth) < 1e-5


def test_memory_estimate_counts_the_move_batch(cornell_384, green_block, device):
    # A move swaps the block's 48 patches in one batch: the update's scratch is sized for it,
    # not for the frame's 8 swaps, and the estimate says so.
    obj = pd.RigidObject(green_block, START)
    dyn = pd.DynamicRadiosity(
        cornell_384,
        None,
        local_size=len(cornell_384),
        resolution=R,
        objects=[obj],
        max_swaps_per_frame=8,
        far_field=False,
        observer=OBSERVER,
        device=device,
    )
    M = len(cornell_384)
    assert dyn.memory_bytes == pd.DynamicRadiosity.estimate_memory_bytes(
        M, 3, "fp32", 8, device, object_patches=len(green_block)
    )
    assert dyn.memory_bytes > pd.DynamicRadiosity.estimate_memory_bytes(M, 3, "fp32", 8, device)


@pytest.mark.slow
def test_a_thousand_moves_do_not_drift_or_grow(device):
    """1,000 moving frames at the default budget (0, a static F, the correction), the block
    stepped along a path whose two ends it keeps coming back to: K is never changed, the answer
    at each end is the same every time to about the correction's tolerance (it stops at an
    estimated 2e-4 of max B from its fixed point, starting from wherever the last frame left
    it: observed 1.5e-4 of max B apart at one end, bounded at the tolerance here; 0 at the
    other, whose rows are K's own), and at the first pose no row is held stale and host memory
    is what it was after its first returns (nothing accumulates move by move)."""
    cornell_384 = pd.scenes.cornell_box(max_edge=250.0)
    green_block = pd.scenes.block(100.0, 0, albedo=(0.1, 0.7, 0.1))
    at = lambda x: pose(0, (x, 430.0, 300.0))  # noqa: E731  (above the tall block, below the light)
    obj = pd.RigidObject(green_block, at(150.0))
    n = len(cornell_384) + len(green_block)
    dyn = pd.DynamicRadiosity(
        cornell_384,
        pd.form_factors(cornell_384, R, device=device),
        local_size=n // 2,
        resolution=R,
        objects=[obj],
        observer=OBSERVER,
        device=device,
    )
    dyn.radiosity(LIGHTS)
    K = dyn.matrix.to_host().copy()
    ends, memory = {150.0: [], 400.0: []}, []
    for k in range(1000):
        x = float(np.linspace(150.0, 400.0, 7)[k % 7]) if k % 2 else (150.0, 400.0)[(k // 2) % 2]
        dyn.move(obj, at(x))
        dyn.update(OBSERVER)
        B = dyn.radiosity(LIGHTS)
        if x in ends:
            ends[x].append(B)
        if x == 150.0:
            memory.append((dyn.host_memory_bytes, len(dyn._stale)))
    np.testing.assert_array_equal(dyn.matrix.to_host(), K)
    for x, answers in ends.items():
        answers = np.array(answers)
        assert len(answers) > 300 and np.abs(answers - answers[0]).max() <= dyn.correction_tolerance * answers.max(), x
    # The first return fills the caches a move keeps (512k -> 606k bytes here); then only a few
    # bytes' jitter of the frame's index arrays.
    assert all(held == 0 for _, held in memory)
    assert max(m for m, _ in memory[-100:]) <= max(m for m, _ in memory[1:10]), memory[:10]


def test_moves_that_fail_or_come_from_elsewhere_leave_the_solution_right(cornell_384, green_block, device):
    """A move refused inside update (an intersection warning made an error) leaves the pose, the
    queue and K as they were, and goes through once allowed; a transform set on the object
    directly, or by another solution sharing it, is a move too (it had been ignored: B of the
    old pose). Rows precomputed for other objects, or another static scene with as many
    patches, are refused (they had been taken as these)."""
    import warnings

    def fresh():
        obj = pd.RigidObject(green_block, START)
        return obj, pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=len(cornell_384) + len(green_block),
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=None),
            observer=OBSERVER,
            device=device,
            far_field=False,
        )

    obj, dyn = fresh()
    K0 = dyn.matrix.to_host()
    cut = pose(0, (200.0, 20.0, 40.0))  # through the floor
    dyn.move(obj, cut)
    with warnings.catch_warnings():
        warnings.simplefilter("error", pd.geometry.ObjectIntersectionWarning)
        with pytest.raises(pd.geometry.ObjectIntersectionWarning):
            dyn.update(OBSERVER)
    np.testing.assert_array_equal(obj.transform, START)
    np.testing.assert_array_equal(dyn.matrix.to_host(), K0)
    with pytest.warns(pd.geometry.ObjectIntersectionWarning):
        assert dyn.update(OBSERVER).moved == 1  # the queued move, applied now
    np.testing.assert_array_equal(obj.transform, cut)
    # Set directly, and moved by a second solution sharing the object: both follow it.
    obj, dyn = fresh()
    other = pd.DynamicRadiosity(
        cornell_384,
        None,
        local_size=len(cornell_384) + len(green_block),
        resolution=R,
        objects=pd.MovingObjects([obj], occlusion=None),
        observer=OBSERVER,
        device=device,
        far_field=False,
    )
    obj.transform = END
    assert dyn.update(OBSERVER).moved == 1 and other.update(OBSERVER).moved == 1
    world = instanced(cornell_384, [obj])
    truth = pd.solve(world, pd.form_factors(world, R, device=device), method="dense").radiosity
    for d in (dyn, other):
        assert np.abs(d.radiosity() - truth).max() <= 1e-6 * truth.max()
    assert dyn.update(OBSERVER).moved == 0
    # Poses of other objects (as many patches) and of another static scene (as many patches).
    small = pd.scenes.block(40.0, 1, albedo=(0.1, 0.7, 0.1))
    poses = pd.precompute.precompute_poses(cornell_384, [pd.RigidObject(small)], [START], resolution=R, device=device)
    with pytest.raises(pd.InvalidInputError, match="other objects"):
        pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=len(cornell_384) + len(green_block),
            resolution=R,
            objects=pd.MovingObjects([pd.RigidObject(green_block, START)], poses=poses),
            observer=OBSERVER,
            device=device,
        )
    turned = pd.Scene(
        cornell_384.vertices[:, [2, 1, 0]],
        cornell_384.faces[:, [0, 2, 1]],
        albedo=cornell_384.albedo,
        emission=cornell_384.emission,
    )
    poses = pd.precompute.precompute_poses(turned, [pd.RigidObject(green_block)], [START], resolution=R, device=device)
    with pytest.raises(pd.InvalidInputError, match="another static scene"):
        pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=len(cornell_384) + len(green_block),
            resolution=R,
            objects=pd.MovingObjects([pd.RigidObject(green_block, START)], poses=poses),
            observer=OBSERVER,
            device=device,
        )
