import numpy as np
import pytest

from pydynrad import InvalidInputError
from pydynrad.compare import comparison_image, false_colour, pixel_error, radiosity_error


def test_colour_map_matches_matplotlib_viridis():
    mpl = pytest.importorskip("matplotlib")
    t = np.linspace(0.0, 1.0, 257)
    np.testing.assert_allclose(false_colour(t, 1.0), mpl.colormaps["viridis"](t)[:, :3], atol=0.02)  # 17 samples: within 2 % (invisible)
    np.testing.assert_allclose(false_colour([-1.0, 5.0], 1.0), mpl.colormaps["viridis"]([0.0, 1.0])[:, :3], atol=1e-6)


def test_radiosity_error_is_area_weighted_relative_rms():
    ref = np.array([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]])
    b = ref.copy()
    b[1] *= 1.1  # 10 % off on the second patch
    areas = np.array([3.0, 1.0])
    expect = np.sqrt(1.0 * 3 * 0.2**2 / (3.0 * 3 * 1 + 1.0 * 3 * 4))
    assert radiosity_error(b, ref, areas) == pytest.approx(expect, rel=1e-12)
    assert radiosity_error(ref, ref, areas) == 0.0
    with pytest.raises(InvalidInputError):
        radiosity_error(b, np.zeros_like(ref), areas)


def test_comparison_image_layout_and_error_values():
    h, w = 24, 32
    ref = np.full((h, w, 3), 0.5, dtype=np.float32)
    dyn = ref.copy()
    dyn[:, : w // 2] *= 1.2  # left half 20 % too bright
    err = pixel_error(dyn, ref)
    np.testing.assert_allclose(err[:, : w // 2], 0.2, rtol=1e-5)
    np.testing.assert_allclose(err[:, w // 2:], 0.0, atol=1e-7)
    img, stats = comparison_image(dyn, ref, exposure=1.0, vmax=0.2)
    assert stats["vmax"] == 0.2 and stats["max"] == pytest.approx(0.2, rel=1e-5)
    assert img.shape[0] == h and img.shape[1] > 3 * w and img.dtype == np.float32
    np.testing.assert_allclose(img[:, :w], 2.0 * dyn, rtol=1e-6)  # exposure applied to the renders
    gap = max(2, w // 64)
    np.testing.assert_allclose(img[:, w + gap:2 * w + gap], 2.0 * ref, rtol=1e-6)
    emap = img[:, 2 * (w + gap):3 * w + 2 * gap]
    from pydynrad.image_io import srgb_encode

    # The map's pixels are linear values whose sRGB encoding is the colour map's colour.
    np.testing.assert_allclose(srgb_encode(emap[0, 0]), false_colour(0.2, 0.2), atol=1e-5)
    np.testing.assert_allclose(srgb_encode(emap[0, -1]), false_colour(0.0, 0.2), atol=1e-5)
    with pytest.raises(InvalidInputError):
        comparison_image(dyn, ref[:, :-1])
