"""Walks as a moving picture: frames encoded to a video file (H.264 in .mp4, or what the suffix
names) through imageio with imageio-ffmpeg, whose wheels ship the ffmpeg encoder.

Needs the ``video`` extra (``pip install 'pydynrad[video]'``); without it
:class:`~pydynrad.errors.MissingExtraError` names the extra, before any work.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .atomic import check_file_target
from .checks import stops
from .errors import InvalidInputError, MissingExtraError
from .image_io import srgb_encode

__all__ = ["VideoWriter", "VIDEO_SUFFIXES", "DEFAULT_FPS"]

#: Containers ffmpeg writes that players open.
VIDEO_SUFFIXES = (".mp4", ".mkv", ".mov", ".webm", ".gif")
#: Frames per second of a walk's video.
DEFAULT_FPS = 24.0


def _require_video(feature: str):
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401  (the encoder imageio's ffmpeg plugin runs)
    except ImportError as exc:
        raise MissingExtraError(feature, "imageio and imageio-ffmpeg", "video", name=exc.name) from exc
    return imageio


class VideoWriter:
    """Linear (H, W, 3) frames, exposed and sRGB-encoded to 8 bits, appended to a video file.

    ``with VideoWriter("walk.mp4") as v: v.append(image, exposure)``. Odd widths or heights are
    padded by one edge pixel (H.264's 4:2:0 needs even sizes). The file is checked (folder,
    suffix, the extra installed) when the writer is made, before any frame's work.
    """

    def __init__(self, path, fps: float = DEFAULT_FPS, feature: str = "a video") -> None:
        self._imageio = _require_video(feature)
        self.path = Path(path)
        if self.path.suffix.lower() not in VIDEO_SUFFIXES:
            raise InvalidInputError(f"video {str(self.path)!r} must end in {', '.join(VIDEO_SUFFIXES)}")
        check_file_target(self.path)
        fps = float(fps)
        if not (np.isfinite(fps) and fps > 0):
            raise InvalidInputError(f"fps must be a positive number; got {fps!r}")
        self.fps, self.frames, self._writer = fps, 0, None

    def append(self, image, exposure: float = 0.0) -> None:
        a = np.asarray(image, dtype=np.float32) * np.float32(2.0 ** stops(exposure))
        if a.ndim != 3 or a.shape[2] != 3:
            raise InvalidInputError(f"a video frame must be (H, W, 3); got {a.shape}")
        h, w = a.shape[:2]
        a = np.pad(a, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        pixels = np.round(srgb_encode(np.nan_to_num(a)) * 255.0).astype(np.uint8)
        if self._writer is None:
            options = {"fps": self.fps}
            if self.path.suffix.lower() != ".gif":
                options.update(macro_block_size=1, quality=8)
            self._writer = self._imageio.get_writer(self.path, **options)
        self._writer.append_data(pixels)
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self) -> VideoWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
