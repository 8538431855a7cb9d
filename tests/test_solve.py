"""The full radiosity solver against independent truths: the furnace B = E / (1 - rho), a
dense float64 solve written here in numpy, energy conservation, and the extremes.

Synthetic F (tests/helpers.py) satisfies reciprocity and its row sums exactly, so
these tests check the solver's algebra apart from any form-factor discretisation.

float32 bound: the iteration stops at relative residual tol, so B's relative error is at most
tol / (1 - rho) plus float32 rounding accumulated over the bounces (~1e-6 here).
"""

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import box_scene, dense_radiosity, reciprocal_F

import pydynrad
from pydynrad import solve


@pytest.mark.parametrize("rho", [0.5, 0.99])
def test_furnace_float64(device, rho):
    s = box_scene(3, albedo=rho, emission=2.0)
    F = reciprocal_F(s.areas, seed=1)
    truth = 2.0 / (1.0 - s.albedo[0, 0].astype(np.float64))  # the stored (float32) albedo
    tol = 1e-9
    sol = solve(s, F, dtype=np.float64, tol=tol, device=device)
    assert sol.converged and sol.channels == 1 and sol.method == "iterative"
    assert sol.radiosity.shape == (len(s), 3) and sol.radiosity.dtype == np.float64
    # Stopping at relative residual tol leaves ~tol / (1 - rho): observed 9e-10 (0.5), 1e-7 (0.99).
    assert np.abs(sol.radiosity / truth - 1).max() < 10 * tol / (1 - rho)
    dense = solve(s, F, method="dense", device=device)
    assert np.abs(dense.radiosity / truth - 1).max() < 1e-13  # observed 7e-16 (0.5), 7e-15 (0.99)


@pytest.mark.parametrize("rho", [0.5, 0.99])
def test_furnace_float32(device, rho):
    s = box_scene(3, albedo=rho, emission=2.0)
    F = reciprocal_F(s.areas, seed=1)
    truth = 2.0 / (1.0 - s.albedo[0, 0].astype(np.float64))
    tol = 1e-6
    sol = solve(s, F, dtype=np.float32, tol=tol, device=device)
    assert sol.converged and sol.residual <= tol
    assert np.abs(sol.radiosity / truth - 1).max() < tol / (1 - rho) + 1e-5


def test_iterative_matches_dense_coloured_leaky(device):
    rng = np.random.default_rng(4)
    s = box_scene(3)
    s = s.with_materials(
        albedo=rng.uniform(0, 0.9, (len(s), 3)),
        emission=rng.uniform(0, 1, (len(s), 3)) * (rng.random((len(s), 1)) < 0.2),
    )
    F = reciprocal_F(s.areas, row_sum=0.9, seed=2)
    truth = dense_radiosity(s, F, s.emission.astype(np.float64))
    dense = solve(s, F, method="dense", device=device)
    np.testing.assert_allclose(dense.radiosity, truth, rtol=1e-12, atol=1e-14)
    it64 = solve(s, F, dtype=np.float64, tol=1e-12, device=device)
    assert it64.channels == 3
    np.testing.assert_allclose(it64.radiosity, truth, rtol=1e-10, atol=1e-12)
    it32 = solve(s, F, dtype=np.float32, tol=1e-6, device=device)
    assert np.abs(it32.radiosity - truth).max() < 2e-5 * np.abs(truth).max()


def test_energy_balance(device):
    """Emitted = absorbed + escaped, with H = F B the irradiance and, by reciprocity, the power
    leaving j that escapes = A_j B_j (1 - sum_i F_ji)."""
    rng = np.random.default_rng(5)
    s = box_scene(3).with_materials(albedo=rng.uniform(0.1, 0.9, (108, 3)))
    s = s.with_materials(emission=np.where(np.arange(len(s))[:, None] < 6, 5.0, 0.0) * np.ones(3))
    A, rho, E = (s.areas.astype(np.float64), s.albedo.astype(np.float64), s.emission.astype(np.float64))
    for row_sum in (1.0, 0.8):
        F = reciprocal_F(s.areas, row_sum=row_sum, seed=3)
        B = solve(s, F, dtype=np.float64, tol=1e-12, device=device).radiosity
        H = F @ B
        emitted = A @ E
        absorbed = A @ ((1 - rho) * H)
        escaped = (A * (1 - np.asarray(F.sum(axis=1)).ravel())) @ B
        np.testing.assert_allclose(absorbed + escaped, emitted, rtol=1e-10)  # observed 4e-12


