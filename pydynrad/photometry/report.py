"""What a lighting designer reads off a work plane: Em, Emin, Emax, U0, as CSV and as a picture."""

from __future__ import annotations

import csv
import io
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..atomic import check_file_target, write_atomic
from ..checks import floats
from ..errors import InvalidInputError, MissingExtraError
from .units import photometric
from .workplane import WorkPlane

__all__ = ["IlluminanceStats", "illuminance_statistics", "write_illuminance_csv", "plot_work_plane"]


@dataclass(frozen=True)
class IlluminanceStats:
    """Statistics of a grid of illuminances (lx): mean Em, minimum, maximum, uniformities
    U0 = Emin / Em (EN 12464-1) and Ud = Emin / Emax, over n points. On a plane without light
    (Em = 0) the uniformities are undefined: NaN here, ``undefined`` in the CSV and the plot."""

    n: int
    Em: float
    Emin: float
    Emax: float
    U0: float
    Ud: float


def _values(E) -> np.ndarray:
    """One value per point: (n,) as is, (n, 3) reduced by :func:`photometric`."""
    a = floats(E, "illuminance")
    if a.ndim == 2 and a.shape[1] == 3:
        a = photometric(a)
    if a.ndim != 1 or len(a) == 0 or not np.all(np.isfinite(a)):
        raise InvalidInputError(f"illuminance must be finite, (n,) or (n, 3) with n >= 1; got shape {np.shape(E)}")
    if a.min() < 0:
        raise InvalidInputError(f"illuminance must be >= 0 (light is not negative); got a minimum of {a.min():g}")
    return a


def _cell(v: float) -> str:
    """A statistic as the CSV and the plot write it: a count whole, a value in 6 digits, or
    ``undefined`` for NaN."""
    if isinstance(v, int):
        return str(v)
    return "undefined" if np.isnan(v) else f"{v:.6g}"


def illuminance_statistics(E) -> IlluminanceStats:
    """Em, Emin, Emax, U0, Ud of illuminances ``E`` ((n,), or (n, 3): Rec. 709-weighted)."""
    a = _values(E)
    em, lo, hi = float(a.mean()), float(a.min()), float(a.max())
    return IlluminanceStats(
        len(a), em, lo, hi, lo / em if em > 0 else float("nan"), lo / hi if hi > 0 else float("nan")
    )


def write_illuminance_csv(path, points, E) -> IlluminanceStats:
    """Write ``points`` (n, 3) and their illuminance ``E`` to a CSV file, atomically.

    One tidy table: a header row ``x,y,z,E_lx`` and one row per point, read back by
    ``numpy.genfromtxt(path, delimiter=",", names=True)`` and ``pandas.read_csv(path,
    comment="#")``. The statistics (n, Em, Emin, Emax, U0, Ud; ``undefined`` for NaN) follow
    the table as ``# name = value`` comment lines, which both skip (after the table, since
    genfromtxt takes its names from the first line, comment or not). Returns the statistics.
    """
    p = floats(points, "points")
    a = _values(E)
    if p.shape != (len(a), 3):
        raise InvalidInputError(f"points must have shape ({len(a)}, 3); got {p.shape}")
    stats = illuminance_statistics(a)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["x", "y", "z", "E_lx"])
    # Every number as it round-trips: 6 digits put points 0.5 m apart at 4e6 m on one place.
    w.writerows([repr(float(v)) for v in row] for row in np.column_stack([p, a]))
    buf.writelines(f"# {k} = {_cell(v)}\n" for k, v in asdict(stats).items())
    write_atomic(path, buf.getvalue().encode())
    return stats


def plot_work_plane(path, plane, E, title: str = "", cmap="jet") -> IlluminanceStats:
    """A false-colour picture of a :class:`~pydynrad.photometry.workplane.WorkPlane`'s illuminance.

    Cells outside the polygon stay blank; the colour bar is in lx; the title carries Em and U0.
    The format follows the file's suffix (png, pdf, svg). ``cmap``: a matplotlib colour map or
    its name. Needs matplotlib (the ``plot`` extra). Returns the statistics.

    Drawn through matplotlib's object API on a figure of its own (``matplotlib.figure.Figure``
    with an Agg canvas): pyplot's global state and the session's backend (a notebook's) are
    left as they were.
    """
    try:  # deferred: matplotlib is the optional ``plot`` extra
        import matplotlib
        import matplotlib.colors  # noqa: F401  (matplotlib.colors.Colormap below)
        from matplotlib.backend_bases import FigureCanvasBase
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise MissingExtraError("plot_work_plane", "matplotlib", "plot", name=exc.name) from exc

    # The format from the file's own suffix (a dotted folder's is not it), checked before drawing.
    fmt = Path(path).suffix.lower().lstrip(".") or "png"
    if fmt not in FigureCanvasBase.get_supported_filetypes():
        raise InvalidInputError(f"cannot write a plot as {str(path)!r}: use one of png, pdf, svg (by the suffix)")
    check_file_target(path)

    if not isinstance(plane, WorkPlane):
        raise InvalidInputError(f"plane must be a WorkPlane (pydynrad.work_plane); got {type(plane).__name__}")
    try:
        colours = cmap if isinstance(cmap, matplotlib.colors.Colormap) else matplotlib.colormaps[cmap]
    except (KeyError, TypeError, ValueError):
        raise InvalidInputError(f"cmap {cmap!r} is not a matplotlib colour map (e.g. 'jet', 'viridis')") from None
    a = _values(E)
    if len(a) != len(plane):
        raise InvalidInputError(f"illuminance has {len(a)} values for {len(plane)} work-plane points")
    stats = illuminance_statistics(a)
    grid = np.full(plane.shape, np.nan)
    grid[plane.cells[:, 0], plane.cells[:, 1]] = a
    (u0, v0), (du, dv) = plane.origin, plane.spacing
    extent = (u0, u0 + du * plane.shape[1], v0, v0 + dv * plane.shape[0])
    fig = Figure(figsize=(6, 5))
    FigureCanvasAgg(fig)  # this figure's own canvas: no pyplot, no backend switch
    ax = fig.add_subplot()
    im = ax.imshow(grid, origin="lower", extent=extent, cmap=colours, interpolation="nearest")
    fig.colorbar(im, ax=ax, label="illuminance (lx)")
    ax.set_aspect("equal")
    u0 = "undefined" if np.isnan(stats.U0) else f"{stats.U0:.3f}"
    heading = f"Em = {stats.Em:.4g} lx, Emin = {stats.Emin:.4g} lx, U0 = {u0}"
    ax.set_title(f"{title}\n{heading}" if title else heading, fontsize=10)
    write_atomic(path, lambda tmp: fig.savefig(tmp, format=fmt, dpi=120, bbox_inches="tight"))
    return stats
