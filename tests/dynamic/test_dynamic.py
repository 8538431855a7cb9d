"""DynamicRadiosity: exact updates against fresh dense builds, lighting against dense solves.

Truths used here are independent of the library: K_S = (I - F_SS P_S)^{-1} F_SS by
numpy.linalg.solve in float64, B = (I - P F)^{-1} L by a dense solve, the single-patch
Sherman-Morrison downdate and bordering update written out in numpy, and a brute-force
full sort for the selection. F is random with exact reciprocity (tests/helpers.py), so
the algebra is tested apart from hemicube error.

Bounds after the random walk (hundreds of swaps, relative to max |K|), observed on PoCL/Xeon
2026-12-01: fp64 storage 1e-13 (observed 9e-16); fp32 storage 2e-5 (each update rounds K to
fp32, observed 3e-7); fp16 storage 3e-3 (the storage rounding, 2^-11, accumulated; observed 9e-4).
"""

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import coloured_box, dense_K, dense_radiosity, observer_walk, reciprocal_F, rel

import pydynrad
from pydynrad.device.matrix import DeviceMatrix
from pydynrad.dynamic import DynamicRadiosity
from pydynrad.dynamic.exact import batched_swap
from pydynrad.dynamic.kupdate import UpdateKernels
from pydynrad.dynamic.selection import NearestSet
from pydynrad.errors import InvalidInputError
from pydynrad.rows.sources import CSRRows

WALK_TOL = {"fp64": 1e-13, "fp32": 2e-5, "fp16": 3e-3}


@pytest.fixture(scope="module")
def coloured_box_F():
    scene = coloured_box(4)  # 192 patches, RGB
    F = reciprocal_F(scene.areas, row_sum=0.95, density=0.08, seed=1)
    return scene, F


def test_entering_blocks_equal_dense_indexing(coloured_box_F):
    """LocalRows.entering's F[S, J], F[J, S], F[J, J], F[S, R] and kept rows against plain numpy indexing
    of the dense F, over frames of random swaps (the scatter map must be clean between calls)."""
    from pydynrad.dynamic.localrows import LocalRows

    scene, F = coloured_box_F
    D = F.toarray()
    rng = np.random.default_rng(3)
    ff = LocalRows(scene, F, 16, None)
    S = rng.choice(len(scene), 40, replace=False)
    ff.fetch_local(S)
    for _ in range(5):
        slots = rng.choice(40, 6, replace=False)
        J = rng.choice(np.setdiff1d(np.arange(len(scene)), S), 6, replace=False)
        F_SJ, F_JS, F_JJ, F_SR = ff.entering(S, J, slots)
        assert np.array_equal(F_SJ, D[np.ix_(S, J)]) and np.array_equal(F_JS, D[np.ix_(J, S)])
        assert np.array_equal(F_JJ, D[np.ix_(J, J)]) and np.array_equal(F_SR, D[np.ix_(S, S[slots])])
        S = S.copy()
        S[slots] = J
        assert np.array_equal(ff.local.toarray(), D[S])


# -- exact mode ----------------------------------------------------------------------------------
@pytest.mark.parametrize("storage", ["fp64", "fp32", "fp16"])
def test_exact_walk_equals_fresh_build(device, coloured_box_F, storage):
    scene, F = coloured_box_F
    rng = np.random.default_rng(5)
    dyn = DynamicRadiosity(
        scene,
        F,
        local_size=48,
        update="exact",
        storage=storage,
        max_swaps_per_frame=6,
        observer=[0.5, 0.5, 0.5],
        device=device,
    )
    swaps = batched = 0
    for p in observer_walk(rng, 90):
        st = dyn.update(p)
        swaps += st.swaps
        batched += st.swaps > 1
        assert len(st.removed) == len(st.added) == st.swaps
    assert swaps >= 200 and batched >= 20  # hundreds of swaps, many of them batched
    S = dyn.local_patches
    assert len(np.unique(S)) == 48 and np.array_equal(np.flatnonzero(dyn.local_mask), np.sort(S))
    assert rel(dyn.matrix.to_host(), dense_K(scene, F, S, 3)) < WALK_TOL[storage]


