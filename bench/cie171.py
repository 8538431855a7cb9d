"""CIE 171:2006 analytic test cases that a diffuse radiosity engine can check.

Each case builds its scene with the public API, computes the reference from the published
formulas (closed forms, or for the reflection cases the defining integral by fine quadrature in
float64 numpy) and returns one row per measuring point: case, point, reference, ours, error.
The geometry is a 4 x 4 x 3 m room (the report's test room), the light sources and points are
stated per case. ``tests/photometry/test_cie171.py`` checks every row against its own, independently written
references; :func:`cie171_section` is the bench report (``python -m bench --sections cie171``).

Cases: 5.2 point sources (isotropic and cosine), 5.3 an area source (floor points: the
parallel-rectangle corner formula; wall points: Lambert's contour integral), 5.4 flux
conservation in a closed black room, 5.6 light reflected by a diffuse floor, 5.7 the same with an
obstruction (the reference is computed from first principles, so the published errata of the
report's table do not enter), 5.8 the internal reflected component (average indirect
illuminance of a closed room), 5.9 a roof opening under a uniform sky.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .cie171_data import LM63_EXAMPLE

__all__ = [
    "LM63_EXAMPLE",
    "CASES",
    "ROOM",
    "room_rectangles",
    "rectangles_scene",
    "parallel_rectangle_factor",
    "contour_factor",
    "cie171_section",
]

#: The test room, metres.
ROOM = (4.0, 4.0, 3.0)


def rectangles_scene(rects, cell: float, albedo=0.0, emission=0.0, name: str = "cie171"):
    """A scene of axis-aligned rectangles ``(corner, u, v, normal)`` split into cells <= ``cell``.

    Each rectangle spans ``corner + s u + t v`` (s, t in [0, 1]) and faces ``normal``; ``albedo`` and
    ``emission`` are scalars or one value per rectangle.
    """
    import pydynrad

    pts, tris, rect_of = [], [], []
    for k, (corner, u, v, normal) in enumerate(rects):
        corner, u, v = (np.asarray(a, float) for a in (corner, u, v))
        if np.cross(u, v) @ np.asarray(normal, float) < 0:
            u, v = v, u
        nu, nv = (max(1, math.ceil(np.linalg.norm(a) / cell - 1e-9)) for a in (u, v))
        s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
        base = len(pts) and sum(len(p) for p in pts)
        pts.append(corner + s.ravel()[:, None] * u + t.ravel()[:, None] * v)
        q = (np.arange(nu)[:, None] * (nv + 1) + np.arange(nv)[None, :]).ravel() + base
        tris += [np.stack([q, q + nv + 1, q + nv + 2], 1), np.stack([q, q + nv + 2, q + 1], 1)]
        rect_of += [k] * (2 * nu * nv)
    rect_of = np.asarray(rect_of)
    per_rect = lambda value: np.asarray(value, float)[rect_of] if np.ndim(value) else value  # noqa: E731
    return pydynrad.Scene(
        np.concatenate(pts), np.concatenate(tris), albedo=per_rect(albedo), emission=per_rect(emission), name=name
    ), rect_of


def room_rectangles(opening=None, ceiling_emitter=None) -> list:
    """The room's six inward-facing walls; the ceiling optionally with a square ``opening`` (x0, x1,
    y0, y1) left out, or split so that ``ceiling_emitter`` (x0, x1, y0, y1) is its own rectangle
    (last in the list)."""
    X, Y, Z = ROOM
    rects = [
        ((0, 0, 0), (X, 0, 0), (0, Y, 0), (0, 0, 1)),  # floor
        ((0, 0, 0), (0, Y, 0), (0, 0, Z), (1, 0, 0)),
        ((X, 0, 0), (0, Y, 0), (0, 0, Z), (-1, 0, 0)),
        ((0, 0, 0), (X, 0, 0), (0, 0, Z), (0, 1, 0)),
        ((0, Y, 0), (X, 0, 0), (0, 0, Z), (0, -1, 0)),
    ]
    hole = opening or ceiling_emitter
    if hole is None:
        return rects + [((0, 0, Z), (X, 0, 0), (0, Y, 0), (0, 0, -1))]
    x0, x1, y0, y1 = hole
    down = (0, 0, -1)
    rects += [
        ((0, 0, Z), (X, 0, 0), (0, y0, 0), down),
        ((0, y1, Z), (X, 0, 0), (0, Y - y1, 0), down),
        ((0, y0, Z), (x0, 0, 0), (0, y1 - y0, 0), down),
        ((x1, y0, Z), (X - x1, 0, 0), (0, y1 - y0, 0), down),
    ]
    if ceiling_emitter is not None:
        rects.append(((x0, y0, Z), (x1 - x0, 0, 0), (0, y1 - y0, 0), down))
    return rects


def parallel_rectangle_factor(p, rect, height):
    """Form factor from points ``p`` (n, 2) (facing up) to the rectangle ``rect`` = (x0, x1, y0, y1)
    ``height`` above them in a parallel plane facing down: the corner formula
    F(A, B) = [A / sqrt(1 + A^2) atan(B / sqrt(1 + A^2)) + B / sqrt(1 + B^2) atan(A / sqrt(1 + B^2))] / (2 pi),
    A = a / h, B = b / h (odd in A and B), summed over the four corners with signs."""
    p = np.atleast_2d(np.asarray(p, float))
    x0, x1, y0, y1 = rect

    def corner(a, b):
        A, B = a / height, b / height
        return (
            A / np.sqrt(1 + A * A) * np.arctan(B / np.sqrt(1 + A * A))
            + B / np.sqrt(1 + B * B) * np.arctan(A / np.sqrt(1 + B * B))
        ) / (2 * math.pi)

    x, y = p[:, 0], p[:, 1]
    return corner(x1 - x, y1 - y) - corner(x0 - x, y1 - y) - corner(x1 - x, y0 - y) + corner(x0 - x, y0 - y)


def contour_factor(p, n, polygon):
    """Lambert's contour integral from a differential area (p, unit n) to a polygon wholly in front of it."""
    r = np.asarray(polygon, float) - p
    r_next = np.roll(r, -1, axis=0)
    c = np.cross(r, r_next)
    angle = np.arctan2(np.linalg.norm(c, axis=1), np.sum(r * r_next, axis=1))
    return abs(float(np.sum(angle * (c @ n) / np.linalg.norm(c, axis=1)))) / (2 * math.pi)


