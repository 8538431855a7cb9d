"""Scenes where a coarse level could carry light across walls: each with its lights,
an observer whose local set covers part of the lit region, and nothing else.

Every scene is built of axis-aligned quads cut into square-ish cells; walls have two faces (a
thickness), holes (a door, a window) are cells left out, with their jambs closed.
"""

from __future__ import annotations

import numpy as np

from pydynrad import DirectionalLight, PointLight, Scene

__all__ = ["LEAK_SCENES", "leak_scene"]

CELL = 0.25  # patch edge (scene units, ~metres)


def _quad(o, u, v, normal, hole=None, cell=CELL):
    """Points and triangles of o + [0,1]u + [0,1]v in cells of about ``cell``, facing ``normal``;
    ``hole`` (u0, u1, v0, v1) in units of length along u and v: cells inside it are left out."""
    o, u, v = (np.asarray(a, dtype=np.float64) for a in (o, u, v))
    lu, lv = np.linalg.norm(u), np.linalg.norm(v)
    nu, nv = max(1, int(round(lu / cell))), max(1, int(round(lv / cell)))
    pts, tris = [], []
    for i in range(nu):
        for j in range(nv):
            cu, cv = (i + 0.5) * lu / nu, (j + 0.5) * lv / nv
            if hole is not None and hole[0] < cu < hole[1] and hole[2] < cv < hole[3]:
                continue
            a = o + u * i / nu + v * j / nv
            b, c, d = a + u / nu, a + u / nu + v / nv, a + v / nv
            k = len(pts)
            pts += [a, b, c, d]
            t = [[k, k + 1, k + 2], [k, k + 2, k + 3]]
            if np.dot(np.cross(u, v), normal) < 0:
                t = [x[::-1] for x in t]
            tris += t
    return np.array(pts).reshape(-1, 3), np.array(tris, dtype=np.int64).reshape(-1, 3)


def _box(lo, hi, inward: bool, skip=(), holes=None):
    """The six faces of the box [lo, hi] facing in or out, without the faces in ``skip``
    ((axis, 0|1)); ``holes``: {(axis, side): hole} as for :func:`_quad` (along the face's two
    other axes, in order)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    out = []
    for axis in range(3):
        for side in (0, 1):
            if (axis, side) in skip:
                continue
            ua, va = [a for a in range(3) if a != axis]
            o = lo.copy()
            o[axis] = (lo, hi)[side][axis]
            u, v = np.zeros(3), np.zeros(3)
            u[ua], v[va] = hi[ua] - lo[ua], hi[va] - lo[va]
            n = np.zeros(3)
            n[axis] = (1.0 if side else -1.0) * (-1.0 if inward else 1.0)
            out.append(_quad(o, u, v, n, (holes or {}).get((axis, side))))
    return out


def _scene(parts, name, albedo=0.7) -> Scene:
    pts, tris, base = [], [], 0
    for p, t in parts:
        if len(t) == 0:
            continue
        pts.append(p)
        tris.append(t + base)
        base += len(p)
    return Scene(np.concatenate(pts), np.concatenate(tris), albedo=albedo, name=name)


def _wall_with_hole(x0, x1, y0, y1, z0, z1, hole):
    """A wall slab [x0, x1] (thin along x) between the two rooms beside it, with a hole
    (z0h, z1h, y0h, y1h) through it: both faces cut, the hole's four jambs closed."""
    zh0, zh1, yh0, yh1 = hole
    parts = [
        _quad([x0, y0, z0], [0, 0, z1 - z0], [0, y1 - y0, 0], [-1, 0, 0], (zh0 - z0, zh1 - z0, yh0 - y0, yh1 - y0)),
        _quad([x1, y0, z0], [0, 0, z1 - z0], [0, y1 - y0, 0], [1, 0, 0], (zh0 - z0, zh1 - z0, yh0 - y0, yh1 - y0)),
    ]
    d = x1 - x0
    parts += [
        _quad([x0, yh0, zh0], [d, 0, 0], [0, yh1 - yh0, 0], [0, 0, 1], cell=CELL / 2),  # jambs face the hole
        _quad([x0, yh0, zh1], [d, 0, 0], [0, yh1 - yh0, 0], [0, 0, -1], cell=CELL / 2),
    ]
    if yh1 < y1:
        parts.append(_quad([x0, yh1, zh0], [d, 0, 0], [0, 0, zh1 - zh0], [0, -1, 0], cell=CELL / 2))
    if yh0 > y0:
        parts.append(_quad([x0, yh0, zh0], [d, 0, 0], [0, 0, zh1 - zh0], [0, 1, 0], cell=CELL / 2))
    return parts


