import numpy as np
import pytest

from pydynrad import Camera, InvalidInputError


def test_centre_ray_points_at_target_and_axes_are_orthonormal():
    cam = Camera(position=(1, 2, 3), look_at=(1, 2, -7), fov_y=60, width=5, height=3)
    d = cam.ray_directions()
    assert d.shape == (3, 5, 3) and d.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d, axis=2), 1.0, rtol=1e-6)
    np.testing.assert_allclose(d[1, 2], [0, 0, -1], atol=1e-7)  # odd size: the middle pixel is on-axis
    right, up, forward = cam.basis()
    np.testing.assert_allclose(np.array([right, up, forward]) @ np.array([right, up, forward]).T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-12)  # looking down -z with +y up: +x is right


def test_field_of_view_and_orientation():
    cam = Camera((0, 0, 0), (0, 0, -1), up=(0, 1, 0), fov_y=90, width=4, height=2)
    d = cam.ray_directions()
    # Vertical: pixel-centre rows at y = +-0.5 on the plane z = -1 (tan(45 deg) = 1, 2 rows).
    # Horizontal: aspect 2, so x = -1.5, -0.5, 0.5, 1.5. Row 0 is the top, column 0 the left.
    plane = d / -d[..., 2:3]
    np.testing.assert_allclose(plane[..., 1], [[0.5] * 4, [-0.5] * 4], atol=1e-6)
    np.testing.assert_allclose(plane[0, :, 0], [-1.5, -0.5, 0.5, 1.5], atol=1e-6)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(position=(0, 0, 0), look_at=(0, 0, 0)), "differ"),
        (dict(position=(0, 0, 0), look_at=(0, 1, 0)), "parallel"),
        (dict(position=(0, 0, 0), look_at=(0, 0, 1), fov_y=180), "fov_y"),
        (dict(position=(0, 0, 0), look_at=(0, 0, 1), fov_y=0), "fov_y"),
        (dict(position=(0, np.nan, 0), look_at=(0, 0, 1)), "finite"),
        (dict(position=(0, 0), look_at=(0, 0, 1)), "three numbers"),
        (dict(position=(0, 0, 0), look_at=(0, 0, 1), width=0), "width"),
        (dict(position=(0, 0, 0), look_at=(0, 0, 1), height=2.5), "whole number"),
        (dict(position=(0, 0, 0), look_at=(0, 0, 1), width=10**6), "width"),
    ],
)
def test_bad_cameras_are_rejected(kwargs, message):
    with pytest.raises(InvalidInputError, match=message):
        Camera(**kwargs)