def test_grey_scene_with_coloured_light_uses_three_channels(device):
    s = box_scene(2, albedo=0.6).with_materials(emission=np.tile([1.0, 0.5, 0.0], (48, 1)))
    F = reciprocal_F(s.areas, seed=6)
    sol = solve(s, F, dtype=np.float64, tol=1e-12, device=device)
    assert sol.channels == 3
    np.testing.assert_allclose(sol.radiosity, dense_radiosity(s, F, s.emission.astype(np.float64)), rtol=1e-10)


def test_analytic_lights_enter_through_L(device):
    s = box_scene(3, albedo=(0.7, 0.5, 0.3))
    F = reciprocal_F(s.areas, seed=7)
    lights = [pydynrad.PointLight((0.5, 0.5, 0.9), 1.0)]
    L = pydynrad.light_vector(s, lights, device=device)
    assert L.max() > 0
    sol = solve(s, F, lights=lights, dtype=np.float64, tol=1e-12, device=device)
    np.testing.assert_allclose(sol.radiosity, dense_radiosity(s, F, L), rtol=1e-10)
    np.testing.assert_allclose(sol.light, L)


def test_fixed_bounces_are_the_truncated_series(device):
    s = box_scene(2, albedo=0.8, emission=np.repeat([1.0, 0.0], [4, 44]))
    F = reciprocal_F(s.areas, seed=8)
    L = s.emission.astype(np.float64)
    PF = s.albedo[:, :1].astype(np.float64) * F.toarray()
    series = L.copy()
    term = L.copy()
    for _ in range(3):
        term = PF @ term
        series += term
    sol = solve(s, F, bounces=3, dtype=np.float64, device=device)
    assert sol.iterations == 3
    np.testing.assert_allclose(sol.radiosity, series, rtol=1e-14)  # observed 3.4e-16
    np.testing.assert_array_equal(solve(s, F, bounces=0, dtype=np.float64, device=device).radiosity, L)


def test_albedo_zero_gives_light_exactly(device):
    s = box_scene(2, albedo=0.0, emission=np.linspace(0, 1, 48))
    F = reciprocal_F(s.areas, seed=9)
    for dtype in (np.float32, np.float64):
        sol = solve(s, F, dtype=dtype, device=device)
        np.testing.assert_array_equal(sol.radiosity, s.emission.astype(dtype).astype(np.float64))
        assert sol.iterations == 1 and sol.residual == 0


def test_albedo_0999_reports_non_convergence_or_converges(device):
    s = box_scene(2, albedo=0.999, emission=1.0)
    F = reciprocal_F(s.areas, seed=10)
    with pytest.raises(pydynrad.errors.ConvergenceError, match="200 iterations"):
        solve(s, F, dtype=np.float64, max_iterations=200, device=device)
    partial = solve(s, F, dtype=np.float64, max_iterations=200, raise_on_failure=False, device=device)
    assert not partial.converged and partial.iterations == 200 and partial.residual > 1e-6
    assert len(partial.history) == 200 and partial.history[-1] < partial.history[0]
    truth = 1.0 / (1.0 - s.albedo[0, 0].astype(np.float64))
    np.testing.assert_allclose(
        solve(s, F, method="dense", device=device).radiosity, truth, rtol=1e-12
    )  # observed 1.2e-14


def test_albedo_one_refused():
    with pytest.raises(pydynrad.InvalidInputError, match=r"\[0, 1\)"):
        box_scene(2, albedo=1.0)
    with pytest.raises(pydynrad.InvalidInputError, match=r"\[0, 1\)"):
        box_scene(2).with_materials(albedo=(1.0, 0.5, 0.5))


