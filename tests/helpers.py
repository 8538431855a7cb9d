"""Inputs and truths shared by the tests, written independently of the code under test.

Meshes built by hand (a closed box, a flat grid), random form-factor matrices that satisfy
reciprocity and chosen row sums exactly (so the algebra is tested apart from the hemicube's
discretisation), dense float64 truths in plain numpy, and a brute-force ray caster.
"""

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

import pydynrad
from pydynrad.geometry.objects import instanced


# -- meshes ----------------------------------------------------------------------------------------
def pose(angle_deg, at) -> np.ndarray:
    """(4, 4) rigid pose: a rotation about +y by ``angle_deg`` degrees, then a translation to ``at``."""
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    T = np.eye(4)
    T[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    T[:3, 3] = at
    return T


def box_mesh(n: int = 2, size: float = 1.0, inward: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A closed cube [0, size]^3, each face an n x n grid of quads split into 2 triangles
    (12 n^2 triangles), normals pointing into the cube (or out of it): (points, triangles)."""
    pts, tris = [], []
    g = np.linspace(0.0, size, n + 1)
    for axis in range(3):
        for side in (0.0, size):
            u_ax, v_ax = [a for a in range(3) if a != axis]
            base = len(pts)
            for a in g:
                for b in g:
                    p = np.zeros(3)
                    p[axis], p[u_ax], p[v_ax] = side, a, b
                    pts.append(p)
            for i in range(n):
                for j in range(n):
                    q = [
                        base + i * (n + 1) + j,
                        base + (i + 1) * (n + 1) + j,
                        base + (i + 1) * (n + 1) + j + 1,
                        base + i * (n + 1) + j + 1,
                    ]
                    tris += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
    pts, tris = np.array(pts), np.array(tris)
    v = pts[tris]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    outward = np.sum(normal * (v.mean(axis=1) - size / 2), axis=1) > 0
    flip = outward if inward else ~outward
    tris[flip] = tris[flip][:, ::-1]
    return pts, tris


def box_scene(n: int = 2, albedo=0.5, emission=0.0, size: float = 1.0) -> pydynrad.Scene:
    """:func:`box_mesh` (inward normals, the lit side faces the interior) as a Scene."""
    return pydynrad.Scene(*box_mesh(n, size), albedo=albedo, emission=emission, name="test box")


def coloured_box(n: int = 4, seed: int = 0, grey: bool = False, albedo=None, emitters: int = 0) -> pydynrad.Scene:
    """:func:`box_scene` with random albedos in [0.1, 0.9) (per patch, per channel unless grey)
    and ``emitters`` random patches of emission 5."""
    scene = box_scene(n)
    rng = np.random.default_rng(seed)
    N = len(scene)
    if albedo is None:
        albedo = rng.uniform(0.1, 0.9, N if grey else (N, 3))
    emission = np.zeros((N, 3))
    emission[rng.choice(N, emitters, replace=False)] = 5.0
    return scene.with_materials(albedo=albedo, emission=emission)


def plane_mesh(n: int, size: float = 1.0, z: float = 0.0, origin=(0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The square [x0, x0 + size] x [y0, y0 + size] on the plane z, an n x n grid of quads split
    into 2 triangles each (2 n^2 triangles, normals +z): (points, triangles)."""
    g = np.linspace(0.0, size, n + 1)
    X, Y = np.meshgrid(g + origin[0], g + origin[1], indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), np.full(X.size, float(z))], axis=1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    b, c, d = a + n + 1, a + n + 2, a + 1
    tris = np.stack([np.stack([a, b, c], 1), np.stack([a, c, d], 1)], axis=1).reshape(-1, 3)
    return pts, tris


def grid_scene(n_side: int = 6, z: float = 0.0) -> pydynrad.Scene:
    """A flat n_side x n_side grid of unit squares, two triangles each: 2 n_side^2 patches."""
    return pydynrad.Scene(*plane_mesh(n_side, size=float(n_side), z=z), name="grid")


# -- form factors ----------------------------------------------------------------------------------
def reciprocal_F(areas, row_sum=1.0, density=0.3, seed=0) -> sp.csr_matrix:
    """Random sparse F >= 0 with A_i F_ij = A_j F_ji and every row summing to ``row_sum``
    (a symmetric Sinkhorn scaling of a random symmetric pattern), zero diagonal."""
    rng = np.random.default_rng(seed)
    a = np.asarray(areas, dtype=np.float64)
    n = len(a)
    S = sp.random(n, n, density=density, random_state=rng, format="csr")
    S = S + S.T + sp.diags(np.full(n - 1, 0.5), 1) + sp.diags(np.full(n - 1, 0.5), -1)  # connected
    S = sp.csr_matrix(S - sp.diags(S.diagonal()))
    d = np.ones(n)
    for _ in range(2000):
        d = np.sqrt(d * a / (S @ d))
    S = sp.diags(d) @ S @ sp.diags(d)
    F = sp.csr_matrix(sp.diags(row_sum / a) @ S)
    assert np.allclose(np.asarray(F.sum(axis=1)).ravel(), row_sum, rtol=1e-12)
    return F


def synthetic_rows(scene, rows, resolution, device=None) -> sp.csr_matrix:
    """Deterministic stand-in for hemicube rows (the ``row_function`` of a store): row i depends
    only on (i, N, resolution)."""
    n = len(scene)
    parts = []
    for i in rows:
        rng = np.random.default_rng([int(i), n, resolution])
        cols = np.sort(rng.choice(n, size=int(rng.integers(0, min(n, 20))), replace=False))
        vals = rng.random(cols.size).astype(np.float32) / 40
        parts.append(sp.csr_matrix((vals, cols, [0, cols.size]), shape=(1, n)))
    return sp.vstack(parts, format="csr").astype(np.float32)


def same_csr(a, b) -> bool:
    """Equal shape, dtype and every value: bit for bit."""
    a, b = sp.csr_matrix(a), sp.csr_matrix(b)
    return a.shape == b.shape and a.dtype == b.dtype and (a != b).nnz == 0


# -- dense truths ----------------------------------------------------------------------------------
def rel(a, b) -> float:
    """max |a - b| relative to max |b|."""
    return float(np.abs(np.asarray(a) - b).max() / np.abs(b).max())


def dense_radiosity(scene, F, L, patches=None) -> np.ndarray:
    """B = L + P F B solved per colour channel in float64, L (N, 3): (N, 3); with ``patches`` S,
    B_S of the closed sub-system B_S = L_S + P_S F_SS B_S: (len(S), 3)."""
    S = np.arange(len(scene)) if patches is None else np.asarray(patches)
    Fs = sp.csr_matrix(F).toarray().astype(np.float64)[np.ix_(S, S)]
    rho, L = scene.albedo[S].astype(np.float64), np.asarray(L, np.float64)[S]
    return np.stack([np.linalg.solve(np.eye(len(S)) - rho[:, c : c + 1] * Fs, L[:, c]) for c in range(3)], axis=1)


def dense_K(scene, F, patches=None, channels: int = 3) -> np.ndarray:
    """K_S = (I - F_SS P_S)^-1 F_SS over the patches S (all by default, in the given order),
    per albedo channel, in float64: (channels, M, M)."""
    Fd = sp.csr_matrix(F).toarray().astype(np.float64)
    S = np.arange(len(scene)) if patches is None else np.asarray(patches)
    Fs = Fd[np.ix_(S, S)]
    rho = scene.albedo[S].astype(np.float64)
    return np.stack([np.linalg.solve(np.eye(len(S)) - Fs * rho[None, :, c], Fs) for c in range(channels)])


def observer_walk(rng, steps: int, start=(0.5, 0.5, 0.5), step: float = 0.12, lo: float = 0.02, hi: float = 0.98):
    """Random observer positions inside [lo, hi]^3 (the unit box), moving a bit each frame."""
    p = np.array(start, dtype=np.float64)
    for _ in range(steps):
        p = np.clip(p + rng.normal(0, step, 3), lo, hi)
        yield p


# -- brute-force ray casting -----------------------------------------------------------------------
class Hits(NamedTuple):
    """Per ray: nearest patch (-1 for a miss), its distance t (inf), whether it is a front face,
    the second-nearest distance, the hit's barycentrics (zeros for a miss) and ``margin``, the
    smallest barycentric (small: the ray grazes an edge; inf for a miss)."""

    patch: np.ndarray
    t: np.ndarray
    front: np.ndarray
    second: np.ndarray
    barycentric: np.ndarray
    margin: np.ndarray


def brute_force_hits(vertices, origins, directions, chunk: int = 128) -> Hits:
    """Every ray against every triangle (N, 3, 3) by float64 Moller-Trumbore in numpy, in chunks
    of rays. ``origins`` is (R, 3) or one point for all rays."""
    v = np.asarray(vertices, np.float64)
    d_all = np.asarray(directions, np.float64).reshape(-1, 3)
    o_all = np.broadcast_to(np.asarray(origins, np.float64), d_all.shape)
    v0, e1, e2 = v[:, 0], v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    R = len(d_all)
    patch, front = np.full(R, -1), np.zeros(R, bool)
    t_near, second, bary = np.full(R, np.inf), np.full(R, np.inf), np.zeros((R, 3))
    for s in range(0, R, chunk):
        o, d = o_all[s : s + chunk, None, :], d_all[s : s + chunk, None, :]
        p = np.cross(d, e2)
        det = np.einsum("rnk,nk->rn", p, e1)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            sv = o - v0
            u = np.einsum("rnk,rnk->rn", sv, p) * inv
            q = np.cross(sv, e1)
            w = np.einsum("rnk,rnk->rn", np.broadcast_to(d, q.shape), q) * inv
            t = np.einsum("nk,rnk->rn", e2, q) * inv
            t = np.where((det != 0) & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0), t, np.inf)
        rows = np.arange(len(t))
        best = np.argmin(t, axis=1)
        hit = np.isfinite(t[rows, best])
        sl = slice(s, s + len(t))
        patch[sl] = np.where(hit, best, -1)
        t_near[sl] = t[rows, best]
        front[sl] = hit & (det[rows, best] > 0)
        if t.shape[1] > 1:
            second[sl] = np.partition(t, 1, axis=1)[:, 1]
        bu, bw = np.where(hit, u[rows, best], 0.0), np.where(hit, w[rows, best], 0.0)
        bary[sl] = np.where(hit[:, None], np.stack([1 - bu - bw, bu, bw], axis=1), 0.0)
    margin = np.where(patch >= 0, bary.min(axis=1), np.inf)
    return Hits(patch, t_near, front, second, bary, margin)