def _rows(case, labels, reference, ours):
    reference, ours = np.asarray(reference, float), np.asarray(ours, float)
    return [[case, lab, float(r), float(o), float((o - r) / r)] for lab, r, o in zip(labels, reference, ours)]


def _label(p) -> str:
    return "(" + ", ".join(f"{v:g}" for v in p) + ")"


# -- 5.2 point sources ----------------------------------------------------------------------------
def case_5_2(device=None, resolution=128):
    """Isotropic (1,000 cd) and cosine (I0 = 1,000 cd, downwards) point sources 0.5 m below the
    ceiling's centre of the black room: E = I(gamma) cos(theta) / d^2 on floor and wall points."""
    import pydynrad
    from pydynrad.lights import LuminaireLight, PhotometricDistribution

    scene, _ = rectangles_scene(room_rectangles(), 0.5)
    src = np.array([2.0, 2.0, 2.5])
    points = np.array([[2, 2, 0], [1, 1, 0], [0.5, 2, 0], [3.5, 0.5, 0], [0, 2, 1.5], [0, 1, 0.5], [0, 2, 2.4]], float)
    normals = np.array([[0, 0, 1]] * 4 + [[1, 0, 0]] * 3, float)
    d = src - points
    r = np.linalg.norm(d, axis=1)
    cos_theta = np.sum(d * normals, axis=1) / r
    cos_gamma = d[:, 2] / r  # the angle from the downward nadir, seen from the source
    rows = []
    iso = pydynrad.illuminance(scene, None, points, normals, lights=pydynrad.PointLight(src, 1000.0), device=device)
    rows += _rows("5.2 isotropic", map(_label, points), 1000.0 * cos_theta / r**2, iso[:, 0])
    lam = LuminaireLight(src, PhotometricDistribution.lambertian(1000.0))
    cosine = pydynrad.illuminance(scene, None, points, normals, lights=lam, device=device)
    rows += _rows("5.2 cosine", map(_label, points), 1000.0 * np.maximum(cos_gamma, 0) * cos_theta / r**2, cosine[:, 0])
    return rows


# -- 5.3 area source ------------------------------------------------------------------------------
AREA_SOURCE = (1.5, 2.5, 1.5, 2.5)  # a 1 x 1 m ceiling emitter at the centre, exitance 1,000 lm/m2


