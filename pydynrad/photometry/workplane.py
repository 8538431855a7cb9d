"""Work planes: a grid of upward-facing sensors at a height over a floor polygon.

The default spacing is EN 12464-1's rule for calculation grids: the maximum grid size
``p = 0.2 * 5^log10(d)`` m, d the longer side of the area's bounding box in metres (p <= 10 m),
with ``ceil(side / p)`` points along each side, at the centres of equal cells (so the spacing
never exceeds p). A border strip (EN 12464-1 excludes 0.5 m along walls from task areas when
their position is unknown) can be left out with ``border``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..checks import floats, integer, number
from ..errors import InvalidInputError
from ..host.memory import available_host_bytes

#: Host bytes per grid point while a work plane is laid out: its (u, v) and row/column grids,
#: the points kept and their inside tests (float64 and int64 arrays, with temporaries).
WORK_PLANE_BYTES = 96

#: The default spacing reads the shorter side of an elongated area as at least this fraction of
#: the longer: EN 12464-1's rule follows a corridor's width, so a sliver 1e-9 m wide would get
#: p = 1e-7 m and 4e7 points along 4 m (docs/decisions/0034-robustness-limits.md). At 1/1000 a 4 m sliver gets about
#: 950 points, and any length L at most about 625 * L^0.3 (L in metres) along it.
MIN_SIDE_RATIO = 1e-3

#: The most grid points :func:`work_plane` lays out unless its ``max_points`` says otherwise
#: (EN 12464-1's default spacing gives 10^4 over a square kilometre).
MAX_WORK_PLANE_POINTS = 1_000_000

__all__ = ["WorkPlane", "work_plane", "en12464_spacing"]


def en12464_spacing(d: float) -> float:
    """EN 12464-1's maximum grid spacing p (m) for an area of dimension d (m): 0.2 * 5^log10(d), at
    most 10. d is the area's longer side, or its shorter one where the longer is at least twice
    it (:func:`work_plane` picks it so)."""
    d = number(d, "the area's longer dimension")
    if not (math.isfinite(d) and d > 0):
        raise InvalidInputError(f"the area's longer dimension must be a positive length; got {d!r}")
    return min(10.0, 0.2 * 5.0 ** math.log10(d))


@dataclass(frozen=True)
class WorkPlane:
    """Sensor points of a work plane.

    points, normals : (n, 3) float64, scene coordinates; the normals point along ``up``.

    cells : (n, 2) int, each point's (row, column) in the grid of ``shape`` (rows along the
    polygon's second coordinate), for plots; grid cells outside the polygon hold no point.

    spacing : (2,) the grid steps along the polygon's two coordinates.
    """

    points: np.ndarray
    normals: np.ndarray
    cells: np.ndarray
    shape: tuple
    spacing: tuple
    origin: tuple

    def __len__(self) -> int:
        return len(self.points)


def _inside(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule: which of the 2-D points p (m, 2) lie inside the polygon (K, 2)."""
    x, y = p[:, 0:1], p[:, 1:2]
    a, b = poly, np.roll(poly, -1, axis=0)
    crosses = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return np.count_nonzero(crosses & (x < xc), axis=1) % 2 == 1


