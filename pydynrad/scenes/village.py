"""A procedural village at night: houses with rooms, doors, windows and pitched roofs.

Lengths in metres, y up. Houses stand in a grid of 18 x 18 m lots, each lot's first 5 m
(along z) a road; a street lamp stands at every lot's road edge. A house is a stone plinth
with a wooden floor, plastered outer walls (0.25 m thick) with a front door facing the road
and windows, 2 or 3 rooms separated by painted interior walls (0.12 m) with doors, one
pendant lamp per room, and a pitched roof over a white ceiling with a wooden soffit under
the eaves. Walls are solid slabs: each side of a wall and the reveals of every opening are
separate one-sided patches, so whatever can be seen faces the viewer. Surfaces tile exactly:
nothing is buried against a solid (no wall tops or bottoms, no floor or ceiling under a
wall, no ground under a house or a lamp post), so no patch is wasted on a hidden face and
no two patches overlap. Emission (radiant exitance, W/m^2) comes only from the lamps, so radiosity alone lights
the scene.

Every surface is a planar quad gridded into near-square cells of ``cell`` metres (the ground
``2 * cell``), two triangles per cell; the triangular gables are split 4-way by
:func:`pydynrad.geometry.patching.subdivide` to the same size. The layout is drawn from
``numpy.random.default_rng(seed)``, so a seed fixes the scene bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InvalidInputError
from ..geometry.patching import subdivide
from ..geometry.scene import Scene

__all__ = ["village", "BASE_CELL", "MATERIALS", "EMISSION"]

#: Cell edge (m) at ``detail=1``: 12 houses then give about 66,000 patches (66,154 for seed 0).
BASE_CELL = 0.59

ROOM_LAMP = (24.0, 19.0, 12.0)
STREET_LAMP = (40.0, 34.0, 22.0)
#: Albedo (RGB) of every material, by name.
MATERIALS = {
    "grass": (0.18, 0.32, 0.10),
    "road": (0.32, 0.31, 0.30),
    "stone": (0.45, 0.43, 0.40),
    "wood": (0.50, 0.34, 0.20),
    "ceiling": (0.80, 0.79, 0.76),
    "metal": (0.20, 0.20, 0.22),
    "room_lamp": (0.80, 0.80, 0.80),
    "street_lamp": (0.80, 0.80, 0.80),
    "plaster_cream": (0.78, 0.70, 0.55),
    "plaster_ochre": (0.72, 0.52, 0.30),
    "plaster_rose": (0.72, 0.50, 0.45),
    "plaster_blue": (0.55, 0.62, 0.70),
    "paint_white": (0.80, 0.78, 0.74),
    "paint_mint": (0.62, 0.74, 0.64),
    "paint_peach": (0.80, 0.66, 0.55),
    "paint_lavender": (0.68, 0.64, 0.76),
    "roof_terracotta": (0.55, 0.22, 0.12),
    "roof_slate": (0.24, 0.26, 0.30),
    "roof_brown": (0.36, 0.24, 0.16),
}
#: Emission (radiant exitance, W/m^2, RGB) of the emitting materials.
EMISSION = {"room_lamp": ROOM_LAMP, "street_lamp": STREET_LAMP}
_ID = {name: k for k, name in enumerate(MATERIALS)}
_ALBEDO = np.array(list(MATERIALS.values()), dtype=np.float64)
_EMISSION = np.array([EMISSION.get(name, (0.0, 0.0, 0.0)) for name in MATERIALS], dtype=np.float64)
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
        if hi[i] <= lo[i] or hi[j] <= lo[j]:
            return  # an empty piece (an opening at a wall's end, a door's missing sill)
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


def _wall(
    parts: _Parts,
    axis: int,
    s0: float,
    s1: float,
    c0: float,
    c1: float,
    y0: float,
    y1: float,
    openings: list[tuple],
    mats: tuple[str, str, str],
    caps: bool = False,
    lo_spans: list[tuple] | None = None,
    hi_spans: list[tuple] | None = None,
) -> None:
    """A wall slab running along ``axis`` (0: x, 2: z) over [s0, s1], thickness [c0, c1] across.

    ``openings`` are (a, b, ya, yb) holes (doors reach ``ya = y0``). ``mats`` = (side c0, which
    faces -c; side c1, facing +c; reveals, sills, lintels and end caps). ``lo_spans`` and
    ``hi_spans`` limit each side to the (a, b) stretches not buried against an abutting wall.
    No top or bottom face: they touch the ceiling and the floor.
    """
    c_axis = 2 - axis

    def corners(sa, sb, ca, cb, ya, yb):
        lo, hi = np.empty(3), np.empty(3)
        lo[axis], hi[axis], lo[c_axis], hi[c_axis], lo[1], hi[1] = sa, sb, ca, cb, ya, yb
        return lo, hi

    pieces, cur = [], s0  # (a, b, ya, yb) of the wall's face with the openings cut out
    for a, b, ya, yb in sorted(openings):
        pieces += [(cur, a, y0, y1), (a, b, y0, ya), (a, b, yb, y1)]
        cur = b
    pieces.append((cur, s1, y0, y1))
    for c, sign, spans, mat in ((c0, -1, lo_spans, mats[0]), (c1, +1, hi_spans, mats[1])):
        for sa, sb, ya, yb in pieces:
            for ea, eb in spans or [(s0, s1)]:
                parts.rect(c_axis, sign, *corners(max(sa, ea), min(sb, eb), c, c, ya, yb), mat)
    for a, b, ya, yb in openings:
        parts.rect(axis, +1, *corners(a, a, c0, c1, ya, yb), mats[2])
        parts.rect(axis, -1, *corners(b, b, c0, c1, ya, yb), mats[2])
        parts.rect(1, +1, *corners(a, b, c0, c1, ya, ya), mats[2] if ya > y0 else "wood")  # sill or threshold
        parts.rect(1, -1, *corners(a, b, c0, c1, yb, yb), mats[2])
    if caps:
        parts.rect(axis, -1, *corners(s0, s0, c0, c1, y0, y1), mats[2])
        parts.rect(axis, +1, *corners(s1, s1, c0, c1, y0, y1), mats[2])


def _frame(parts: _Parts, y: float, sign: int, outer: tuple, hole: tuple, mat: str) -> None:
    """The horizontal rectangle ``outer`` = (x0, z0, x1, z1) at height y minus the rectangle ``hole``."""
    x0, z0, x1, z1 = outer
    hx0, hz0, hx1, hz1 = hole
    for a, b in (((x0, z0), (x1, hz0)), ((x0, hz1), (x1, z1)), ((x0, hz0), (hx0, hz1)), ((hx1, hz0), (x1, hz1))):
        parts.rect(1, sign, np.array([a[0], y, a[1]]), np.array([b[0], y, b[1]]), mat)


def _horizontal(parts: _Parts, y: float, sign: int, rect: tuple, mat: str) -> None:
    x0, z0, x1, z1 = rect
    parts.rect(1, sign, np.array([x0, y, z0]), np.array([x1, y, z1]), mat)


def _centred(lo: float, hi: float, width: float, y0: float, y1: float, jitter: float) -> tuple:
    mid = 0.5 * (lo + hi) + jitter
    return (mid - 0.5 * width, mid + 0.5 * width, y0, y1)


def _house(parts: _Parts, rng: np.random.Generator, width: float, depth: float) -> None:
    """One house in local coordinates: footprint [0, width] x [0, depth], front (door) at z = 0."""
    t, ti, p = _OUTER, _INNER, _PLINTH
    top = p + rng.uniform(2.6, 3.0)
    plaster, paint, roof = (str(rng.choice(names)) for names in (_PLASTERS, _PAINTS, _ROOFS))
    parts.box((0, 0, 0), (width, p, depth), {"-x": "stone", "+x": "stone", "-z": "stone", "+z": "stone"})

    n_cols = int(rng.integers(2, 4))
    walls_x = t + (width - 2 * t) * np.arange(1, n_cols) / n_cols + rng.uniform(-0.3, 0.3, n_cols - 1)
    col_lo = np.concatenate([[t], walls_x + 0.5 * ti])
    col_hi = np.concatenate([walls_x - 0.5 * ti, [width - t]])
    split = bool(rng.random() < 0.5)  # column 0 split into a front and a back room
    z_split = 0.5 * depth + rng.uniform(-0.5, 0.5)
    z_split_lo, z_split_hi = z_split - 0.5 * ti, z_split + 0.5 * ti

    door_col = int(rng.integers(n_cols))
    door_h, sill, win_top = p + _DOOR_H, p + _SILL, p + _WINDOW_TOP
    front = [
        _centred(col_lo[k], col_hi[k], 1.0, p, door_h, rng.uniform(-0.2, 0.2))
        if k == door_col
        else _centred(col_lo[k], col_hi[k], 1.2, sill, win_top, rng.uniform(-0.2, 0.2))
        for k in range(n_cols)
    ]
    back = [_centred(col_lo[k], col_hi[k], 1.2, sill, win_top, rng.uniform(-0.2, 0.2)) for k in range(n_cols)]
    left = [_centred(t, z_split_lo if split else depth - t, 1.0, sill, win_top, 0.0)]
    right = [_centred(t, depth - t, 1.2, sill, win_top, rng.uniform(-0.3, 0.3))]
    columns = list(zip(col_lo, col_hi))
    beside_split = [(t, z_split_lo), (z_split_hi, depth - t)] if split else None
    outside, inside = (plaster, paint, plaster), (paint, plaster, plaster)
    _wall(parts, 0, 0, width, 0, t, p, top, front, outside, caps=True, hi_spans=columns)
    _wall(parts, 0, 0, width, depth - t, depth, p, top, back, inside, caps=True, lo_spans=columns)
    _wall(parts, 2, t, depth - t, 0, t, p, top, left, outside, hi_spans=beside_split)
    _wall(parts, 2, t, depth - t, width - t, width, p, top, right, inside)

    for k, x in enumerate(walls_x):
        # With column 0 split, the first wall's door opens into the back room, clear of the cross wall.
        z_lo = z_split_hi + 0.2 if (k == 0 and split) else t + 0.3
        dz = rng.uniform(z_lo, depth - t - 1.2)
        _wall(
            parts,
            2,
            t,
            depth - t,
            x - 0.5 * ti,
            x + 0.5 * ti,
            p,
            top,
            [(dz, dz + 0.9, p, p + 2.05)],
            (paint, paint, paint),
            lo_spans=beside_split if k == 0 else None,
        )
    rooms = [(col_lo[k], t, col_hi[k], depth - t) for k in range(1 if split else 0, n_cols)]
    if split:
        dx = rng.uniform(t + 0.2, col_hi[0] - 1.1)
        _wall(
            parts, 0, t, col_hi[0], z_split_lo, z_split_hi, p, top, [(dx, dx + 0.9, p, p + 2.05)], (paint, paint, paint)
        )
        rooms += [(col_lo[0], t, col_hi[0], z_split_lo), (col_lo[0], z_split_hi, col_hi[0], depth - t)]
    shade = {
        "-x": "room_lamp",
        "+x": "room_lamp",
        "-y": "room_lamp",
        "-z": "room_lamp",
        "+z": "room_lamp",
        "+y": "metal",
    }
    for room in rooms:
        _horizontal(parts, p, +1, room, "wood")
        _horizontal(parts, top, -1, room, "ceiling")
        cx, cz = 0.5 * (room[0] + room[2]), 0.5 * (room[1] + room[3])
        parts.box((cx - 0.25, top - 0.45, cz - 0.25), (cx + 0.25, top - 0.33, cz + 0.25), shade)

    eave = 0.4
    xa, xb, za, zb, zr = -eave, width + eave, -eave, depth + eave, 0.5 * depth
    ridge = top + (zr - za) * math.tan(math.radians(rng.uniform(30.0, 40.0)))
    _frame(parts, top, -1, (xa, za, xb, zb), (0, 0, width, depth), "wood")  # the soffit under the eaves
    parts.quad((xa, top, za), (xb - xa, 0, 0), (0, ridge - top, zr - za), roof, outward=(0, 1, -1))
    parts.quad((xa, top, zb), (xb - xa, 0, 0), (0, ridge - top, zr - zb), roof, outward=(0, 1, 1))
    for x, out in ((xa, -1), (xb, 1)):
        parts.triangle((x, top, za), (x, ridge, zr), (x, top, zb), plaster, outward=(out, 0, 0))


_POLE, _HEAD = 0.06, 0.2  # half widths (m)


def _street_lamp(parts: _Parts, x: float, z: float) -> None:
    """A pole with a glowing head; the head's underside is a frame around the pole's top."""
    parts.box(
        (x - _POLE, 0, z - _POLE),
        (x + _POLE, 3.6, z + _POLE),
        {"-x": "metal", "+x": "metal", "-z": "metal", "+z": "metal"},
    )
    head = {"-x": "street_lamp", "+x": "street_lamp", "-z": "street_lamp", "+z": "street_lamp", "+y": "metal"}
    parts.box((x - _HEAD, 3.6, z - _HEAD), (x + _HEAD, 3.85, z + _HEAD), head)
    _frame(
        parts,
        3.6,
        -1,
        (x - _HEAD, z - _HEAD, x + _HEAD, z + _HEAD),
        (x - _POLE, z - _POLE, x + _POLE, z + _POLE),
        "street_lamp",
    )


def _grid(
    o: np.ndarray, u: np.ndarray, v: np.ndarray, mat: np.ndarray, cell: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Grid each quad (o + a u + b v, 0 <= a, b <= 1) into cells no longer than ``cell`` per side.

    Returns points (P, 3), triangles (2C, 3) counter-clockwise about u x v, and each
    triangle's material id (its quad's). Points are shared inside a quad.
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
    return points, tris.reshape(-1, 3), np.repeat(mat[qc], 2)


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
        houses gives about 66,000 patches (63,000 to 69,000 over seeds; the paper's test
        scene had 63,125); patch count grows about linearly in ``detail`` and in ``houses``:
        ``detail=20`` gives about 1,070,000 (built in about 2 s here).
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

    parts, ground = _Parts(), _Parts()
    _frame(
        ground,
        0.0,
        +1,
        (-MARGIN, -MARGIN, n_cols * LOT + MARGIN, n_rows * LOT + MARGIN),
        (0, 0, n_cols * LOT, n_rows * LOT),
        "grass",
    )
    for lot in range(n_cols * n_rows):
        x0, z0 = (lot % n_cols) * LOT, (lot // n_cols) * LOT
        road, garden = (x0, z0, x0 + LOT, z0 + ROAD), (x0, z0 + ROAD, x0 + LOT, z0 + LOT)
        if lot >= houses:
            _horizontal(ground, 0.0, +1, road, "road")
            _horizontal(ground, 0.0, +1, garden, "grass")
            continue
        lamp_x, lamp_z = x0 + 0.6, z0 + ROAD - 0.6
        _street_lamp(parts, lamp_x, lamp_z)
        _frame(ground, 0.0, +1, road, (lamp_x - _POLE, lamp_z - _POLE, lamp_x + _POLE, lamp_z + _POLE), "road")
        width, depth = rng.uniform(9.0, 13.0), rng.uniform(6.5, 9.0)
        hx, hz = x0 + rng.uniform(1.5, LOT - width - 1.5), z0 + ROAD + rng.uniform(1.5, LOT - ROAD - depth - 1.0)
        _frame(ground, 0.0, +1, garden, (hx, hz, hx + width, hz + depth), "grass")
        parts.origin = np.array([hx, 0.0, hz])
        _house(parts, rng, width, depth)
        parts.origin = np.zeros(3)

    pts_q, tri_q, mat_q = _grid(*parts.arrays(), cell)
    pts_g, tri_g, mat_g = _grid(*ground.arrays(), 2 * cell)
    corners = np.array([t[:3] for t in parts.tris])
    pts_t, tri_t, from_tri = subdivide(
        corners.reshape(-1, 3), np.arange(3 * len(corners)).reshape(-1, 3), max_edge=1.5 * cell
    )
    mat_t = np.array([t[3] for t in parts.tris])[from_tri]

    points = np.concatenate([pts_q, pts_g, pts_t])
    offsets = np.cumsum([0, len(pts_q), len(pts_g)])
    triangles = np.concatenate([tri_q + offsets[0], tri_g + offsets[1], tri_t + offsets[2]])
    mats = np.concatenate([mat_q, mat_g, mat_t])
    return Scene(
        points,
        triangles,
        albedo=_ALBEDO[mats],
        emission=_EMISSION[mats],
        name=f"village(seed={seed})",
        unit="m",
        up="+y",
    )