def test_single_swap_is_downdate_then_bordering():
    """k = 1 of the batched formula == Sherman-Morrison removal followed by the bordering add."""
    scene = coloured_box(3, seed=3)
    F = reciprocal_F(scene.areas, row_sum=0.9, density=0.2, seed=4).toarray()
    rho = scene.albedo[:, 1].astype(np.float64)
    rng = np.random.default_rng(0)
    S = rng.choice(len(scene), 20, replace=False)
    j = next(x for x in range(len(scene)) if x not in S)
    s = 7
    K = dense_K(scene, F, S, channels=2)[1]
    # Sherman-Morrison downdate of slot s (docs/design.md, 'Exact mode'), then drop its row and column.
    ri = rho[S[s]]
    Kd = K - np.outer(K[:, s], K[s, :]) * ri / (1 + ri * K[s, s])
    keep = np.arange(20) != s
    Kd, T = Kd[np.ix_(keep, keep)], S[keep]
    # Bordering update adding j.
    f_c, f_r, PT = F[T, j], F[j, T], rho[T]
    c = f_c + Kd @ (PT * f_c)
    r = f_r + (f_r * PT) @ Kd
    lam = r @ (PT * f_c)
    d = 1 - rho[j] * lam
    want = np.zeros((20, 20))
    want[np.ix_(keep, keep)] = Kd + (rho[j] / d) * np.outer(c, r)
    want[keep, s], want[s, keep], want[s, s] = c / d, r / d, lam / d
    # The batched formula with k = 1.
    F_SJ = F[S, j][:, None].copy()
    F_SJ[s] = 0
    F_JS = F[j, S][None].copy()
    F_JS[0, s] = 0
    rS = rho[S]
    u = batched_swap(
        K[:, [s]],
        K[[s], :],
        K @ (rS[:, None] * F_SJ),
        (F_JS * rS) @ K,
        F_SJ,
        F_JS,
        F[[j]][:, [j]],
        rS,
        rho[[j]],
        np.array([s]),
    )
    got = K + u.A @ u.B
    got[:, s], got[s, :] = u.cols[0], u.rows[0]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)  # observed 1.4e-17 (PoCL/Xeon)
    S2 = S.copy()
    S2[s] = j
    np.testing.assert_allclose(got, dense_K(scene, F, S2, channels=2)[1], rtol=0, atol=1e-15)  # observed 3.5e-17


def test_row_source_matches_sparse(device, coloured_box_F):
    """A RowSource gives only rows; F[S, J] comes from the kept rows of S, so a walk over a row
    source equals the walk over the matrix itself."""
    scene, F = coloured_box_F
    kw = dict(
        local_size=40, update="exact", storage="fp64", max_swaps_per_frame=4, observer=[0.2, 0.5, 0.5], device=device
    )
    a, b = DynamicRadiosity(scene, F, **kw), DynamicRadiosity(scene, CSRRows(F), **kw)
    for p in observer_walk(np.random.default_rng(2), 15):
        assert a.update(p).swaps == b.update(p).swaps
    assert np.array_equal(a.local_patches, b.local_patches)
    assert rel(b.matrix.to_host(), a.matrix.to_host()) < 1e-6  # a row source serves F rounded to float32


def test_hemicube_rows_on_demand(device):
    """form_factors=None: one hemicube per entering patch. The walk equals, bit for bit, the walk
    over the rows of the whole hemicube matrix; K is the dense multibounce matrix of those rows;
    with every patch in the set, B is the full solve of that matrix."""
    scene = coloured_box(3, seed=26, emitters=2)  # 108 patches
    F = pydynrad.form_factors(scene, resolution=16, device=device)
    kw = dict(
        local_size=40, update="exact", storage="fp64", max_swaps_per_frame=4, observer=[0.5, 0.5, 0.5], device=device
    )
    lazy, full = DynamicRadiosity(scene, None, resolution=16, **kw), DynamicRadiosity(scene, CSRRows(F), **kw)
    swaps = 0
    for p in observer_walk(np.random.default_rng(27), 12):
        st = lazy.update(p)
        assert st.swaps == full.update(p).swaps
        swaps += st.swaps
    assert swaps >= 10
    np.testing.assert_array_equal(lazy.local_patches, full.local_patches)
    K = lazy.matrix.to_host()
    np.testing.assert_array_equal(K, full.matrix.to_host())
    assert rel(K, dense_K(scene, F, lazy.local_patches)) < 1e-13  # observed 6e-16 (PoCL/Xeon)
    everything = DynamicRadiosity(scene, None, local_size=len(scene), resolution=16, storage="fp64", device=device)
    everything.update([0.5, 0.5, 0.5])
    assert rel(everything.radiosity(), pydynrad.solve(scene, F, method="dense").radiosity) < 1e-13  # observed 5e-16