def test_bad_form_factors_refused(device):
    s = box_scene(2, emission=1.0)
    F = reciprocal_F(s.areas, seed=11)
    with pytest.raises(pydynrad.InvalidInputError, match="shape"):
        solve(s, F[:10, :10], device=device)
    bad = F.tolil()
    bad[0, 1] = -0.1
    with pytest.raises(pydynrad.InvalidInputError, match=">= 0"):
        solve(s, bad.tocsr(), device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="sums to"):
        solve(s, F * 1.2, device=device)
    nan = F.toarray()
    nan[3, 4] = np.nan
    with pytest.raises(pydynrad.InvalidInputError, match="NaN"):
        solve(s, nan, device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="method"):
        solve(s, F, method="magic", device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="tol"):
        solve(s, F, tol=0, device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="dtype"):
        solve(s, F, dtype=np.int32, device=device)


def test_dense_refused_when_too_large(device, monkeypatch):
    import sys

    solve_module = sys.modules["pydynrad.solution"]  # the package attribute is the function
    s = box_scene(2, emission=1.0)
    monkeypatch.setattr(solve_module, "DENSE_MAX_PATCHES", 10)
    with pytest.raises(pydynrad.InvalidInputError, match="iterative"):
        solve(s, reciprocal_F(s.areas), method="dense", device=device)


@pytest.fixture(scope="module")
def cornell_solved(device):
    s = pydynrad.scenes.cornell_box(max_edge=200.0)
    assert len(s) == 384  # the floor cut at the blocks' footprints (274 when it ran on under them)
    F = pydynrad.form_factors(s, resolution=32, device=device)
    return s, F, solve(s, F, dtype=np.float64, tol=1e-12, device=device)


def test_cornell_energy_balance(cornell_solved):
    """Two checks. (1) Exact bookkeeping, any F: with H = F B, absorbed - emitted =
    sum_j B_j (sum_i A_i F_ij - A_j); this holds to the solve's tolerance. (2) Physics:
    emitted = absorbed + escaped through the open front, escaped = sum_j A_j B_j (1 - sum_i F_ji).
    (2) is exact only for a reciprocal F (test_energy_balance: 1e-9); hemicube rows at R = 32
    break reciprocity by a few percent per entry, which leaves 1.7% here: nearly all of it the
    light's two patches, whose columns (the others' centre-point hemicubes) take 3% more than
    their rows send. The floor's share fell from 0.66% to 0.13% when it stopped running on under
    the blocks (the total was 1.3% then because the two partly cancelled). Area-sampled rows
    (``form_factors(samples=)``) remove the centre points' part: test_scenes.py."""
    s, F, sol = cornell_solved
    A, rho, E, B = (
        s.areas.astype(np.float64),
        s.albedo.astype(np.float64),
        s.emission.astype(np.float64),
        sol.radiosity,
    )
    H = F @ B
    emitted, absorbed = A @ E, A @ ((1 - rho) * H)
    column_mass = np.asarray(F.T @ A).ravel()
    np.testing.assert_allclose(absorbed - emitted, B.T @ (column_mass - A), rtol=1e-9)  # observed 5.5e-11
    escaped = (A * (1 - np.asarray(F.sum(axis=1)).ravel())) @ B
    assert np.all(escaped > 0.1 * emitted)  # the front is open
    np.testing.assert_allclose(absorbed + escaped, emitted, rtol=0.03)


def test_cornell_colour_bleeding(cornell_solved):
    s, _, sol = cornell_solved
    rho = s.albedo
    red = (rho[:, 0] > 0.5) & (rho[:, 1] < 0.2)
    green = (rho[:, 1] > 0.3) & (rho[:, 0] < 0.2)
    x_red, x_green = s.centers[red, 0].mean(), s.centers[green, 0].mean()
    floor = (s.normals[:, 1] > 0.99) & (s.centers[:, 1] < 1.0)
    x = s.centers[:, 0]
    third = abs(x_red - x_green) / 3
    near_red = floor & (np.abs(x - x_red) < third)
    near_green = floor & (np.abs(x - x_green) < third)
    assert near_red.sum() >= 3 and near_green.sum() >= 3
    B = sol.radiosity
    # Summed over each region (floor patches under the blocks receive nothing: no 0/0).
    red_over_green = lambda m: B[m, 0].sum() / B[m, 1].sum()  # noqa: E731
    assert red_over_green(near_red) > 1.1 * red_over_green(near_green)


