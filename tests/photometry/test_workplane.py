"""Work planes (EN 12464-1 grids), their statistics, CSV and false-colour plot."""

import csv
import math

import numpy as np
import pytest

import pydynrad
from pydynrad import InvalidInputError, PointLight
from pydynrad.photometry import (
    en12464_spacing,
    illuminance,
    illuminance_statistics,
    plot_work_plane,
    work_plane,
    write_illuminance_csv,
)


def test_en12464_spacing_rule():
    # p = 0.2 * 5^log10(d): 0.2 m at 1 m, 1 m at 10 m, 5 m at 100 m, capped at 10 m.
    assert [en12464_spacing(d) for d in (1.0, 10.0, 100.0, 1000.0)] == pytest.approx([0.2, 1.0, 5.0, 10.0])
    with pytest.raises(InvalidInputError, match="positive length"):
        en12464_spacing(0.0)


def test_rectangular_room_grid():
    plane = work_plane([[0, 0], [4, 0], [4, 3], [0, 3]], 0.8)
    p = 0.2 * 5 ** math.log10(4)  # 0.527 m: 8 x 6 cells of 0.5 m
    assert plane.shape == (6, 8) and len(plane) == 48
    assert plane.spacing == pytest.approx((0.5, 0.5)) and max(plane.spacing) <= p
    np.testing.assert_allclose(np.unique(plane.points[:, 0]), 0.25 + 0.5 * np.arange(8))
    np.testing.assert_allclose(plane.points[:, 2], 0.8)
    np.testing.assert_array_equal(plane.normals, np.tile([0, 0, 1.0], (48, 1)))


def test_l_shaped_room_and_border():
    L = [[0, 0], [4, 0], [4, 2], [2, 2], [2, 4], [0, 4]]
    plane = work_plane(L, 0.0, spacing=0.5)
    x, y = plane.points[:, 0], plane.points[:, 1]
    assert len(plane) == 64 - 16  # the 2 x 2 m notch holds 16 of the 8 x 8 cells
    assert not np.any((x > 2) & (y > 2))
    inner = work_plane(L, 0.0, spacing=0.5, border=0.5)
    xi, yi = inner.points[:, 0], inner.points[:, 1]
    # Cell centres at 0.25 + 0.5 k: the strip removes the outer ring (6 x 6 left) and every
    # centre within 0.5 of the notch's corner edges, i.e. the 4 x 4 with x, y > 1.5 (1.75: 0.35 from (2, 2)).
    assert np.all((xi >= 0.5) & (yi >= 0.5) & (xi <= 3.5) & (yi <= 3.5))
    assert not np.any((xi > 1.5) & (yi > 1.5))
    assert len(inner) == 36 - 16
    y_plane = work_plane([[0, 0], [1, 0], [1, 1]], 2.5, spacing=0.25, up=1)
    np.testing.assert_allclose(y_plane.points[:, 1], 2.5)
    np.testing.assert_array_equal(y_plane.normals[0], [0, 1, 0])


def test_bad_work_planes_are_refused():
    with pytest.raises(InvalidInputError, match="polygon"):
        work_plane([[0, 0], [1, 1]], 0.0)
    with pytest.raises(InvalidInputError, match="no area"):
        work_plane([[0, 0], [1, 1], [2, 2]], 0.0)
    with pytest.raises(InvalidInputError, match="no grid point"):
        work_plane([[0, 0], [1, 0], [1, 1], [0, 1]], 0.0, border=0.6)