def case_5_3(device=None, resolution=128):
    """A Lambertian 1 x 1 m ceiling source of exitance M = 1,000 lm/m2 (L = M / pi) in the black
    room: E = M F(point -> source), by the hemicube (R = ``resolution``) and by the contour integral."""
    import pydynrad

    rects = room_rectangles(ceiling_emitter=AREA_SOURCE)
    emission = [0.0] * (len(rects) - 1) + [1000.0]
    scene, _ = rectangles_scene(rects, 0.25, albedo=0.0, emission=emission)
    floor = np.array([[2, 2, 0], [1.5, 1.5, 0], [0.5, 0.5, 0], [0.5, 2, 0], [3, 2, 0]], float)
    wall = np.array([[0, 2, 1.5], [0, 2, 2.5], [0, 1, 2.8]], float)
    points = np.vstack([floor, wall])
    normals = np.array([[0, 0, 1]] * len(floor) + [[1, 0, 0]] * len(wall), float)
    x0, x1, y0, y1 = AREA_SOURCE
    square = np.array([[x0, y0, 3], [x1, y0, 3], [x1, y1, 3], [x0, y1, 3]], float)
    reference = np.concatenate(
        [
            1000.0 * parallel_rectangle_factor(floor[:, :2], AREA_SOURCE, 3.0),
            [1000.0 * contour_factor(p, np.array([1.0, 0, 0]), square) for p in wall],
        ]
    )
    B = scene.emission.astype(np.float64)  # black room: the radiosity is the emission
    hemi = pydynrad.illuminance(scene, B, points, normals, resolution=resolution, emitters="hemicube", device=device)
    exact = pydynrad.illuminance(scene, B, points, normals, emitters="analytic", device=device)
    default = pydynrad.illuminance(scene, B, points, normals, device=device)  # every setting its default
    labels = [_label(p) for p in points]
    return (
        _rows(f"5.3 hemicube R={resolution}", labels, reference, hemi[:, 0])
        + _rows("5.3 contour", labels, reference, exact[:, 0])
        + _rows("5.3 defaults", labels, reference, default[:, 0])
    )


# -- 5.4 flux conservation ------------------------------------------------------------------------
def case_5_4(device=None, resolution=128):
    """All the flux of a source inside the closed black room arrives on its walls: sum E_i A_i over
    patches (patch-centre direct light, 0.1 m cells) against the source's flux."""
    import pydynrad
    from pydynrad.lights import LuminaireLight, parse_ies

    scene, _ = rectangles_scene(room_rectangles(), 0.1)
    rows = []
    iso = pydynrad.PointLight([1.2, 2.3, 1.9], 1000.0)
    H = pydynrad.lights.direct_irradiance(scene, [iso], device).astype(np.float64)
    rows += _rows("5.4 flux", ["isotropic 1,000 cd"], [4 * math.pi * 1000.0], [np.sum(H[:, 0] * scene.areas)])
    dist = parse_ies(LM63_EXAMPLE)
    lum = LuminaireLight([2.0, 2.0, 2.7], dist, nadir=(0.2, 0.1, -1.0))
    H = pydynrad.lights.direct_irradiance(scene, [lum], device).astype(np.float64)
    rows += _rows("5.4 flux", ["LM-63-2002 example"], [dist.flux()], [np.sum(H[:, 0] * scene.areas)])
    return rows


# -- 5.6 / 5.7 diffuse reflection, with and without an obstruction ---------------------------------
FLOOR_SOURCE = np.array([2.0, 2.0, 2.0])  # 1,000 cd isotropic, 2 m above a 4 x 4 m floor of reflectance 0.5
OBSTRUCTION = (0.5, 1.5, 1.5, 2.5, 0.5)  # x0, x1, y0, y1, z: a black 1 x 1 m square


def _shadow_rectangle(apex, obstruction, plane_z: float = 0.0):
    """The central projection from ``apex`` of the horizontal obstruction square onto z = plane_z:
    an axis-aligned rectangle (x0, x1, y0, y1), or None when the square is not between them."""
    x0, x1, y0, y1, z = obstruction
    if not (min(apex[2], plane_z) < z < max(apex[2], plane_z)):
        return None
    k = (apex[2] - plane_z) / (apex[2] - z)
    xs = sorted(apex[0] + (v - apex[0]) * k for v in (x0, x1))
    ys = sorted(apex[1] + (v - apex[1]) * k for v in (y0, y1))
    return (*xs, *ys)


