import numpy as np
import pytest
from helpers import box_mesh, brute_force_hits

from pydynrad import Camera, InvalidInputError, Scene
from pydynrad.renderer import Renderer, render, smoothing_groups


def cast_camera(scene, camera):
    """:func:`helpers.brute_force_hits` for every pixel's ray: patch (H, W), barycentrics
    (H, W, 3), front (H, W) and margin (H, W)."""
    h = brute_force_hits(scene.triangles, camera.position, camera.ray_directions())
    shape = camera.shape
    return h.patch.reshape(shape), h.barycentric.reshape(*shape, 3), h.front.reshape(shape), h.margin.reshape(shape)


@pytest.fixture(scope="module")
def cluttered_scene():
    """An inward box (open front) with tilted triangles inside: front faces, back faces and misses."""
    rng = np.random.default_rng(7)
    pts, tris = box_mesh(n=2, inward=True)
    v = pts[tris]
    keep = ~np.all(np.isclose(v[:, :, 2], 1.0), axis=1)  # remove the z = 1 wall: the camera looks in
    pts_in, tris_in = pts, tris[keep]
    centres = rng.uniform(0.25, 0.75, size=(12, 3))
    extra = centres[:, None, :] + rng.normal(scale=0.15, size=(12, 3, 3))
    all_pts = np.concatenate([pts_in, extra.reshape(-1, 3)])
    all_tris = np.concatenate([tris_in, len(pts_in) + np.arange(36).reshape(12, 3)])
    return Scene(all_pts, all_tris, albedo=0.5, emission=0.0)


def test_patch_ids_match_brute_force(device, cluttered_scene):
    cam = Camera(position=(0.5, 0.55, 2.2), look_at=(0.45, 0.5, 0.0), fov_y=50, width=48, height=36)
    vis = Renderer(cluttered_scene, device).visibility(cam)
    patch, bary, front, margin = cast_camera(cluttered_scene, cam)
    clear = margin > 1e-4  # rays that graze an edge may legitimately pick either neighbour
    assert clear.mean() > 0.95
    np.testing.assert_array_equal(vis.patch[clear], patch[clear])
    np.testing.assert_array_equal(vis.front[clear], front[clear])
    np.testing.assert_allclose(vis.barycentric[clear], bary[clear], atol=5e-5)  # float32 kernel: observed 6e-7
    # The view really covers the three cases.
    assert (patch == -1).any() and front.any() and ((patch >= 0) & ~front).any()


@pytest.mark.parametrize("shading", ["flat", "smooth"])
def test_furnace_renders_flat_image_of_expected_value(device, shading):
    # Closed box, E = 1 and rho = 0.6 everywhere: the radiosity is B = E / (1 - rho) = 2.5 on
    # every patch, so every pixel of a view from inside must show exactly 2.5.
    pts, tris = box_mesh(n=3, inward=True)
    scene = Scene(pts, tris, albedo=0.6, emission=1.0)
    b = np.full((len(scene), 3), 1.0 / (1.0 - 0.6))
    cam = Camera(position=(0.3, 0.6, 0.7), look_at=(0.9, 0.2, 0.1), fov_y=100, width=40, height=30)
    img = render(scene, b, cam, shading, background=-1.0, backface=-2.0, device=device)
    assert img.shape == (30, 40, 3) and img.dtype == np.float32
    np.testing.assert_allclose(img, 2.5, rtol=1e-6)


def test_background_and_back_faces(device):
    pts, tris = box_mesh(n=2, inward=True)
    scene = Scene(pts, tris)
    cam = Camera(position=(0.5, 0.5, 4.0), look_at=(0.5, 0.5, 0.5), fov_y=40, width=32, height=32)
    img = render(scene, np.ones(len(scene)), cam, "smooth", background=(0.1, 0.2, 0.3), backface=0.0, device=device)
    np.testing.assert_array_equal(img[0, 0], np.float32([0.1, 0.2, 0.3]))  # the corner sees the sky
    np.testing.assert_array_equal(img[16, 16], 0.0)  # the centre sees the box from outside