def two_rooms_and_a_door():
    """Two 2 x 1.5 x 2 rooms side by side along x, a 0.1-thick wall between them with a narrow
    door (0.25 wide, 1 high) near one side; a lamp in the first room only."""
    W, H, D, t = 2.0, 1.5, 2.0, 0.125
    parts = _box([0, 0, 0], [2 * W + t, H, D], inward=True)
    parts += _wall_with_hole(W, W + t, 0, H, 0, D, (1.5, 1.75, 0.0, 1.0))
    return _scene(parts, "two rooms and a door"), [PointLight((0.6, 1.2, 0.6), (2.0,) * 3)], (1.0, 0.8, 1.0)


def sealed_room_beside_a_lit_one():
    """A lit room and a sealed room sharing a thin (0.125) wall: nothing of the second is lit."""
    parts = _box([0, 0, 0], [2, 1.5, 2], inward=True)
    parts += _box([2.125, 0, 0], [4.125, 1.5, 2], inward=True)
    return _scene(parts, "sealed room beside a lit one"), [PointLight((1.0, 1.2, 1.0), (2.0,) * 3)], (0.5, 0.8, 0.5)


def box_in_a_box():
    """A hollow box (walls 0.125 thick) inside a lit room: its inside is dark."""
    parts = _box([0, 0, 0], [3, 2, 3], inward=True)
    parts += _box([1.0, 0.0, 1.0], [2.0, 1.0, 2.0], inward=False, skip=[(1, 0)])  # standing on the floor
    parts += _box([1.125, 0.125, 1.125], [1.875, 0.875, 1.875], inward=True)
    return _scene(parts, "box in a box"), [PointLight((0.5, 1.7, 0.5), (3.0,) * 3)], (0.5, 1.0, 2.5)


def closed_corner():
    """A lit room whose far corner is closed off by two thin walls from floor to ceiling: a
    closet with no door, its inside dark, its inner walls coplanar with the room's lit ones."""
    W, H = 3.0, 1.5
    c, t = 2.0, 0.125  # the closet [c + t, W] x [c + t, W]; its walls' outside faces at c
    # The room's faces where the closet stands are the closet's own (cut out of the room's).
    parts = _box(
        [0, 0, 0],
        [W, H, W],
        inward=True,
        holes={
            (0, 1): (-1, H + 1, c, W + 1),
            (2, 1): (c, W + 1, -1, H + 1),
            (1, 0): (c, W + 1, c, W + 1),
            (1, 1): (c, W + 1, c, W + 1),
        },
    )
    parts.append(_quad([c, 0, c], [0, 0, W - c], [0, H, 0], [-1, 0, 0]))  # outside faces, into the room
    parts.append(_quad([c, 0, c], [W - c, 0, 0], [0, H, 0], [0, 0, -1]))
    parts += _box([c + t, 0, c + t], [W, H, W], inward=True)  # the closet's inside
    return _scene(parts, "closed corner"), [PointLight((0.8, 1.2, 0.8), (2.0,) * 3)], (0.6, 0.8, 1.2)


def room_with_a_window():
    """A room (walls 0.125 thick) on open ground, lit by a low sun through one window."""
    W, H, t = 2.0, 1.5, 0.125
    parts = [_quad([-1, 0, -1], [4, 0, 0], [0, 0, 4], [0, 1, 0], (1 - t, 1 + W + t, 1 - t, 1 + W + t))]  # the ground
    parts += _box([0, 0, 0], [W, H, W], inward=True, skip=[(0, 0)])  # inside; its -x wall has the window
    parts += _box([-t, 0, -t], [W + t, H + t, W + t], inward=False, skip=[(1, 0), (0, 0)])
    parts += _wall_with_hole(-t, 0, 0, H, 0, W, (0.75, 1.25, 0.5, 1.0))
    sun = [DirectionalLight((1.0, -0.6, 0.2), (3.0,) * 3)]
    return _scene(parts, "room with a window"), sun, (1.0, 0.8, 1.0)


LEAK_SCENES = {
    "two rooms and a door": two_rooms_and_a_door,
    "sealed room": sealed_room_beside_a_lit_one,
    "box in a box": box_in_a_box,
    "closed corner": closed_corner,
    "sun through a window": room_with_a_window,
}


def leak_scene(name: str):
    """(scene, lights, observer) of :data:`LEAK_SCENES` ``name``."""
    return LEAK_SCENES[name]()


if __name__ == "__main__":  # patches per scene
    for k, make in LEAK_SCENES.items():
        s = make()[0]
        print(k, len(s))