def _series(scene, F, L, bounces):
    """sum_{k <= bounces} (P F)^k L per channel, in float64 numpy."""
    rho, Fd = scene.albedo.astype(np.float64), sp.csr_matrix(F).toarray()
    out, term = L.copy(), L.copy()
    for _ in range(bounces):
        term = rho * (Fd @ term)
        out += term
    return out


def _leaky_F_with_empty_rows(scene, seed):
    """A reciprocal F whose first 5 and last 7 rows (and columns) are empty: patches that see
    nothing, at both ends of the row range the kernel splits into blocks."""
    F = reciprocal_F(scene.areas, row_sum=0.9, seed=seed).tolil()
    for i in [*range(5), *range(len(scene) - 7, len(scene))]:
        F[i, :] = 0
        F[:, i] = 0
    return F.tocsr()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_rgb_pass_equals_three_grey_solves(device, dtype):
    """One RGB pass over F (all channels per entry) gives what three single-channel solves give."""
    rng = np.random.default_rng(12)
    s = box_scene(3)
    s = s.with_materials(albedo=rng.uniform(0, 0.9, (len(s), 3)), emission=rng.uniform(0, 1, (len(s), 3)))
    F = reciprocal_F(s.areas, row_sum=0.95, seed=13)
    rgb = solve(s, F, dtype=dtype, bounces=6, device=device)
    assert rgb.channels == 3
    for c in range(3):
        grey = s.with_materials(
            albedo=np.repeat(s.albedo[:, c : c + 1], 3, axis=1), emission=np.repeat(s.emission[:, c : c + 1], 3, axis=1)
        )
        one = solve(grey, F, dtype=dtype, bounces=6, device=device)
        assert one.channels == 1
        rtol = 1e-13 if dtype == np.float64 else 2e-6  # observed 3e-15 and 1.2e-7
        np.testing.assert_allclose(rgb.radiosity[:, c], one.radiosity[:, 0], rtol=rtol)
    truth = _series(s, F, s.emission.astype(np.float64), 6)
    assert (
        np.abs(rgb.radiosity - truth).max() < (1e-14 if dtype == np.float64 else 2e-6) * np.abs(truth).max()
    )  # 2.5e-16, 8e-8


@pytest.mark.parametrize("layout", [None, (1, 1), (1, 7), (1, 1000), (16, 5), (64, 1000)])
@pytest.mark.parametrize("grey", [True, False])
def test_kernel_layouts_give_the_series(device, layout, grey):
    """Every work split (one block or many, one work-item per block or a work-group per row,
    the GPU's CSR-vector path run here on the CPU) computes the same bounces and residual."""
    from pydynrad.solution import RadiositySolver

    rng = np.random.default_rng(14)
    s = box_scene(3)
    albedo = np.full((len(s), 3), 0.8) if grey else rng.uniform(0, 0.9, (len(s), 3))
    emission = np.repeat(rng.uniform(0, 1, (len(s), 1)), 3, axis=1) if grey else rng.uniform(0, 1, (len(s), 3))
    s = s.with_materials(albedo=albedo, emission=emission)
    F = _leaky_F_with_empty_rows(s, seed=15)
    L = s.emission.astype(np.float64)
    solver = RadiositySolver(s, F, dtype=np.float64, device=device, layout=layout)
    sol = solver.solve(L, bounces=4)
    assert sol.channels == (1 if grey else 3)
    np.testing.assert_allclose(sol.radiosity, _series(s, F, L, 4), rtol=1e-14)  # observed 3.5e-16
    # The residual reduced over blocks is the one of the equation at the third iterate.
    B3 = _series(s, F, L, 3)
    r = np.abs(_series(s, F, L, 4) - B3).max() / np.abs(_series(s, F, L, 4)).max()
    assert sol.residual == pytest.approx(r, rel=1e-12)  # observed 1.1e-14


