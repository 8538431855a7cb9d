import numpy as np
import pytest

from pydynrad.checks import finite, integer, number, scene, vec3
from pydynrad.errors import InvalidInputError


def test_vec3_accepts_three_finite_numbers():
    a = vec3([1, 2.5, np.float32(-3)], "p")
    assert a.dtype == np.float64 and a.tolist() == [1.0, 2.5, -3.0]


@pytest.mark.parametrize("value, message", [
    ((1, 2), r"observer must be a 3-vector .* shape \(2,\)"),
    ([[1, 2, 3]], r"shape \(1, 3\)"),
    ("abc", "observer must be numbers; got 'abc'"),
    ((0, np.nan, 0), r"observer must be finite .*nan"),
    ((0, 0, np.inf), "NaN or infinite"),
])
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
    with pytest.raises(InvalidInputError, match="scene must be a pydynrad.Scene; got str"):
        scene("cornell_box")


def test_public_entry_points_reject_non_numbers_and_non_scenes():
    import pydynrad

    with pytest.raises(InvalidInputError, match="PointLight.intensity must be numbers; got 'bright'"):
        pydynrad.PointLight((0, 0, 0), "bright")
    with pytest.raises(InvalidInputError, match="SpotLight.inner_angle"):
        pydynrad.SpotLight((0, 0, 0), (0, 0, 1), 1.0, "narrow", 0.2)
    with pytest.raises(InvalidInputError, match="camera fov_y"):
        pydynrad.Camera((0, 0, -1), (0, 0, 0), fov_y="wide")
    light = pydynrad.PointLight((0, 0, 0), 1.0)
    for call in (lambda: pydynrad.light_vector(None, [light]), lambda: pydynrad.direct_irradiance(None, [light]),
                 lambda: pydynrad.form_factors("box"), lambda: pydynrad.multibounce(None, np.eye(3))):
        with pytest.raises(InvalidInputError, match="scene must be a pydynrad.Scene"):
            call()