def two_triangles(fold_deg=0.0):
    """Two triangles sharing the edge (0,0,0)-(0,1,0); the second is folded by fold_deg."""
    a = np.radians(fold_deg)
    pts = np.array([[0, 0, 0], [0, 1, 0], [-1, 0, 0], [2 * np.cos(a), 0, 2 * np.sin(a)]], dtype=float)
    tris = np.array([[0, 1, 2], [0, 3, 1]])  # both face +z when flat
    return pts, tris


def test_smooth_corner_values_area_weighted_and_split_at_creases_and_materials():
    b = np.array([[1.0, 2.0, 3.0], [4.0, 8.0, 12.0]])
    pts, tris = two_triangles(0.0)
    flat = Scene(pts, tris, albedo=0.5)
    assert smoothing_groups(flat)[1] == 4  # 4 distinct points, one group each
    corners = Renderer(flat).corner_radiosity(b)
    areas = flat.areas.astype(float)  # 0.5 and 1.0
    shared = (areas[0] * b[0] + areas[1] * b[1]) / areas.sum()
    np.testing.assert_allclose(corners[0, 0], shared, rtol=1e-6)  # point 0 is shared
    np.testing.assert_allclose(corners[0, 1], shared, rtol=1e-6)  # point 1 is shared
    np.testing.assert_allclose(corners[0, 2], b[0], rtol=1e-6)  # point 2 is its own
    np.testing.assert_allclose(corners[1, 1], b[1], rtol=1e-6)  # point 3 is its own

    gentle = Scene(*two_triangles(20.0), albedo=0.5)
    assert smoothing_groups(gentle, crease_angle=30.0)[1] == 4
    for scene in (
        Scene(*two_triangles(60.0), albedo=0.5),
        flat.with_materials(albedo=[[0.5] * 3, [0.7, 0.5, 0.5]]),
        flat.with_materials(emission=[0.0, 1.0]),
    ):
        groups, n_groups = smoothing_groups(scene, crease_angle=30.0)
        assert n_groups == 6
        corners = Renderer(scene).corner_radiosity(b)
        np.testing.assert_allclose(corners[0], np.repeat(b[:1], 3, axis=0), rtol=1e-6)
        np.testing.assert_allclose(corners[1], np.repeat(b[1:], 3, axis=0), rtol=1e-6)


def test_smooth_pixels_interpolate_corner_values(device, cluttered_scene):
    rng = np.random.default_rng(3)
    b = rng.uniform(0.0, 5.0, size=(len(cluttered_scene), 3))
    cam = Camera(position=(0.5, 0.55, 2.2), look_at=(0.45, 0.5, 0.0), fov_y=50, width=24, height=18)
    r = Renderer(cluttered_scene, device)
    img = r.render(b, cam, "smooth", background=-1.0, backface=-2.0)
    flat = r.render(b, cam, "flat", background=-1.0, backface=-2.0)
    patch, bary, front, margin = cast_camera(cluttered_scene, cam)
    clear = margin > 1e-4
    corners = r.corner_radiosity(b)
    sel = clear & front
    expect = np.einsum("pk,pkc->pc", bary[sel], corners[patch[sel]])
    np.testing.assert_allclose(img[sel], expect, rtol=5e-5, atol=5e-6)  # float32 kernel: observed 6e-7 relative
    np.testing.assert_allclose(flat[sel], b[patch[sel]], rtol=1e-6)
    np.testing.assert_array_equal(img[clear & (patch == -1)], -1.0)
    np.testing.assert_array_equal(img[clear & (patch >= 0) & ~front], -2.0)


def test_render_rejects_bad_input(device, cluttered_scene):
    cam = Camera((0, 0, 3), (0, 0, 0), width=8, height=8)
    n = len(cluttered_scene)
    with pytest.raises(InvalidInputError, match="radiosity must have shape"):
        render(cluttered_scene, np.ones((n + 1, 3)), cam, device=device)
    with pytest.raises(InvalidInputError, match="NaN"):
        render(cluttered_scene, np.full((n, 3), np.nan), cam, device=device)
    with pytest.raises(InvalidInputError, match="shading"):
        render(cluttered_scene, np.ones((n, 3)), cam, "phong", device=device)
    with pytest.raises(InvalidInputError, match="Camera"):
        render(cluttered_scene, np.ones((n, 3)), "front", device=device)