@pytest.mark.parametrize("layout", [(1, 3, 2), (1, 3, 4)])
def test_float32_rgb_steps_give_the_series(device, layout):
    """Both vector steps of the float32 RGB loop (pairs of entries for 8-float registers, fours
    for 16-float ones; each machine uses one) compute the same bounces, on rows of every length
    mod 4."""
    from pydynrad.solution import RadiositySolver

    rng = np.random.default_rng(17)
    s = box_scene(3)
    s = s.with_materials(albedo=rng.uniform(0, 0.9, (len(s), 3)), emission=rng.uniform(0, 1, (len(s), 3)))
    F = _leaky_F_with_empty_rows(s, seed=18)
    L = s.emission.astype(np.float64)
    sol = RadiositySolver(s, F, dtype=np.float32, device=device, layout=layout).solve(L, bounces=4)
    truth = _series(s, F, L, 4)
    assert np.abs(sol.radiosity - truth).max() < 2e-7 * np.abs(truth).max()  # observed 5.5e-8


def test_row_blocks_cover_every_row_with_balanced_entries():
    from pydynrad.device.csr import row_blocks

    rng = np.random.default_rng(16)
    lengths = rng.integers(0, 300, 1000)
    lengths[:10] = 0
    lengths[-25:] = 0  # trailing empty rows still belong to the last block
    indptr = np.concatenate([[0], np.cumsum(lengths)])
    for blocks in (1, 3, 32, 1000):
        blk = row_blocks(indptr, blocks)
        assert blk.dtype == np.int32 and len(blk) == blocks + 1
        assert blk[0] == 0 and blk[-1] == 1000 and np.all(np.diff(blk) >= 0)
        per_block = np.diff(indptr[blk])
        assert per_block.sum() == indptr[-1]
        assert per_block.max() <= indptr[-1] / blocks + lengths.max()


def test_bad_layout_refused(device):
    from pydynrad.solution import RadiositySolver

    s = box_scene(2, emission=1.0)
    with pytest.raises(pydynrad.InvalidInputError, match="layout"):
        RadiositySolver(s, reciprocal_F(s.areas), device=device, layout=(3, 4))
    with pytest.raises(pydynrad.InvalidInputError, match="RGB_STEP"):
        RadiositySolver(s, reciprocal_F(s.areas), device=device, layout=(1, 4, 3))


@pytest.mark.parametrize("traits", [{}, {"float_width": 8, "double_width": 4}, {"cpu": False}])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_grey_solve_in_every_device_format(device, traits, dtype):
    """A grey scene runs SELL-16 (float) / SELL-8 (double) on an AVX-512 CPU, CSR on a narrower
    CPU and CSR-vector on a GPU: the same bounces either way."""
    from pydynrad.solution import RadiositySolver

    dev = device.with_traits(**traits)
    rng = np.random.default_rng(17)
    s = box_scene(4)
    s = s.with_materials(
        albedo=np.full((len(s), 3), 0.7), emission=np.repeat(rng.uniform(0, 1, (len(s), 1)), 3, axis=1)
    )
    F = _leaky_F_with_empty_rows(s, seed=18)
    L = s.emission.astype(np.float64)
    solver = RadiositySolver(s, F, dtype=dtype, device=dev)
    t = device.traits
    wide = not traits and t.cpu and t.float_width >= 16 and (dtype == np.float32 or t.double_width >= 8)
    assert solver.format(1) == (("sell-16" if dtype == np.float32 else "sell-8") if wide else "csr")
    assert solver.format(3) == "csr"  # RGB: CSR's float4 loads beat three gathers per entry
    nbytes = solver.nbytes
    sol = solver.solve(L, bounces=5)
    assert sol.channels == 1 and solver.nbytes == nbytes  # F uploaded once, in the grey format
    rtol = 1e-14 if dtype == np.float64 else 2e-6  # observed 4e-16 and 1.2e-7
    np.testing.assert_allclose(sol.radiosity, _series(s, F, L, 5), rtol=rtol)
    B4 = _series(s, F, L, 4)
    r = np.abs(_series(s, F, L, 5) - B4).max() / np.abs(_series(s, F, L, 5)).max()
    assert sol.residual == pytest.approx(r, rel=1e-4 if dtype == np.float32 else 1e-11)