# -- lighting ------------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["exact", "paper"])
def test_full_set_reproduces_the_full_solution(device, mode):
    scene = coloured_box(3, emitters=3, seed=7)  # 108 patches
    F = reciprocal_F(scene.areas, row_sum=1.0, density=0.2, seed=8)
    dyn = DynamicRadiosity(
        scene, F, local_size=len(scene), update=mode, storage="fp64", observer=[0.5, 0.5, 0.5], device=device
    )
    assert dyn.update([0.1, 0.9, 0.3]).swaps == 0
    L = np.random.default_rng(1).random((len(scene), 3))
    B = dyn.radiosity(light=L)
    np.testing.assert_allclose(B, dense_radiosity(scene, F, L), rtol=1e-13)  # observed 9e-16
    ref = pydynrad.solve(scene, F, method="dense").radiosity
    np.testing.assert_allclose(dyn.radiosity(), ref, rtol=1e-13)  # observed 1.2e-15


def test_one_patch_gives_its_own_light(device, coloured_box_F):
    scene, F = coloured_box_F
    dyn = DynamicRadiosity(scene, F, local_size=1, observer=[0.5, 0.5, 0.02], far_field=False, device=device)
    L = np.random.default_rng(3).random((len(scene), 3))
    (i,) = dyn.local_patches
    d = np.linalg.norm(scene.centers - [0.5, 0.5, 0.02], axis=1)
    assert d[i] == d.min()
    np.testing.assert_array_equal(dyn.radiosity(light=L), L)
    st = dyn.update([0.5, 0.5, 0.98])
    assert st.swaps == 1 and dyn.local_patches[0] != i
    np.testing.assert_array_equal(dyn.radiosity(light=L), L)


@pytest.mark.parametrize("albedo", [0.0, 0.999])
@pytest.mark.parametrize("mode", ["exact", "paper"])
def test_albedo_extremes(device, albedo, mode):
    scene = coloured_box(3, albedo=albedo, emitters=2, seed=9)
    F = reciprocal_F(scene.areas, row_sum=1.0, density=0.2, seed=10)
    dyn = DynamicRadiosity(
        scene,
        F,
        local_size=50,
        update=mode,
        storage="fp64",
        max_swaps_per_frame=3,
        observer=[0.5, 0.5, 0.5],
        far_field=False,
        device=device,
    )
    for p in observer_walk(np.random.default_rng(4), 10):
        dyn.update(p)
    L = np.random.default_rng(5).random((len(scene), 3))
    B = dyn.radiosity(light=L)
    assert np.all(np.isfinite(B)) and np.all(B >= L - 1e-12)
    S = dyn.local_patches
    if albedo == 0.0:  # nothing reflects: K may hold anything, B is L
        np.testing.assert_array_equal(B, L)
    elif mode == "exact":  # B on the set = the dense solve restricted to S
        rho = scene.albedo[S, :1].astype(np.float64)  # 0.999 as stored (float32)
        want = L[S] + rho * (dense_K(scene, F, S, channels=1)[0] @ L[S])
        np.testing.assert_allclose(B[S], want, rtol=1e-13)  # observed 4e-16


def test_light_vector_reused_while_the_lights_stay(device, coloured_box_F, monkeypatch):
    """radiosity(lights) traces the lights' shadows once while the light objects (equal ones
    count), the emitter mode and the world stay: the same B, bit for bit, with no new light
    vector; new lights, another emitter mode or a given light vector are computed, and the B of
    new lights equals that of their light vector passed as light=. The held vector is read-only."""
    from pydynrad.dynamic import radiosity

    scene, F = coloured_box_F
    made = []
    real = radiosity.analytic_emitter_light
    monkeypatch.setattr(radiosity, "analytic_emitter_light", lambda *a, **k: made.append(1) or real(*a, **k))
    dyn = DynamicRadiosity(scene, F, local_size=48, observer=[0.5, 0.5, 0.5], device=device)
    made.clear()  # the constructor's warm-up lights once
    lamp = pydynrad.PointLight((0.5, 0.8, 0.5), (2.0, 1.5, 1.0))
    B1 = dyn.radiosity([lamp])
    B2 = dyn.radiosity([pydynrad.PointLight((0.5, 0.8, 0.5), (2.0, 1.5, 1.0))])  # equal, not the same object
    assert len(made) == 1 and np.array_equal(B1, B2) and not dyn._held_light.L.flags.writeable
    moved = pydynrad.PointLight((0.3, 0.8, 0.5), (2.0, 1.5, 1.0))
    B3 = dyn.radiosity([moved])
    assert len(made) == 2 and not np.array_equal(B3, B1)
    np.testing.assert_array_equal(B3, dyn.radiosity(light=pydynrad.light_vector(scene, [moved], device=device)))
    assert len(made) == 3  # light= is not held
    dyn.radiosity([moved], emitters="analytic")
    dyn.radiosity([moved])
    assert len(made) == 5
    dyn.radiosity([moved, lamp])
    dyn.radiosity([lamp, moved])  # order matters to the check, not to the light: computed again
    assert len(made) == 7


