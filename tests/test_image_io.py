import numpy as np
import pytest

from pydynrad import InvalidInputError
from pydynrad.image_io import read_image, srgb_encode, write_image


def test_exr_round_trip_is_exact_and_linear(tmp_path):
    rng = np.random.default_rng(0)
    img = rng.uniform(-0.5, 40.0, size=(7, 5, 3)).astype(np.float32)  # HDR values survive
    out = write_image(tmp_path / "a.exr", img)
    np.testing.assert_array_equal(read_image(out), img)
    write_image(tmp_path / "b.exr", img, exposure=2.0)
    np.testing.assert_allclose(read_image(tmp_path / "b.exr"), 4.0 * img, rtol=1e-7)


def test_srgb_curve_matches_openimageio_colorconvert():
    import OpenImageIO as oiio

    x = np.linspace(0.0, 1.0, 101, dtype=np.float32).reshape(1, 101, 1).repeat(3, axis=2)
    buf = oiio.ImageBuf(oiio.ImageSpec(101, 1, 3, oiio.FLOAT))
    buf.set_pixels(oiio.ROI(), x)
    ref = oiio.ImageBufAlgo.colorconvert(buf, "linear", "sRGB").get_pixels(oiio.FLOAT)
    np.testing.assert_allclose(srgb_encode(x), ref, atol=2e-5)


@pytest.mark.parametrize("ext", ["png", "jpg"])
def test_display_formats_are_exposed_srgb_8bit(tmp_path, ext):
    import OpenImageIO as oiio

    img = np.zeros((4, 6, 3), dtype=np.float32)
    img[:2] = 0.25  # one stop up: 0.5 linear -> sRGB 0.7354 -> code 188
    img[2:, :3] = 7.0  # over-exposed: clipped to 255
    img[2:, 3:] = -1.0  # negative: clipped to 0
    path = write_image(tmp_path / f"x.{ext}", img, exposure=1.0)
    inp = oiio.ImageInput.open(str(path))
    assert inp.spec().format == oiio.UINT8
    inp.close()
    codes = np.round(read_image(path) * 255)
    assert codes.shape == (4, 6, 3)
    tol = 0 if ext == "png" else 3  # JPEG is lossy
    np.testing.assert_allclose(codes[:2], 188, atol=tol)
    np.testing.assert_allclose(codes[2:, :3], 255, atol=tol)
    np.testing.assert_allclose(codes[2:, 3:], 0, atol=tol)


def test_grey_images_and_replacing_a_file_leave_no_temporaries(tmp_path):
    path = tmp_path / "g.png"
    write_image(path, np.zeros((3, 3)))
    write_image(path, np.ones((3, 3, 1)))  # replaces the first file whole
    np.testing.assert_array_equal(read_image(path), 1.0)
    assert [p.name for p in tmp_path.iterdir()] == ["g.png"]


def test_bad_paths_and_images_give_clear_errors(tmp_path):
    img = np.zeros((2, 2, 3))
    with pytest.raises(InvalidInputError, match="extensions"):
        write_image(tmp_path / "a.xyz", img)
    with pytest.raises(InvalidInputError, match="does not exist"):
        write_image(tmp_path / "missing" / "a.png", img)
    with pytest.raises(InvalidInputError, match="NaN"):
        write_image(tmp_path / "a.exr", np.full((2, 2, 3), np.nan))
    with pytest.raises(InvalidInputError, match="shape"):
        write_image(tmp_path / "a.exr", np.zeros((2, 2, 5)))
    with pytest.raises(InvalidInputError, match="no such file"):
        read_image(tmp_path / "nothing.png")
    with pytest.raises(InvalidInputError, match="not a regular file"):  # a folder is there, not missing
        read_image(tmp_path)
    (tmp_path / "junk.png").write_bytes(b"not an image")
    with pytest.raises(InvalidInputError, match="cannot read"):
        read_image(tmp_path / "junk.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.png"]


def test_a_file_that_reads_back_different_is_not_kept(tmp_path, monkeypatch):
    """Each image is read back before it replaces the target: an encoder that changed the
    values (simulated here) leaves neither the target nor a temporary file."""
    from pydynrad import image_io

    real = image_io._read_pixels
    monkeypatch.setattr(image_io, "_read_pixels", lambda path, name: real(path, name) + 1.0)
    target = tmp_path / "x.exr"
    with pytest.raises(OSError, match="read back differs"):
        write_image(target, np.ones((3, 4, 3), dtype=np.float32))
    assert list(tmp_path.iterdir()) == []


def test_pfm_rows_follow_the_spec_and_round_trip(tmp_path):
    """A PFM holds its rows from the bottom up; read_image returns the image as written (OpenImageIO
    had returned a .pfm file's rows bottom first: the image upside down) and a truncated file is
    named."""
    a = np.arange(18, dtype=np.float32).reshape(3, 2, 3)
    path = tmp_path / "a.pfm"
    write_image(path, a)
    raw = path.read_bytes()
    assert raw.startswith(b"PF") and np.frombuffer(raw[-18 * 4 :], "<f4")[0] == a[-1, 0, 0]  # bottom row first
    np.testing.assert_array_equal(read_image(path), a)
    path.write_bytes(raw[:-8])
    with pytest.raises(InvalidInputError, match="malformed PFM"):
        read_image(path)


def test_hdr_takes_tiny_values_as_zeros_and_refuses_negative_ones(tmp_path):
    """RGBE has no exponent below float32's normal range and no sign: a lamp of 1e-38 W had been
    "read back differs" from the write's check, a negative image likewise."""
    write_image(tmp_path / "t.hdr", np.full((2, 2, 3), 1e-40, np.float32))
    assert read_image(tmp_path / "t.hdr").max() == 0.0
    with pytest.raises(InvalidInputError, match="no negative values"):
        write_image(tmp_path / "n.hdr", -np.ones((2, 2, 3), np.float32))
