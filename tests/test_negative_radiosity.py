"""render and export_mesh refuse negative radiosity beyond rounding, and show rounding's as 0
(both had accepted negative radiosity)."""

import numpy as np
import pytest

import pydynrad
from pydynrad.errors import InvalidInputError
from pydynrad.smoothing import NEGATIVE_RADIOSITY_TOLERANCE, checked_radiosity


@pytest.fixture(scope="module")
def box():
    return pydynrad.scenes.closed_box(subdivisions=1)


def _camera():
    return pydynrad.Camera((0.5, 0.5, 0.05), (0.5, 0.5, 0.9), (0.0, 1.0, 0.0), 60.0, 16, 12)


def test_the_check_names_the_patch_and_the_numbers():
    b = np.ones((10, 3))
    b[7, 2] = -0.5
    with pytest.raises(InvalidInputError) as err:
        checked_radiosity(b, 10)
    msg = str(err.value)
    assert msg.startswith("radiosity is negative beyond rounding: patch 7 (channel 2) holds -0.5, 0.5 of")
    assert f"down to {NEGATIVE_RADIOSITY_TOLERANCE:g}" in msg and "1 values are" in msg
    with pytest.raises(InvalidInputError, match="negative beyond rounding: patch 0 .channel 0. holds -1e-09"):
        checked_radiosity(-1e-9 * np.ones(10), 10)  # nothing positive: any negative is beyond rounding


def test_rounding_is_read_as_zero():
    b = np.ones((10, 3))
    b[3] = -2e-8  # a float32 solve's rounding: shown as 0, not refused
    out = checked_radiosity(b, 10)
    assert out.min() == 0.0 and out[3].tolist() == [0.0, 0.0, 0.0] and out[4].tolist() == [1.0, 1.0, 1.0]
    assert not np.shares_memory(out, b) and b[3, 0] == -2e-8  # the caller's array is not changed
    np.testing.assert_array_equal(checked_radiosity(np.zeros(10), 10), 0.0)


def test_render_and_export_mesh_refuse_it(box, tmp_path, device):
    b = np.full((len(box), 3), 2.0)
    b[5] = -0.01
    with pytest.raises(InvalidInputError, match="radiosity is negative beyond rounding: patch 5"):
        pydynrad.render(box, b, _camera(), device=device)
    with pytest.raises(InvalidInputError, match="radiosity is negative beyond rounding: patch 5"):
        pydynrad.export_mesh(box, b, tmp_path / "m.glb")
    assert not (tmp_path / "m.glb").exists()
    b[5] = -1e-7  # rounding: rendered and written as 0
    img = pydynrad.render(box, b, _camera(), shading="flat", device=device)
    assert img.min() >= 0.0
    pydynrad.export_mesh(box, b, tmp_path / "m.ply")
    assert (tmp_path / "m.ply").stat().st_size > 0
