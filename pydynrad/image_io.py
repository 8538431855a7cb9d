"""Image files through OpenImageIO.

Renders are linear float32 (H, W, 3). Two kinds of file come out of them:

* linear formats (``.exr``, ``.hdr``, ``.tif``/``.tiff``, ``.pfm``) keep float values
  (scaled by ``2 ** exposure``, which is 1 by default): data for compositing or comparison;
* display formats (``.png``, ``.jpg``/``.jpeg``, ``.bmp``, ``.tga``) are exposed, encoded
  with the sRGB transfer curve written out here (OIIO would otherwise clamp linear floats
  without encoding them) and stored as 8-bit.

Files are written whole (:func:`pydynrad.atomic.write_atomic`): into a temporary file in the
same folder, read back and compared with the image, then renamed over the target, so a reader
never sees half an image or one the encoder changed, and a failed write leaves no debris.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .atomic import check_file_target, write_atomic
from .checks import stops
from .errors import InvalidInputError

__all__ = ["write_image", "read_image", "srgb_encode", "LINEAR_FORMATS", "DISPLAY_FORMATS"]

#: Extension -> OIIO format name for files that store linear floats.
LINEAR_FORMATS = {".exr": "openexr", ".hdr": "hdr", ".tif": "tiff", ".tiff": "tiff", ".pfm": "pnm"}
#: Extension -> OIIO format name for 8-bit sRGB files.
DISPLAY_FORMATS = {".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg", ".bmp": "bmp", ".tga": "targa"}


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) on values clipped to [0, 1]."""
    x = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def _checked_image(image) -> np.ndarray:
    a = np.asarray(image, dtype=np.float32)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[2] not in (1, 3) or a.shape[0] == 0 or a.shape[1] == 0:
        raise InvalidInputError(f"an image must have shape (H, W), (H, W, 1) or (H, W, 3); got {np.shape(image)}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError("the image contains NaN or infinite values; refusing to write it")
    return np.ascontiguousarray(a)


def _format_for(path: Path) -> tuple[str, bool]:
    ext = path.suffix.lower()
    if ext in LINEAR_FORMATS:
        return LINEAR_FORMATS[ext], True
    if ext in DISPLAY_FORMATS:
        return DISPLAY_FORMATS[ext], False
    known = ", ".join(sorted({*LINEAR_FORMATS, *DISPLAY_FORMATS}))
    raise InvalidInputError(f"cannot tell the image format of {str(path)!r}: use one of the extensions {known}")


def write_image(path, image, exposure: float = 0.0) -> Path:
    """Write a linear image.

    Parameters
    ----------
    path : str or Path
        Target file; its extension picks the format (see the module docstring). The folder
        must exist.
    image : (H, W), (H, W, 1) or (H, W, 3) float
        Linear values, e.g. from :func:`pydynrad.render`.
    exposure : float
        Photographic stops: values are multiplied by ``2 ** exposure`` before writing.

    Returns
    -------
    The path written.
    """
    import OpenImageIO as oiio

    path = Path(path)
    fmt, linear = _format_for(path)
    exposure = stops(exposure)
    check_file_target(path)
    with np.errstate(over="ignore"):
        a = _checked_image(image) * np.float32(2.0**exposure)
    if not np.all(np.isfinite(a)):  # 2**exposure or the product overflowed float32
        raise InvalidInputError(
            f"exposure {exposure:g} stops overflows float32 for this image (largest value "
            f"{float(np.abs(_checked_image(image)).max()):g}): use a smaller exposure"
        )
    if fmt == "hdr" and a.min() < 0:  # RGBE has no sign
        raise InvalidInputError(
            f"cannot write {str(path)!r}: Radiance HDR stores no negative values (the image's "
            f"least is {float(a.min()):g}); use .exr or .pfm"
        )
    if linear:
        spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], oiio.FLOAT)
        pixels = a
    else:
        spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], oiio.UINT8)
        spec.attribute("oiio:ColorSpace", "sRGB")
        pixels = np.round(srgb_encode(a) * 255.0).astype(np.uint8)
    buf = oiio.ImageBuf(spec)
    if not buf.set_pixels(oiio.ROI(), pixels):
        raise InvalidInputError(f"cannot store the image for {str(path)!r}: {buf.geterror()}")

    def write(tmp: Path) -> None:
        if not buf.write(str(tmp), fileformat=fmt) or buf.has_error:
            raise OSError(f"cannot write {str(path)!r}: {buf.geterror().strip() or 'OpenImageIO failed'}")
        _check_read_back(tmp, path, pixels, fmt)

    return write_atomic(path, write)


