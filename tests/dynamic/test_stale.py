"""Rows a move leaves stale (pydynrad.dynamic.stale): the correction against the dense solve of the rows at the current poses, its tolerance, and the differences it keeps."""

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import END, MIDDLE, START, dense_K, dense_radiosity, pose, rel
from helpers import MOVING_LIGHTS as LIGHTS
from helpers import MOVING_OBSERVER as OBSERVER
from helpers import MOVING_R as R

import pydynrad as pd


def test_stale_rows_corrected(cornell_384, green_block, device):
    """With a static F the rows a budget leaves stale are corrected in radiosity(): B is the
    dense numpy solve of the F that refreshing every row gives (the same rows at the current
    poses), while K stays that of the rows swapped in; refresh() swaps them all in."""
    F_static = pd.form_factors(cornell_384, R, device=device)
    n = len(cornell_384) + len(green_block)

    def moved(budget, correct):
        obj = pd.RigidObject(green_block, START)
        dyn = pd.DynamicRadiosity(
            cornell_384,
            F_static,
            local_size=n,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=budget, occlusion_correction=correct),
            observer=OBSERVER,
            device=device,
        )
        dyn.radiosity(LIGHTS)
        for T in (MIDDLE, END):
            dyn.move(obj, T)
            dyn.update(OBSERVER)
            dyn.radiosity(LIGHTS)
        return dyn

    every = moved(None, False)
    world, S = every.scene, every.local_patches
    F_all = sp.csr_matrix(every._ff.local[np.argsort(S)])  # patch order
    L = pd.light_vector(world, LIGHTS, device=device)
    truth = dense_radiosity(world, F_all, L)
    stale = moved(0, False)
    uncorrected = rel(stale.radiosity(LIGHTS, far_field=False), truth)
    unmoved = pd.DynamicRadiosity(
        cornell_384,
        F_static,
        local_size=n,
        resolution=R,
        objects=[pd.RigidObject(green_block, START)],
        observer=OBSERVER,
        device=device,
    ).matrix.to_host()
    for budget in (0, 16):
        dyn = moved(budget, True)
        assert (
            len(dyn._stale) > 100
        )  # rows left stale in K: observed 414 (budget 0: the block's 48 among them), 349 (16)
        dyn.radiosity(LIGHTS)
        assert dyn._stale.iterations == 1  # the last frame's answer, confirmed by one pass over K
        B = dyn.radiosity(LIGHTS, far_field=False)
        # The far field switched off: from B^(0) plus the last correction (one pass), then one to confirm.
        assert dyn._stale.converged and dyn._stale.iterations == 2
        # The iteration stops at 1e-4 of max B; observed 8e-9, 2.3e-8 with the Gauss-Seidel step on the stale rows
        # (5e-8, 2e-8 without; PoCL, Xeon).
        assert rel(B, truth) < 2e-7
        assert rel(B, truth) < uncorrected / 100  # uncorrected observed 0.012
        if budget == 0:  # no swap at all: K is still the one built at the first pose
            np.testing.assert_array_equal(dyn.matrix.to_host(), unmoved)
            block_slots = np.flatnonzero(dyn.local_patches >= len(cornell_384))
            assert np.isin(block_slots, dyn._stale.slots).all()  # its rows enter through the correction
        dyn.refresh()
        assert len(dyn._stale) == 0
        np.testing.assert_allclose(dyn.matrix.to_host(), dense_K(world, F_all, dyn.local_patches), atol=1e-6, rtol=0)
        assert rel(dyn.radiosity(LIGHTS, far_field=False), truth) < 2e-6  # fp32 K; observed 8e-9


