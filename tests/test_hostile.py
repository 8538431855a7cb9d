"""Hostile input: what used to crash the process or answer wrongly is refused, naming the problem.

Each test here was a defect of issue 14; the broken-F cases that segfaulted run in a
subprocess, so a crash fails the test instead of killing the run.
"""

import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import scipy.sparse as sp

import pydynrad
from pydynrad.checks import sparse_structure
from pydynrad.errors import InvalidInputError
from pydynrad.renderer import Renderer
from pydynrad.geometry.scene import PrecisionWarning


@pytest.fixture(scope="module")
def box():
    return pydynrad.scenes.closed_box(subdivisions=1)  # 48 patches


@pytest.fixture(scope="module")
def box_F(box, device):
    return pydynrad.form_factors(box, resolution=16, device=device)


def _broken(F: sp.csr_matrix, kind: str) -> sp.csr_matrix:
    """A copy of F with its structure broken one way (scipy does not check any of these)."""
    G = F.copy()
    if kind == "column out of range":
        G.indices[3] = F.shape[1] + 10**6
    elif kind == "negative column":
        G.indices[-1] = -1
    elif kind == "1-based":
        G.indices += 1
    elif kind == "negative indptr":
        G.indptr[5] = -3
    elif kind == "reversed indptr":
        G.indptr[5], G.indptr[6] = G.indptr[6], G.indptr[5]
    return G


KINDS = {"column out of range": r"row 0 has column index 1000048 outside 0\.\.47",
         "negative column": r"row 47 has column index -1 outside 0\.\.47",
         "1-based": r"column index 48 outside 0\.\.47 \(1-based indices\?",
         "negative indptr": r"row 4 has a negative length \(indptr decreases from \d+ to -3\)",
         "reversed indptr": r"row 5 has a negative length"}


@pytest.mark.parametrize("kind", KINDS)
def test_broken_F_is_refused_by_every_entry_point(box, box_F, device, kind):
    G = _broken(box_F, kind)
    calls = {"solve": lambda: pydynrad.solve(box, G, device=device),
             "multibounce": lambda: pydynrad.multibounce(box, G, np.arange(8), device=device),
             "DynamicRadiosity": lambda: pydynrad.DynamicRadiosity(box, G, local_size=8, device=device),
             "CSRRows": lambda: pydynrad.rows.CSRRows(G),
             "CSC input": lambda: pydynrad.solve(box, sp.csc_matrix((G.data, G.indices, G.indptr), shape=G.shape),
                                                 device=device)}
    for name, call in calls.items():
        with pytest.raises(InvalidInputError, match=KINDS[kind] if name != "CSC input" else "CSC"):
            call()