def test_lighting_changes_B_not_K(device, coloured_box_F):
    import pyopencl as cl

    scene, F = coloured_box_F
    dyn = DynamicRadiosity(
        scene, F, local_size=32, storage="fp16", observer=[0.5, 0.5, 0.5], far_field=False, device=device
    )
    dyn.update([0.3, 0.6, 0.5])

    def raw():
        out = []
        for buf in dyn.matrix.buffers:
            h = np.empty(buf.size, dtype=np.uint8)
            cl.enqueue_copy(device.queue, h, buf, is_blocking=True)
            out.append(h)
        return np.concatenate(out)

    before = raw()
    rng = np.random.default_rng(6)
    L1, L2 = rng.random((len(scene), 3)), rng.random((len(scene), 3))
    B1, B2 = dyn.radiosity(light=L1), dyn.radiosity(light=L2)
    assert np.array_equal(raw(), before)
    K = dyn.matrix.to_host()
    S = dyn.local_patches
    for L, B in ((L1, B1), (L2, B2)):
        want = L[S] + scene.albedo[S] * np.einsum("cij,jc->ic", K, L[S])
        np.testing.assert_allclose(B[S], want, rtol=1e-5)  # fp32 products, observed 9e-8
        outside = ~dyn.local_mask
        np.testing.assert_array_equal(B[outside], L[outside])
    assert not np.allclose(B1, B2)


def test_emitters_are_never_evicted(device):
    scene = coloured_box(4, emitters=5, seed=11)
    F = reciprocal_F(scene.areas, row_sum=0.95, density=0.08, seed=12)
    emit = np.flatnonzero(scene.emission.max(axis=1) > 0)
    for mode in ("exact", "paper"):
        dyn = DynamicRadiosity(
            scene, F, local_size=40, update=mode, storage="fp32", observer=[0.5, 0.5, 0.5], device=device
        )
        held = set(emit) & set(dyn.local_patches)
        for p in observer_walk(np.random.default_rng(13), 25):
            st = dyn.update(p)
            assert not set(st.removed) & set(emit)
            held |= set(emit) & set(st.added)
        assert held <= set(dyn.local_patches)


def test_grey_scene_keeps_one_channel(device):
    scene = coloured_box(3, grey=True, seed=14)
    F = reciprocal_F(scene.areas, row_sum=0.95, density=0.2, seed=15)
    dyn = DynamicRadiosity(
        scene,
        F,
        local_size=30,
        storage="fp64",
        max_swaps_per_frame=4,
        observer=[0.5, 0.5, 0.1],
        far_field=False,
        device=device,
    )
    for p in observer_walk(np.random.default_rng(16), 12):
        dyn.update(p)
    assert dyn.matrix.C == 1
    S = dyn.local_patches
    assert rel(dyn.matrix.to_host(), dense_K(scene, F, S, 1)) < 1e-13  # observed 1e-15
    L = np.random.default_rng(17).random((len(scene), 3))
    np.testing.assert_allclose(
        dyn.radiosity(light=L)[S], L[S] + scene.albedo[S] * (dense_K(scene, F, S, 1)[0] @ L[S]), rtol=1e-13
    )


# -- drift, refresh, memory ----------------------------------------------------------------------
def test_residual_and_refresh(device, coloured_box_F):
    scene, F = coloured_box_F
    exact = DynamicRadiosity(
        scene, F, local_size=40, update="exact", storage="fp64", observer=[0.5, 0.5, 0.5], device=device
    )
    paper = DynamicRadiosity(
        scene,
        F,
        local_size=40,
        update="paper",
        storage="fp64",
        observer=[0.5, 0.5, 0.5],
        refresh_tolerance=1e-3,
        refresh_interval=10,
        device=device,
    )
    # Both start from a fresh build: fp64 rounding, observed ~7e-16 (the former warm-started
    # GMRES probe read exactly 0 here).
    assert exact.residual() < 1e-9 and paper.residual() < 1e-9
    refreshed = []
    for p in observer_walk(np.random.default_rng(18), 20):
        exact.update(p)
        st = paper.update(p)
        assert (st.residual is not None) == (st.frame % 10 == 0)
        refreshed.append(st.refreshed)
    assert exact.residual() < 1e-9
    assert any(refreshed) and paper.refreshes == sum(refreshed)
    # Right after a refresh, K is a fresh build over the current set.
    paper.refresh()
    assert rel(paper.matrix.to_host(), dense_K(scene, F, paper.local_patches, 3)) < 1e-13  # observed 4e-16
    # An exact K with a known perturbation: the probe sees it.
    K = exact.matrix.to_host()
    exact.matrix.upload(K * 1.01)
    assert 0.003 < exact.residual() < 0.03


