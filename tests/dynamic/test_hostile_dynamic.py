"""Hostile dynamic solutions: re-entrant updates, huge observers, rows checked once, albedos near one."""

import numpy as np
import pytest
import scipy.sparse as sp

import pydynrad
from pydynrad.errors import InvalidInputError
from pydynrad.geometry.scene import PrecisionWarning


@pytest.mark.parametrize("storage", ["fp32", "fp16"])
def test_residual_sees_the_max_entry_error(device, storage):
    # Against a dense float64 K over the same local set: the probe of 8 columns reads within
    # 1.3x of max entry error / max entry (observed fp32 3.6e-8 vs 4.2e-8, fp16 4.2e-4 vs 3.4e-4,
    # closed box, 192 patches); the former probe read 1-2e-7 for fp32 where entries were off 5e-6.
    scene = pydynrad.scenes.closed_box(subdivisions=2, albedo=0.8)
    F = pydynrad.form_factors(scene, resolution=16, device=device)
    dyn = pydynrad.DynamicRadiosity(
        scene, F, local_size=96, storage=storage, observer=[0.5, 0.5, 0.5], far_field=False, device=device
    )
    rng = np.random.default_rng(3)
    for _ in range(40):
        dyn.update(rng.random(3))
    S = dyn.local_patches
    FS, rho = F[S][:, S].toarray().astype(np.float64), scene.albedo[S, 0].astype(np.float64)
    fresh = np.linalg.solve(np.eye(len(S)) - FS * rho[None, :], FS)
    true = np.abs(dyn.matrix.to_host()[0] - fresh).max() / np.abs(fresh).max()
    assert true / 3 < dyn.residual() < 3 * true


# State and concurrency, outputs that cannot overflow silently (item 6).
def test_update_is_not_re_entrant_and_a_huge_observer_is_refused_before_the_frame_advances(
    closed_box_48, closed_box_48_F, device
):
    import threading

    dyn = pydynrad.DynamicRadiosity(
        closed_box_48, closed_box_48_F, local_size=8, observer=[0.5, 0.5, 0.5], far_field=False, device=device
    )
    with pytest.raises(InvalidInputError, match="too far from the scene"):
        dyn.update([1e155, 0.0, 0.0])  # main: an IndexError from the selection, frame counter advanced
    assert dyn.frame == 0
    errors = []
    entered, release = threading.Event(), threading.Event()
    real = dyn._update

    def slow(obs):  # hold the first call inside update() while a second thread calls it
        entered.set()
        release.wait(10)
        return real(obs)

    dyn._update = slow
    worker = threading.Thread(target=lambda: dyn.update([0.2, 0.5, 0.5]))
    worker.start()
    entered.wait(10)
    try:
        dyn.update([0.8, 0.5, 0.5])
    except pydynrad.errors.PydynradError as exc:
        errors.append(str(exc))
    release.set()
    worker.join(10)
    assert errors and "already running" in errors[0]
    assert dyn.frame == 1 and len(np.unique(dyn.local_patches)) == 8


def test_rows_are_checked_once_on_their_way_to_the_local_set(monkeypatch, closed_box_48, closed_box_48_F, device):
    import pydynrad.rows.sources as sources
    from pydynrad.dynamic.localrows import LocalRows
    from pydynrad.rows.cache import RowCache

    in_memory = sources.CSRRows(closed_box_48_F)  # checks its matrix once, here
    calls = []
    real = sources.check_form_factor_rows
    monkeypatch.setattr(sources, "check_form_factor_rows", lambda *a, **k: calls.append(1) or real(*a, **k))
    idx = np.array([3, 1, 4])
    want = sp.csr_matrix(closed_box_48_F, dtype=np.float64)[idx].toarray()
    with RowCache(in_memory, 2**20) as cache:
        for source in (cache, cache.source):
            got = LocalRows(closed_box_48, source, 8, device).rows(idx)
            assert got.dtype == np.float64 and np.array_equal(got.toarray(), want)
    assert calls == []  # main: checked again by the cache and again by LocalRows
    bare = type(
        "Bare", (), {"n_patches": len(closed_box_48), "rows": lambda self, i: sp.csr_matrix(closed_box_48_F)[i]}
    )()
    assert np.array_equal(LocalRows(closed_box_48, bare, 8, device).rows(idx).toarray(), want)
    assert len(calls) == 1  # a source without the contract is checked by its reader


