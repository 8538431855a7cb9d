"""Trapped light (pydynrad.farfield.trapped): the patches a sweep hardly damps, solved directly,
against dense float64 solves of their block, and on a real scene whose refinement they shorten."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import pydynrad
from pydynrad import DynamicRadiosity
from pydynrad.comparison import radiosity_error
from pydynrad.farfield import trapped
from pydynrad.farfield.trapped import TrappedLight


@pytest.fixture
def box(closed_box_48, closed_box_48_F):
    """The closed box (every row of F sums to 1) with coloured albedos on both sides of 0.7."""
    F = closed_box_48_F.tocsr().astype(np.float64)
    rng = np.random.default_rng(3)
    rho = np.column_stack([rng.uniform(0.3, 0.95, 48), rng.uniform(0.3, 0.95, 48), np.full(48, 0.5)])
    return F, rho, F.toarray()


def _whole(F) -> int:
    """F's entries as a budget base that holds a block as large as F (a small box's F is dense,
    so its share of its own entries would hold a handful of patches)."""
    return int(np.ceil(F.nnz / trapped.TRAPPED_SHARE))


def _dense_block(F, rho, L, B, Q):
    """B_Q from (I - P_Q F_QQ) B_Q = L_Q + P_Q F_QX B_X, per channel, by numpy's dense solve."""
    X = np.setdiff1d(np.arange(len(F)), Q)
    out = np.empty((len(Q), 3))
    for c in range(3):
        A = np.eye(len(Q)) - rho[Q, c][:, None] * F[np.ix_(Q, Q)]
        out[:, c] = np.linalg.solve(A, L[Q, c] + rho[Q, c] * (F[np.ix_(Q, X)] @ B[X, c]))
    return out


def test_the_trapped_patches_are_solved_exactly_from_the_rest(box):
    F, rho, Fd = box
    sums = np.asarray(F.sum(axis=1)).ravel()
    t = TrappedLight(rho, sums, lambda idx: F[idx], _whole(F))
    expected = np.flatnonzero(rho.max(axis=1) * sums > trapped.TRAPPED)
    assert 0 < len(expected) < 48  # both kinds of patch, so the block and the rest are both there
    np.testing.assert_array_equal(t.patches, expected)
    rng = np.random.default_rng(4)
    L, B = rng.uniform(0, 1, (48, 3)), rng.uniform(0, 5, (48, 3))
    np.testing.assert_allclose(t.solve(L, B), _dense_block(Fd, rho, L, B, t.patches), rtol=1e-12)
    # The whole solution is a fixed point: its trapped patches solved from the rest are themselves.
    exact = np.column_stack([np.linalg.solve(np.eye(48) - rho[:, c][:, None] * Fd, L[:, c]) for c in range(3)])
    np.testing.assert_allclose(t.solve(L, exact), exact[t.patches], rtol=1e-12)


def test_a_grey_scene_factors_once_and_none_trapped_costs_nothing(box):
    F, rho, Fd = box
    sums = np.asarray(F.sum(axis=1)).ravel()
    grey = np.repeat(rho[:, :1], 3, axis=1)
    t = TrappedLight(grey, sums, lambda idx: F[idx], _whole(F))
    assert len(t._lu) == 1
    L, B = np.ones((48, 3)), np.full((48, 3), 2.0)
    np.testing.assert_allclose(t.solve(L, B), _dense_block(Fd, grey, L, B, t.patches), rtol=1e-12)
    dim = TrappedLight(np.full((48, 3), 0.5), sums, lambda idx: F[idx], _whole(F))
    assert len(dim) == 0 and dim.rows is None


