"""A pinhole camera and its primary rays.

The ray generation lives here once: the OpenCL renderer uploads the directions that
:meth:`Camera.ray_directions` returns, and the tests cast the same rays in numpy, so the two
can never disagree about which pixel looks where.

Conventions: right-handed world; the image's row 0 is the top row and column 0 the left
column; the ray of pixel (row r, column c) passes through the centre of that pixel on an
image plane at distance 1 whose height is ``2 tan(fov_y / 2)``.

See docs/design.md, 'Conventions'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..checks import number, vec3
from ..errors import InvalidInputError, OutOfMemoryError
from ..host.memory import available_host_bytes

__all__ = ["Camera", "MAX_IMAGE_SIDE", "check_image_memory"]

#: Largest accepted image width or height in pixels (a 16k image already needs 3 GiB of rays;
#: whether a large image fits is decided by :func:`check_image_memory`).
MAX_IMAGE_SIDE = 16384


def _side(value, what: str) -> int:
    # Numbers only: "32" had been 32 pixels, where "45" is refused as a field of view.
    if isinstance(value, (bool, np.bool_, str, bytes)) or not float(number(value, what)).is_integer():
        raise InvalidInputError(f"{what} must be a whole number of pixels; got {value!r}")
    v = int(value)
    if not 1 <= v <= MAX_IMAGE_SIDE:
        raise InvalidInputError(f"{what} must be between 1 and {MAX_IMAGE_SIDE} pixels; got {v}")
    return v


def check_image_memory(camera: Camera, bytes_per_pixel: int, what: str) -> None:
    """Refuse, before anything is allocated, an image whose ``what`` needs more host memory
    (``bytes_per_pixel`` at its peak) than this process can have."""
    need, have = camera.width * camera.height * bytes_per_pixel, available_host_bytes()
    if need > have:
        raise OutOfMemoryError(
            f"{what} a {camera.width} x {camera.height} image needs about {need / 2**30:.1f} GiB "
            f"of host memory; {have / 2**30:.1f} GiB is available. Render a smaller image"
        )


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera.

    Parameters
    ----------
    position : (3,) float
        Eye point, in scene units.
    look_at : (3,) float
        A point the camera looks at; it must differ from ``position``.
    up : (3,) float
        Rough up direction; it only has to be non-parallel to the view direction.
    fov_y : float
        Vertical field of view in degrees, in (0, 180).
    width, height : int
        Image size in pixels.
    """

    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray = (0.0, 1.0, 0.0)  # type: ignore[assignment]
    fov_y: float = 45.0
    width: int = 320
    height: int = 240

    def __post_init__(self) -> None:
        pos = vec3(self.position, "camera position")
        target = vec3(self.look_at, "camera look_at")
        up = vec3(self.up, "camera up")
        forward = target - pos
        dist = np.linalg.norm(forward)
        if dist <= 1e-9 * max(1.0, float(np.linalg.norm(pos))):
            raise InvalidInputError(f"camera look_at {target.tolist()} must differ from its position {pos.tolist()}")
        forward /= dist
        if np.linalg.norm(up) == 0 or np.linalg.norm(np.cross(forward, up / np.linalg.norm(up))) < 1e-6:
            raise InvalidInputError(
                f"camera up must not be zero or parallel to the view direction {forward.tolist()}; got {up.tolist()}"
            )
        fov = number(self.fov_y, "camera fov_y")
        if not (np.isfinite(fov) and 0.0 < fov < 180.0):
            raise InvalidInputError(f"camera fov_y must be in (0, 180) degrees; got {self.fov_y!r}")
        # Frozen dataclass: normalise the fields through object.__setattr__.
        object.__setattr__(self, "position", pos)
        object.__setattr__(self, "look_at", target)
        object.__setattr__(self, "up", up / np.linalg.norm(up))
        object.__setattr__(self, "fov_y", fov)
        object.__setattr__(self, "width", _side(self.width, "image width"))
        object.__setattr__(self, "height", _side(self.height, "image height"))

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the image."""
        return (self.height, self.width)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Orthonormal ``(right, true_up, forward)`` camera axes in world space."""
        forward = self.look_at - self.position
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, self.up)
        right /= np.linalg.norm(right)
        return right, np.cross(right, forward), forward

    def ray_directions(self) -> np.ndarray:
        """(height, width, 3) float32 unit directions of the rays through each pixel centre.

        Every ray starts at :attr:`position`.
        """
        right, up, forward = self.basis()
        half_h = np.tan(np.radians(self.fov_y) / 2.0)
        half_w = half_h * self.width / self.height
        x = ((np.arange(self.width) + 0.5) / self.width * 2.0 - 1.0) * half_w
        y = (1.0 - (np.arange(self.height) + 0.5) / self.height * 2.0) * half_h
        d = forward + x[None, :, None] * right + y[:, None, None] * up
        d /= np.linalg.norm(d, axis=2, keepdims=True)
        return d.astype(np.float32)

    def with_view(self, position, look_at) -> Camera:
        """The same lens and image size at a new position and target."""
        return Camera(position, look_at, self.up, self.fov_y, self.width, self.height)
