"""Independent inputs for the radiosity tests: a closed box scene built by hand and random
form-factor matrices that satisfy reciprocity and chosen row sums exactly (so the algebra
is tested apart from the hemicube's discretisation)."""

import numpy as np
import scipy.sparse as sp

import pydynrad


def box_scene(n: int = 2, albedo=0.5, emission=0.0, size: float = 1.0) -> pydynrad.Scene:
    """A closed cube [0, size]^3, each face an n x n grid of quads split into 2 triangles,
    normals pointing inwards (the lit side faces the interior)."""
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
                    q = [base + i * (n + 1) + j, base + (i + 1) * (n + 1) + j,
                         base + (i + 1) * (n + 1) + j + 1, base + i * (n + 1) + j + 1]
                    tris += [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]
    pts, tris = np.array(pts), np.array(tris)
    # Orient every triangle so its normal points into the cube.
    v = pts[tris]
    normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    inward = np.sum(normal * (size / 2 - v.mean(axis=1)), axis=1) > 0
    tris[~inward] = tris[~inward][:, ::-1]
    return pydynrad.Scene(pts, tris, albedo=albedo, emission=emission, name="test box")


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
    F = sp.diags(row_sum / a) @ S
    F = sp.csr_matrix(F)
    assert np.allclose(np.asarray(F.sum(axis=1)).ravel(), row_sum, rtol=1e-12)
    return F
