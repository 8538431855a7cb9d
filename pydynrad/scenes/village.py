"""A procedural village at night: houses with rooms, doors, windows and pitched roofs.

Lengths in metres, y up. Houses stand in a grid of 18 x 18 m lots, each lot's first 5 m
(along z) a road; a street lamp stands at every lot's road edge. A house is a stone plinth
with a wooden floor, plastered outer walls (0.25 m thick) with a front door facing the road
and windows, 2 or 3 rooms separated by painted interior walls (0.12 m) with doors, one
pendant lamp per room, and a pitched roof whose underside is the white ceiling inside and
the soffit outside. Walls are solid slabs: each side of a wall and the reveals of every
opening are separate one-sided patches, so whatever can be seen faces the viewer; faces
buried against other solids (wall tops and bottoms, the ground under a house) are left
out. Emission (radiant exitance, W/m^2) comes only from the lamps, so radiosity alone lights
the scene.

Every surface is a planar quad gridded into near-square cells of ``cell`` metres (the ground
``2 * cell``), two triangles per cell; the triangular gables are split 4-way by
:func:`pydynrad.patching.subdivide` to the same size. The layout is drawn from
``numpy.random.default_rng(seed)``, so a seed fixes the scene bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidInputError
from ..patching import subdivide
from ..scene import Scene

__all__ = ["village", "BASE_CELL", "MATERIALS"]

#: Cell edge (m) at ``detail=1``: 12 houses then give about 64,000 patches (64,455 for seed 0).
BASE_CELL = 0.59

ROOM_LAMP = (24.0, 19.0, 12.0)
STREET_LAMP = (40.0, 34.0, 22.0)
#: name: (albedo RGB, emission RGB)
MATERIALS = {
    "grass": ((0.18, 0.32, 0.10), (0, 0, 0)),
    "road": ((0.32, 0.31, 0.30), (0, 0, 0)),
    "stone": ((0.45, 0.43, 0.40), (0, 0, 0)),
    "wood": ((0.50, 0.34, 0.20), (0, 0, 0)),
    "ceiling": ((0.80, 0.79, 0.76), (0, 0, 0)),
    "metal": ((0.20, 0.20, 0.22), (0, 0, 0)),
    "room_lamp": ((0.80, 0.80, 0.80), ROOM_LAMP),
    "street_lamp": ((0.80, 0.80, 0.80), STREET_LAMP),
    "plaster_cream": ((0.78, 0.70, 0.55), (0, 0, 0)),
    "plaster_ochre": ((0.72, 0.52, 0.30), (0, 0, 0)),
    "plaster_rose": ((0.72, 0.50, 0.45), (0, 0, 0)),
    "plaster_blue": ((0.55, 0.62, 0.70), (0, 0, 0)),
    "paint_white": ((0.80, 0.78, 0.74), (0, 0, 0)),
    "paint_mint": ((0.62, 0.74, 0.64), (0, 0, 0)),
    "paint_peach": ((0.80, 0.66, 0.55), (0, 0, 0)),
    "paint_lavender": ((0.68, 0.64, 0.76), (0, 0, 0)),
    "roof_terracotta": ((0.55, 0.22, 0.12), (0, 0, 0)),
    "roof_slate": ((0.24, 0.26, 0.30), (0, 0, 0)),
    "roof_brown": ((0.36, 0.24, 0.16), (0, 0, 0)),
}
_ID = {name: k for k, name in enumerate(MATERIALS)}
_ALBEDO = np.array([a for a, _ in MATERIALS.values()], dtype=np.float64)
_EMISSION = np.array([e for _, e in MATERIALS.values()], dtype=np.float64)
_PLASTERS = [n for n in MATERIALS if n.startswith("plaster_")]
_PAINTS = [n for n in MATERIALS if n.startswith("paint_")]
_ROOFS = [n for n in MATERIALS if n.startswith("roof_")]

LOT = 18.0  # lot edge (m)
ROAD = 5.0  # road band at the start of every lot row (m)
MARGIN = 6.0  # ground beyond the outer lots (m)
_PLINTH, _OUTER, _INNER = 0.2, 0.25, 0.12  # plinth height, outer and interior wall thickness (m)
_DOOR_H, _SILL, _WINDOW_TOP = 2.1, 0.9, 2.1  # above the floor (m)


class _Parts:
    """Quads (corner, edge u, edge v; front = u x v) and triangles, with material ids."""

    def __init__(self) -> None:
        self.quads: list[tuple] = []
        self.tris: list[tuple] = []
        self.origin = np.zeros(3)

    def rect(self, k: int, sign: int, lo, hi, mat: str) -> None:
        """Axis-aligned rectangle in the plane coord k = lo[k] (= hi[k]), facing sign * e_k."""
        i, j = (k + 1) % 3, (k + 2) % 3  # e_i x e_j = e_k
        u, v = np.zeros(3), np.zeros(3)
        u[i], v[j] = hi[i] - lo[i], hi[j] - lo[j]
        if sign < 0:
            u, v = v, u
        self.quads.append((self.origin + lo, u, v, _ID[mat]))

    def box(self, lo, hi, faces: dict[str, str]) -> None:
        """Faces of the box [lo, hi] named "-x", "+y", ...: each facing out of the box."""
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        for key, mat in faces.items():
            k, sign = "xyz".index(key[1]), (1 if key[0] == "+" else -1)
            a, b = lo.copy(), hi.copy()
            a[k] = b[k] = hi[k] if sign > 0 else lo[k]
            self.rect(k, sign, a, b, mat)

    def quad(self, o, u, v, mat: str, outward) -> None:
        o, u, v = (np.asarray(x, dtype=np.float64) for x in (o, u, v))
        if np.dot(np.cross(u, v), outward) < 0:
            u, v = v, u
        self.quads.append((self.origin + o, u, v, _ID[mat]))

    def triangle(self, a, b, c, mat: str, outward) -> None:
        a, b, c = (self.origin + np.asarray(x, dtype=np.float64) for x in (a, b, c))
        if np.dot(np.cross(b - a, c - a), outward) < 0:
            b, c = c, b
        self.tris.append((a, b, c, _ID[mat]))

    def arrays(self):
        o, u, v, m = (np.array(x) for x in zip(*self.quads))
        return o, u, v, m


def _wall(parts: _Parts, axis: int, s0: float, s1: float, c0: float, c1: float, y0: float, y1: float,
          openings: list[tuple], mat_lo: str, mat_hi: str, mat_edge: str, caps: bool = False) -> None:
    """A wall slab running along ``axis`` (0: x, 2: z) over [s0, s1], thickness [c0, c1] across.

    ``openings`` are (a, b, ya, yb) holes (doors reach ``ya = y0``). Side c0 faces -c with
    ``mat_lo``, side c1 faces +c with ``mat_hi``; reveals, sills, lintels and the optional end
    caps take ``mat_edge``. No top or bottom face: they touch the ceiling and the floor.
    """
    c_axis = 2 - axis

    def corners(sa, sb, ca, cb, ya, yb):
        lo, hi = np.empty(3), np.empty(3)
        lo[axis], hi[axis], lo[c_axis], hi[c_axis], lo[1], hi[1] = sa, sb, ca, cb, ya, yb
        return lo, hi

    spans, cur = [], s0
    for a, b, ya, yb in sorted(openings):
        spans += [(cur, a, y0, y1)] if a > cur else []
        spans += [(a, b, y0, ya)] if ya > y0 else []
        spans += [(a, b, yb, y1)] if yb < y1 else []
        cur = b
    spans += [(cur, s1, y0, y1)] if s1 > cur else []
    for sa, sb, ya, yb in spans:
        parts.rect(c_axis, -1, *corners(sa, sb, c0, c0, ya, yb), mat_lo)
        parts.rect(c_axis, +1, *corners(sa, sb, c1, c1, ya, yb), mat_hi)
    for a, b, ya, yb in openings:
        parts.rect(axis, +1, *corners(a, a, c0, c1, ya, yb), mat_edge)
        parts.rect(axis, -1, *corners(b, b, c0, c1, ya, yb), mat_edge)
        if ya > y0:
            parts.rect(1, +1, *corners(a, b, c0, c1, ya, ya), mat_edge)
        if yb < y1:
            parts.rect(1, -1, *corners(a, b, c0, c1, yb, yb), mat_edge)
    if caps:
        parts.rect(axis, -1, *corners(s0, s0, c0, c1, y0, y1), mat_edge)
        parts.rect(axis, +1, *corners(s1, s1, c0, c1, y0, y1), mat_edge)


def _centred(lo: float, hi: float, width: float, y0: float, y1: float, jitter: float) -> tuple:
    mid = 0.5 * (lo + hi) + jitter
    return (mid - 0.5 * width, mid + 0.5 * width, y0, y1)


def _house(parts: _Parts, rng: np.random.Generator, width: float, depth: float) -> None:
    """One house in local coordinates: footprint [0, width] x [0, depth], front (door) at z = 0."""
    t, ti, p = _OUTER, _INNER, _PLINTH
    top = p + rng.uniform(2.6, 3.0)
    plaster, paint, roof = (str(rng.choice(names)) for names in (_PLASTERS, _PAINTS, _ROOFS))
    parts.box((0, 0, 0), (width, p, depth), {"-x": "stone", "+x": "stone", "-z": "stone", "+z": "stone", "+y": "wood"})

    n_cols = int(rng.integers(2, 4))
    walls_x = t + (width - 2 * t) * np.arange(1, n_cols) / n_cols + rng.uniform(-0.3, 0.3, n_cols - 1)
    col_lo = np.concatenate([[t], walls_x + 0.5 * ti])
    col_hi = np.concatenate([walls_x - 0.5 * ti, [width - t]])
    split = bool(rng.random() < 0.5)  # column 0 split into a front and a back room
    z_split = 0.5 * depth + rng.uniform(-0.5, 0.5)

    door_col = int(rng.integers(n_cols))
    door_h, sill, win_top = p + _DOOR_H, p + _SILL, p + _WINDOW_TOP
    front = [_centred(col_lo[k], col_hi[k], 1.0, p, door_h, rng.uniform(-0.2, 0.2)) if k == door_col
             else _centred(col_lo[k], col_hi[k], 1.2, sill, win_top, rng.uniform(-0.2, 0.2)) for k in range(n_cols)]
    back = [_centred(col_lo[k], col_hi[k], 1.2, sill, win_top, rng.uniform(-0.2, 0.2)) for k in range(n_cols)]
    left_hi = z_split - 0.5 * ti if split else depth - t
    left = [_centred(t, left_hi, 1.0, sill, win_top, 0.0)]
    right = [_centred(t, depth - t, 1.2, sill, win_top, rng.uniform(-0.3, 0.3))]
    _wall(parts, 0, 0, width, 0, t, p, top, front, plaster, paint, plaster, caps=True)
    _wall(parts, 0, 0, width, depth - t, depth, p, top, back, paint, plaster, plaster, caps=True)
    _wall(parts, 2, t, depth - t, 0, t, p, top, left, plaster, paint, plaster)
    _wall(parts, 2, t, depth - t, width - t, width, p, top, right, paint, plaster, plaster)

    rooms = []  # (x0, x1, z0, z1) of every room, for its lamp
    for k, x in enumerate(walls_x):
        # Keep the door clear of the cross wall's end (which has no cap) when column 0 is split.
        z_lo = z_split + 0.5 * ti + 0.2 if (k == 0 and split) else t + 0.3
        dz = rng.uniform(z_lo, depth - t - 1.2)
        _wall(parts, 2, t, depth - t, x - 0.5 * ti, x + 0.5 * ti, p, top, [(dz, dz + 0.9, p, p + 2.05)], paint, paint, paint)
    if split:
        dx = rng.uniform(t + 0.2, col_hi[0] - 1.1)
        _wall(parts, 0, t, col_hi[0], z_split - 0.5 * ti, z_split + 0.5 * ti, p, top, [(dx, dx + 0.9, p, p + 2.05)],
              paint, paint, paint)
        rooms += [(col_lo[0], col_hi[0], t, z_split - 0.5 * ti), (col_lo[0], col_hi[0], z_split + 0.5 * ti, depth - t)]
    rooms += [(col_lo[k], col_hi[k], t, depth - t) for k in range(1 if split else 0, n_cols)]
    for x0, x1, z0, z1 in rooms:
        cx, cz = 0.5 * (x0 + x1), 0.5 * (z0 + z1)
        shade = {"-x": "room_lamp", "+x": "room_lamp", "-y": "room_lamp", "-z": "room_lamp", "+z": "room_lamp", "+y": "metal"}
        parts.box((cx - 0.25, top - 0.45, cz - 0.25), (cx + 0.25, top - 0.33, cz + 0.25), shade)

    eave = 0.4
    xa, xb, za, zb, zr = -eave, width + eave, -eave, depth + eave, 0.5 * depth
    ridge = top + (zr - za) * math.tan(math.radians(rng.uniform(30.0, 40.0)))
    parts.rect(1, -1, np.array([xa, top, za]), np.array([xb, top, zb]), "ceiling")
    parts.quad((xa, top, za), (xb - xa, 0, 0), (0, ridge - top, zr - za), roof, outward=(0, 1, -1))
    parts.quad((xa, top, zb), (xb - xa, 0, 0), (0, ridge - top, zr - zb), roof, outward=(0, 1, 1))
    for x, out in ((xa, -1), (xb, 1)):
        parts.triangle((x, top, za), (x, ridge, zr), (x, top, zb), plaster, outward=(out, 0, 0))


def _street_lamp(parts: _Parts, x: float, z: float) -> None:
    parts.box((x - 0.06, 0, z - 0.06), (x + 0.06, 3.6, z + 0.06), {"-x": "metal", "+x": "metal", "-z": "metal", "+z": "metal"})
    head = {"-x": "street_lamp", "+x": "street_lamp", "-y": "street_lamp", "-z": "street_lamp", "+z": "street_lamp", "+y": "metal"}
    parts.box((x - 0.2, 3.6, z - 0.2), (x + 0.2, 3.85, z + 0.2), head)


def _grid(o: np.ndarray, u: np.ndarray, v: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid each quad (o + a u + b v, 0 <= a, b <= 1) into cells no longer than ``cell`` per side.

    Returns points (P, 3), triangles (2C, 3) counter-clockwise about u x v, and the index of
    the quad each triangle came from. Points are shared inside a quad.
    """
    nu = np.maximum(1, np.ceil(np.linalg.norm(u, axis=1) / cell - 1e-9)).astype(np.int64)
    nv = np.maximum(1, np.ceil(np.linalg.norm(v, axis=1) / cell - 1e-9)).astype(np.int64)
    n_pts, n_cells = (nu + 1) * (nv + 1), nu * nv
    p_start = np.concatenate([[0], np.cumsum(n_pts)[:-1]])
    q = np.repeat(np.arange(len(o)), n_pts)
    local = np.arange(len(q)) - p_start[q]
    a = (local // (nv[q] + 1)) / nu[q]
    b = (local % (nv[q] + 1)) / nv[q]
    points = o[q] + a[:, None] * u[q] + b[:, None] * v[q]

    qc = np.repeat(np.arange(len(o)), n_cells)
    lc = np.arange(len(qc)) - np.concatenate([[0], np.cumsum(n_cells)[:-1]])[qc]
    i, j = lc // nv[qc], lc % nv[qc]
    c00 = p_start[qc] + i * (nv[qc] + 1) + j  # corners at (i, j), (i+1, j), (i+1, j+1), (i, j+1)
    c10 = c00 + nv[qc] + 1
    tris = np.stack([np.stack([c00, c10, c10 + 1], axis=1), np.stack([c00, c10 + 1, c00 + 1], axis=1)], axis=1)
    return points, tris.reshape(-1, 3), np.repeat(qc, 2)


def _ground(n_cols: int, n_rows: int, footprints: np.ndarray, cell: float):
    """Ground grid (points, triangles, material ids): roads on every lot row's first ROAD metres,
    grass elsewhere, and no patches whose centre lies under a house."""
    lo = np.array([-MARGIN, 0.0, -MARGIN])
    size = np.array([n_cols * LOT + 2 * MARGIN, 0.0, n_rows * LOT + 2 * MARGIN])
    points, tris, _ = _grid(lo[None], np.array([[0, 0, size[2]]]), np.array([[size[0], 0, 0]]), cell)
    centre = points[tris].mean(axis=1)
    under = np.zeros(len(tris), dtype=bool)
    for x0, z0, x1, z1 in footprints:
        under |= (centre[:, 0] > x0) & (centre[:, 0] < x1) & (centre[:, 2] > z0) & (centre[:, 2] < z1)
    in_lots = (centre[:, 0] > 0) & (centre[:, 0] < n_cols * LOT) & (centre[:, 2] > 0) & (centre[:, 2] < n_rows * LOT)
    road = in_lots & (np.mod(centre[:, 2], LOT) < ROAD)
    mats = np.where(road, _ID["road"], _ID["grass"])
    return points, tris[~under], mats[~under]


def village(seed: int = 0, houses: int | None = None, detail: float = 1.0) -> Scene:
    """A deterministic procedural village (see the module docstring), lengths in metres.

    Parameters
    ----------
    seed : int
        Seeds the layout: house sizes, rooms, doors, windows, colours, roof pitches.
    houses : int, optional
        Number of houses (default 12), laid out on a near-square grid of lots.
    detail : float
        Patch density: cells of ``BASE_CELL / sqrt(detail)`` metres. ``detail=1`` with 12
        houses gives about 64,000 patches (the paper's test scene had 63,125); patch count
        grows about linearly in ``detail`` and in ``houses``: ``detail=16`` gives about
        890,000 and ``detail=20`` about 1,100,000 (built in about a second here).
    """
    houses = 12 if houses is None else houses
    if isinstance(houses, bool) or not isinstance(houses, (int, np.integer)) or houses < 1:
        raise InvalidInputError(f"houses must be a positive integer; got {houses!r}")
    if not (isinstance(detail, (int, float, np.number)) and np.isfinite(detail) and detail > 0):
        raise InvalidInputError(f"detail must be a positive finite number; got {detail!r}")
    cell = BASE_CELL / math.sqrt(float(detail))
    rng = np.random.default_rng(seed)
    n_cols = math.ceil(math.sqrt(houses))
    n_rows = math.ceil(houses / n_cols)

    parts = _Parts()
    footprints = []
    for h in range(houses):
        x0, z0 = (h % n_cols) * LOT, (h // n_cols) * LOT
        parts.origin = np.array([x0, 0.0, z0])
        _street_lamp(parts, 0.6, ROAD - 0.6)
        width, depth = rng.uniform(9.0, 13.0), rng.uniform(6.5, 9.0)
        hx, hz = rng.uniform(1.5, LOT - width - 1.5), ROAD + rng.uniform(1.5, LOT - ROAD - depth - 1.0)
        parts.origin = np.array([x0 + hx, 0.0, z0 + hz])
        _house(parts, rng, width, depth)
        footprints.append((x0 + hx, z0 + hz, x0 + hx + width, z0 + hz + depth))

    o, u, v, quad_mat = parts.arrays()
    pts_q, tri_q, from_quad = _grid(o, u, v, cell)
    corners = np.array([t[:3] for t in parts.tris])
    pts_t, tri_t, from_tri = subdivide(corners.reshape(-1, 3), np.arange(3 * len(corners)).reshape(-1, 3), max_edge=1.5 * cell)
    pts_g, tri_g, mat_g = _ground(n_cols, n_rows, np.array(footprints), 2 * cell)

    points = np.concatenate([pts_q, pts_t, pts_g])
    triangles = np.concatenate([tri_q, tri_t + len(pts_q), tri_g + len(pts_q) + len(pts_t)])
    mats = np.concatenate([quad_mat[from_quad], np.array([t[3] for t in parts.tris])[from_tri], mat_g])
    return Scene(points, triangles, albedo=_ALBEDO[mats], emission=_EMISSION[mats], name=f"village(seed={seed})")