def test_broken_F_in_a_subprocess_fails_cleanly_instead_of_crashing(tmp_path):
    # multibounce with 1-based indices segfaulted on main before issue 14.
    script = textwrap.dedent("""
        import numpy as np, pydynrad
        scene = pydynrad.scenes.closed_box(subdivisions=1)
        F = pydynrad.form_factors(scene, resolution=8)
        F.indices += 1
        try:
            pydynrad.multibounce(scene, F, np.arange(len(scene)))
        except pydynrad.InvalidInputError as exc:
            print("refused:", exc)
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, f"crashed with rc {run.returncode}: {run.stderr[-2000:]}"
    assert re.search(r"refused: F: row \d+ has column index 48 outside 0\.\.47 \(1-based", run.stdout), run.stdout


class _Source:
    """A row source that serves F's rows with one block broken."""

    def __init__(self, F, kind, bad_patch):
        self.F, self.kind, self.bad_patch, self.n_patches = F, kind, bad_patch, F.shape[0]

    def rows(self, idx):
        block = self.F[idx]
        if self.bad_patch in set(np.asarray(idx).tolist()):
            k = int(np.flatnonzero(np.asarray(idx) == self.bad_patch)[0])
            if self.kind == "column":
                block.indices[block.indptr[k]] = self.n_patches + 7
            elif self.kind == "value":
                block.data[block.indptr[k]] = np.nan
            elif self.kind == "shape":
                block = block[:, :-1]
        return block


@pytest.mark.parametrize("kind, message", [
    ("column", r"row 30 has column index 55 outside 0\.\.47"),
    ("value", "NaN or infinite"),
    ("shape", r"must have shape \(\d+, 48\); got \(\d+, 47\)"),
])
def test_row_source_blocks_are_checked_with_the_patch_named(box, box_F, device, kind, message):
    source = _Source(box_F, kind, bad_patch=30)
    # The far field sums G from every row at construction: the bad block is refused there.
    with pytest.raises(InvalidInputError, match=message):
        pydynrad.DynamicRadiosity(box, source, local_size=48, device=device)
    # Row 30's patch is near the observer below, so it enters the local set on the first update.
    dyn = pydynrad.DynamicRadiosity(box, source, local_size=48, far_field=False, device=device)
    with pytest.raises(InvalidInputError, match=message):
        dyn.update(box.centers[30])
    with pydynrad.rows.RowCache(source, 1 << 20) as cache, pytest.raises(InvalidInputError, match=message):
        cache.rows([29, 30])


def test_a_form_factor_file_with_broken_arrays_is_refused(box, box_F, tmp_path):
    path = pydynrad.save_form_factors(box, tmp_path / "F.npz", box_F, 16)
    with np.load(path) as z:
        arrays = dict(z)
    arrays["indices"] = arrays["indices"].copy()
    arrays["indices"][arrays["indptr"][9]] = 4096
    np.savez(path, **arrays)
    with pytest.raises(InvalidInputError, match=r"F\.npz'.*row 9 has column index 4096 outside 0\.\.47"):
        pydynrad.rows.load_form_factors(box, path)
    arrays["indptr"] = arrays["indptr"][:-1]
    np.savez(path, **arrays)
    with pytest.raises(InvalidInputError, match="indptr has 48 entries; 48 rows need 49"):
        pydynrad.rows.load_form_factors(box, path)


def test_sparse_structure_accepts_what_scipy_builds():
    A = sp.random(50, 40, density=0.2, format="csr", random_state=1)
    sparse_structure(A.indptr, A.indices, A.shape)
    sparse_structure(np.zeros(4, np.int64), np.zeros(0, np.int32), (3, 3))  # all rows empty
    with pytest.raises(InvalidInputError, match="indptr must start at 0"):
        sparse_structure(A.indptr + 1, A.indices, A.shape)
    with pytest.raises(InvalidInputError, match="indptr ends at"):
        sparse_structure(A.indptr, A.indices[:-1], A.shape)
    with pytest.raises(InvalidInputError, match="indices must be a 1-D integer array"):
        sparse_structure(A.indptr, A.indices.astype(float), A.shape)


@pytest.mark.parametrize("size, subdivisions, resolutions, rows", [
    ((1, 1, 1), 2, (2, 6, 16, 64), None),
    ((3, 1, 0.1), 1, (2, 16, 64), None),
    # A thin box seen edge-on from its side walls: rays graze the big walls' shared edges. The
    # Moller-Trumbore test with slack lost one pixel of one of these rows at R = 128 (2.2e-5).
    ((1, 1, 0.01), 2, (16, 128), np.arange(128)),
])
def test_closed_boxes_rows_sum_to_one_at_every_resolution(device, size, subdivisions, resolutions, rows):
    scene = pydynrad.scenes.closed_box(size=size, subdivisions=subdivisions)
    for R in resolutions:
        F = pydynrad.form_factors(scene, resolution=R, rows=rows, device=device)
        sums = np.asarray(F.sum(axis=1)).ravel()
        # float32 pixel weights summed: the observed worst is 2.4e-7.
        assert np.abs(sums - 1).max() < 1e-6, (R, int(np.argmax(np.abs(sums - 1))), np.abs(sums - 1).max())


# Far from the origin and at extreme scales: the device frame (docs/design.md, 'Device frame').
SHIFT = np.array([1.0, -0.5, 0.25])


def _moved_box(scale, offset, albedo=0.5, emission=1.0):
    base = pydynrad.scenes.closed_box(subdivisions=1)
    return pydynrad.Scene(base.points * scale + offset * SHIFT, base.triangles, albedo=albedo, emission=emission)


@pytest.mark.parametrize("scale, offset", [(1e-6, 0.0), (1e6, 0.0), (1.0, 1e6), (1.0, 1e7), (1e-3, 1e4), (1e6, -1e7),
                                           (1e-15, 0.0), (1e14, 0.0)])
def test_furnace_far_from_origin_and_at_extreme_scales(device, scale, offset):
    # Closed box, albedo 0.5, emission 1: B = E / (1 - rho) = 2 everywhere. Before the device
    # frame a unit box at 1e6 gave 1.961 and its F was empty at 1e14 or 1e-15.
    scene = _moved_box(scale, offset)
    F = pydynrad.form_factors(scene, resolution=16, device=device)
    B = pydynrad.solve(scene, F, device=device).radiosity
    assert np.abs(B / 2 - 1).max() < 1e-4  # observed 5.4e-7 at every scale and offset


@pytest.mark.parametrize("scale, offset", [(1.0, 0.0), (1e-4, 1e3), (1e3, 1e7)])
def test_point_light_and_rays_in_the_users_frame(device, scale, offset):
    scene = _moved_box(scale, offset, emission=0.0)
    light = scene.bbox.mean(axis=0) + 0.1 * scale
    E = pydynrad.lights.direct_irradiance(scene, [pydynrad.PointLight(light, 5.0)], device=device)[:, 0]
    # Nothing inside a convex box occludes: E = I cos / r^2 in float64.
    to_light = light - scene.centers
    r = np.linalg.norm(to_light, axis=1)
    expected = 5.0 * np.einsum("ij,ij->i", scene.normals.astype(np.float64), to_light) / r**3
    np.testing.assert_allclose(E, expected, rtol=1e-5)
    # A ray from the light to each patch centre stops there: t = 1 for directions of that length.
    patch, t, front = pydynrad.geometry.bvh.cast_rays(scene, np.broadcast_to(light, to_light.shape), -to_light, device=device)
    np.testing.assert_allclose(t, 1.0, rtol=1e-5)
    assert front.all() and np.mean(patch == np.arange(len(scene))) > 0.99  # a centre may sit on an edge
    # Depth from the renderer in the user's unit: the box is [0, scale]^3 shifted.
    cam = pydynrad.Camera(light, light + [1.0, 0.0, 0.0], up=(0, 0, 1), fov_y=10.0, width=8, height=8)
    depth = Renderer(scene, device=device).visibility(cam).depth
    wall_x = scale + offset * SHIFT[0]
    assert np.abs(depth.min() / (wall_x - light[0]) - 1) < 1e-3  # the centre pixels are off-axis by < fov


def test_patches_too_small_for_float32_warn():
    base = pydynrad.scenes.closed_box(subdivisions=0)
    tiny = np.array([[0.5, 0.5, 0.5], [0.5 + 1e-7, 0.5, 0.5], [0.5, 0.5 + 1e-7, 0.5]])
    points = np.concatenate([base.points, tiny])
    triangles = np.concatenate([base.triangles, [[len(base.points), len(base.points) + 1, len(base.points) + 2]]])
    with pytest.warns(pydynrad.geometry.scene.PrecisionWarning, match="1 patch"):
        pydynrad.Scene(points, triangles)


@pytest.mark.parametrize("storage", ["fp32", "fp16"])
def test_residual_sees_the_max_entry_error(device, storage):
    # Against a dense float64 K over the same local set: the probe of 8 columns reads within
    # 1.3x of max entry error / max entry (observed fp32 3.6e-8 vs 4.2e-8, fp16 4.2e-4 vs 3.4e-4,
    # closed box, 192 patches); the former probe read 1-2e-7 for fp32 where entries were off 5e-6.
    scene = pydynrad.scenes.closed_box(subdivisions=2, albedo=0.8)
    F = pydynrad.form_factors(scene, resolution=16, device=device)
    dyn = pydynrad.DynamicRadiosity(scene, F, local_size=96, storage=storage, observer=[0.5, 0.5, 0.5],
                                    far_field=False, device=device)
    rng = np.random.default_rng(3)
    for _ in range(40):
        dyn.update(rng.random(3))
    S = dyn.local_patches
    FS, rho = F[S][:, S].toarray().astype(np.float64), scene.albedo[S, 0].astype(np.float64)
    fresh = np.linalg.solve(np.eye(len(S)) - FS * rho[None, :], FS)
    true = np.abs(dyn.matrix.to_host()[0] - fresh).max() / np.abs(fresh).max()
    assert true / 3 < dyn.residual() < 3 * true


# State and concurrency (issue 14, item 7), outputs that cannot overflow silently (item 6).
def test_update_is_not_re_entrant_and_a_huge_observer_is_refused_before_the_frame_advances(box, box_F, device):
    import threading

    dyn = pydynrad.DynamicRadiosity(box, box_F, local_size=8, observer=[0.5, 0.5, 0.5], far_field=False,
                                    device=device)
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


def test_scene_arrays_are_read_only_and_overflowing_values_are_refused(box, device):
    with pytest.raises(ValueError, match="read-only"):
        box.albedo[:] = 1.0  # main: solve then iterated 10,000 times before failing
    with pytest.raises(ValueError, match="read-only"):
        box.points[0, 0] = 5.0
    points = np.array(box.points)
    pydynrad.Scene(points, box.triangles)
    points[0, 0] = 0.25  # the caller's own array stays writable: the scene copied it
    with pytest.raises(InvalidInputError, match=r"emission exceeds float32's range"):
        pydynrad.Scene(box.points, box.triangles, emission=1e39)  # main: stored as inf
    with pytest.raises(InvalidInputError, match="direct irradiance overflows float32"):
        pydynrad.light_vector(box, [pydynrad.PointLight([0.5, 0.5, 0.5], 3e38)], device=device)  # main: inf


def test_an_exposure_that_overflows_is_refused_not_written_as_inf(tmp_path):
    image = np.full((4, 4, 3), 2.0, dtype=np.float32)
    with pytest.raises(InvalidInputError, match="exposure 120 stops overflows float32"):
        pydynrad.image_io.write_image(tmp_path / "x.exr", image * 1e3, exposure=120.0)  # once: an all-inf EXR, rc 0
    assert not (tmp_path / "x.exr").exists()
    # 2**exposure itself beyond float32 (2000 stops overflowed float64 in 2.0**exposure: a raw
    # OverflowError from write_image, the bake, the comparison image).
    from pydynrad.bake import export_mesh
    from pydynrad.comparison import comparison_image

    for exposure in (2000.0, -127.0, float("nan")):
        for call in (lambda: pydynrad.image_io.write_image(tmp_path / "z.exr", image, exposure=exposure),
                     lambda: comparison_image(image, image, exposure),
                     lambda: export_mesh(pydynrad.scenes.block(1.0, 0), np.ones((12, 3)), tmp_path / "m.glb",
                                         exposure=exposure)):
            with pytest.raises(InvalidInputError, match="exposure"):
                call()
    assert not list(tmp_path.glob("[zm].*"))
    with pytest.raises(InvalidInputError, match="overflows float32"):
        pydynrad.image_io.write_image(tmp_path / "y.exr", np.full((2, 2, 3), 3e38, np.float32), exposure=1.0)


def test_a_form_factor_file_of_another_dtype_is_refused(box, box_F, tmp_path):
    """float16 or text values (a file not written by pydynrad) are named, not left to scipy (a raw
    ValueError inside it)."""
    path = pydynrad.save_form_factors(box, tmp_path / "F.npz", box_F, 16)
    with np.load(path) as z:
        arrays = dict(z)
    for data in (arrays["data"].astype(np.float16), arrays["data"].astype(str)):
        np.savez(path, **{**arrays, "data": data})
        with pytest.raises(InvalidInputError, match=f"holds {data.dtype} values"):
            pydynrad.rows.load_form_factors(box, path)


def test_outputs_in_a_folders_place_and_exposures_are_refused_before_any_work(tmp_path, capsys):
    """A folder where the output file goes, or an exposure beyond float32, is one line from the
    CLI before the solve (once: after it, naming the temporary file, or a raw OverflowError);
    `bake --lightmap` writes its mesh before its lightmap, so a refused mesh leaves neither."""
    from helpers import run_main

    (tmp_path / "d.png").mkdir()
    code, _, err = run_main(["render", "cornell_box", "--max-edge", "250", "-o", str(tmp_path / "d.png")], capsys)
    assert code == 2 and "a folder of that name is in the way" in err
    code, _, err = run_main(["render", "cornell_box", "-o", str(tmp_path / "e.png"), "--exposure", "2000"], capsys)
    assert code == 2 and "within +-126 stops" in err and "Traceback" not in err
    # 126 stops times the lamp's radiosity passes float32 in the mesh's embedded 8-bit image
    # only, found after the solve: the lightmap had been written first, then the mesh refused.
    code, _, err = run_main(["bake", "cornell_box", "--max-edge", "250", "--resolution", "8", "-o",
                             str(tmp_path / "k.glb"), "--lightmap", str(tmp_path / "l.exr"), "--exposure", "126"],
                            capsys)
    assert code == 2 and "overflows float32" in err and not list(tmp_path.glob("[kl].*"))


def test_a_light_past_float32_is_refused_and_leaves_the_far_field_as_it_was(device):
    """max B <= max L / (1 - max albedo): where that passes float32 the full solve, the dynamic
    solution and the far field refuse the light before computing it (the iterative solve had
    returned inf, and one such light was kept among the far field's answers and broke every
    later one: inf, or LAPACK's SVD failing); a negative L is refused by the far field as by
    the others. After the refusals the far field answers a light as a fresh one does."""
    from pydynrad.farfield import FarField

    box = pydynrad.scenes.cornell_box(max_edge=None)
    F = pydynrad.form_factors(box, 16, device=device)
    L = pydynrad.light_vector(box, [pydynrad.PointLight((278.0, 500.0, 280.0), (3e5,) * 3)], device=device)
    far = FarField(box, F, clusters=len(box) // 8, device=device)
    dyn = pydynrad.DynamicRadiosity(box, F, local_size=64, observer=(278.0, 273.0, -300.0), device=device)
    for bad in (L / L.max() * 3e38, L / L.max() * 1e298):
        for call in (lambda: far.light(bad), lambda: dyn.radiosity(light=bad),
                     lambda: pydynrad.solve(box, F, light=bad, device=device)):
            with pytest.raises(InvalidInputError, match="beyond float32"):
                call()
    with pytest.raises(InvalidInputError, match="L must be >= 0"):
        far.light(-L)
    # Each bound is the narrowest type its products compute in: a float64 far field with an fp32
    # K_c is float32's, a K on the device its storage's; fp64 storage takes what fits float64.
    from pydynrad.device.matrix import DeviceMatrix

    big = L / L.max() * 1e300
    far64 = FarField(box, F, clusters=len(box) // 8, dtype=np.float64, coarse="dense", coarse_storage="fp32",
                     device=device)
    K = DeviceMatrix(device, pydynrad.multibounce(box, F, device=device), "fp32")
    for call in (lambda: far64.light(big), lambda: pydynrad.multibounce_radiosity(box, K, light=big)):
        with pytest.raises(InvalidInputError, match="beyond float32"):
            call()
    dyn64 = pydynrad.DynamicRadiosity(box, F, local_size=64, storage="fp64", far_field=False,
                                      observer=(278.0, 273.0, -300.0), device=device)
    huge = L / L.max() * 2e38  # radiosity past float32, within float64
    B = dyn64.radiosity(light=huge)
    assert np.all(np.isfinite(B)) and B.max() >= 2e38
    fresh = FarField(box, F, clusters=len(box) // 8, device=device)
    for x in (L, 2.0 * L):
        np.testing.assert_array_equal(far.light(x), fresh.light(x))


def test_coarse_sweeps_that_do_not_converge_raise_and_keep_nothing(device):
    """At albedo 0.999 one coarse sweep is far from the answer (99.6% off, returned silently
    once): the far field raises ConvergenceError as the full solve does, and a later light with
    enough sweeps is answered as by a fresh far field."""
    from pydynrad.errors import ConvergenceError
    from pydynrad.farfield import FarField

    box = pydynrad.scenes.closed_box(subdivisions=2, albedo=0.999, emission=1.0)
    F = pydynrad.form_factors(box, 16, device=device)
    L = np.asarray(box.emission, np.float64)
    far = FarField(box, F, coarse="sweeps", max_sweeps=1, device=device)
    with pytest.raises(ConvergenceError, match="max_sweeps=1"):
        far.light(L)
    far.max_sweeps = 100_000
    fresh = FarField(box, F, coarse="sweeps", max_sweeps=100_000, device=device)
    np.testing.assert_array_equal(far.light(L), fresh.light(L))


def test_a_walk_checks_every_frame_before_any_work_and_deep_json_is_named(box, box_F, tmp_path, device):
    """A camera that degenerates mid-path (the position interpolated onto its look-at point) is
    refused before the solution is built, naming the frame (once: frame 0 was written first),
    and a path file nested too deeply for Python's parser is named (once: a RecursionError)."""
    import json

    doc = {"frames": 3, "interpolation": "linear", "width": 8, "height": 6,
           "keyframes": [{"position": [0.5, 0.5, -2.0], "look_at": [0.5, 0.5, 0.0]},
                         {"position": [0.5, 0.5, 0.0], "look_at": [0.5, 0.5, -2.0]}]}
    (tmp_path / "degenerate.json").write_text(json.dumps(doc))
    camera_path, _ = pydynrad.load_path(tmp_path / "degenerate.json")
    with pytest.raises(InvalidInputError, match="frame 1 of 3: camera look_at"):
        pydynrad.walk(box, camera_path, form_factors=box_F, local_size=16, output=tmp_path / "out", device=device)
    assert not (tmp_path / "out").exists()
    (tmp_path / "out" / "frame_0001.png").mkdir(parents=True)  # a folder in a later frame's place
    good = pydynrad.fly_through([[0.5, 0.5, -2.0], [0.5, 0.5, -1.0]], 3, width=8, height=6)
    with pytest.raises(InvalidInputError, match="frame_0001.png': a folder of that name is in the way"):
        pydynrad.walk(box, good, form_factors=box_F, local_size=16, output=tmp_path / "out", device=device)
    assert not (tmp_path / "out" / "frame_0000.png").exists()
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(InvalidInputError, match="nested too deeply"):
        pydynrad.walks.load_walk(tmp_path / "deep.json")


def test_a_radiosity_past_float32_is_named_by_the_renderer(box, device):
    """A float64 B from the dense solve can exceed float32; rendering it is refused as out of
    float32's range (once: "NaN or infinite values", of values that were neither)."""
    camera = pydynrad.Camera((0.5, 0.5, -2.0), (0.5, 0.5, 0.5), width=8, height=6)
    with pytest.raises(InvalidInputError, match="radiosity reaches 1e\\+39, beyond float32"):
        pydynrad.render(box, np.full((len(box), 3), 1e39), camera, device=device)


def test_unit_vectors_of_huge_and_tiny_lengths():
    """Directions are scaled before they are normalised: (1e300, -2e300, 1e301) overflowed the
    norm and became (0, 0, 0), a light that silently lit nothing; 1e-300 was refused as zero."""
    from pydynrad.checks import unit_vector

    d = np.array([1.0, -2.0, 10.0])
    for scale in (1e300, 1e-300, 1.0):
        np.testing.assert_allclose(unit_vector(d * scale, "direction"), d / np.linalg.norm(d), rtol=1e-15)
    sun = pydynrad.DirectionalLight(direction=d * 1e300, irradiance=(1.0, 1.0, 1.0))
    np.testing.assert_allclose(sun.direction, d / np.linalg.norm(d), rtol=1e-15)


def test_obj_and_mtl_lines_trimesh_drops_are_named(tmp_path):
    from pydynrad.geometry.loading import MalformedLineWarning

    (tmp_path / "m.mtl").write_text("newmtl wall\nKd x y z\n")
    (tmp_path / "s.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl wall\n"
                                    "f 1 2 3\nf 2 4\n")
    with pytest.warns(MalformedLineWarning) as record:
        scene = pydynrad.load(tmp_path / "s.obj")
    messages = " | ".join(str(w.message) for w in record)
    assert "line 8 'f 2 4' (a face needs 3 corners)" in messages  # main: dropped without a word
    assert "line 2 'Kd x y z' (not numbers)" in messages
    assert len(scene) == 1


# Stores that know their own blocks (issue 14, item 2).
def test_a_block_from_another_store_is_refused_and_recomputed_on_resume(tmp_path, capsys, device):
    import json
    import shutil

    from pydynrad.cli.main import main
    from pydynrad.rows.store import StoreCorruptError

    def formfactors(name, R):
        code = main(["formfactors", "closed_box", "-o", str(tmp_path / name), "--resolution", str(R),
                     "--block-rows", "64", "--workers", "0", "--quiet"])
        out = capsys.readouterr().out
        assert code == 0, out
        return out

    formfactors("a", 8)
    formfactors("b", 16)
    scene = pydynrad.scenes.closed_box()
    a, b = (pydynrad.open_form_factors(scene, tmp_path / n) for n in "ab")
    shutil.copy(a.block_path(1), b.block_path(1))  # same scene, other resolution: its own checksum is intact
    with pytest.raises(StoreCorruptError, match="belongs to another store or block"):
        b.read_block(1)  # main: served silently
    shutil.copy(b.block_path(0), b.block_path(2))  # moved within the store
    with pytest.raises(StoreCorruptError, match="belongs to another store or block"):
        b.read_block(2)
    # Re-running the command reads every finished block: the two are recomputed, not reported as done.
    out = formfactors("b", 16)
    assert "1 of 3 blocks already done; 2 fail their checksum and are recomputed (block 1, 2)" in out
    fresh = pydynrad.form_factors(scene, resolution=16, device=device)
    assert abs(pydynrad.open_form_factors(scene, tmp_path / "b").to_csr() - fresh).max() == 0
    # Headers every reader relies on: one-line errors.
    header = json.loads((tmp_path / "a" / "header.json").read_text())
    for field, value, needle in (("block_rows", 0, "block_rows must be a positive integer; got 0"),
                                 ("block_rows", "64", "block_rows must be a positive integer; got '64'"),
                                 ("params", None, "params must be an object")):
        broken = dict(header, **{field: value})
        (tmp_path / "a" / "header.json").write_text(json.dumps(broken))
        with pytest.raises(StoreCorruptError, match=needle):
            pydynrad.FormFactorStore.read_header(tmp_path / "a")


def test_formfactors_verify_checks_every_block_and_recomputes_what_fails(tmp_path, capsys, device):
    from pydynrad.cli.main import main

    out = tmp_path / "s"
    args = ["formfactors", "closed_box", "-o", str(out), "--resolution", "8", "--block-rows", "64", "--workers", "0",
            "--clusters", "6", "--quiet"]
    assert main(args) == 0
    capsys.readouterr()
    scene = pydynrad.scenes.closed_box()
    store = pydynrad.open_form_factors(scene, out)
    assert {k: len(v) for k, v in store.verify("G").items()} == {"verified": 3, "missing": 0, "corrupt": 0}
    good_f, good_g = store.read_block(1), store.read_block(2, "G")
    store.block_path(1).write_bytes(store.block_path(1).read_bytes()[:-40])  # truncated
    store.block_path(0, "G").write_bytes(store.block_path(1, "G").read_bytes())  # another block's
    store.block_path(2, "G").unlink()
    assert store.verify("F") == {"verified": [0, 2], "missing": [], "corrupt": [1]}
    assert store.verify("G") == {"verified": [1], "missing": [2], "corrupt": [0]}
    assert main(args + ["--verify"]) == 0
    printed = capsys.readouterr().out
    assert f"verified {out}: 2 of 3 blocks already done; 1 fail their checksum and are recomputed (block 1)" in printed
    assert f"verified {out}, G: 1 of 3 blocks already done; 1 fail their checksum and are recomputed (block 0); 1 missing" in printed
    assert all(not v for k, v in store.verify("F").items() if k != "verified")
    assert all(not v for k, v in store.verify("G").items() if k != "verified")
    assert abs(store.read_block(1) - good_f).max() == 0 and abs(store.read_block(2, "G") - good_g).max() == 0
    # Only for a store that exists, and not for a single file.
    for target, needle in ((tmp_path / "none", "--verify checks an existing store"),
                           (tmp_path / "f.npz", "--verify apply to a store folder")):
        assert main(["formfactors", "closed_box", "-o", str(target), "--resolution", "8", "--verify", "--quiet"]) == 2
        assert needle in capsys.readouterr().err


def test_one_line_errors_for_wrong_types(box, box_F, device):
    # Each was a raw TypeError or ValueError from numpy on main (issue 14, item 8).
    with pytest.raises(InvalidInputError, match="refresh_tolerance must be a positive number or None; got '1e-4'"):
        pydynrad.DynamicRadiosity(box, box_F, local_size=8, refresh_tolerance="1e-4", device=device)
    with pytest.raises(pydynrad.errors.SceneFileError, match="path must be a file name .* got NoneType"):
        pydynrad.load(None)
    with pytest.raises(InvalidInputError, match="points must be numbers"):
        pydynrad.Scene([["a", "b", "c"]] * 3, [[0, 1, 2]])


def test_formfactors_will_not_overwrite_an_unrelated_npz(tmp_path, capsys):
    from pydynrad.cli.main import main

    other = tmp_path / "weights.npz"
    np.savez(other, w=np.arange(3))
    args = ["formfactors", "closed_box", "--resolution", "8", "--quiet", "-o", str(other)]
    assert main(args) == 2  # main: overwrote it without a word
    err = capsys.readouterr().err
    assert "is not a pydynrad form-factor file: not overwriting it (pass --force" in err and len(err.splitlines()) == 1
    assert np.load(other)["w"].tolist() == [0, 1, 2]
    assert main(args + ["--force"]) == 0
    assert main(args) == 0  # now a form-factor file: recomputing it in place is fine


@pytest.mark.parametrize("frames, message", [("ten", "frames must be a whole number >= 1; got 'ten'"),
                                             (10**9, "frames must be at most 1,000,000")])
def test_path_file_frames_are_named(tmp_path, frames, message):
    import json

    path = tmp_path / "p.json"
    path.write_text(json.dumps({"frames": frames, "width": 8, "height": 8, "fov_y": 40, "keyframes": [
        {"position": [0.1, 0.5, 0.5], "look_at": [0.9, 0.5, 0.5]}, {"position": [0.2, 0.5, 0.5], "look_at": [0.9, 0.5, 0.5]}]}))
    with pytest.raises(InvalidInputError, match=message):  # main: "could not convert string to float"; 10^9 accepted
        pydynrad.paths.load_path(path)


def test_bad_pyopencl_ctx_is_one_line(monkeypatch, capsys):
    from helpers import assert_one_line_error, run_main

    monkeypatch.setattr(pydynrad.device.devices, "_default", None)  # the session's device is built already
    monkeypatch.setenv("PYOPENCL_CTX", "9:0")
    code, _, err = run_main(["info"], capsys)  # main: pyopencl's RuntimeError with a traceback
    assert_one_line_error(code, err, "PYOPENCL_CTX='9:0' selects no OpenCL device", "pydynrad info")


@pytest.mark.parametrize("address, why", [("tcp://host:port", "invalid literal"), ("host", "missing port"),
                                          ("http://host:8786", "unknown address scheme")])
def test_malformed_scheduler_is_one_line(tmp_path, capsys, address, why):
    from helpers import assert_one_line_error, run_main

    code, _, err = run_main(["formfactors", "closed_box", "--resolution", "8", "--quiet", "-o", str(tmp_path / "ff"),
                             "--scheduler", address], capsys)  # main: distributed's ValueError, with a traceback
    assert_one_line_error(code, err, f"malformed scheduler address {address!r}", why, "tcp://host:8786")


def test_malformed_scheduler_leaves_no_half_built_client():
    # distributed's Client refuses the address after starting its IO loop; left to the collector,
    # the half-built Client stopped that loop later from a new LocalCluster's loop thread and
    # failed its start (the next test, in some orders of the suite).
    import gc

    from distributed import Client

    from pydynrad.precompute.distributed import _start_client

    with pytest.raises(InvalidInputError, match="missing port"):
        _start_client(None, "host")
    assert not [o for o in gc.get_objects() if isinstance(o, Client)]


def test_worker_dying_at_start_up_is_one_line(tmp_path, capsys):
    import dask
    from helpers import assert_one_line_error, run_main

    die = tmp_path / "die.py"
    die.write_text("import os\nos._exit(3)\n")  # a worker's preload: the process ends before it serves
    with dask.config.set({"distributed.worker.preload": [str(die)]}):
        code, _, err = run_main(["formfactors", "closed_box", "--resolution", "8", "--quiet", "-o", str(tmp_path / "ff"),
                                 "--workers", "1"], capsys)  # main: RuntimeError('Nanny failed to start.'), a traceback
    assert_one_line_error(code, err, "the local Dask cluster of 1 workers failed to start (Nanny failed to start.)")


def test_oversize_image_is_refused_before_the_solve(monkeypatch, capsys, box, device):
    from helpers import assert_one_line_error, run_main

    monkeypatch.setattr(pydynrad.geometry.camera, "available_host_bytes", lambda: 8 * 2**30)  # a 24 GiB machine, in use
    code, _, err = run_main(["render", "cornell_box", "-o", "x.png", "--width", "16384", "--height", "16384"], capsys)
    assert_one_line_error(code, err, "rendering a 16384 x 16384 image needs about 32.0 GiB of host memory; 8.0 GiB")
    camera = pydynrad.Camera((0.5, 0.5, 0.5), (0.5, 0.5, 0.0), width=16384, height=8192)
    with pytest.raises(pydynrad.errors.OutOfMemoryError, match="16384 x 8192 image needs about 16.0 GiB"):
        Renderer(box, device).render(np.ones((len(box), 3)), camera)
    with pytest.raises(pydynrad.errors.OutOfMemoryError, match="path tracing a 16384 x 8192 image needs about 10.0 GiB"):
        pydynrad.path_trace(box, camera, spp=1, device=device)


def test_resolution_needing_more_than_memory_is_refused(monkeypatch, box, device):
    with pytest.raises(InvalidInputError, match=r"resolution must lie in 2\.\.4096; got 8192"):
        pydynrad.form_factors(box, resolution=8192, rows=[0], device=device)
    monkeypatch.setattr(pydynrad.formfactors, "available_host_bytes", lambda: 8 * 2**30)
    with pytest.raises(pydynrad.errors.OutOfMemoryError, match="resolution 4096 needs about 11.2 GiB .* 8.0 GiB is available"):
        pydynrad.form_factors(box, resolution=4096, rows=[0], device=device)  # main: 11 GiB in numpy first


def test_available_memory_obeys_rlimit_as():
    code = textwrap.dedent("""
        import resource
        from pydynrad.host.memory import available_host_bytes
        size = next(int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith("VmSize:"))
        resource.setrlimit(resource.RLIMIT_AS, (size + 2**30, resource.getrlimit(resource.RLIMIT_AS)[1]))
        print(available_host_bytes())
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 0.9 * 2**30 < int(out.stdout) <= 2**30  # main: MemAvailable, whatever ulimit -v said


@pytest.mark.parametrize("layout", ["v2", "v1"])
def test_available_memory_obeys_the_cgroup_limit(monkeypatch, tmp_path, layout):
    from pydynrad.host import memory

    folder = tmp_path if layout == "v2" else tmp_path / "memory"
    folder.mkdir(exist_ok=True)
    limit, usage, stat = (("memory.max", "memory.current", "inactive_file") if layout == "v2" else
                          ("memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file"))
    (folder / limit).write_text(f"{2 * 2**30}\n")
    (folder / usage).write_text(f"{3 * 2**29}\n")
    (folder / "memory.stat").write_text(f"anon 123\n{stat} {2**28}\n")
    monkeypatch.setattr(memory, "CGROUP_ROOT", tmp_path)
    assert memory._cgroup_bytes() == 2 * 2**30 - 3 * 2**29 + 2**28  # the limit, less usage, plus reclaimable cache
    assert memory.available_host_bytes() <= 3 * 2**28  # main: MemAvailable of the whole machine
    (folder / limit).write_text("max\n")
    assert memory._cgroup_bytes() is None


def test_rows_are_checked_once_on_their_way_to_the_local_set(monkeypatch, box, box_F, device):
    import pydynrad.rows.sources as sources
    from pydynrad.dynamic.localrows import LocalRows
    from pydynrad.rows.cache import RowCache

    in_memory = sources.CSRRows(box_F)  # checks its matrix once, here
    calls = []
    real = sources.check_form_factor_rows
    monkeypatch.setattr(sources, "check_form_factor_rows", lambda *a, **k: calls.append(1) or real(*a, **k))
    idx = np.array([3, 1, 4])
    want = sp.csr_matrix(box_F, dtype=np.float64)[idx].toarray()
    with RowCache(in_memory, 2**20) as cache:
        for source in (cache, cache.source):
            got = LocalRows(box, source, 8, device).rows(idx)
            assert got.dtype == np.float64 and np.array_equal(got.toarray(), want)
    assert calls == []  # main: checked again by the cache and again by LocalRows
    bare = type("Bare", (), {"n_patches": len(box), "rows": lambda self, i: sp.csr_matrix(box_F)[i]})()
    assert np.array_equal(LocalRows(box, bare, 8, device).rows(idx).toarray(), want)
    assert len(calls) == 1  # a source without the contract is checked by its reader


def test_albedos_near_one_are_solved_or_named_for_what_they_are(device):
    # A Scene takes albedos below 1. At 0.9995 the radiosity bound with F's row-sum slack was
    # infinite and every light was refused as "beyond float32: scale the lights down", which
    # could not help; the bound now takes the albedo alone there, the dynamic solution answers
    # as the dense solve does, and the bounce iteration names the bounces it would need.
    box = pydynrad.scenes.closed_box(subdivisions=0, emission=0.0)
    F = pydynrad.form_factors(box, resolution=64, device=device)
    bright = box.with_materials(albedo=0.9995, emission=np.where(box.source_face // 2 == 4, 1.0, 0.0))
    ref = pydynrad.solve(bright, F, method="dense", dtype=np.float64, device=device).radiosity
    dyn = pydynrad.DynamicRadiosity(bright, F, local_size=len(bright), far_field=False, storage="fp64",
                                    observer=[0.5, 0.5, 0.5], device=device)
    B = dyn.radiosity()
    assert ref.max() > 300  # about 1 / (1 - 0.9995) / 6 faces' worth
    np.testing.assert_allclose(B, ref, rtol=1e-12, atol=1e-12 * ref.max())
    with pytest.raises(pydynrad.errors.ConvergenceError, match="albedos near 1 need about"):
        pydynrad.solve(bright, F, tol=1e-8, dtype=np.float64, device=device)
    # K itself past fp16's range is refused at the build, not stored as inf with a warning.
    brighter = box.with_materials(albedo=0.999999, emission=np.where(box.source_face // 2 == 4, 1.0, 0.0))
    with pytest.raises(InvalidInputError, match="beyond fp16's range"), pytest.warns(PrecisionWarning):
        pydynrad.DynamicRadiosity(brighter, F, local_size=len(brighter), far_field=False, storage="fp16",
                                  observer=[0.5, 0.5, 0.5], device=device)


def test_residual_is_scaled_by_k_not_by_a_column_of_rounding_residue(device):
    # Patches that no other local patch sees have a zero column in a fresh K and rounding
    # residue after exact swaps; scaled by that column's own maximum the residual read ~1 for
    # a K accurate to 1e-6 and refreshed it for nothing.
    box = pydynrad.scenes.cornell_box(max_edge=200.0)
    F = pydynrad.form_factors(box, resolution=64, device=device)
    a, b = np.array([50.0, 100.0, 50.0]), np.array([500.0, 450.0, 500.0])
    dyn = pydynrad.DynamicRadiosity(box, F, local_size=128, update="exact", storage="fp32", far_field=False,
                                    observer=a, device=device)
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


def test_bake_and_store_arguments_are_refused_before_the_solve(tmp_path, capsys, monkeypatch):
    """Values only found after the form factors and the solve (or, for a store, after it was
    half made) are refused by the parser, and an unwritable folder before any work."""
    from helpers import run_main

    bake = ["bake", "parallel_plates", "--resolution", "8", "-o", str(tmp_path / "m.glb")]
    for extra, message in ((["--crease-angle", "nan"], "expected a number in 0..180"),
                           (["--lightmap", str(tmp_path / "l.exr"), "--padding", "100"], "whole number in 1..64"),
                           (["--lightmap", str(tmp_path / "l.exr"), "--texels-per-unit", "1e9"], "texels")):
        code, out, err = run_main(bake + extra, capsys)
        assert code == 2 and message in err and "solved" not in out, (extra, err)
    code, _, err = run_main(["formfactors", "parallel_plates", "-o", str(tmp_path / "store"), "--clusters", "4",
                             "--cluster-resolution", "7", "--resolution", "8"], capsys)
    assert code == 2 and "even" in err and not (tmp_path / "store").exists()
    assert not list(tmp_path.iterdir())
    # A folder the process may not write into (root passes permission bits, so it is simulated).
    import pydynrad.atomic as atomic

    monkeypatch.setattr(atomic.os, "access", lambda path, mode, **kw: False)
    code, out, err = run_main(bake, capsys)
    assert code == 2 and "is not writable" in err and "solved" not in out


def test_a_failed_write_names_the_file_asked_for(tmp_path):
    from pydynrad.atomic import write_atomic

    def refuse(tmp):
        raise PermissionError(1, "Operation not permitted", str(tmp))

    with pytest.raises(PermissionError, match=r"cannot write '.*out\.glb': Operation not permitted") as info:
        write_atomic(tmp_path / "out.glb", refuse)
    assert ".tmp-" not in str(info.value) and not list(tmp_path.iterdir())


def test_sensors_and_bakes_refuse_what_would_come_back_as_inf_or_text(tmp_path):
    from pydynrad.photometry import illuminance
    from pydynrad.lights import LuminaireLight, PhotometricDistribution

    plates = pydynrad.scenes.parallel_plates(subdivisions=1)
    # 1e39 cd is inf in the device's table (inf times a zero weight: NaN at the sensor), and 1e30
    # cd times 1e10 passes float32 at the sensor: both came back as NaN or inf with a warning.
    for lum, message in ((LuminaireLight((0.5, 0.5, 0.5), PhotometricDistribution.isotropic(1e39)), "candela table"),
                         (LuminaireLight((0.5, 0.5, 0.5), PhotometricDistribution.isotropic(1e30), scale=1e10),
                          "illuminance overflows float32")):
        with pytest.raises(InvalidInputError, match=message):
            illuminance(plates, None, [[0.5, 0.5, 0.0]], [0, 0, 1], lights=lum)
    with pytest.raises(InvalidInputError, match="radiosity must be numbers"):
        pydynrad.bake.export_mesh(plates, np.full((len(plates), 3), "1"), tmp_path / "m.glb")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("text", ["point:pos=1,2,3;intensity=1_000", "point:pos=1,2,3;intensity=５",
                                  "point:pos=1,2,3;intensity=\u0665", "point:pos=0x10,2,3;intensity=5"])
def test_light_text_takes_plain_numbers_only(text):
    # Python's float() reads "1_000" and other scripts' digits: a typo must not become a light.
    from pydynrad.lights.text import parse_light

    with pytest.raises(InvalidInputError, match="must be"):
        parse_light(text)


def test_a_sky_resolution_of_a_fraction_is_refused_not_cut():
    from pydynrad.lights.text import parse_light

    with pytest.raises(InvalidInputError, match="resolution must be an integer; got 64.5"):
        parse_light("sky:model=uniform;zenith=100;resolution=64.5")
    assert parse_light("sky:model=uniform;zenith=100;resolution=32").resolution == 32


def test_review_of_the_days_fixes(tmp_path, capsys, device):
    """What a review of this landing's fixes found they had broken, each kept working."""
    from helpers import run_main
    from pydynrad.atomic import write_atomic
    from pydynrad.lights.sources import check_radiosity_range
    from pydynrad.lights import LuminaireLight, PhotometricDistribution

    # A grazing point light of 1e37 W/sr 1 mm over a unit floor: I / r^2 passes float32 before
    # the cosine comes in; the irradiance itself (I cos / r^2 at most 2.4e37) does not.
    plates = pydynrad.scenes.parallel_plates(subdivisions=2)
    for light in (pydynrad.PointLight((0.5, 0.5, 0.001), 1e37),
                  LuminaireLight((0.5, 0.5, 0.001), PhotometricDistribution.isotropic(1e37))):
        E = pydynrad.lights.direct_irradiance(plates, [light], device).astype(np.float64)
        assert np.isfinite(E).all() and 1e35 < E.max() < 3.4e38
    # The radiosity bound grows with the albedo: a higher albedo never passes where a lower fails.
    L = np.full((4, 3), 1e33)
    refused = []
    for rho in (0.998, 0.999, 0.9990009, 0.99901, 0.9995, 0.99999):
        try:
            check_radiosity_range(L, np.full((4, 3), rho), np.float32)
            refused.append(False)
        except InvalidInputError:
            refused.append(True)
    assert refused == sorted(refused), refused
    # A write that fails for another file, or is already worded, passes through as it is.
    def other(tmp):
        raise FileNotFoundError(2, "No such file or directory", "/elsewhere/source.png")

    with pytest.raises(FileNotFoundError) as info:
        write_atomic(tmp_path / "x.png", other)
    assert info.value.filename == "/elsewhere/source.png"
    long_name = tmp_path / ("a" * 240 + ".npz")
    write_atomic(long_name, b"data")
    assert long_name.read_bytes() == b"data"
    # The CLI's numbers: whitespace around them is fine, underscores are not.
    code, _, err = run_main(["render", "cornell_box", "--max-edge", "250", "--resolution", "8", "--size", "16x12",
                             "--position", "278,\t273,-800", "-o", str(tmp_path / "c.png")], capsys)
    assert code == 0, err
    code, _, err = run_main(["bake", "parallel_plates", "--resolution", "8", "-o", str(tmp_path / "m.glb"),
                             "--lightmap", str(tmp_path / "l.exr"), "--padding", "1_0"], capsys)
    assert code == 2 and "whole number in 1..64" in err
    # A scene with no light at all is black for that reason, not the camera's.
    code, _, err = run_main(["render", "parallel_plates", "--resolution", "8", "--size", "16x12", "-o",
                             str(tmp_path / "p.png")], capsys)
    assert code == 0 and "the scene has no light" in err


def test_photometric_files_the_review_found_refused_still_read():
    from bench.cie171_data import LM63_EXAMPLE
    from pydynrad.lights import parse_ies, parse_ldt
    from test_luminaires import ldt_text

    # A DOS end-of-file mark after the table.
    assert parse_ies(LM63_EXAMPLE.rstrip() + "\r\n\x1a").candela.max() == parse_ies(LM63_EXAMPLE).candela.max()
    # Isym = 0 with two planes C0 and C180 goes round the circle; one plane is rotational.
    two = parse_ldt(ldt_text(0, 2, 180.0, [0.0, 90.0], [[100.0, 50.0], [80.0, 40.0]]))
    assert two.c_angles.tolist() == [0.0, 180.0, 360.0]
    assert parse_ldt(ldt_text(0, 1, 0.0, [0.0, 90.0], [[100.0, 50.0]])).c_angles.tolist() == [0.0]