def test_memory_bytes(device, coloured_box_F):
    scene, F = coloured_box_F
    dyn = DynamicRadiosity(
        scene,
        F,
        local_size=64,
        storage="fp16",
        max_swaps_per_frame=8,
        observer=[0.5, 0.5, 0.5],
        far_field=False,
        device=device,
    )
    assert dyn.memory_bytes == DynamicRadiosity.estimate_memory_bytes(64, 3, "fp16", 8, device)
    assert dyn.memory_bytes >= 3 * 64 * 64 * 2
    # The paper's figure: M = 4096, RGB, fp16 is about 96 MiB: K alone is exactly 96 MiB, the
    # update's scratch (partial sums, the result slab and the uploads of two frames' passes, for
    # 8 vectors) adds about 8%.
    assert DynamicRadiosity.estimate_memory_bytes(4096, 3, "fp16", 1, device) / 2**20 < 97.5
    mib = DynamicRadiosity.estimate_memory_bytes(4096, 3, "fp16", 8, device) / 2**20
    assert 96 <= mib < 104


# -- selection -----------------------------------------------------------------------------------
def test_selection_matches_the_papers_loop_by_full_sort():
    rng = np.random.default_rng(19)
    centers = rng.random((500, 3))
    pinned = rng.random(500) < 0.05
    sel = NearestSet(centers, pinned)
    obs = np.array([0.5, 0.5, 0.5])
    members = sel.nearest(obs, 60)[0]
    included = np.zeros(500, bool)
    included[members] = True
    # Each observer asked three times (a still observer: the set it settles on asks for nothing
    # more, without a query), and once after a swap made by hand (the set changed under it).
    for step in range(90):
        if step % 3 == 0:
            obs = obs + rng.normal(0, 0.05, 3)
        if step % 9 == 8:
            out = np.flatnonzero(~included)[0]
            included[members[0]], included[out] = False, True
            members[0] = out
        slots, J = sel.propose(obs, members, included, 5)
        # The paper's loop, brute force: full sorts of both sides, one swap at a time.
        m2, inc2 = members.copy(), included.copy()
        want = []
        for _ in range(5):
            d = np.linalg.norm(centers - obs, axis=1)
            d_in = np.where(pinned[m2], -np.inf, d[m2])
            s = int(np.argmax(d_in))
            j = int(np.flatnonzero(~inc2)[np.argmin(d[~inc2])])
            if not d[j] < d_in[s]:
                break
            want.append((s, j))
            inc2[m2[s]], inc2[j] = False, True
            m2[s] = j
        assert list(zip(slots.tolist(), J.tolist())) == want
        included[members[slots]] = False
        members[slots] = J
        included[J] = True


def test_a_still_observer_asks_for_no_query_again():
    """Once a still observer's set asks for no swap, the same question is answered without a
    k-d tree query, also with k above M (k is clamped inside propose)."""
    rng = np.random.default_rng(3)
    sel = NearestSet(rng.uniform(-1, 1, (200, 3)))
    obs = np.zeros(3)
    members = sel.nearest(obs, 16)[0]
    included = np.zeros(200, bool)
    included[members] = True
    calls = []
    real = sel.nearest
    sel.nearest = lambda o, n: (calls.append(n), real(o, n))[1]
    for k in (4, 32):
        calls.clear()
        for _ in range(3):
            slots, J = sel.propose(obs, members, included, k)
            assert len(slots) == len(J) == 0
        assert len(calls) == 1