def test_albedos_near_one_are_solved_or_named_for_what_they_are(device):
    # A Scene takes albedos below 1. At 0.9995 the radiosity bound with F's row-sum slack was
    # infinite and every light was refused as "beyond float32: scale the lights down", which
    # could not help; the bound now takes the albedo alone there, the dynamic solution answers
    # as the dense solve does, and the bounce iteration names the bounces it would need.
    closed_box_48 = pydynrad.scenes.closed_box(subdivisions=0, emission=0.0)
    F = pydynrad.form_factors(closed_box_48, resolution=64, device=device)
    bright = closed_box_48.with_materials(
        albedo=0.9995, emission=np.where(closed_box_48.source_face // 2 == 4, 1.0, 0.0)
    )
    ref = pydynrad.solve(bright, F, method="dense", dtype=np.float64, device=device).radiosity
    dyn = pydynrad.DynamicRadiosity(
        bright, F, local_size=len(bright), far_field=False, storage="fp64", observer=[0.5, 0.5, 0.5], device=device
    )
    B = dyn.radiosity()
    assert ref.max() > 300  # about 1 / (1 - 0.9995) / 6 faces' worth
    np.testing.assert_allclose(B, ref, rtol=1e-12, atol=1e-12 * ref.max())
    with pytest.raises(pydynrad.errors.ConvergenceError, match="albedos near 1 need about"):
        pydynrad.solve(bright, F, tol=1e-8, dtype=np.float64, device=device)
    # K itself past fp16's range is refused at the build, not stored as inf with a warning.
    brighter = closed_box_48.with_materials(
        albedo=0.999999, emission=np.where(closed_box_48.source_face // 2 == 4, 1.0, 0.0)
    )
    with pytest.raises(InvalidInputError, match="beyond fp16's range"), pytest.warns(PrecisionWarning):
        pydynrad.DynamicRadiosity(
            brighter,
            F,
            local_size=len(brighter),
            far_field=False,
            storage="fp16",
            observer=[0.5, 0.5, 0.5],
            device=device,
        )


def test_residual_is_scaled_by_k_not_by_a_column_of_rounding_residue(device):
    # Patches that no other local patch sees have a zero column in a fresh K and rounding
    # residue after exact swaps; scaled by that column's own maximum the residual read ~1 for
    # a K accurate to 1e-6 and refreshed it for nothing.
    closed_box_48 = pydynrad.scenes.cornell_box(max_edge=200.0)
    F = pydynrad.form_factors(closed_box_48, resolution=64, device=device)
    a, b = np.array([50.0, 100.0, 50.0]), np.array([500.0, 450.0, 500.0])
    dyn = pydynrad.DynamicRadiosity(
        closed_box_48, F, local_size=128, update="exact", storage="fp32", far_field=False, observer=a, device=device
    )
    for f in range(224):
        t = (f % 80) / 40
        dyn.update(a + (b - a) * (t if t <= 1 else 2 - t))
    residuals = [dyn.residual() for _ in range(10)]
    B = dyn.radiosity()
    dyn.refresh()  # K built afresh over the same local set
    S = dyn.local_patches
    B_fresh = dyn.radiosity()
    assert np.abs(B[S] - B_fresh[S]).max() < 1e-6 * B_fresh.max()  # K is accurate: so must the residual say
    assert max(residuals) < 1e-5, residuals
    with pytest.raises(InvalidInputError, match="far_field must be True or False"):
        dyn.radiosity(far_field="no")