def test_correction_tolerance_trades_passes_for_accuracy(cornell_384, green_block, device):
    """correction_tolerance bounds the correction's estimated distance from its fixed point (what
    refresh() then solves exactly): the answer's distance stays under it, a tighter one takes more
    passes over K for a closer answer; values outside (0, 1) are refused."""
    from pydynrad.dynamic.stale import _error_estimate

    assert _error_estimate(1.0, np.inf) == 1.0 and _error_estimate(0.6, 1.0) == 0.6  # no clear contraction: the step
    assert _error_estimate(0.1, 1.0) == pytest.approx(0.1 / 9.0)  # q = 0.1: q / (1 - q) of the step
    F_static = pd.form_factors(cornell_384, R, device=device)
    n = len(cornell_384) + len(green_block)
    errors, passes = {}, {}
    for tol in (2e-4, 1e-7):
        obj = pd.RigidObject(green_block, START)
        dyn = pd.DynamicRadiosity(
            cornell_384,
            F_static,
            local_size=n - 150,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=0, correction_tolerance=tol),
            observer=OBSERVER,
            device=device,
        )
        dyn.radiosity(LIGHTS, far_field=False)
        passes[tol] = 0
        for T in (MIDDLE, END):
            dyn.move(obj, T)
            dyn.update(OBSERVER)
            B = dyn.radiosity(LIGHTS, far_field=False)
            passes[tol] += dyn._stale.iterations
            assert dyn._stale.converged
        dyn.refresh()
        errors[tol] = rel(B, dyn.radiosity(LIGHTS, far_field=False))
    # Observed 1.1e-5 in 7 passes and 4.7e-8 in 10 over the two moves (fp32 K; PoCL, Zen 4).
    assert errors[2e-4] < 1e-4 and errors[1e-7] < 2e-7 and passes[1e-7] > passes[2e-4]
    for bad in (0, 1.0, float("nan"), "1e-4", True):
        with pytest.raises(pd.InvalidInputError, match="correction_tolerance"):
            pd.DynamicRadiosity(
                cornell_384,
                F_static,
                local_size=n - 150,
                resolution=R,
                objects=pd.MovingObjects([pd.RigidObject(green_block, START)], correction_tolerance=bad),
                device=device,
            )