def test_statistics_csv_and_plot_of_a_lit_work_plane(tmp_path, device):
    # A 4 x 4 m floor at z = 0 under a 1,000 cd point light 2 m above its centre; no reflections.
    pts = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]], float)
    scene = pydynrad.Scene(pts, [[0, 1, 2], [0, 2, 3]], albedo=0.0)
    plane = work_plane(pts[:, :2], 0.75)
    E = illuminance(scene, None, plane.points, plane.normals, lights=PointLight([2, 2, 2.75], 1000.0), device=device)
    d = plane.points - [2, 2, 2.75]
    expected = 1000.0 * 2.0 / np.linalg.norm(d, axis=1) ** 3  # I cos / r^2, cos = h / r
    np.testing.assert_allclose(E[:, 0], expected, rtol=1e-6)
    stats = write_illuminance_csv(tmp_path / "plane.csv", plane.points, E)
    assert stats.Em == pytest.approx(expected.mean(), rel=1e-6)
    assert stats.U0 == pytest.approx(expected.min() / expected.mean(), rel=1e-6)
    lines = (tmp_path / "plane.csv").read_text().splitlines()
    table = dict(line[2:].split(" = ") for line in lines if line.startswith("# "))  # the statistics, as comments
    rows = list(csv.reader(line for line in lines if not line.startswith("#")))
    assert rows[0] == ["x", "y", "z", "E_lx"] and len(rows) == 1 + len(plane)
    np.testing.assert_allclose(np.array(rows[1 : 1 + len(plane)], float)[:, 3], expected, rtol=1e-5)
    assert float(table["U0"]) == pytest.approx(stats.U0, rel=1e-5) and int(table["n"]) == len(plane)
    from pydynrad.photometry.report import _cell

    assert _cell(1_234_567) == "1234567"  # a count whole past 6 digits (was 1.23457e+06)
    plot_work_plane(tmp_path / "plane.png", plane, E, title="point light")
    import matplotlib.image

    assert matplotlib.image.imread(tmp_path / "plane.png").shape[2] in (3, 4)
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir())  # no temporary debris


def test_statistics_by_hand():
    s = illuminance_statistics([100.0, 200.0, 300.0])
    assert (s.Em, s.Emin, s.Emax, s.U0, s.Ud, s.n) == pytest.approx((200.0, 100.0, 300.0, 0.5, 1 / 3, 3))
    with pytest.raises(InvalidInputError, match="finite"):
        illuminance_statistics([1.0, np.nan])


def test_a_plot_name_is_checked_by_its_own_suffix_before_drawing(tmp_path):
    plane = work_plane([[0, 0], [4, 0], [4, 3], [0, 3]], 0.75)
    with pytest.raises(InvalidInputError, match="use one of png, pdf, svg"):
        plot_work_plane(tmp_path / "plane.xyz", plane, np.ones(len(plane)))
    (tmp_path / "a.b").mkdir()
    plot_work_plane(tmp_path / "a.b" / "plane", plane, np.ones(len(plane)))  # a dotted folder: png
    assert (tmp_path / "a.b" / "plane").read_bytes()[:4] == b"\x89PNG"


def test_elongated_areas_take_the_shorter_side_and_the_csv_round_trips(tmp_path):
    """EN 12464-1: a side at least twice the other makes d the shorter one (10 m x 2 m: p for
    2 m); the CSV writes every coordinate as it round-trips (0.5 m apart at 4e6 m); a dark
    plane's uniformities are written as undefined, a negative illuminance is refused."""
    plane = work_plane([[0, 0], [10, 0], [10, 2], [0, 2]], 0.8)
    assert max(plane.spacing) <= en12464_spacing(2.0) < en12464_spacing(10.0)
    # 10 m x 6 m is not elongated: d is the longer side (the shorter's p would be 0.70 m)
    assert work_plane([[0, 0], [10, 0], [10, 6], [0, 6]], 0.8).spacing == (en12464_spacing(10.0),) * 2
    far = work_plane([[500000, 4000000], [500004, 4000000], [500004, 4000003], [500000, 4000003]], 12.75)
    out = tmp_path / "e.csv"
    write_illuminance_csv(out, far.points, np.zeros(len(far)))
    lines = out.read_text().splitlines()
    rows = list(csv.reader(line for line in lines if not line.startswith("#")))
    pts = np.array([[float(v) for v in r[:3]] for r in rows[1 : 1 + len(far)]])
    np.testing.assert_array_equal(pts, far.points)
    assert "# U0 = undefined" in lines
    with pytest.raises(InvalidInputError, match=">= 0"):
        illuminance_statistics([-1.0, 2.0, 3.0])
    with pytest.raises(InvalidInputError, match="not a matplotlib colour map"):
        plot_work_plane(tmp_path / "p.png", far, np.ones(len(far)), cmap="nope")
    import matplotlib

    viridis = matplotlib.colormaps["viridis"]  # a Colormap, as imshow takes it, not only its name
    assert plot_work_plane(tmp_path / "v.png", far, np.ones(len(far)), cmap=viridis).Em == 1.0
    with pytest.raises(InvalidInputError, match="must be a WorkPlane"):
        plot_work_plane(tmp_path / "p.png", None, np.ones(3))
