"""Hostile input: what used to crash the process or answer wrongly is refused, naming the problem.

Each test here was once a defect; the broken-F cases that segfaulted run in a
subprocess, so a crash fails the test instead of killing the run."""

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


KINDS = {
    "column out of range": r"row 0 has column index 1000048 outside 0\.\.47",
    "negative column": r"row 47 has column index -1 outside 0\.\.47",
    "1-based": r"column index 48 outside 0\.\.47 \(1-based indices\?",
    "negative indptr": r"row 4 has a negative length \(indptr decreases from \d+ to -3\)",
    "reversed indptr": r"row 5 has a negative length",
}


@pytest.mark.parametrize("kind", KINDS)
def test_broken_F_is_refused_by_every_entry_point(closed_box_48, closed_box_48_F, device, kind):
    G = _broken(closed_box_48_F, kind)
    calls = {
        "solve": lambda: pydynrad.solve(closed_box_48, G, device=device),
        "multibounce": lambda: pydynrad.multibounce(closed_box_48, G, np.arange(8), device=device),
        "DynamicRadiosity": lambda: pydynrad.DynamicRadiosity(closed_box_48, G, local_size=8, device=device),
        "CSRRows": lambda: pydynrad.rows.CSRRows(G),
        "CSC input": lambda: pydynrad.solve(
            closed_box_48, sp.csc_matrix((G.data, G.indices, G.indptr), shape=G.shape), device=device
        ),
    }
    for name, call in calls.items():
        with pytest.raises(InvalidInputError, match=KINDS[kind] if name != "CSC input" else "CSC"):
            call()


def test_broken_F_in_a_subprocess_fails_cleanly_instead_of_crashing(tmp_path):
    # multibounce with 1-based indices segfaulted before the structure checks.
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


@pytest.mark.parametrize(
    "size, subdivisions, resolutions, rows",
    [
        ((1, 1, 1), 2, (2, 6, 16, 64), None),
        ((3, 1, 0.1), 1, (2, 16, 64), None),
        # A thin box seen edge-on from its side walls: rays graze the big walls' shared edges. The
        # Moller-Trumbore test with slack lost one pixel of one of these rows at R = 128 (2.2e-5).
        ((1, 1, 0.01), 2, (16, 128), np.arange(128)),
    ],
)
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
    return pydynrad.Scene(base.vertices * scale + offset * SHIFT, base.faces, albedo=albedo, emission=emission)


@pytest.mark.parametrize(
    "scale, offset",
    [(1e-6, 0.0), (1e6, 0.0), (1.0, 1e6), (1.0, 1e7), (1e-3, 1e4), (1e6, -1e7), (1e-15, 0.0), (1e14, 0.0)],
)
def test_furnace_far_from_origin_and_at_extreme_scales(device, scale, offset):
    # Closed box, albedo 0.5, emission 1: B = E / (1 - rho) = 2 everywhere. Before the device
    # frame a unit box at 1e6 gave 1.961 and its F was empty at 1e14 or 1e-15.
    scene = _moved_box(scale, offset)
    F = pydynrad.form_factors(scene, resolution=16, device=device)
    B = pydynrad.solve(scene, F, device=device).radiosity
    assert np.abs(B / 2 - 1).max() < 1e-4  # observed 5.4e-7 at every scale and offset


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
        for call in (
            lambda: pydynrad.image_io.write_image(tmp_path / "z.exr", image, exposure=exposure),
            lambda: comparison_image(image, image, exposure),
            lambda: export_mesh(pydynrad.scenes.block(1.0, 0), np.ones((12, 3)), tmp_path / "m.glb", exposure=exposure),
        ):
            with pytest.raises(InvalidInputError, match="exposure"):
                call()
    assert not list(tmp_path.glob("[zm].*"))
    with pytest.raises(InvalidInputError, match="overflows float32"):
        pydynrad.image_io.write_image(tmp_path / "y.exr", np.full((2, 2, 3), 3e38, np.float32), exposure=1.0)