def _edge_distance(p: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance of 2-D points p (m, 2) to the polygon's boundary."""
    a, b = poly[None], np.roll(poly, -1, axis=0)[None]
    ab = b - a
    t = np.clip(np.sum((p[:, None] - a) * ab, axis=2) / np.maximum(np.sum(ab * ab, axis=2), 1e-300), 0.0, 1.0)
    return np.min(np.linalg.norm(p[:, None] - (a + t[..., None] * ab), axis=2), axis=1)


def work_plane(
    polygon,
    height: float,
    spacing: float | None = None,
    border: float = 0.0,
    up: int | None = None,
    scene=None,
    max_points: int = MAX_WORK_PLANE_POINTS,
) -> WorkPlane:
    """A grid of sensors at ``height`` over ``polygon``, facing up.

    Parameters
    ----------
    polygon : (K, 2) float
        The floor area's corners in order (either orientation), in the two coordinates other
        than ``up`` (x, y for ``up=2``; z, x for ``up=1``; y, z for ``up=0``), scene units.
    height : float
        The plane's coordinate along ``up`` (e.g. 0.75 m above a floor at 0 for desks).
    spacing : float, optional
        Largest grid step; by default EN 12464-1's p for the polygon's longer side, or its
        shorter one where the longer is at least twice it (:func:`en12464_spacing`, in metres:
        converted through ``scene.unit`` when a scene is given, else lengths read as metres).
        The shorter side is read as at least ``MIN_SIDE_RATIO`` (1/1000) of the longer, so a
        sliver gets a grid along its length, not one of a billion points.
    border : float
        Width of the strip along the polygon's edges left without points.
    up : int, optional
        The axis (0, 1, 2) the plane faces; by default the scene's up axis (which must then be
        a coordinate axis, + or -), or 2 (z) without a scene.
    scene : Scene, optional
        The scene the plane lies in: its ``up`` and ``unit`` give the defaults above.
    max_points : int
        The most grid points laid out (inside the polygon or not; 10^6 by default): a larger
        grid is refused with an :class:`InvalidInputError` naming its size, before it is made.
    """
    metres = 1.0
    if scene is not None:
        metres = float(scene.unit)
        if up is None:
            axis = int(np.argmax(np.abs(scene.up)))
            if abs(abs(float(scene.up[axis])) - 1.0) > 1e-9:
                raise InvalidInputError(
                    f"the scene's up axis {tuple(map(float, scene.up))} is not a coordinate axis: give work_plane's up"
                )
            up = axis
            if scene.up[axis] < 0:
                raise InvalidInputError(f"the scene's up axis points down its axis {axis}: give work_plane's up")
    up = 2 if up is None else up
    poly = floats(polygon, "polygon")
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3 or not np.all(np.isfinite(poly)):
        raise InvalidInputError(f"polygon must be (K >= 3, 2) finite corners; got shape {poly.shape}")
    # The area test on the polygon scaled to its extent: the corners' own products overflow
    # far before the grid would be refused for its size.
    extent = float(np.ptp(poly, axis=0).max())
    q = (poly - poly.min(axis=0)) / (extent if extent > 0 else 1.0)
    if abs(float(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))) < 1e-12:
        raise InvalidInputError("polygon has no area")
    up = integer(up, "up (the axis the plane faces)", 0, 2)  # 2.0 and True had passed `in (0, 1, 2)`
    height = number(height, "height")
    border = number(border, "border")
    if not border >= 0:
        raise InvalidInputError(f"border must be >= 0; got {border!r}")
    lo, hi = poly.min(axis=0), poly.max(axis=0)
    size = hi - lo
    if spacing is None:
        # EN 12464-1's d is the longer side, but the shorter where the longer is twice it or more
        # (a corridor's grid follows its width).
        longer, shorter = float(size.max()), float(size.min())
        shorter = max(shorter, MIN_SIDE_RATIO * longer)  # a sliver's width is no grid step
        spacing = en12464_spacing((shorter if longer >= 2.0 * shorter else longer) * metres) / metres
    max_points = integer(max_points, "max_points", 1)
    spacing = number(spacing, "spacing")
    if not (math.isfinite(spacing) and spacing > 0):
        raise InvalidInputError(f"spacing must be a positive length; got {spacing!r}")
    # The grid and its inside test hold about WORK_PLANE_BYTES per point: refused before they
    # are allocated (a spacing of 1e-4 over a room had raised MemoryError at 11.9 GiB).
    with np.errstate(over="ignore"):
        counts_f = np.maximum(1.0, np.ceil(size / spacing - 1e-9))
        points = float(np.prod(counts_f))
    need = points * WORK_PLANE_BYTES
    if not need <= available_host_bytes() / 2:
        raise InvalidInputError(
            f"a work plane of {points:.3g} grid points at spacing {spacing:g} "
            f"would need {need / 2**30:.3g} GiB, more than half the memory available: use a "
            "larger spacing"
        )
    if not points <= max_points:
        raise InvalidInputError(
            f"a work plane of {counts_f[0]:.0f} x {counts_f[1]:.0f} = {points:.3g} grid points over "
            f"{size[0]:g} x {size[1]:g} at spacing {spacing:g} is more than max_points = {max_points}: "
            "use a larger spacing (or raise max_points)"
        )
    counts = counts_f.astype(int)
    steps = size / counts
    u = lo[0] + (np.arange(counts[0]) + 0.5) * steps[0]
    v = lo[1] + (np.arange(counts[1]) + 0.5) * steps[1]
    vv, uu = np.meshgrid(v, u, indexing="ij")
    rows, cols = np.meshgrid(np.arange(counts[1]), np.arange(counts[0]), indexing="ij")
    flat = np.stack([uu.ravel(), vv.ravel()], axis=1)
    keep = _inside(flat, poly)
    if border > 0:
        keep &= _edge_distance(flat, poly) >= border
    if not np.any(keep):
        raise InvalidInputError("no grid point lies inside the polygon (and outside its border strip)")
    flat = flat[keep]
    axes = [(1, 2), (2, 0), (0, 1)][up]
    points = np.zeros((len(flat), 3))
    points[:, axes[0]], points[:, axes[1]], points[:, up] = flat[:, 0], flat[:, 1], height
    normals = np.zeros_like(points)
    normals[:, up] = 1.0
    cells = np.stack([rows.ravel()[keep], cols.ravel()[keep]], axis=1)
    return WorkPlane(
        points,
        normals,
        cells,
        (int(counts[1]), int(counts[0])),
        (float(steps[0]), float(steps[1])),
        (float(lo[0]), float(lo[1])),
    )
