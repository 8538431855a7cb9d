"""CIE 171:2006 analytic test cases (bench/cie171.py builds and runs them): each point within
the issue's 2% of a reference computed here from the published formula, and near the error we
observe. Resolutions: sensor hemicubes R = 128, the 5.8 room solved with R = 32 on 0.5 m patches."""

import math

import numpy as np
import pytest
from scipy import integrate

from bench import cie171
from pydynrad.lights import parse_ies

CIE_TOLERANCE = 0.02  # the per-point requirement (CIE's own practice: 5%)


def _point(label: str) -> np.ndarray:
    return np.array([float(v) for v in label.strip("()").split(",")])


def _check(rows, reference, tol, bench_rtol=1e-6):
    """Rows' points against this file's references: within tol and within the CIE tolerance;
    the bench's own reference within bench_rtol of this file's."""
    ours = np.array([r[3] for r in rows])
    err = np.abs(ours - reference) / reference
    assert np.all(err < min(tol, CIE_TOLERANCE)), (err, rows)
    np.testing.assert_allclose([r[2] for r in rows], reference, rtol=bench_rtol)


def test_5_2_point_sources(device):
    rows = cie171.case_5_2(device)
    src = (2.0, 2.0, 2.5)
    for kind in ("isotropic", "cosine"):
        mine = [r for r in rows if r[0] == f"5.2 {kind}"]
        ref = []
        for r in mine:
            x, y, z = _point(r[1])
            normal = (0.0, 0.0, 1.0) if z == 0 else (1.0, 0.0, 0.0)
            dx, dy, dz = src[0] - x, src[1] - y, src[2] - z
            d = math.sqrt(dx * dx + dy * dy + dz * dz)
            cos_theta = (dx * normal[0] + dy * normal[1] + dz * normal[2]) / d
            intensity = 1000.0 if kind == "isotropic" else 1000.0 * dz / d  # I0 cos(gamma), gamma from straight down
            ref.append(intensity * cos_theta / d**2)
        _check(mine, np.array(ref), 2e-5)  # 4.7e-6 observed (float32)


def _corner(a, b, h):
    # Point h below a corner of an a x b rectangle in a parallel plane (signed a, b).
    A, B = a / h, b / h
    a_side = A / math.hypot(1, A) * math.atan(B / math.hypot(1, A))
    b_side = B / math.hypot(1, B) * math.atan(A / math.hypot(1, B))
    return (a_side + b_side) / (2 * math.pi)


def _parallel(x, y, rect, h):
    x0, x1, y0, y1 = rect
    return (
        _corner(x1 - x, y1 - y, h)
        - _corner(x0 - x, y1 - y, h)
        - _corner(x1 - x, y0 - y, h)
        + _corner(x0 - x, y0 - y, h)
    )