# -- kernels -------------------------------------------------------------------------------------
@pytest.mark.parametrize("storage", ["fp32", "fp64"])
def test_update_kernels_against_numpy(device, storage):
    rng = np.random.default_rng(20)
    M = 150
    m = DeviceMatrix(device, rng.random((1, M, M)), storage)
    uk = UpdateKernels(m, 4)
    K = m.to_host()[0]
    tol = 1e-13 if storage == "fp64" else 1e-5  # observed 1.1e-15 and 2.1e-7
    X, Y = rng.random((3, M)), rng.random((3, M))
    KX, YK = uk.gather(0, X, Y)
    assert rel(KX, X @ K.T) < tol and rel(YK, Y @ K) < tol
    A, B = rng.random((5, M)), rng.random((5, M))
    uk.rank_update(0, A, B)
    K2 = m.to_host()[0]
    assert rel(K2, K + A.T @ B) < tol
    slots = np.array([4, 149, 0])
    cols, rows = uk.read_slots(0, slots)
    np.testing.assert_array_equal(cols, K2[:, slots].T)
    np.testing.assert_array_equal(rows, K2[slots])
    f = rng.random((3, M))
    np.testing.assert_allclose(uk.double_reflection(*f), np.sum(f[0] * f[1] * f[2]), rtol=tol / 10)  # 1.8e-16, 7.5e-8


# -- bad input -----------------------------------------------------------------------------------
def test_bad_input(device, coloured_box_F):
    scene, F = coloured_box_F
    N = len(scene)
    for M in (0, -3, N + 1, 2.5, True):
        with pytest.raises(InvalidInputError, match="local_size"):
            DynamicRadiosity(scene, F, local_size=M, device=device)
    with pytest.raises(InvalidInputError, match="storage"):
        DynamicRadiosity(scene, F, local_size=10, storage="fp8", device=device)
    with pytest.raises(InvalidInputError, match="update"):
        DynamicRadiosity(scene, F, local_size=10, update="approximate", device=device)
    with pytest.raises(InvalidInputError, match="shape"):
        DynamicRadiosity(scene, sp.eye(N - 1, format="csr") * 0.5, local_size=10, device=device)
    with pytest.raises(InvalidInputError, match="patches"):
        DynamicRadiosity(scene, CSRRows(sp.eye(N + 2, format="csr") * 0.5), local_size=10, device=device)
    with pytest.raises(InvalidInputError, match="max_swaps"):
        DynamicRadiosity(scene, F, local_size=10, max_swaps_per_frame=0, device=device)
    with pytest.raises(InvalidInputError, match="refresh_tolerance"):
        DynamicRadiosity(scene, F, local_size=10, refresh_tolerance=float("nan"), device=device)
    with pytest.raises(InvalidInputError, match="NaN"):
        DynamicRadiosity(scene, F, local_size=10, observer=[0, np.nan, 0], device=device)
    dyn = DynamicRadiosity(scene, F, local_size=10, device=device)
    with pytest.raises(pydynrad.PydynradError, match="not built"):
        dyn.radiosity()
    st = dyn.update([0.5, 0.5, 0.5])
    assert st.refreshed and st.swaps == 0 and dyn.local_mask.sum() == 10
    with pytest.raises(InvalidInputError, match="NaN"):
        dyn.update([np.nan, 0, 0])
    with pytest.raises(InvalidInputError, match="3-vector"):
        dyn.update([0, 0])
    with pytest.raises(InvalidInputError, match="light vector"):
        dyn.radiosity(light=np.ones((N, 2)))
    with pytest.raises(InvalidInputError, match="light=L"):  # a vector in lights= names the right keyword
        dyn.radiosity(np.ones((N, 3)))
    with pytest.raises(InvalidInputError, match="not both"):
        dyn.radiosity([pydynrad.PointLight([0.5, 0.5, 0.5], 1.0)], light=np.ones((N, 3)))


def test_prefetch_time_is_its_own_field(device, coloured_box_F, monkeypatch):
    """A prefetching row source's call is timed as t_prefetch, not folded into t_select or
    t_update. The frame loop's clock is replaced by one that a prefetch call advances by
    1,000 s, so the split is checked exactly and no load on the machine can blur it."""
    import time
    import types

    import pydynrad.dynamic.radiosity as frame_loop

    scene, F = coloured_box_F
    skipped = [0.0]
    monkeypatch.setattr(
        frame_loop, "time", types.SimpleNamespace(perf_counter=lambda: time.perf_counter() + skipped[0])
    )

    class SlowPrefetch(CSRRows):
        calls = 0

        def prefetch(self, idx):
            SlowPrefetch.calls += 1
            skipped[0] += 1000.0

    dyn = DynamicRadiosity(scene, SlowPrefetch(F), local_size=20, device=device)
    first = dyn.update([0.5, 0.5, 0.02])
    st = dyn.update([0.5, 0.5, 0.98])
    assert SlowPrefetch.calls == 2 and st.swaps > 0
    for s in (first, st):
        assert s.t_prefetch >= 1000.0
        assert s.t_select < 1000.0 and s.t_update < 1000.0
        assert s.t_total == s.t_select + s.t_form_factors + s.t_update + s.t_prefetch


