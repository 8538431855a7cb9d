"""The far field (pydynrad.farfield) against full solves of the same scene and F."""

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import box_scene, dense_radiosity, reciprocal_F
from scipy.linalg import lu_factor, lu_solve

import pydynrad
from pydynrad import DirectionalLight, DynamicRadiosity, PointLight, Scene
from pydynrad.comparison import radiosity_error
from pydynrad.device.matrix import DeviceMatrix
from pydynrad.farfield import Clusters, FarField, cluster_patches
from pydynrad.farfield.clusters import NORMAL_BINS
from pydynrad.host.product import HostBounce, HostMatrix


@pytest.fixture(scope="module")
def cornell_lit(device):
    scene = pydynrad.scenes.cornell_box()
    F = pydynrad.form_factors(scene, resolution=32, device=device, progress=False)
    # W/sr in the millimetre box, irradiance per m^2: what 2e5 had lit per mm^2
    lights = [PointLight(position=[278, 450, 280], intensity=[0.2] * 3)]
    L = pydynrad.light_vector(scene, lights, device=device)
    Fd, rho = F.toarray(), scene.albedo.astype(np.float64)
    lu = [lu_factor(np.eye(len(scene)) - rho[:, c][:, None] * Fd) for c in range(3)]

    def full(L):  # the dense float64 solve of (I - P F) B = L, factorised once
        return np.stack([lu_solve(lu[c], L[:, c]) for c in range(3)], axis=1)

    return scene, F, L, full(L), full


def rect(o, u, v, nu, nv, normal):
    """Points and triangles of the quad o + [0,1]u + [0,1]v as nu x nv cells, facing ``normal``."""
    o, u, v = (np.asarray(a, dtype=np.float64) for a in (o, u, v))
    g = np.array([[o + u * i / nu + v * j / nv for j in range(nv + 1)] for i in range(nu + 1)]).reshape(-1, 3)
    tris = []
    for i in range(nu):
        for j in range(nv):
            a, b, c, d = i * (nv + 1) + j, (i + 1) * (nv + 1) + j, (i + 1) * (nv + 1) + j + 1, i * (nv + 1) + j + 1
            tris += [[a, b, c], [a, c, d]]
    tris = np.array(tris)
    n = np.cross(u, v)
    if np.dot(n, normal) < 0:
        tris = tris[:, ::-1]
    return g, tris


