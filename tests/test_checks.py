import numpy as np
import pytest

import pydynrad
from pydynrad.checks import finite, integer, number, vec3
from pydynrad.errors import InvalidInputError
from pydynrad.geometry.loading import checked_scene as scene


def test_vec3_accepts_three_finite_numbers():
    a = vec3([1, 2.5, np.float32(-3)], "p")
    assert a.dtype == np.float64 and a.tolist() == [1.0, 2.5, -3.0]


@pytest.mark.parametrize(
    "value, message",
    [
        ((1, 2), r"observer must be a 3-vector .* shape \(2,\)"),
        ([[1, 2, 3]], r"shape \(1, 3\)"),
        ("abc", "observer must be numbers; got 'abc'"),
        ((0, np.nan, 0), r"observer must be finite .*nan"),
        ((0, 0, np.inf), "NaN or infinite"),
    ],
)
def test_vec3_names_the_bad_value(value, message):
    with pytest.raises(InvalidInputError, match=message):
        vec3(value, "observer")


def test_integer_range_and_type():
    assert integer(np.int64(4), "k", 1, 4) == 4 and type(integer(np.int64(4), "k")) is int
    for bad in (True, 2.0, "3", None):
        with pytest.raises(InvalidInputError, match="k must be an integer"):
            integer(bad, "k")
    with pytest.raises(InvalidInputError, match=r"k must lie in 1\.\.4; got 5"):
        integer(5, "k", 1, 4)
    with pytest.raises(InvalidInputError, match="k must be >= 1; got 0"):
        integer(0, "k")


def test_finite_names_the_first_bad_element():
    finite(np.ones((2, 3)), "K")
    with pytest.raises(InvalidInputError, match=r"x contains NaN or infinite values \(1 of 4; first at index 2: nan\)"):
        finite(np.array([0.0, 1.0, np.nan, 3.0]), "x")
    with pytest.raises(InvalidInputError, match=r"\(2 of 6; first at index \(1, 0\): inf\)"):
        finite(np.array([[0, 1, 2], [np.inf, 4, -np.inf]]), "B")


def test_number_and_scene():
    assert number(np.float32(1.5), "fov") == 1.5
    for bad in ("wide", None, (1, 2), np.nan):
        with pytest.raises(InvalidInputError, match="fov must be"):
            number(bad, "fov")
    with pytest.raises(InvalidInputError, match="scene must be a pydynrad.Scene or a trimesh mesh; got str"):
        scene("cornell_box")
    # A Python int past float64 is a value error with a message a line long, not an OverflowError.
    with pytest.raises(InvalidInputError, match=r"fov must be one finite number; got 1000.{0,60}\.\.\. \(int\)$"):
        number(10**400, "fov")
    with pytest.raises(InvalidInputError, match="within float64's range"):
        pydynrad.PointLight((0.0, 0.0, 10**400), (1.0, 1.0, 1.0))


def test_public_entry_points_reject_non_numbers_and_non_scenes():
    import pydynrad

    with pytest.raises(InvalidInputError, match="PointLight.intensity must be numbers; got 'bright'"):
        pydynrad.PointLight((0, 0, 0), "bright")
    with pytest.raises(InvalidInputError, match="SpotLight.inner_angle"):
        pydynrad.SpotLight((0, 0, 0), (0, 0, 1), 1.0, "narrow", 0.2)
    with pytest.raises(InvalidInputError, match="camera fov_y"):
        pydynrad.Camera((0, 0, -1), (0, 0, 0), fov_y="wide")
    # Text that spells a number is refused too (numpy alone would parse "45" as 45.0), as
    # integers refuse it.
    with pytest.raises(InvalidInputError, match="camera fov_y must be one finite number; got '45'"):
        pydynrad.Camera((0, 0, -1), (0, 0, 0), fov_y="45")
    with pytest.raises(InvalidInputError, match="PointLight.position must be numbers"):
        pydynrad.PointLight(("0", 0, 0), 1.0)
    with pytest.raises(InvalidInputError, match="PointLight.intensity must be numbers"):
        pydynrad.PointLight((0, 0, 0), np.array(["1e3"] * 3, dtype=object))
    assert pydynrad.Camera((0, 0, -1), (0, 0, 0), fov_y=np.float32(45)).fov_y == 45.0
    light = pydynrad.PointLight((0, 0, 0), 1.0)
    for call in (
        lambda: pydynrad.light_vector(None, [light]),
        lambda: pydynrad.lights.direct_irradiance(None, [light]),
        lambda: pydynrad.form_factors("box"),
        lambda: pydynrad.multibounce(None, np.eye(3)),
    ):
        with pytest.raises(InvalidInputError, match="scene must be a pydynrad.Scene"):
            call()


def _index_takers(device, tmp_path):
    """Every public entry point that takes patch indices, as f(indices) on one 16-patch scene."""
    import pydynrad
    from pydynrad.rows.cache import RowCache

    s = pydynrad.scenes.parallel_plates(subdivisions=1)
    F = pydynrad.form_factors(s, resolution=8, device=device)
    store = pydynrad.compute_store(s, tmp_path / "store", resolution=8, block_rows=4, progress=False, device=device)
    cache = RowCache(store, 2**20)
    takers = {
        "form_factors rows": lambda i: pydynrad.form_factors(s, resolution=8, rows=i, device=device),
        "CSRRows": lambda i: pydynrad.rows.CSRRows(F).rows(i),
        "FormFactorStore": store.rows,
        "RowCache": cache.rows,
        "HemicubeRows": lambda i: pydynrad.rows.HemicubeRows(s, 8, device).rows(i),
        "multibounce patches": lambda i: pydynrad.multibounce(s, F, patches=i, device=device),
        "path_trace_patches": lambda i: pydynrad.pathtracer.path_trace_patches(s, patches=i, spp=1, device=device),
    }
    return s, takers, cache