@pytest.mark.parametrize("mode,storage", [("exact", "fp16"), ("paper", "fp32")])
def test_warm_up_leaves_K_unchanged(device, coloured_box_F, mode, storage):
    """The constructor's warm-up launches every update kernel; a second one must leave K
    bit for bit as it was, and the frames after it give what a solver never warmed gives."""
    scene, F = coloured_box_F
    dyn = DynamicRadiosity(
        scene, F, local_size=48, update=mode, storage=storage, observer=[0.5, 0.5, 0.5], device=device
    )
    before = dyn.matrix.to_host()
    dyn.warm_up()
    assert np.array_equal(dyn.matrix.to_host(), before)
    assert np.array_equal(before, DeviceMatrix(device, dyn._fresh_K(dyn.local_patches), storage).to_host())


def test_warm_up_keeps_the_far_fields_light(device, coloured_box_F):
    """A warm-up after lighting leaves the far field's B_far for the same light in place: it
    relit the far field with its zero-power light, so the next radiosity() solved the far field
    again (and a FarField shared with a new solver lost its light the same way)."""
    scene, F = coloured_box_F
    dyn = DynamicRadiosity(scene, F, local_size=48, observer=[0.5, 0.5, 0.5], device=device)
    light = [pydynrad.PointLight([0.5, 0.9, 0.5], 2.0)]
    B = dyn.radiosity(light)
    kept = dyn.far.B_far
    dyn.warm_up()
    DynamicRadiosity(scene, F, local_size=48, observer=[0.5, 0.5, 0.5], far_field=dyn.far, device=device)
    assert dyn.far.B_far is kept
    assert np.array_equal(dyn.radiosity(light), B) and dyn.far.B_far is kept  # served from the cache


def test_frames_build_no_program(device, coloured_box_F):
    """Every program the frames use is built with the solver: updates (swaps in both modes,
    and the first update() of a solver built without an observer) and lighting after
    construction add none to the device's cache."""
    scene, F = coloured_box_F
    rng = np.random.default_rng(11)
    for mode, observer in (("exact", [0.5, 0.5, 0.5]), ("paper", [0.5, 0.5, 0.5]), ("exact", None)):
        # Without an observer the first update() builds the set and K: still no program.
        dyn = DynamicRadiosity(scene, F, local_size=48, update=mode, storage="fp16", observer=observer, device=device)
        built = set(device._programs)
        swaps = 0
        for p in observer_walk(rng, 6):
            swaps += dyn.update(p).swaps
            dyn.radiosity([pydynrad.PointLight(p, 1.0)])
        dyn.residual()
        assert swaps > 0 and set(device._programs) == built


@pytest.mark.parametrize("mode", ["exact", "paper"])
def test_sparse_and_dense_gathers_give_one_K(device, coloured_box_F, monkeypatch, mode):
    """The same walk with the sparse gathers forced on and off: K within rounding of each other
    (exact mode also of a fresh build over the final set)."""
    scene, F = coloured_box_F
    out = {}
    for share in (0.0, 1.0):  # 0: never sparse (every batch has non-zeros), 1: always
        monkeypatch.setenv("PYDYNRAD_SPARSE_DENSITY", str(share))
        dyn = DynamicRadiosity(
            scene,
            F,
            local_size=48,
            update=mode,
            storage="fp64",
            max_swaps_per_frame=6,
            observer=[0.5, 0.5, 0.5],
            device=device,
        )
        for p in observer_walk(np.random.default_rng(7), 30):
            dyn.update(p)
        out[share] = (dyn.local_patches, dyn.matrix.to_host())
    assert np.array_equal(out[0.0][0], out[1.0][0])
    assert rel(out[1.0][1], out[0.0][1]) < 1e-14  # observed 6e-17, 1.3e-16 (fp64)
    if mode == "exact":
        assert rel(out[1.0][1], dense_K(scene, F, out[1.0][0], 3)) < WALK_TOL["fp64"]


