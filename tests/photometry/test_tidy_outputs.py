"""Photometry outputs a user's tools read: the CSV is one table that numpy and pandas
read back; the plot leaves matplotlib's backend and pyplot's figures alone."""

import numpy as np
import pytest

from pydynrad.photometry import plot_work_plane, work_plane, write_illuminance_csv


def _plane_and_values():
    plane = work_plane([[0, 0], [4, 0], [4, 3], [0, 3]], 0.75)
    E = 100.0 + 10.0 * plane.points[:, 0]  # independent of pydynrad: a known field
    return plane, E


def test_csv_reads_back_with_numpy_genfromtxt_names(tmp_path):
    plane, E = _plane_and_values()
    stats = write_illuminance_csv(tmp_path / "e.csv", plane.points, E)
    table = np.genfromtxt(tmp_path / "e.csv", delimiter=",", names=True)
    assert table.dtype.names == ("x", "y", "z", "E_lx") and len(table) == len(plane)
    np.testing.assert_array_equal(np.column_stack([table["x"], table["y"], table["z"]]), plane.points)
    np.testing.assert_array_equal(table["E_lx"], E)
    assert stats.Em == pytest.approx(E.mean()) and stats.U0 == pytest.approx(E.min() / E.mean())
    comments = [line for line in (tmp_path / "e.csv").read_text().splitlines() if line.startswith("#")]
    assert comments[0] == f"# n = {len(plane)}" and any(c.startswith("# U0 = ") for c in comments)


def test_csv_reads_back_with_pandas(tmp_path):
    pd = pytest.importorskip("pandas")
    plane, E = _plane_and_values()
    write_illuminance_csv(tmp_path / "e.csv", plane.points, E)
    df = pd.read_csv(tmp_path / "e.csv", comment="#")
    assert list(df.columns) == ["x", "y", "z", "E_lx"] and len(df) == len(plane)
    np.testing.assert_array_equal(df["E_lx"].to_numpy(), E)


def test_plot_leaves_the_backend_and_pyplot_alone(tmp_path):
    matplotlib = pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt

    plane, E = _plane_and_values()
    before = matplotlib.get_backend()
    with matplotlib.rc_context():
        matplotlib.use("svg")  # stands for a notebook's inline backend: anything but Agg
        figures = plt.get_fignums()
        plot_work_plane(tmp_path / "p.png", plane, E)
        assert matplotlib.get_backend() == "svg" and plt.get_fignums() == figures
    matplotlib.use(before)
    assert (tmp_path / "p.png").stat().st_size > 0