# -- the command line ----------------------------------------------------------------------------
def run_main(argv, capsys):
    """pydynrad.cli.main.main(argv) -> (exit code, stdout, stderr); argparse's own exits count as exit codes."""
    from pydynrad.cli.main import main

    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, *needles):
    """A user error: exit status 2 and one line on stderr holding every needle, no traceback."""
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], lines[0]


def ceiling_lit_box(albedo: float, exitance: float = 10.0, subdivisions: int = 2) -> pydynrad.Scene:
    """The unit closed box whose ceiling (wall 5, z = 1) emits ``exitance``; the rest emits nothing."""
    scene = pydynrad.scenes.closed_box(subdivisions=subdivisions, albedo=albedo, emission=0.0)
    emission = np.zeros((len(scene), 3))
    emission[scene.source_face // 2 == 5] = exitance
    return scene.with_materials(emission=emission)


# -- A block moving through the Cornell box (tests/dynamic and tests/precompute) -------------------
#: Hemicube resolution of the moving-object tests.
MOVING_R = 16
#: Where the observer stands: the box's open side, at mid height.
MOVING_OBSERVER = (278.0, 273.0, 0.0)
#: W/sr in the millimetre box, irradiance per square metre.
MOVING_LIGHTS = [pydynrad.PointLight((278.0, 500.0, 280.0), (0.3, 0.3, 0.3))]
#: The block's poses: on the floor, in the air, near the right wall.
START, MIDDLE, END = pose(0, (150.0, 300.0, 400.0)), pose(30, (250.0, 420.0, 300.0)), pose(70, (380.0, 420.0, 150.0))


def moving_full_solve(scene, objects, device):
    """B of the world from scratch: fresh hemicubes of every patch, solved in float64."""
    world = instanced(scene, objects)
    F = pydynrad.form_factors(world, MOVING_R, device=device)
    return world, F, dense_radiosity(world, F, pydynrad.light_vector(world, MOVING_LIGHTS, device=device))


def store_of(scene, F, folder, resolution: int):
    """``folder``, a store of ``scene`` holding F's own rows (no hemicubes run) and the far
    field's G for the default clusters: a walk from it reads what a walk with F in memory holds."""
    from pydynrad.farfield.clusters import cluster_patches
    from pydynrad.precompute.store import compute_store

    compute_store(
        scene,
        folder,
        resolution=resolution,
        clusters=cluster_patches(scene),
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    return folder