def test_the_budget_keeps_the_most_trapped_patches(box):
    """Where Q's block would exceed its share of F's entries, the most trapped patches whose block
    fits are kept, and the solve is exact for them."""
    F, rho, Fd = box
    sums = np.asarray(F.sum(axis=1)).ravel()
    g = rho.max(axis=1) * sums
    full = TrappedLight(rho, sums, lambda idx: F[idx], _whole(F))
    entries = int(F[full.patches][:, full.patches].nnz / trapped.TRAPPED_SHARE)
    cut = TrappedLight(rho, sums, lambda idx: F[idx], entries // 3)
    assert 0 < len(cut) < len(full)
    assert F[cut.patches][:, cut.patches].nnz <= trapped.TRAPPED_SHARE * (entries // 3)
    assert g[cut.patches].min() >= np.sort(g[full.patches])[::-1][len(cut) - 1]  # the top ones
    rng = np.random.default_rng(5)
    L, B = rng.uniform(0, 1, (48, 3)), rng.uniform(0, 5, (48, 3))
    np.testing.assert_allclose(cut.solve(L, B), _dense_block(Fd, rho, L, B, cut.patches), rtol=1e-12)


def test_solving_trapped_light_shortens_refinement_on_a_real_scene(device, monkeypatch):
    """veach_ajar (a lamp behind an ajar door, white walls at albedo 0.8): the patches nearly
    enclosed by bright ones hold the error a sweep damps slowest. Both ways reach the tolerance
    against the full solve; solving them directly takes fewer sweeps (2 against 14 when measured)."""
    corpus = Path(__file__).resolve().parents[2] / "bench" / "data" / "corpus"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the file's own clamped albedos and missing textures
        scene = pydynrad.load(corpus / "veach_ajar" / "veach_ajar.obj")
    F = pydynrad.form_factors(scene, resolution=24, device=device, progress=False)
    L = pydynrad.light_vector(scene, device=device)
    ref = pydynrad.solve(scene, F, light=L, tol=1e-10, device=device).radiosity
    obs, tolerance = [4.05, 1.62, -2.31], 0.001

    def first_light():
        dyn = DynamicRadiosity(scene, F, local_size=1024, observer=obs, device=device, tolerance=tolerance)
        B = dyn.radiosity(light=L)
        return dyn, radiosity_error(B, ref, scene.areas, emission=np.minimum(scene.emission, L))

    dyn, err = first_light()
    assert len(dyn._errors.trapped) > 0
    monkeypatch.setattr(trapped, "TRAPPED", np.inf)  # nothing trapped: sweeps alone
    plain, plain_err = first_light()
    assert len(plain._errors.trapped) == 0
    assert err <= tolerance and plain_err <= tolerance, (err, plain_err)
    assert dyn.error_estimate.sweeps < plain.error_estimate.sweeps / 2, (dyn.error_estimate, plain.error_estimate)


def test_without_host_columns_the_trapped_patches_are_solved_with_the_local_set(device):
    """Where F's columns are not on the host (a GPU device: each update of the residual is a pass
    of F) the trapped patches are solved after the sweep, with the local set: the carried
    residual is still the answer's own, and the tolerance is met against the full solve."""
    scene = pydynrad.scenes.village(houses=1, detail=0.5)
    F = pydynrad.form_factors(scene, resolution=16, device=device, progress=False)
    L = pydynrad.light_vector(scene, [pydynrad.PointLight((8.0, 3.0, 8.0), (400.0,) * 3)], device=device)
    ref = pydynrad.solve(scene, F, light=L, tol=1e-10, device=device).radiosity
    dyn = DynamicRadiosity(scene, F, local_size=len(scene) // 8, observer=[5.0, 1.7, 5.0], device=device)
    dyn._errors._F_cols = None  # as beside a GPU
    B = dyn.radiosity(light=L)
    assert len(dyn._errors.trapped) > 0 and dyn.error_estimate.sweeps > 0
    assert radiosity_error(B, ref, scene.areas, emission=np.minimum(scene.emission, L)) <= 0.001
    kept, r, _ = dyn._errors._held
    fresh = L + scene.albedo * (F.astype(np.float64) @ B) - B
    np.testing.assert_array_equal(kept, B)
    # Observed 1.2e-8 of max B: F's float32 products on the device.
    assert np.abs(r - fresh).max() <= 1e-7 * np.abs(B).max()
