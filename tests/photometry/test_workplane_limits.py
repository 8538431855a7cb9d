"""Work planes over slivers and fine spacings: a floor on the default spacing, a cap on the points
(a 4 m x 1e-9 m sliver would get 4e7 points)."""

import time

import pytest

from pydynrad.errors import InvalidInputError
from pydynrad.photometry import en12464_spacing, work_plane
from pydynrad.photometry.workplane import MAX_WORK_PLANE_POINTS, MIN_SIDE_RATIO


def _rect(a, b):
    return [[0, 0], [a, 0], [a, b], [0, b]]


def test_a_sliver_gets_a_grid_along_its_length_quickly():
    t = time.perf_counter()
    plane = work_plane(_rect(4.0, 1e-9), 0.75)
    assert time.perf_counter() - t < 1.0
    # the width is read as 4 m / 1000: p for 4 mm, about 950 points along the 4 m
    assert plane.spacing[0] <= en12464_spacing(4.0 * MIN_SIDE_RATIO)
    assert plane.shape == (1, len(plane)) and 900 < len(plane) < 1000


@pytest.mark.parametrize("length", [1e-6, 1.0, 4.0, 1e3, 1e6])
def test_the_default_grid_stays_small_at_every_scale(length):
    assert len(work_plane(_rect(length, length * 1e-6), 0.75)) <= 100_000


def test_corridors_keep_the_rule_for_their_width():
    # 100 m x 1 m is well inside the floor: d is the 1 m width as before
    assert max(work_plane(_rect(100.0, 1.0), 0.8).spacing) <= en12464_spacing(1.0)


def test_too_many_points_are_refused_naming_the_numbers():
    with pytest.raises(InvalidInputError) as err:
        work_plane(_rect(4.0, 1e-9), 0.75, spacing=1e-7)
    msg = str(err.value)
    for part in (
        "40000000 x 1",
        "4e+07 grid points",
        "4 x 1e-09",
        "spacing 1e-07",
        f"max_points = {MAX_WORK_PLANE_POINTS}",
    ):
        assert part in msg
    # the cap is the caller's to raise, and is checked like any count
    assert len(work_plane(_rect(4.0, 1.0), 0.75, spacing=0.1, max_points=400)) == 400
    with pytest.raises(InvalidInputError, match="max_points = 399"):
        work_plane(_rect(4.0, 1.0), 0.75, spacing=0.1, max_points=399)
    for bad in (0, 2.5, True):
        with pytest.raises(InvalidInputError, match="max_points must"):
            work_plane(_rect(4.0, 1.0), 0.75, max_points=bad)