@pytest.mark.parametrize(
    "bad, message",
    [
        ([0.5], r"1-D array of integers; got shape \(1,\), dtype float64"),
        ([[0, 1]], r"1-D array of integers; got shape \(1, 2\)"),
        ([0, 16], r"patch indices in 0\.\.15; got values in \[0, 16\]"),
        ([-1], r"patch indices in 0\.\.15; got values in \[-1, -1\]"),
    ],
)
def test_one_patch_index_rule_everywhere(device, tmp_path, bad, message):
    s, takers, cache = _index_takers(device, tmp_path)
    try:
        for name, take in takers.items():
            with pytest.raises(InvalidInputError, match=message):
                take(bad)
            assert np.shape(take(np.array([3, 1]))) == (
                (2, 3) if name == "path_trace_patches" else (1, 2, 2) if name == "multibounce patches" else (2, len(s))
            )
    finally:
        cache.close()


def test_repeats_and_empty_sets_only_refused_where_they_mean_nothing(device, tmp_path):
    """K's rows and columns are its patches: repeated or no patches are an error there; a
    row source may serve a row twice, and no rows."""
    s, takers, cache = _index_takers(device, tmp_path)
    try:
        with pytest.raises(InvalidInputError, match=r"patches contains repeated indices, e.g. \[1\]"):
            takers["multibounce patches"]([1, 1])
        with pytest.raises(InvalidInputError, match="patches must not be empty"):
            takers["multibounce patches"]([])
        for name in ("form_factors rows", "CSRRows", "FormFactorStore", "RowCache"):
            assert takers[name]([]).shape == (0, len(s))
            rows = takers[name]([1, 1]).toarray()
            np.testing.assert_array_equal(rows[0], rows[1])
    finally:
        cache.close()


@pytest.mark.parametrize(
    "bad, message", [(3, "even"), (0, r"2\.\.4096"), (4098, r"2\.\.4096"), (8.0, "integer"), (True, "integer")]
)
def test_one_resolution_rule_everywhere(device, tmp_path, bad, message):
    """Whatever form_factors rejects, no store, file, solver or CLI option accepts or records."""
    import scipy.sparse as sp

    import pydynrad
    from pydynrad.cli.main import build_parser

    s = pydynrad.scenes.parallel_plates(subdivisions=0)
    F = sp.csr_matrix((len(s), len(s)), dtype=np.float32)
    takers = [
        lambda R: pydynrad.form_factors(s, resolution=R, device=device),
        lambda R: pydynrad.FormFactorStore.create(s, tmp_path / "st", resolution=R),
        lambda R: pydynrad.compute_store(s, tmp_path / "st", resolution=R, progress=False, device=device),
        lambda R: pydynrad.save_form_factors(s, tmp_path / "f.npz", F, R),
        lambda R: pydynrad.rows.HemicubeRows(s, R, device),
        lambda R: pydynrad.DynamicRadiosity(s, None, local_size=1, resolution=R, device=device),
    ]
    for take in takers:
        with pytest.raises(InvalidInputError, match=message):
            take(bad)
    assert not (tmp_path / "st").exists() and not (tmp_path / "f.npz").exists()
    if isinstance(bad, int) and not isinstance(bad, bool):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["render", "cornell_box", "-o", "x.png", "--resolution", str(bad)])


def test_booleans_are_not_numbers():
    """A path file's ``"radius": true`` had been a radius of 1, ``"width": "32"`` 32 pixels."""
    from pydynrad.geometry.camera import Camera

    with pytest.raises(InvalidInputError, match="True or False"):
        pydynrad.checks.floats([1.0, True], "radius")
    with pytest.raises(InvalidInputError, match="fov must be one finite number"):
        number(True, "fov")
    with pytest.raises(InvalidInputError, match="whole number of pixels"):
        Camera(position=(0, 0, -5), look_at=(0, 0, 0), width="32", height=24)


def test_form_factors_with_a_diagonal_or_complex_entries_are_refused():
    """A flat patch sees none of itself: a non-zero F[i, i] is another matrix's rows or a shifted
    index; complex entries had lost their imaginary part with only numpy's warning."""
    import scipy.sparse as sp

    from pydynrad.checks import check_form_factors

    scene = pydynrad.scenes.cornell_box(max_edge=250.0)
    n = len(scene)
    F = sp.random(n, n, density=0.01, random_state=1, format="csr") * 0.01
    F.setdiag(0.0)
    F.eliminate_zeros()
    assert check_form_factors(scene, F).nnz == F.nnz
    shifted = F.tolil()
    shifted[5, 5] = 0.001
    with pytest.raises(InvalidInputError, match=r"F\[5, 5\] = 0.001"):
        check_form_factors(scene, shifted.tocsr())
    with pytest.raises(InvalidInputError, match="real numbers"):
        check_form_factors(scene, F.astype(np.complex128))