def test_rows_of_another_scene_small_sets_and_albedos_near_one(device, tmp_path):
    """Rows of another geometry with as many patches (hemicubes of it, or its store) are refused
    (they had given a 2.4% wrong answer); residual() probes at most M columns by default, so
    refresh_tolerance works for M < 8; near albedo 1 float32 K warns that it wants fp64."""
    import warnings

    from pydynrad.geometry.scene import PrecisionWarning

    box = pydynrad.scenes.cornell_box(max_edge=250.0)
    turned = pydynrad.Scene(
        box.vertices[:, [2, 1, 0]], box.faces[:, [0, 2, 1]], albedo=box.albedo, emission=box.emission
    )
    store = pydynrad.compute_store(turned, tmp_path / "st", resolution=8, progress=False)
    for rows in (pydynrad.rows.HemicubeRows(turned, 8, device), store):
        with pytest.raises(InvalidInputError, match="another scene geometry"):
            DynamicRadiosity(box, rows, local_size=len(box), resolution=8, far_field=False, device=device)
    dyn = DynamicRadiosity(
        box,
        pydynrad.rows.HemicubeRows(box, 8, device),
        local_size=4,
        resolution=8,
        far_field=False,
        refresh_tolerance=1e-3,
        refresh_interval=1,
        device=device,
    )
    centre = box.bbox.mean(axis=0)
    dyn.update(centre)  # the build
    for step in (1, 2):
        assert dyn.update(centre + [100.0 * step, 0.0, 0.0]).residual < 1e-3
    closed = pydynrad.scenes.closed_box(size=1.0, subdivisions=1)
    emission = np.zeros((len(closed), 3))
    emission[0] = 1.0
    for albedo, storage, warned in ((0.9999999, "fp32", True), (0.9999999, "fp64", False), (0.999, "fp16", False)):
        scene = closed.with_materials(albedo=albedo, emission=emission)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            DynamicRadiosity(
                scene,
                pydynrad.form_factors(scene, 8, device=device),
                local_size=len(scene),
                resolution=8,
                storage=storage,
                far_field=False,
                observer=[0.5, 0.5, 0.5],
                device=device,
            )
        assert any(issubclass(w.category, PrecisionWarning) for w in caught) == warned, (albedo, storage)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            pydynrad.multibounce(
                scene,
                pydynrad.form_factors(scene, 8, device=device),
                dtype=np.float64 if storage == "fp64" else np.float32,
                device=device,
            )
        assert any(issubclass(w.category, PrecisionWarning) for w in caught) == warned, (albedo, storage)


def test_arguments_that_had_crashed_or_been_misread(device):
    """A far observer in the constructor, a device that is not one, stopping arguments past
    their range, flags given as text and cluster options beside a far field that is not built:
    each a value error that names it (they had crashed in scipy, numpy or pyopencl, run until
    killed, or been read as True or ignored)."""
    box = pydynrad.scenes.cornell_box(max_edge=250.0)
    F = pydynrad.form_factors(box, 8, device=device)
    cases = [
        (
            lambda: DynamicRadiosity(box, F, local_size=64, resolution=8, observer=[1e160, 0, 0], device=device),
            "too far",
        ),
        (lambda: DynamicRadiosity(box, F, local_size=64, device="cpu"), "device must be a pydynrad Device"),
        (lambda: pydynrad.solve(box, F, device="x"), "device must be a pydynrad Device"),
        (lambda: pydynrad.solve(box, F, tol="1e-3", device=device), "tol must be one finite number"),
        (lambda: pydynrad.solve(box, F, max_iterations=np.inf, device=device), "max_iterations"),
        (lambda: pydynrad.solve(box, F, bounces=10**30, device=device), r"bounces must be an integer in 0\.\.1000000"),
        (lambda: pydynrad.solve(box, F, bounces=np.nan, device=device), "bounces"),
        (
            lambda: pydynrad.solve(box, F, raise_on_failure="no", device=device),
            "raise_on_failure must be True or False",
        ),
        (lambda: DynamicRadiosity(box, F, local_size=64, keep_emitters="no", device=device), "keep_emitters"),
        (
            lambda: DynamicRadiosity(box, F, local_size=64, far_field=False, clusters=50, device=device),
            "clusters build the far field",
        ),
        (
            lambda: (
                pydynrad.bake.LightGroups(box, {"a": [pydynrad.PointLight([100, 500, 100], 1e5)]}, device=device)
                .dynamic(DynamicRadiosity(box, F, local_size=64, device=device, observer=box.bbox.mean(axis=0)))
                .combine({"a": 1e308})
            ),
            "past float64's range",
        ),
    ]
    for call, message in cases:
        with pytest.raises(InvalidInputError, match=message):
            call()
    assert pydynrad.solve(box, F, bounces=3.0, device=device).iterations == 3  # a whole float is a count