def reflected_reference(points, normals, obstruction=None, order: int = 16, piece: float = 0.25) -> np.ndarray:
    """E at points from the floor's reflected light: the integral over the floor of
    (rho / pi) E_d(y) cos(theta_p) cos(theta_y) / r^2 dA, E_d = I h / d^3. The obstruction's
    shadow (seen from the source) and the floor it hides from the point (seen from the point) are
    axis-aligned rectangles, so the floor is cut along their edges into cells that are wholly in or
    out, and each cell (split into pieces of at most ``piece`` m) gets an order x order Gauss-Legendre
    rule: a smooth integrand per cell (but for the kink where a tilted point's own plane meets the
    floor)."""
    rho, I = 0.5, 1000.0
    nodes, weights = np.polynomial.legendre.leggauss(order)
    out = []
    for p, nrm in zip(np.asarray(points, float), np.asarray(normals, float)):
        holes = (
            []
            if obstruction is None
            else [
                r
                for r in (_shadow_rectangle(FLOOR_SOURCE, obstruction), _shadow_rectangle(p, obstruction))
                if r is not None
            ]
        )
        cuts = [
            np.unique(np.clip([0.0, 4.0, *[h[k] for h in holes for k in axis]], 0.0, 4.0)) for axis in ((0, 1), (2, 3))
        ]
        total = 0.0
        for xa, xb in zip(cuts[0][:-1], cuts[0][1:]):
            for ya, yb in zip(cuts[1][:-1], cuts[1][1:]):
                cx, cy = 0.5 * (xa + xb), 0.5 * (ya + yb)
                if any(h[0] < cx < h[1] and h[2] < cy < h[3] for h in holes):
                    continue
                gx = np.linspace(xa, xb, max(1, math.ceil((xb - xa) / piece)) + 1)
                gy = np.linspace(ya, yb, max(1, math.ceil((yb - ya) / piece)) + 1)
                for u0, u1 in zip(gx[:-1], gx[1:]):
                    for v0, v1 in zip(gy[:-1], gy[1:]):
                        X = 0.5 * (u0 + u1) + 0.5 * (u1 - u0) * nodes
                        Y = 0.5 * (v0 + v1) + 0.5 * (v1 - v0) * nodes
                        XX, YY = np.meshgrid(X, Y, indexing="ij")
                        y = np.stack([XX, YY, np.zeros_like(XX)], axis=-1)
                        to_src = FLOOR_SOURCE - y
                        E_d = I * to_src[..., 2] / np.linalg.norm(to_src, axis=-1) ** 3
                        d = y - p
                        r2 = np.sum(d * d, axis=-1)
                        f = rho / math.pi * E_d * np.maximum(d @ nrm, 0) * np.maximum(-d[..., 2], 0) / r2**2
                        total += float(weights @ f @ weights) * 0.25 * (u1 - u0) * (v1 - v0)
        out.append(total)
    return np.array(out)


def _reflection_case(case, obstruction, device, resolution):
    import pydynrad

    rects = [((0, 0, 0), (4, 0, 0), (0, 4, 0), (0, 0, 1))]
    if obstruction is not None:
        x0, x1, y0, y1, z = obstruction
        rects += [
            ((x0, y0, z), (x1 - x0, 0, 0), (0, y1 - y0, 0), (0, 0, 1)),
            ((x0, y0, z), (x1 - x0, 0, 0), (0, y1 - y0, 0), (0, 0, -1)),
        ]
    # 1/12 m cells put patch edges on the shadow's edges (x = 4/3, y = 4/3 and 8/3): with cells
    # that cut it, triangles whose centres lie on the edge come out wholly lit or dark (1/16 m
    # cells: 4.4% at the point below the obstruction, which sees mostly that edge).
    scene, _ = rectangles_scene(rects, 1.0 / 12.0, albedo=[0.5, 0.0, 0.0][: len(rects)])
    light = pydynrad.PointLight(FLOOR_SOURCE, 1000.0)
    # A lone plane sees nothing of itself (F = 0), so its radiosity is its light vector L.
    B = pydynrad.light_vector(scene, [light], device)
    points = np.array([[2, 2, 1], [1, 1, 1], [0.5, 3, 1.5], [3, 2, 0.3], [1, 2, 0.2]], float)
    normals = np.array([[0, 0, -1]] * 3 + [[0, 0, -1], [-0.6, 0, -0.8]], float)
    ours = pydynrad.illuminance(scene, B, points, normals, resolution=resolution, device=device)
    reference = reflected_reference(points, normals, obstruction)
    return _rows(case, map(_label, points), reference, ours[:, 0])


def case_5_6(device=None, resolution=128):
    """A 4 x 4 m floor of reflectance 0.5 under a 1,000 cd source 2 m above its centre, alone in
    space; downward-facing points above it receive only the floor's reflected light."""
    return _reflection_case(f"5.6 R={resolution}", None, device, resolution)