def _check_read_back(tmp: Path, path: Path, pixels: np.ndarray, fmt: str) -> None:
    """OSError unless the file at ``tmp`` reads back as ``pixels``: exactly, to RGBE's 8-bit
    mantissa for .hdr, in shape only for JPEG (lossy by design)."""
    back = _read_pixels(tmp, path)
    want = pixels.astype(np.float32)
    if pixels.dtype == np.uint8:  # compared as code values: OIIO scales them to [0, 1] on reading
        back = np.round(back * 255.0)
    if back.shape != want.shape:
        raise OSError(f"cannot write {str(path)!r}: it reads back as {back.shape}, not {want.shape}")
    if fmt == "jpeg":
        return
    # RGBE shares one exponent per pixel: each channel keeps 8 bits relative to the pixel's largest,
    # and values below float32's normal range (2^-126) are below its exponents: zeros.
    tol = np.maximum(want.max(axis=2, keepdims=True) / 128.0, 2.0**-126) if fmt == "hdr" else 0.0
    if not np.all(np.abs(back - want) <= tol):
        raise OSError(f"cannot write {str(path)!r}: the file read back differs from the image written")


def _read_pfm(path: Path, name: Path) -> np.ndarray:
    """A PFM file read by its spec (``PF`` RGB or ``Pf`` grey, width height, scale whose sign is
    the byte order, float rows from the bottom up): OpenImageIO 3.2 returns a ``.pfm``-named
    file's rows bottom first and the same bytes under another name top first."""
    data = path.read_bytes()
    header = re.match(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+(\S+)\s", data)
    try:
        kind, w, h, scale = header.group(1), int(header.group(2)), int(header.group(3)), float(header.group(4))
        c = 3 if kind == b"PF" else 1
        rows = np.frombuffer(data, "<f4" if scale < 0 else ">f4", count=w * h * c, offset=header.end())
    except (AttributeError, ValueError) as exc:
        raise InvalidInputError(f"cannot read image {str(name)!r}: a malformed PFM file ({exc})") from None
    return rows.reshape(h, w, c)[::-1].astype(np.float32)


def _read_pixels(path: Path, name: Path) -> np.ndarray:
    import OpenImageIO as oiio

    with open(path, "rb") as f:
        if f.read(2) in (b"PF", b"Pf"):
            return _read_pfm(path, name)
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InvalidInputError(f"cannot read image {str(name)!r}: {oiio.geterror().strip() or 'unknown format'}")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.FLOAT)
        if pixels is None or inp.has_error:
            raise InvalidInputError(f"cannot read image {str(name)!r}: {inp.geterror().strip()}")
    finally:
        inp.close()
    return np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, spec.nchannels)


def read_image(path) -> np.ndarray:
    """Read an image file as float32 (H, W, C).

    Values are the file's own: linear floats from EXR/HDR/TIFF, and the stored sRGB-encoded
    code values scaled to [0, 1] from 8-bit files (no decoding).
    """
    path = Path(path)
    if not path.is_file():
        why = "no such file" if not path.exists() else "not a regular file"
        raise InvalidInputError(f"cannot read image {str(path)!r}: {why}")
    return _read_pixels(path, path)