def test_a_walk_checks_every_frame_before_any_work_and_deep_json_is_named(
    closed_box_48, closed_box_48_F, tmp_path, device
):
    """A camera that degenerates mid-path (the position interpolated onto its look-at point) is
    refused before the solution is built, naming the frame (once: frame 0 was written first),
    and a path file nested too deeply for Python's parser is named (once: a RecursionError)."""
    import json

    doc = {
        "frames": 3,
        "interpolation": "linear",
        "width": 8,
        "height": 6,
        "keyframes": [
            {"position": [0.5, 0.5, -2.0], "look_at": [0.5, 0.5, 0.0]},
            {"position": [0.5, 0.5, 0.0], "look_at": [0.5, 0.5, -2.0]},
        ],
    }
    (tmp_path / "degenerate.json").write_text(json.dumps(doc))
    camera_path, _ = pydynrad.load_path(tmp_path / "degenerate.json")
    with pytest.raises(InvalidInputError, match="frame 1 of 3: camera look_at"):
        pydynrad.walk(
            closed_box_48,
            camera_path,
            form_factors=closed_box_48_F,
            local_size=16,
            output=tmp_path / "out",
            device=device,
        )
    assert not (tmp_path / "out").exists()
    (tmp_path / "out" / "frame_0001.png").mkdir(parents=True)  # a folder in a later frame's place
    good = pydynrad.fly_through([[0.5, 0.5, -2.0], [0.5, 0.5, -1.0]], 3, width=8, height=6)
    with pytest.raises(InvalidInputError, match="frame_0001.png': a folder of that name is in the way"):
        pydynrad.walk(
            closed_box_48, good, form_factors=closed_box_48_F, local_size=16, output=tmp_path / "out", device=device
        )
    assert not (tmp_path / "out" / "frame_0000.png").exists()
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(InvalidInputError, match="nested too deeply"):
        pydynrad.walks.load_walk(tmp_path / "deep.json")


def test_a_radiosity_past_float32_is_named_by_the_renderer(closed_box_48, device):
    """A float64 B from the dense solve can exceed float32; rendering it is refused as out of
    float32's range (once: "NaN or infinite values", of values that were neither)."""
    camera = pydynrad.Camera((0.5, 0.5, -2.0), (0.5, 0.5, 0.5), width=8, height=6)
    with pytest.raises(InvalidInputError, match="radiosity reaches 1e\\+39, beyond float32"):
        pydynrad.render(closed_box_48, np.full((len(closed_box_48), 3), 1e39), camera, device=device)


def test_unit_vectors_of_huge_and_tiny_lengths():
    """Directions are scaled before they are normalised: (1e300, -2e300, 1e301) overflowed the
    norm and became (0, 0, 0), a light that silently lit nothing; 1e-300 was refused as zero."""
    from pydynrad.checks import unit_vector

    d = np.array([1.0, -2.0, 10.0])
    for scale in (1e300, 1e-300, 1.0):
        np.testing.assert_allclose(unit_vector(d * scale, "direction"), d / np.linalg.norm(d), rtol=1e-15)
    sun = pydynrad.DirectionalLight(direction=d * 1e300, irradiance=(1.0, 1.0, 1.0))
    np.testing.assert_allclose(sun.direction, d / np.linalg.norm(d), rtol=1e-15)


@pytest.mark.parametrize(
    "frames, message",
    [("ten", "frames must be a whole number >= 1; got 'ten'"), (10**9, "frames must be at most 1,000,000")],
)
def test_path_file_frames_are_named(tmp_path, frames, message):
    import json

    path = tmp_path / "p.json"
    path.write_text(
        json.dumps(
            {
                "frames": frames,
                "width": 8,
                "height": 8,
                "fov_y": 40,
                "keyframes": [
                    {"position": [0.1, 0.5, 0.5], "look_at": [0.9, 0.5, 0.5]},
                    {"position": [0.2, 0.5, 0.5], "look_at": [0.9, 0.5, 0.5]},
                ],
            }
        )
    )
    with pytest.raises(InvalidInputError, match=message):  # main: "could not convert string to float"; 10^9 accepted
        pydynrad.paths.load_path(path)


def test_a_failed_write_names_the_file_asked_for(tmp_path):
    from pydynrad.atomic import write_atomic

    def refuse(tmp):
        raise PermissionError(1, "Operation not permitted", str(tmp))

    with pytest.raises(PermissionError, match=r"cannot write '.*out\.glb': Operation not permitted") as info:
        write_atomic(tmp_path / "out.glb", refuse)
    assert ".tmp-" not in str(info.value) and not list(tmp_path.iterdir())