def _lambert(p, n, corners):
    # Lambert's contour integral, edge by edge.
    total = 0.0
    for k in range(len(corners)):
        a, b = np.subtract(corners[k], p), np.subtract(corners[(k + 1) % len(corners)], p)
        c = np.cross(a, b)
        gamma = math.acos(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
        total += gamma * np.dot(c, n) / np.linalg.norm(c)
    return abs(total) / (2 * math.pi)


def test_5_3_area_source(device):
    rows = cie171.case_5_3(device)
    x0, x1, y0, y1 = cie171.AREA_SOURCE
    square = [(x0, y0, 3.0), (x1, y0, 3.0), (x1, y1, 3.0), (x0, y1, 3.0)]
    ref = {}
    for r in rows:
        x, y, z = _point(r[1])
        on_floor = z == 0
        ref[r[1]] = 1000.0 * (
            _parallel(x, y, cie171.AREA_SOURCE, 3.0) if on_floor else _lambert((x, y, z), (1, 0, 0), square)
        )
    contour = [r for r in rows if r[0] == "5.3 contour"]
    _check(contour, np.array([ref[r[1]] for r in contour]), 1e-5)  # 2.2e-7 observed
    # The hemicube, except 20 cm below the ceiling on the wall, where it sees the source
    # edge-on at 7.6 degrees: 14% too much at R = 128 (the reason for the contour integral).
    hemi = [r for r in rows if r[0].startswith("5.3 hemicube") and r[1] != "(0, 1, 2.8)"]
    _check(hemi, np.array([ref[r[1]] for r in hemi]), 5e-3)  # 2.3e-3 observed


def test_5_4_flux_conservation(device):
    rows = cie171.case_5_4(device)
    lm63 = parse_ies(cie171.LM63_EXAMPLE)
    # Flux of the interpolated table by a Gauss-Legendre rule per table interval (gamma) and C.
    g_nodes, g_w = np.polynomial.legendre.leggauss(8)
    flux = 0.0
    for ga, gb in zip(lm63.gamma_angles[:-1], lm63.gamma_angles[1:]):
        gam = 0.5 * (ga + gb) + 0.5 * (gb - ga) * g_nodes
        for ca, cb in zip(lm63.c_angles[:-1], lm63.c_angles[1:]):
            c = 0.5 * (ca + cb) + 0.5 * (cb - ca) * g_nodes
            I = lm63.intensity(c[:, None], gam[None, :])
            cell = np.radians(cb - ca) * np.radians(gb - ga) / 4
            flux += float(g_w @ (I * np.sin(np.radians(gam))[None, :]) @ g_w) * cell
    _check(rows, np.array([4 * math.pi * 1000.0, flux]), 2e-3)  # 1.3e-4 and 4.1e-4 observed


def _reflected(p, n, holes):
    """int over the floor minus ``holes`` of (rho/pi) E_d cos cos / r^2, by scipy per cell."""
    src = cie171.FLOOR_SOURCE
    xs = sorted({0.0, 4.0, *[min(max(v, 0.0), 4.0) for h in holes for v in h[:2]]})
    ys = sorted({0.0, 4.0, *[min(max(v, 0.0), 4.0) for h in holes for v in h[2:]]})

    def f(y, x):
        dx, dy, dz = x - p[0], y - p[1], -p[2]
        r2 = dx * dx + dy * dy + dz * dz
        e_d = 1000.0 * src[2] / ((src[0] - x) ** 2 + (src[1] - y) ** 2 + src[2] ** 2) ** 1.5
        return 0.5 / math.pi * e_d * max(dx * n[0] + dy * n[1] + dz * n[2], 0.0) * (-dz) / r2**2

    total = 0.0
    for xa, xb in zip(xs[:-1], xs[1:]):
        for ya, yb in zip(ys[:-1], ys[1:]):
            cx, cy = (xa + xb) / 2, (ya + yb) / 2
            if not any(h[0] < cx < h[1] and h[2] < cy < h[3] for h in holes):
                total += integrate.dblquad(f, xa, xb, ya, yb, epsabs=1e-10, epsrel=1e-8)[0]
    return total


def _projection(apex, square, z):
    # Central projection from apex of the horizontal square (x0, x1, y0, y1) at height z onto the floor.
    k = apex[2] / (apex[2] - z)
    xs = sorted(apex[0] + (v - apex[0]) * k for v in square[:2])
    ys = sorted(apex[1] + (v - apex[1]) * k for v in square[2:])
    return (*xs, *ys)


_REFLECTION_NORMALS = {"(3, 2, 0.3)": (0.0, 0.0, -1.0), "(1, 2, 0.2)": (-0.6, 0.0, -0.8)}


def test_5_6_diffuse_reflection(device):
    rows = cie171.case_5_6(device)
    ref = [_reflected(_point(r[1]), _REFLECTION_NORMALS.get(r[1], (0.0, 0.0, -1.0)), []) for r in rows]
    # The bench's fixed Gauss-Legendre rule meets the kink where the tilted point's own plane
    # crosses the floor: 3e-5 off scipy's adaptive rule there.
    _check(rows, np.array(ref), 1e-3, bench_rtol=1e-4)  # 1.2e-4 observed


def test_5_7_diffuse_reflection_with_an_obstruction(device):
    rows = cie171.case_5_7(device)
    x0, x1, y0, y1, z = cie171.OBSTRUCTION
    shadow = _projection(cie171.FLOOR_SOURCE, (x0, x1, y0, y1), z)  # the floor the source cannot reach
    ref = []
    for r in rows:
        p = _point(r[1])
        holes = [shadow] + ([_projection(p, (x0, x1, y0, y1), z)] if p[2] > z else [])  # and what p cannot see
        ref.append(_reflected(p, _REFLECTION_NORMALS.get(r[1], (0.0, 0.0, -1.0)), holes))
    _check(rows, np.array(ref), 3e-3, bench_rtol=1e-4)  # 5.0e-4 observed


def test_5_8_internal_reflected_component(device):
    rows = cie171.case_5_8(device, resolution=32, cell=0.5)
    X, Y, Z = cie171.ROOM
    area = 2 * (X * Y + X * Z + Y * Z)
    # Flux balance of a closed room of uniform reflectance rho: the average indirect
    # illuminance is Phi rho / (A (1 - rho)).
    _check(rows, np.array([4 * math.pi * 1000.0 * 0.5 / (area * 0.5)]), 0.02)  # 0.74% observed at R = 32


def test_5_9_roof_opening_under_a_uniform_sky(device):
    rows = cie171.case_5_9(device)
    ref = [1000.0 * _parallel(*_point(r[1])[:2], cie171.OPENING, 3.0) for r in rows]  # pi L F, pi L = 1,000
    _check(rows, np.array(ref), 1e-2)  # 4.0e-3 observed at R = 128


@pytest.mark.slow
def test_5_8_at_the_bench_resolution(device):
    rows = cie171.case_5_8(device, resolution=64, cell=0.25)
    X, Y, Z = cie171.ROOM
    _check(rows, np.array([4 * math.pi * 1000.0 / (2 * (X * Y + X * Z + Y * Z))]), 5e-3)  # 0.24% observed