def case_5_7(device=None, resolution=128):
    """5.6 with a black 1 x 1 m square obstruction 0.5 m above the floor: it shades the floor
    from the source and hides part of the floor from the points."""
    return _reflection_case(f"5.7 R={resolution}", OBSTRUCTION, device, resolution)


# -- 5.8 internal reflected component --------------------------------------------------------------
def case_5_8(device=None, resolution=64, cell=0.25):
    """The closed room with all surfaces of reflectance rho = 0.5 and a 1,000 cd isotropic source:
    the area-averaged indirect illuminance is Phi rho / (A (1 - rho)) (the flux balance of a closed
    room: exact whatever its shape). Solved with hemicube F at R = ``resolution``, ``cell`` m patches."""
    import pydynrad

    rho = 0.5
    scene, _ = rectangles_scene(room_rectangles(), cell, albedo=rho)
    light = pydynrad.PointLight([1.7, 2.2, 1.6], 1000.0)
    F = pydynrad.form_factors(scene, resolution, device=device)
    B = pydynrad.solve(scene, F, lights=[light], tol=1e-9, device=device).radiosity
    direct = pydynrad.lights.direct_irradiance(scene, [light], device).astype(np.float64)
    indirect = B[:, 0] / rho - direct[:, 0]  # B = rho (H_direct + H_indirect)
    A = scene.areas.astype(np.float64)
    phi = 4 * math.pi * 1000.0
    reference = phi * rho / (A.sum() * (1 - rho))
    return _rows(
        f"5.8 R={resolution}, {len(scene)} patches", ["area average"], [reference], [np.sum(indirect * A) / A.sum()]
    )


# -- 5.9 roof opening under a uniform sky ----------------------------------------------------------
OPENING = (1.5, 2.5, 1.0, 2.0)


def case_5_9(device=None, resolution=128):
    """The black room with a 1 x 1 m opening in its roof under a uniform sky of luminance
    L = 1,000 / pi cd/m2: E = pi L F(point -> opening) at floor points."""
    import pydynrad
    from pydynrad.lights import SkyLight

    scene, _ = rectangles_scene(room_rectangles(opening=OPENING), 0.5)
    points = np.array([[2, 1.5, 0], [2, 2, 0], [1, 1, 0], [3.5, 3.5, 0], [0.5, 1.5, 0]], float)
    sky = SkyLight("uniform", zenith_luminance=1000.0 / math.pi)
    ours = pydynrad.illuminance(scene, None, points, [0, 0, 1], lights=sky, resolution=resolution, device=device)
    reference = 1000.0 * parallel_rectangle_factor(points[:, :2], OPENING, 3.0)
    return _rows(f"5.9 R={resolution}", map(_label, points), reference, ours[:, 0])


#: Case -> function, in the report's order.
CASES = {
    "5.2": case_5_2,
    "5.3": case_5_3,
    "5.4": case_5_4,
    "5.6": case_5_6,
    "5.7": case_5_7,
    "5.8": case_5_8,
    "5.9": case_5_9,
}


def cie171_section(ctx) -> dict:
    """Every case's rows in one table, the worst error per case in a second."""
    p = ctx.params
    rows, worst = [], []
    for name, case in CASES.items():
        kw = (
            {"resolution": p["room_resolution"], "cell": p["room_cell"]}
            if name == "5.8"
            else {"resolution": p["resolution"]}
        )
        t0 = time.perf_counter()
        r = case(ctx.device, **kw)
        dt = time.perf_counter() - t0
        rows += r
        worst.append([name, len(r), max(abs(x[4]) for x in r), dt])
    return {
        "title": "CIE 171:2006 analytic test cases",
        "description": (
            "Each row: the case, the measuring point (m), the reference from the published formula "
            "(closed form, or for 5.6/5.7 the defining integral by Gauss-Legendre quadrature on cells cut "
            "along the shadow edges), "
            "ours, and the relative error. CIE's own validation practice accepts 5% per point; the "
            "tests (tests/photometry/test_cie171.py) require 2%. Geometry: a 4 x 4 x 3 m room; see bench/cie171.py."
        ),
        "tables": [
            {
                "title": "Points",
                "columns": ["case", "point", "reference (lx or lm)", "ours", "rel. error"],
                "rows": rows,
            },
            {
                "title": "Worst point per case",
                "columns": ["case", "points", "max |rel. error|", "time s"],
                "rows": worst,
            },
        ],
        "plots": [],
    }