def box_faces(lo, hi, cells, inward):
    """The six faces of the box [lo, hi], facing out (or in)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    out = []
    for axis in range(3):
        for side, sign in ((lo, -1.0), (hi, 1.0)):
            u_ax, v_ax = [a for a in range(3) if a != axis]
            o = lo.copy()
            o[axis] = side[axis]
            u, v = np.zeros(3), np.zeros(3)
            u[u_ax], v[v_ax] = hi[u_ax] - lo[u_ax], hi[v_ax] - lo[v_ax]
            normal = np.zeros(3)
            normal[axis] = -sign if inward else sign
            out.append(rect(o, u, v, cells, cells, normal))
    return out


def yard_and_room() -> Scene:
    """An open yard (ground and a free-standing wall casting a hard shadow) beside a closed room
    raised above the ground (its shadow lit only indirectly): a hollow box whose inner faces no
    light reaches."""
    parts = [rect([0, 0, 0], [4, 0, 0], [0, 0, 2], 16, 8, [0, 1, 0])]
    parts += box_faces([1.0, 0.0, 0.8], [1.1, 1.0, 1.6], 3, inward=False)  # the wall
    parts += box_faces([2.5, 0.3, 0.5], [3.5, 1.3, 1.5], 4, inward=False)  # the room on stilts, outside
    parts += box_faces([2.6, 0.4, 0.6], [3.4, 1.2, 1.4], 4, inward=True)  # and inside
    pts, tris, base = [], [], 0
    for p, t in parts:
        pts.append(p)
        tris.append(t + base)
        base += len(p)
    return Scene(np.concatenate(pts), np.concatenate(tris), albedo=0.7, name="yard and room")


# -- clusters ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("per", [1, 3, 8, 40])
def test_clusters_are_pure_and_cover_every_patch_once(cornell_lit, per):
    scene = cornell_lit[0]
    cl = cluster_patches(scene, patches_per_cluster=per)
    assert cl.labels.shape == (len(scene),) and np.array_equal(np.unique(cl.labels), np.arange(cl.count))
    assert cl.count == max(cl.groups, -(-len(scene) // per))
    bins = np.argmax(scene.normals @ NORMAL_BINS.T, axis=1)
    for what in (scene.albedo, scene.emission, bins[:, None]):
        key = np.unique(np.column_stack([cl.labels, what]), axis=0)
        assert len(key) == cl.count  # one value per cluster
    assert np.array_equal(cluster_patches(scene, patches_per_cluster=per).labels, cl.labels)  # deterministic
    # Compact: every cluster's patches lie within a small part of the box.
    if per == 8:
        spread = [np.ptp(scene.centers[cl.labels == c], axis=0).max() for c in range(cl.count)]
        assert np.median(spread) < 0.15 * scene.scale


def test_every_patch_its_own_cluster_is_the_full_solve(device):
    scene = box_scene(3).with_materials(
        albedo=np.random.default_rng(1).uniform(0.1, 0.9, (108, 3)), emission=np.where(np.arange(108) < 3, 4.0, 0.0)
    )
    F = reciprocal_F(scene.areas, row_sum=1.0, density=0.2, seed=2)
    L = np.random.default_rng(3).random((len(scene), 3))
    want = dense_radiosity(scene, F, L)
    for M, obs, coarse in (
        (1, [0.5, 0.5, 0.02], "dense"),
        (7, [0.1, 0.9, 0.5], "sweeps"),
        (30, [0.9, 0.1, 0.9], "dense"),
    ):
        far = FarField(
            scene, F, clusters=len(scene), coarse=coarse, tol=1e-14, max_sweeps=5000, dtype=np.float64, device=device
        )
        dyn = DynamicRadiosity(scene, F, local_size=M, storage="fp64", observer=obs, far_field=far, device=device)
        dyn.update([0.5, 0.5, 0.5])
        np.testing.assert_allclose(dyn.radiosity(light=L), want, rtol=1e-13)  # observed 1.5e-15 (PoCL)
        levels = dyn.patch_levels
        assert (levels == "local").sum() == M and (levels == "far").sum() == len(scene) - M


@pytest.mark.parametrize("inside", [True, False])
@pytest.mark.parametrize("fraction", [8, 4])
def test_cornell_box_within_one_percent(device, cornell_lit, inside, fraction):
    scene, F, L, ref, _ = cornell_lit
    obs = [278, 273, 280] if inside else [278, 273, -800]
    n = len(scene)
    dyn = DynamicRadiosity(scene, F, local_size=n // fraction, observer=obs, clusters=n // fraction, device=device)
    B = dyn.radiosity(light=L)
    err = radiosity_error(B, ref, scene.areas)
    off = DynamicRadiosity(scene, F, local_size=n // fraction, observer=obs, far_field=False, device=device)
    assert err < 0.01 < radiosity_error(off.radiosity(light=L), ref, scene.areas)


def test_sun_lights_every_lit_patch_and_leaks_nothing(device):
    scene = yard_and_room()
    F = pydynrad.form_factors(scene, resolution=32, device=device, progress=False)
    sun = [DirectionalLight((-0.5, -1.0, -0.2), (3.0,) * 3)]
    L = pydynrad.light_vector(scene, sun, device=device)
    ref = dense_radiosity(scene, F, L)
    mean = ref.mean()
    dark = ref.max(axis=1) < 1e-3 * mean
    assert 0.1 < dark.mean() < 0.5  # the room's inside: a real test of leaks
    # Observed (PoCL): no leak at all (0.0); all-patch error 0.53% (first bounce), 0.40% (shared
    # with a fine sweep) and 2.6% (cluster).
    for gather, fine_sweeps, tol in (("first_bounce", 0, 0.01), ("shared", 1, 0.01), ("cluster", 0, 0.05)):
        far = FarField(scene, F, clusters=len(scene) // 8, gather=gather, fine_sweeps=fine_sweeps, device=device)
        dyn = DynamicRadiosity(
            scene, F, local_size=len(scene) // 8, observer=[0.5, 0.5, 1.0], far_field=far, device=device
        )
        B = dyn.radiosity(light=L)
        assert np.all(B[~dark].max(axis=1) > 0)  # nothing the full solution lights is black
        assert B[dark].max() < 1e-2 * mean  # no leaks into the closed room
        assert radiosity_error(B, ref, scene.areas) < tol


@pytest.mark.parametrize("storage, rtol", [("fp64", 5e-14), ("fp32", 5e-6), ("fp16", 2e-3)])
def test_dense_coarse_level_and_first_bounce_gather(device, cornell_lit, storage, rtol):
    """B_far = L + D1 + P G D_c, D1 = P F L, with D_c = R D1 + P_c F_c D_c solved densely in float64."""
    scene, F, L, _, _ = cornell_lit
    far = FarField(
        scene, F, clusters=len(scene) // 8, coarse="dense", coarse_storage=storage, dtype=np.float64, device=device
    )
    # Small beside a CPU device: K_c and G on the host (pydynrad.host.product); elsewhere on the device.
    assert far.coarse == "dense" and isinstance(far.K_c, HostMatrix) and isinstance(far._G_product, HostBounce)
    assert far.host_memory_bytes > far.K_c.nbytes >= 3 * far.C**2 * int(storage[2:]) // 8
    rho = scene.albedo.astype(np.float64)
    D1 = rho * (F @ L)
    s = far.R @ D1
    D_c = np.stack(
        [np.linalg.solve(np.eye(far.C) - far.rho_c[:, [c]] * far.F_c.toarray(), s[:, c]) for c in range(3)], 1
    )
    want = L + D1 + rho * (far.G @ D_c)
    # Observed max relative error (PoCL): 6e-16 (fp64), 5e-8 (fp32), 2e-5 (fp16 K_c); 4e-15 swept.
    np.testing.assert_allclose(far.light(L), want, rtol=rtol, atol=rtol * want.max())
    # As on a GPU: D1 from a device pass of F's rows, not the host's lit columns of F.
    gpu = FarField(
        scene,
        F,
        clusters=far.clusters,
        coarse="dense",
        coarse_storage=storage,
        dtype=np.float64,
        device=device.with_traits(cpu=False),
    )
    assert gpu._F_cols is None and gpu._F_dev is not None and isinstance(gpu.K_c, DeviceMatrix)
    assert gpu.device_memory_bytes > gpu.K_c.nbytes >= 3 * far.C**2 * int(storage[2:]) // 8
    np.testing.assert_allclose(gpu.light(L), want, rtol=rtol, atol=rtol * want.max())
    sweeps = FarField(scene, F, clusters=far.clusters, coarse="sweeps", tol=1e-13, dtype=np.float64, device=device)
    np.testing.assert_allclose(sweeps.light(L), want, rtol=2e-13, atol=2e-13 * want.max())
    assert sweeps.K_c is None and sweeps.sweeps > 10


def test_coarse_sweeps_start_from_earlier_solutions_combined(device, cornell_lit):
    """The coarse solution is linear in its source: lights that are a combination of earlier ones
    start the sweeps at their answer (one sweep to confirm it); new lights still converge to the
    answer a far field that never saw other lights gives."""
    scene, F, _, _, _ = cornell_lit

    def lamp(x):
        return pydynrad.light_vector(scene, [PointLight(position=[x, 450, 280], intensity=[0.2] * 3)], device=device)

    far = FarField(scene, F, clusters=len(scene) // 8, coarse="sweeps", dtype=np.float64, device=device)
    far._combined = lambda L: None  # the answer's own combination would skip the coarse solve
    a, b = lamp(150.0), lamp(400.0)
    far.light(a)
    cold = far.sweeps
    far.light(b)
    both = far.light(a + 0.5 * b).copy()
    assert far.sweeps == 1 < cold
    fresh = FarField(scene, F, clusters=far.clusters, coarse="sweeps", dtype=np.float64, device=device)
    # Both stop at a relative change of tol = 1e-4 from different starts: observed 1.4e-6 and 3.4e-6 apart.
    np.testing.assert_allclose(both, fresh.light(a + 0.5 * b), rtol=1e-4, atol=1e-4 * both.max())
    new = far.light(lamp(270.0))  # not a combination: sweeps as usual, the same answer
    assert far.sweeps > 1
    np.testing.assert_allclose(new, fresh.light(lamp(270.0)), rtol=1e-4, atol=1e-4 * new.max())


def coloured_lamp(scene, x: float, device):
    """L of a warm point lamp over the Cornell box's floor at height 450, x along the box."""
    return pydynrad.light_vector(scene, [PointLight(position=[x, 450, 280], intensity=[0.2, 0.1, 0.05])], device=device)