def test_walk_frames_resume_the_correction(cornell_384, green_block, device):
    """Walk frames after budget-0 moves (patches swap in and out of S, the far field on): each
    correction starts from the last answer where S had the patch, converges, and the last frame
    is what refresh() (every stale row swapped in) gives; a frame with nothing changed then
    takes one pass over K."""
    F_static = pd.form_factors(cornell_384, R, device=device)
    obj = pd.RigidObject(green_block, START)
    dyn = pd.DynamicRadiosity(
        cornell_384,
        F_static,
        local_size=len(cornell_384) + len(green_block) - 150,
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
    swaps, passes = 0, []
    for k in range(1, 6):
        swaps += dyn.update(np.add(OBSERVER, (0.0, 0.0, 50.0 * k))).swaps
        B = dyn.radiosity(LIGHTS)
        passes.append(dyn._stale.iterations)
        assert dyn._stale.converged
    assert swaps > 20 and len(dyn._stale) > 100  # observed 47 swaps
    assert max(passes) <= 5  # observed 3-4 passes over K per walk frame
    dyn.radiosity(LIGHTS)
    assert dyn._stale.iterations == 1
    dyn.refresh()
    assert rel(B, dyn.radiosity(LIGHTS)) < 1e-5  # observed 3.2e-6 (PoCL, Zen 4)


def test_rows_minus_matches_scipy(monkeypatch):
    """D = rows - kept[slots] by the native merge against scipy, sorted and unsorted rows, one
    matrix or blocks, one part or parts on the cores, exact zeros dropped; slots outside the
    kept rows refused."""
    from pydynrad.dynamic import stale
    from pydynrad.dynamic.stale import rows_minus

    rng = np.random.default_rng(7)
    kept = sp.random(30, 50, density=0.3, random_state=rng, format="csr")
    slots = rng.integers(0, 30, 40)
    rows = sp.csr_matrix(kept[slots])
    rows.data[rng.random(rows.nnz) < 0.5] *= 0.5  # some entries changed, the others equal: zeros in D
    rows = sp.csr_matrix(rows + sp.random(40, 50, density=0.1, random_state=rng, format="csr"))
    truth = (rows - kept[slots]).toarray()
    got = rows_minus(rows, kept, slots)
    np.testing.assert_array_equal(got.toarray(), truth)
    assert got.nnz == np.count_nonzero(truth) and got.has_sorted_indices
    monkeypatch.setattr(stale, "PARALLEL_ENTRIES", 1)  # each block in parts, as many as cores: 4
    monkeypatch.setattr(stale, "cores", lambda: 4)
    blocks = [rows[:13], rows[13:14], rows[14:14], rows[14:]]
    for parted in (rows_minus(blocks, kept, slots), rows_minus(rows, kept, slots)):
        np.testing.assert_array_equal(parted.toarray(), truth)
        assert parted.nnz == got.nnz and parted.has_sorted_indices
    shuffled = rows.copy()
    for k in range(shuffled.shape[0]):  # each row's entries reversed: columns out of order
        a, b = shuffled.indptr[k], shuffled.indptr[k + 1]
        shuffled.indices[a:b], shuffled.data[a:b] = shuffled.indices[a:b][::-1].copy(), shuffled.data[a:b][::-1].copy()
    shuffled.has_sorted_indices = False
    np.testing.assert_array_equal(rows_minus(shuffled, kept, slots).toarray(), truth)
    with pytest.raises(pd.InvalidInputError, match=r"\[0, 30\)"):
        rows_minus(rows, kept, np.full(40, 30))
    with pytest.raises(pd.InvalidInputError, match="one kept row per row"):
        rows_minus(rows, kept, slots[:-1])


def test_stale_rows_hold_differences():
    """StaleRows holds D only: put replaces what was held for its slots and holds none whose D
    is empty, drop forgets slots, rebase keeps the rows at the pose when the kept rows change
    under them, and current gives those rows back (kept + D); against dense numpy."""
    from pydynrad.dynamic.stale import StaleRows

    rng = np.random.default_rng(11)
    M, N = 40, 60
    kept = sp.random(M, N, density=0.3, random_state=rng, format="csr")
    pose = kept.toarray()  # the rows at the current poses, where they are stale
    held = rng.permutation(M)[:25]
    pose[held[:20]] *= rng.choice([0.5, 1.0], (20, 1))  # some rows unchanged: not stale
    pose[held[20:], :7] = 0.01
    st = StaleRows(N)
    st.put(held[:10], sp.csr_matrix(pose[held[:10]] - kept.toarray()[held[:10]]))
    st.put(held[5:], sp.csr_matrix(pose[held[5:]] - kept.toarray()[held[5:]]))  # replaces 5..9
    stale = held[np.any(pose[held] != kept.toarray()[held], axis=1)]
    assert sorted(st.slots) == sorted(stale) and len(st) == len(stale) < len(held)
    slots, rows = st.current(kept)  # kept + (pose - kept): to a rounding of each, entries below 1
    np.testing.assert_allclose(rows.toarray(), pose[slots], rtol=0, atol=2.3e-16)
    st.drop(held[:3])
    assert not np.isin(held[:3], st.slots).any() and len(st) == len(np.setdiff1d(stale, held[:3]))
    # The kept rows change (rows swapped in elsewhere, object columns rescaled): D follows.
    after = kept.toarray()
    after[:, -4:] *= 0.5
    after[held[10]] = pose[held[10]]  # this one is current now
    st.rebase(kept, sp.csr_matrix(after))
    slots, rows = st.current(sp.csr_matrix(after))
    np.testing.assert_allclose(rows.toarray(), pose[slots], rtol=0, atol=4.5e-16)
    assert held[10] not in st.slots
    np.testing.assert_allclose(st.delta.toarray(), pose[st.slots] - after[st.slots], rtol=0, atol=4.5e-16)
    with pytest.raises(pd.InvalidInputError, match="one row of 60 columns per slot"):
        st.put(held[:2], sp.csr_matrix((3, N)))
    with pytest.raises(pd.InvalidInputError, match="each slot once"):
        st.put(held[[4, 4]], sp.csr_matrix(np.ones((2, N))))
    st.clear()
    assert len(st) == 0 and st.nbytes < 1000


def test_stale_rows_put_that_fails_leaves_no_pose(monkeypatch):
    """A D put for a pose is started from at the next move only once it is held: a put that
    fails on the way leaves its slots without that pose (their old D is not taken for it)."""
    from pydynrad.dynamic import stale

    N = 12
    st = stale.StaleRows(N)
    st.put(np.array([1, 2]), sp.csr_matrix(np.eye(2, N)), pose=1)
    flags, last, row = st.since(np.array([1, 2, 3]), 1)
    assert flags.tolist() == [True, True, False] and row.tolist() == [0, 1, -1]
    monkeypatch.setattr(stale, "stacked_rows", lambda *a: (_ for _ in ()).throw(MemoryError()))
    with pytest.raises(MemoryError):
        st.put(np.array([1, 4]), sp.csr_matrix(np.eye(2, N)), pose=2)  # stacked with slot 2's held row
    assert not st.since(np.array([1, 4]), 2)[0].any() and not st.since(np.array([1]), 1)[0].any()
    assert st.since(np.array([2]), 1)[0].tolist() == [True]  # untouched


def test_rows_minus_sorts_kept_rows_out_of_order():
    """A kept row out of column order (and one with a column twice, as a CSR sum can leave it)
    is sorted, duplicates summed, before the merge: the answer is scipy's."""
    from pydynrad.dynamic.stale import rows_minus

    kept = sp.csr_matrix(
        (np.array([1.0, 2.0, 0.5, 0.25, 3.0]), np.array([3, 1, 1, 1, 0]), np.array([0, 2, 4, 5])), shape=(3, 5)
    )
    rows = sp.csr_matrix(np.array([[0.0, 2.0, 0.0, 4.0, 0.0], [0.0, 0.75, 1.0, 0.0, 0.0]]))
    slots = np.array([0, 1])
    truth = rows.toarray() - kept.toarray()[slots]
    np.testing.assert_array_equal(rows_minus(rows, kept, slots).toarray(), truth)


def test_moves_start_from_the_last_poses_difference(cornell_384, green_block, device, monkeypatch):
    """At budget 0 each move after the first starts D from the last move's where it can (the
    same rows, held since against the same kept rows): the stale rows then held are those of a
    solution that makes every D whole, bit for bit, through moves, walk frames that swap slots
    (their rows not started from) and a move that fails (nothing started from after it)."""
    from pydynrad.dynamic import moves

    F_static = pd.form_factors(cornell_384, R, device=device)
    n = len(cornell_384) + len(green_block)
    started = []
    real = moves.difference_at_pose

    def counted(*args):
        out = real(*args)
        since = args[-1]
        started.append(0 if since is None else int(since.rows.sum()))
        return out

    def solution():
        obj = pd.RigidObject(green_block, START)
        return obj, pd.DynamicRadiosity(
            cornell_384,
            F_static,
            local_size=n - 150,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=0),
            max_swaps_per_frame=16,
            observer=OBSERVER,
            device=device,
        )

    path = [MIDDLE, END, MIDDLE, pose(50, (300.0, 420.0, 250.0)), END, START, MIDDLE]
    monkeypatch.setattr(moves, "difference_at_pose", counted)
    held = []
    for since in (True, False):
        if not since:
            monkeypatch.setattr(moves.WorldRows, "_since", lambda self, *a: None)
        obj, dyn = solution()
        dyn.radiosity(LIGHTS)
        for k, T in enumerate(path):
            dyn.move(obj, T)
            if k == 4:  # a move that fails half-way through the differences: nothing of it is kept
                with monkeypatch.context() as m:
                    m.setattr(moves, "difference_at_pose", lambda *a: (_ for _ in ()).throw(RuntimeError("no")))
                    with pytest.raises(RuntimeError):
                        dyn.update(OBSERVER)
            dyn.update(np.add(OBSERVER, (0.0, 0.0, 40.0 * (k % 3))))  # walk frames swap slots as well
            dyn.radiosity(LIGHTS)
        held.append((dyn._stale.slots.copy(), dyn._stale.delta.copy(), dyn.radiosity(LIGHTS, far_field=False)))
    (slots, D, B), (slots0, D0, B0) = held
    assert np.array_equal(slots, slots0) and all(
        np.array_equal(getattr(D, k), getattr(D0, k)) for k in ("indptr", "indices", "data")
    )
    np.testing.assert_array_equal(B, B0)
    per_move = started[: len(path)]
    # Started from: none at the first move, nor at the one retried after its failure; most rows at the others
    # (observed 194-218 of 204-222 rows).
    assert per_move[0] == 0 and per_move[4] == 0 and min(per_move[1:4] + per_move[5:]) > 150, per_move
    assert not any(started[len(path) :])
    source = dyn._ff.source
    with pytest.raises(pd.InvalidInputError, match="distinct patches"):
        source.differences(np.array([0]), dyn._ff.local, np.array([0]), also=np.array([3, 3]))
    dyn._moved_world([START])  # a world at a new pose, no rows made there yet
    monkeypatch.setattr(source, "_at", lambda idx, make, also=None: make(idx[:1]))
    with pytest.raises(pd.PydynradError, match="not those made"):
        source.differences(np.array([0]), dyn._ff.local, np.array([0]), also=np.array([3, 4]))
