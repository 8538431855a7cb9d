"""Direct light of emitting patches by Lambert's contour integral with shadow-ray visibility."""

import numpy as np
import pytest
from helpers import ceiling_lit_box

import pydynrad
from pydynrad.formfactors import _polygon_form_factor
from pydynrad.photometry import illuminance

EMITTER = np.array([[0, 0, 1], [0, 1, 1], [1, 1, 1], [1, 0, 1]], float)  # 1 x 1 m at z = 1, facing down


def exact(polygon, p, n):
    """Point-to-polygon form factor, the polygon clipped to the point's half-space (numpy, float64)."""
    z = n / np.linalg.norm(n)
    x = np.cross(z, [0.123, 1.0, 0.2])
    x /= np.linalg.norm(x)
    q = (polygon - p) @ np.stack([x, np.cross(z, x), z], 1)
    out = []
    for a, b in zip(q, np.roll(q, -1, axis=0)):
        if a[2] >= 0:
            out.append(a)
        if (a[2] >= 0) != (b[2] >= 0):
            out.append(a + (b - a) * (a[2] / (a[2] - b[2])))
    return float(_polygon_form_factor(np.array(out))) if len(out) >= 3 else 0.0


def test_unoccluded_emitter_matches_the_contour_integral(device):
    scene = pydynrad.Scene(EMITTER, [[0, 1, 2], [0, 2, 3]], albedo=0.0, emission=100.0)
    points = np.array([[0.3, 0.4, 0.0], [0.5, 0.5, 0.94], [1.06, 0.5, 0.94], [0.2, 0.7, 0.5], [0.5, 0.5, 0.999]])
    normals = np.array([[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0.3, -0.2, 1], [0, 1, 0.01]], float)
    E = illuminance(scene, None, points, normals, emitters="analytic", device=device)
    expected = [100.0 * exact(EMITTER, p, n / np.linalg.norm(n)) for p, n in zip(points, normals)]
    # Straddling the receiver's plane (points 1, 2, 4) included; float32 on the device: 1e-6.
    np.testing.assert_allclose(E[:, 0], expected, rtol=2e-5)
    # Behind the emitter nothing arrives.
    assert illuminance(scene, None, [0.5, 0.5, 1.5], [0, 0, -1], emitters="analytic", device=device)[0, 0] == 0


def test_occluders_hide_the_emitter(device):
    # A black blocker at z = 0.5 over x < 0.5, between the emitter and points on the floor.
    blocker = np.array([[-1, -1, 0.5], [0.5, -1, 0.5], [0.5, 2, 0.5], [-1, 2, 0.5]], float)
    pts = np.vstack([EMITTER, blocker])
    tris = [[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]]
    emission = np.array([100.0, 100.0, 0.0, 0.0])[:, None].repeat(3, 1)
    scene = pydynrad.Scene(pts, tris, albedo=0.0, emission=emission)
    # From (0.4, 0.5, 0) the blocker's edge hides the emitter where x < 0.6.
    p = np.array([0.4, 0.5, 0.0])
    E = illuminance(scene, None, p, [0, 0, 1], emitters="analytic", visibility_grid=16, device=device)[0, 0]
    visible = 100.0 * exact(np.array([[0.6, 0, 1], [0.6, 1, 1], [1, 1, 1], [1, 0, 1]], float), p, np.array([0, 0, 1.0]))
    # The visible share is sampled (16 x 16 points per triangle, weighted by cos cos / r^2):
    # -1.9% here; the same estimator in numpy gives +0.1% at 256 x 256.
    assert E == pytest.approx(visible, rel=0.04)
    hidden = illuminance(scene, None, [0.0, 0.5, 0.0], [0, 0, 1], emitters="analytic", device=device)[0, 0]
    assert hidden == 0.0  # from x = 0 all of the emitter is behind the blocker


def test_analytic_emitters_and_hemicube_agree_in_a_lit_box(device):
    # The box lit by its ceiling, solved with hemicube F; sensors from 0.9 m to 3 cm below the
    # ceiling, facing up and sideways, both ways (the hemicube gathering B, or B - E plus the
    # contour integral).
    room = ceiling_lit_box(albedo=0.5)
    B = pydynrad.solve(room, pydynrad.form_factors(room, 64, device=device), device=device).radiosity
    points = np.array([[0.5, 0.5, 0.1], [0.3, 0.7, 0.2], [0.5, 0.5, 0.9], [0.2, 0.5, 0.95], [0.5, 0.5, 0.97]])
    for normal in ([0, 0, 1], [1, 0, 0]):
        a = illuminance(room, B, points, normal, emitters="analytic", resolution=128, device=device)
        h = illuminance(room, B, points, normal, resolution=128, device=device)
        # 0.2% at most observed at R = 128 (the hemicube's pixels against the emitter's edges).
        np.testing.assert_allclose(h, a, rtol=5e-3)


def _exact_rows(scene):
    """Dense F of a convex scene by Lambert's contour integral at each patch centre (no occlusion)."""
    V, C, N = (a.astype(np.float64) for a in (scene.triangles, scene.centers, scene.normals))
    F = np.zeros((len(scene), len(scene)))
    for i in range(len(scene)):
        x = np.cross(N[i], [0.123, 1.0, 0.2])
        x /= np.linalg.norm(x)
        q = (V - C[i]) @ np.stack([x, np.cross(N[i], x), N[i]], 1)
        seen = ~np.all(np.abs(q[..., 2]) < 1e-9, axis=1)  # patches in i's own plane: 0
        F[i, seen] = _polygon_form_factor(q[seen])
    return F


def test_solve_with_analytic_emitters_is_closer_to_exact_form_factors(device):
    # The ceiling-lit box (192 patches, rho = 0.5): a dense solve with point-to-patch form
    # factors from Lambert's formula is the truth for both (rows at the centres, as hemicubes).
    room = ceiling_lit_box(albedo=0.5)
    truth = np.linalg.solve(np.eye(len(room)) - 0.5 * _exact_rows(room), room.emission[:, 0].astype(np.float64))
    F = pydynrad.form_factors(room, 16, device=device)
    hemi = pydynrad.solve(room, F, tol=1e-9, device=device).radiosity[:, 0]
    exact = pydynrad.solve(room, F, tol=1e-9, emitters="analytic", device=device)
    lit = room.emission[:, 0] == 0
    err_h = np.abs(hemi - truth)[lit] / truth[lit]
    err_a = np.abs(exact.radiosity[:, 0] - truth)[lit] / truth[lit]
    # R = 16: the hemicube 1.0% RMS (3.5% at worst), analytic emitters 0.23% (0.8%): the rest
    # is F's error on the reflected light alone.
    assert np.sqrt(np.mean(err_a**2)) < 0.004 and err_a.max() < 0.012
    assert np.sqrt(np.mean(err_a**2)) < 0.4 * np.sqrt(np.mean(err_h**2))
    np.testing.assert_allclose(exact.radiosity[~lit, 0], truth[~lit], rtol=3e-3)  # the ceiling: E + its reflection
    dyn = pydynrad.DynamicRadiosity(
        room, F, local_size=len(room), storage="fp64", observer=[0.5, 0.5, 0.5], device=device
    )
    np.testing.assert_allclose(dyn.radiosity(emitters="analytic"), exact.radiosity, rtol=1e-5)
    with pytest.raises(pydynrad.InvalidInputError, match="cannot be split"):
        pydynrad.solve(room, F, light=exact.light, emitters="analytic", device=device)