def test_light_combinations_reuse_earlier_answers(device, cornell_lit):
    """B_far is linear in L: a light that is a combination of the last ones (switched back,
    dimmed, recoloured, summed) is answered by the same combination of their B_far, with no pass
    over F or G, and equals what a far field computing it gives; a new light, or one that only
    an extrapolation of near-parallel lights makes, is computed."""
    scene, F, _, _, full = cornell_lit

    def lamp(x):
        return coloured_lamp(scene, x, device)

    far = FarField(scene, F, clusters=len(scene) // 8, device=device)
    fresh = FarField(scene, F, clusters=far.clusters, device=device)
    fresh._combined = lambda L: None
    a, b = lamp(150.0), lamp(400.0)
    unlit = far.host_memory_bytes
    for L in (a, b):
        far.light(L)
        assert not far.combined
    n = len(scene)  # what a light change keeps is counted: B_far, the record (L in float64, B in
    # float32, 4 deep), and on a CPU device the last first bounce and its light (float64)
    bounce = 0 if far._bounced is None else 2 * n * 3 * 8
    assert far.host_memory_bytes - unlit >= n * 3 * 8 + 4 * n * 3 * (8 + 4) + bounce
    for L in (a, 2.0 * b, a + 0.5 * b, a * [0.3, 1.0, 2.0]):
        B = far.light(L).copy()
        assert far.combined and far.sweeps == 0 and far.first_bounce_columns == 0
        # The same dense coarse product and gathers (float32) on L or on a and b: observed 8e-8.
        np.testing.assert_allclose(B, fresh.light(L), rtol=1e-5, atol=1e-6 * B.max())
        assert radiosity_error(B, full(L), scene.areas) < 0.01
    far.light(lamp(270.0))  # not a combination
    assert not far.combined
    c, d = lamp(200.0), lamp(200.01)
    far.light(c)
    far.light(d)
    far.light(c + 1000.0 * (d - c))  # a combination only with coefficients -999 and 1000
    assert not far.combined
    # A dim lamp as the difference of a bright scene with and without it: exact in L, but the
    # answers' own errors would be multiplied by ~200 (1e-3 of max B with coarse sweeps).
    bright, cancels = 100.0 * lamp(150.0), FarField(scene, F, clusters=far.clusters, device=device)
    cancels.light(bright + c)
    cancels.light(bright)
    cancels.light(c)
    assert not cancels.combined


def test_light_combinations_in_float64(device, cornell_lit):
    """A float64 far field keeps its answers in float64: a combination is as exact as they are."""
    scene, F, _, _, _ = cornell_lit

    def lamp(x):
        return coloured_lamp(scene, x, device)

    far = FarField(scene, F, clusters=len(scene) // 8, coarse_storage="fp64", dtype=np.float64, device=device)
    fresh = FarField(scene, F, clusters=far.clusters, coarse_storage="fp64", dtype=np.float64, device=device)
    fresh._combined = lambda L: None
    a, b = lamp(150.0), lamp(400.0)
    far.light(a)
    far.light(b)
    B = far.light(a + 0.5 * b).copy()
    assert far.combined
    np.testing.assert_allclose(B, fresh.light(a + 0.5 * b), rtol=1e-12, atol=1e-14 * B.max())  # observed 7e-16 of max B


def test_first_bounce_of_a_lamp_switched_under_a_sun_multiplies_only_its_columns(device, monkeypatch):
    """D1 = P F L is linear in L: switching a lamp under a sun adds the lamp's first bounce (its
    few columns of F) to the last one; the answer is that of a whole product, to float32 rounding."""
    from pydynrad.farfield import level

    scene = yard_and_room()
    F = pydynrad.form_factors(scene, resolution=16, device=device, progress=False)
    sun = pydynrad.light_vector(scene, [DirectionalLight((-0.5, -1.0, -0.2), (3.0,) * 3)], device=device)
    lamp = pydynrad.light_vector(scene, [PointLight(position=[0.5, 0.3, 1.0], intensity=[0.05] * 3)], device=device)
    lamp[np.abs(lamp) < 1e-3 * np.abs(lamp).max()] = 0.0  # a lamp of small reach: few patches lit by it alone
    monkeypatch.setattr(level, "DELTA_BOUNCES", 3)
    far = FarField(scene, F, clusters=len(scene) // 8, device=device)
    far._combined = lambda L: None  # sun, sun + lamp, sun: the answers' combination would skip D1
    fresh = FarField(scene, F, clusters=far.clusters, device=device)
    lit = lambda L: int(np.count_nonzero(np.any(L != 0, axis=1)))  # noqa: E731
    columns = []
    for L in (sun, sun + lamp, sun, sun + lamp, sun, sun + 0.5 * lamp):
        B = far.light(L)
        columns.append(far.first_bounce_columns)
        fresh._bounced = None  # a whole product every time
        # Observed max relative difference 3.6e-7 (the change's product in float32 on the float64 D1).
        np.testing.assert_allclose(B, fresh.light(L), rtol=1e-5, atol=1e-6 * B.max())
    changed = int(np.count_nonzero(np.any(lamp != 0, axis=1)))
    assert changed < lit(sun) / 2
    # Whole, then three changes, then whole again (DELTA_BOUNCES = 3), then a change.
    assert columns == [lit(sun), changed, changed, changed, lit(sun), changed]


def test_light_changes_follow_the_full_solve(device, cornell_lit):
    scene, F, _, _, full = cornell_lit
    for coarse in ("dense", "sweeps"):
        far = FarField(scene, F, clusters=len(scene) // 8, coarse=coarse, device=device)
        dyn = DynamicRadiosity(
            scene, F, local_size=len(scene) // 8, observer=[278, 273, 280], far_field=far, device=device
        )
        sweeps = []
        for x in (150.0, 200.0, 400.0):
            lights = [PointLight(position=[x, 450, 280], intensity=[0.2] * 3)]
            dyn.update([x, 273, 280])
            L = pydynrad.light_vector(scene, lights, device=device)
            B = dyn.radiosity(lights)
            assert radiosity_error(B, full(L), scene.areas) < 0.01
            sweeps.append(dyn.far.sweeps)
        if coarse == "sweeps":
            assert sweeps[1] < sweeps[0]  # the coarse solve starts from the previous lights' solution


def test_injection_from_the_columns_outside_the_local_set(device, cornell_lit):
    """The injection P_S F[S, X] B_far[X]: a first call with new rows multiplies them whole, a
    second with the same rows and local set only their entries outside it, cut out once (where
    they are fewer than half: a large local set); every call equals the product of the whole
    rows with B_far zeroed on S, bit for bit."""
    scene, F, L, _, _ = cornell_lit
    far = FarField(scene, F, clusters=len(scene) // 8, device=device)
    for share, cut_out in ((0.75, True), (0.25, False)):
        S = np.random.default_rng(3).choice(len(scene), int(share * len(scene)), replace=False)
        rows = sp.csr_matrix(F[S], dtype=np.float64)
        for scale in (1.0, 0.5, 2.0):  # new lights each time: B_far changes, the rows do not
            far.light(L * scale)
            outside = far.B_far.copy()
            outside[S] = 0.0
            np.testing.assert_array_equal(far.injection(rows, S), far.rho[S] * (rows @ outside))
        held, cut = far._outside_cols[0], far._outside_cols[2]
        assert held is rows and (cut is not None) == cut_out
        if cut_out:
            assert 0 < cut.nnz < rows.nnz / 2 and not np.isin(cut.indices, S).any()


@pytest.mark.parametrize("update", ["exact", "paper"])
def test_injection_follows_the_swaps_of_a_walk(device, cornell_lit, update):
    """A walk's frames replace the local rows on every swap; the injection is carried over each
    swap (FarField.follow_swap: the kept slots' change from the columns of the patches that
    entered and left, the swapped slots' new rows) and equals the whole product of the rows
    with B_far zeroed on the local set, to float64 rounding, also over frames whose radiosity()
    is skipped; B equals that of a solution that multiplies the rows whole (to a float32
    rounding: the light reaches the device's products in float32)."""
    scene, F, L, _, _ = cornell_lit
    kw = dict(
        local_size=len(scene) // 4, update=update, max_swaps_per_frame=8, observer=[278, 273, -300], device=device
    )
    dyn, whole = DynamicRadiosity(scene, F, **kw), DynamicRadiosity(scene, F, **kw)
    dyn.radiosity(light=L)
    carried = worst = 0
    for k, z in enumerate(np.linspace(-300, 500, 12)):
        stats = dyn.update([278, 273, z])
        S, rows = dyn._local_patches, dyn._ff.local
        if stats.swaps and dyn.far._injected[1] is rows:  # carried, not recomputed
            carried += 1
            outside = dyn.far.B_far.copy()
            outside[S] = 0.0
            expected = dyn.far.rho[S] * (rows @ outside)
            worst = max(worst, np.abs(dyn.far._injected[3] - expected).max() / np.abs(expected).max())
        whole.update([278, 273, z])
        whole.far._injected = None  # its injection multiplies the whole rows
        if k % 3 != 1:
            np.testing.assert_allclose(dyn.radiosity(light=L), whole.radiosity(light=L), rtol=1e-7, atol=0)
    assert carried >= 8 and worst < 2e-15  # 5.6e-16 of the largest over 11 carried frames


def test_injection_after_a_carried_swap_cuts_nothing(device, cornell_lit, monkeypatch):
    """New lights on every frame of a walk: each injection multiplies the rows as the swap left
    them (they are new to the product), and none cuts out their outside columns, which the next
    swap would drop; the carry count restarts at each product, and past MAX_CARRIED_SWAPS a
    carry hands over to a full product."""
    from pydynrad.farfield import level

    scene, F, L, _, _ = cornell_lit
    # tolerance=None: one injection per frame (refinement sweeps inject again, with the same rows).
    dyn = DynamicRadiosity(
        scene,
        F,
        local_size=len(scene) // 2,
        max_swaps_per_frame=8,
        observer=[278, 273, -300],
        device=device,
        tolerance=None,
    )
    for k, z in enumerate(np.linspace(-300, 500, 8)):
        dyn.update([278, 273, z])
        S, rows = dyn._local_patches, dyn._ff.local
        B = dyn.radiosity(light=L * (1.0 + 0.1 * k))  # a new light vector each frame: B_far changes
        assert dyn.far._outside_cols is None and dyn.far._carried == 0
        outside = dyn.far.B_far.copy()
        outside[S] = 0.0
        np.testing.assert_array_equal(dyn.far._injected[3], dyn.far.rho[S] * (rows @ outside))
        assert np.isfinite(B).all()
    monkeypatch.setattr(level, "MAX_CARRIED_SWAPS", 2)
    carried = []
    for z in np.linspace(500, -300, 5):
        if dyn.update([278, 273, z]).swaps:
            carried.append(dyn.far._injected is not None and dyn.far._injected[1] is dyn._ff.local)
    assert carried[:3] == [True, True, False]


def test_far_field_from_a_store_and_from_rows_on_demand(device, cornell_lit, tmp_path):
    from pydynrad.precompute.store import compute_store
    from pydynrad.rows.files import open_form_factors

    scene, F, L, ref, _ = cornell_lit
    cl = cluster_patches(scene, patches_per_cluster=8)
    compute_store(
        scene,
        tmp_path / "ff",
        resolution=32,
        clusters=cl,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    obs = [278, 273, 280]
    store = open_form_factors(scene, tmp_path / "ff")
    dyn = DynamicRadiosity(scene, store, local_size=137, observer=obs, device=device)
    assert np.array_equal(dyn.far.clusters.labels, cl.labels) and dyn.far.gather == "cluster"  # the store's own G
    err = radiosity_error(dyn.radiosity(light=L), ref, scene.areas)
    on_demand = DynamicRadiosity(
        scene, None, local_size=137, observer=obs, resolution=32, clusters=cl.count, device=device
    )
    # Observed 0.57% for both (G by hemicubes at R = 24, the linear basis; the indicator's 1.1%;
    # 0.14% from F in memory, with the per-patch first bounce).
    assert dyn.far.prolongation == on_demand.far.prolongation == "linear"
    assert radiosity_error(on_demand.radiosity(light=L), ref, scene.areas) < 0.008 and err < 0.008
    bare = DynamicRadiosity(scene, store, local_size=137, observer=obs, far_field=False, device=device)
    # Without F, F_c lives on the device only (as K_c here) and a store's G stays in the store.
    assert dyn.far.G is None is dyn.far.F_c and dyn.host_memory_bytes - bare.host_memory_bytes > dyn.far.R.data.nbytes
    assert dyn.far._G_stream is not None and dyn.far.device_memory_bytes < 8 * dyn.far.G_nnz
    assert dyn.memory_bytes - bare.memory_bytes == dyn.far.device_memory_bytes
    held = FarField(scene, None, dyn.far.clusters, G=store.cluster_form_factors(), device=device)
    # G held whole: on the host beside a CPU device where it is small (pydynrad.host.product), else on the device.
    assert isinstance(held._G_product, HostBounce) and held.device_memory_bytes == dyn.far.device_memory_bytes
    assert held.host_memory_bytes > held._G_product.nbytes >= 4 * held.G_nnz
    gpu = FarField(scene, None, dyn.far.clusters, G=store.cluster_form_factors(), device=device.with_traits(cpu=False))
    assert gpu.device_memory_bytes - dyn.far.device_memory_bytes > 8 * gpu.G_nnz
    compute_store(
        scene,
        tmp_path / "no-G",
        resolution=32,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    with pytest.raises(pydynrad.InvalidInputError, match="holds no far-field G"):
        DynamicRadiosity(scene, open_form_factors(scene, tmp_path / "no-G"), local_size=10, device=device)


def test_light_refuses_bad_light_vectors(device, cornell_lit):
    scene, F, L, _, _ = cornell_lit
    far = FarField(scene, F, clusters=len(scene) // 8, coarse="sweeps", device=device)
    nan = L.copy()
    nan[3, 1] = np.nan
    # Each went through before: NaN to an all-NaN B_far, (N, 2) to a grey answer, others to numpy's errors.
    for bad, match in (
        (nan, "L contains NaN"),
        (L[:, :2], r"shape \(\d+, 3\)"),
        (L[:-1], "shape"),
        (L[:, 0], "shape"),
        ("light", "array of numbers"),
    ):
        with pytest.raises(pydynrad.InvalidInputError, match=match):
            far.light(bad)
    assert far.B_far is None


def test_bad_input(device, cornell_lit):
    scene, F = cornell_lit[:2]
    n = len(scene)
    groups = cluster_patches(scene).groups
    for bad in (0, -1, n + 1, groups - 1, 2.5):
        with pytest.raises(pydynrad.InvalidInputError, match="clusters"):
            cluster_patches(scene, bad)
    with pytest.raises(pydynrad.InvalidInputError, match="patches_per_cluster"):
        cluster_patches(scene, patches_per_cluster=0.5)
    with pytest.raises(pydynrad.InvalidInputError, match="not both"):
        cluster_patches(scene, 10, 10)
    cl = cluster_patches(scene)
    with pytest.raises(pydynrad.InvalidInputError, match=r"G must have shape"):
        FarField(scene, None, cl, G=sp.csr_matrix((n, cl.count + 1)), device=device)
    with pytest.raises(pydynrad.InvalidInputError, match=rf"G must have shape \(\d+, {3 * cl.count}\)"):
        FarField(scene, None, cl, G=F @ cl.indicator(), device=device)  # without F the basis is linear: 3C columns
    with pytest.raises(pydynrad.InvalidInputError, match=r"row \d+ of G sums to"):
        FarField(scene, None, cl, G=3 * (F @ cl.indicator()), prolongation="indicator", device=device)
    other = scene.with_materials(albedo=0.3)
    with pytest.raises(pydynrad.InvalidInputError, match="another scene"):
        FarField(other, None, cl, G=F @ cl.indicator(), prolongation="indicator", device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="needs F in memory or"):
        FarField(scene, None, cl, device=device)
    for needs_F in ({"gather": "first_bounce"}, {"gather": "shared"}, {"fine_sweeps": 1}):
        with pytest.raises(pydynrad.InvalidInputError, match="need F in memory"):
            FarField(scene, None, cl, G=F @ cl.indicator(), prolongation="indicator", device=device, **needs_F)
    with pytest.raises(pydynrad.InvalidInputError, match="not 'linear'"):
        FarField(scene, F, cl, prolongation="linear", gather="first_bounce", device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="prolongation"):
        FarField(scene, F, cl, prolongation="smooth", device=device)
    for bad, match in (
        ({"tol": -1.0}, "tol"),
        ({"tol": float("nan")}, "tol"),
        ({"max_sweeps": 0}, "max_sweeps"),
        ({"fine_sweeps": -1}, "fine_sweeps"),
        ({"gather": "pairs"}, "gather"),
        ({"coarse": "lu"}, "coarse"),
        ({"coarse_storage": "fp8"}, "storage"),
        ({"dtype": np.float16}, "dtype"),
    ):
        with pytest.raises(pydynrad.InvalidInputError, match=match):
            FarField(scene, F, cl, device=device, **bad)
    with pytest.raises(pydynrad.InvalidInputError, match="mixes albedos"):
        Clusters.from_labels(scene, np.zeros(n, dtype=int))
    with pytest.raises(pydynrad.InvalidInputError, match="every value"):
        Clusters.from_labels(scene, cl.labels * 2)
    far = FarField(scene, F, cl, device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="another scene"):
        DynamicRadiosity(other, F, local_size=10, far_field=far, device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="far_field must be"):
        DynamicRadiosity(scene, F, local_size=10, far_field="yes", device=device)


@pytest.mark.slow
def test_village_at_night_within_one_percent(device):
    scene = pydynrad.scenes.village()
    F = pydynrad.form_factors(scene, resolution=16, device=device, progress=False)
    L = pydynrad.light_vector(scene, device=device)  # the lamps
    ref = pydynrad.solve(scene, F, light=L, device=device).radiosity
    dyn = DynamicRadiosity(scene, F, local_size=1024, observer=[10.0, 1.7, 2.5], device=device)
    B = dyn.radiosity(light=L)
    assert radiosity_error(B, ref, scene.areas) < 0.01
    S = dyn.local_patches
    assert radiosity_error(B[S], ref[S], scene.areas[S]) < 0.01


def test_answers_fit_combinations_of_the_last_sources():
    """The record behind the warm start and the combined light changes: the last `depth` pairs
    (older ones dropped in turn), the fit per channel exact for a combination of them, the
    answers combined alike; a source of another shape starts it afresh."""
    from pydynrad.farfield.history import Answers

    rng = np.random.default_rng(3)
    record = Answers(3, np.float32)
    assert record.fit(np.ones((50, 3))) is None
    sources = [rng.standard_normal((50, 3)) for _ in range(5)]
    for s in sources:
        record.add(s, 2.0 * s)
    assert record.count == 3
    s = 0.5 * sources[2] - 3.0 * sources[4] + sources[3] * [1.0, 0.0, 2.0]
    a, combined, rest, off = record.fit(s)
    assert np.abs(rest).max() < 1e-13 * np.abs(s).max() and off[:, 0].max() < 1e-13
    held = [sources[3], sources[4], sources[2]]  # slot order after two wrap-arounds
    sizes = np.array([np.abs(h).max(axis=0) for h in held]).T  # (k, 3)
    np.testing.assert_allclose(off[:, 1], np.einsum("ch,ch->c", np.abs(a), sizes) / np.abs(s).max(axis=0), rtol=1e-12)
    np.testing.assert_allclose(combined, 2.0 * s, rtol=0, atol=1e-6 * np.abs(s).max())  # float32 answers
    np.testing.assert_allclose(np.sort(np.abs(a[1])), [0.0, 0.5, 3.0], atol=1e-12)  # channel 1: no sources[3]
    a, _, rest, off = record.fit(sources[0])  # dropped: only its best fit by the three held
    assert np.abs(rest).max() > 0.1 and off[:, 0].min() > 0.1
    record.add(np.ones((50, 1)), np.ones((50, 1)))  # one channel: the record starts again
    assert record.count == 1 and record.fit(s) is None


def test_first_bounce_by_columns_or_by_a_pass_is_the_same_product(device, cornell_lit):
    """The far field's first bounce P F L goes over F's lit columns on the host, or through the
    error estimate's copy of F on the device once a pass is measured to cost less (a sun lights
    most columns): the same product either way, to float32 rounding, against numpy's."""
    scene, F, L, _, _ = cornell_lit
    dyn = DynamicRadiosity(scene, F, local_size=len(scene) // 4, observer=[278, 273, -300], device=device)
    dyn.radiosity(light=L)  # the estimate's pass: F on the device, shared, and its time measured
    far = dyn.far
    if far._F_cols is None:
        pytest.skip("the device is not the host: the first bounce is always a pass of F's rows")
    assert far._F_dev is not None and far._F_dev.seconds_bounce is not None
    expected = far.rho * (F.astype(np.float64) @ L)
    by_columns = far._first_bounce(L)
    far._bounced = None
    far._column_seconds = 1.0  # a pass now predicted cheaper than any column product
    by_pass = far._first_bounce(L)
    assert far.first_bounce_columns == len(scene)
    for D1 in (by_columns, by_pass):
        np.testing.assert_allclose(D1, expected, rtol=2e-6, atol=1e-7 * np.abs(expected).max())
