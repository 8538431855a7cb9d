import numpy as np
import pytest

from pydynrad import InvalidInputError
from pydynrad.comparison import comparison_image, false_colour, pixel_error, radiosity_error


def _linear_viridis(t):
    import matplotlib as mpl

    c = mpl.colormaps["viridis"](t)[..., :3]
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def test_colour_map_is_matplotlibs_viridis_in_linear_values():
    """OpenImageIO's viridis is matplotlib's at 17 knots (k / 16), decoded from sRGB, and linear
    in between: equal at the knots (5e-7 observed), within 0.025 of matplotlib's 256 steps between."""
    knots = np.arange(17) / 16
    np.testing.assert_allclose(false_colour(2.0 * knots, 2.0), _linear_viridis(knots), atol=1e-6)
    t = np.linspace(0.0, 1.0, 1001)
    np.testing.assert_allclose(false_colour(t, 1.0), _linear_viridis(t), atol=0.03)
    np.testing.assert_allclose(false_colour([-1.0, 5.0], 1.0), _linear_viridis(np.array([0.0, 1.0])), atol=1e-6)
    assert false_colour(np.zeros((2, 5)), 1.0).shape == (2, 5, 3)


def test_radiosity_error_is_area_weighted_relative_rms():
    ref = np.array([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0]])
    b = ref.copy()
    b[1] *= 1.1  # 10 % off on the second patch
    areas = np.array([3.0, 1.0])
    expect = np.sqrt(1.0 * 3 * 0.2**2 / (3.0 * 3 * 1 + 1.0 * 3 * 4))
    assert radiosity_error(b, ref, areas) == pytest.approx(expect, rel=1e-13)
    assert radiosity_error(ref, ref, areas) == 0.0
    with pytest.raises(InvalidInputError):
        radiosity_error(b, np.zeros_like(ref), areas)
    # Relative to the reflected light: the first patch emits 0.75 of its 1.0, left out below.
    emission = np.array([[0.75, 0.75, 0.75], [0.0, 0.0, 0.0]])
    expect = np.sqrt(1.0 * 3 * 0.2**2 / (3.0 * 3 * 0.25**2 + 1.0 * 3 * 4))
    assert radiosity_error(b, ref, areas, emission=emission) == pytest.approx(expect, rel=1e-13)
    with pytest.raises(InvalidInputError, match="emission"):
        radiosity_error(b, ref, areas, emission=emission[:1])


def test_comparison_image_layout_and_error_values():
    h, w = 24, 32
    ref = np.full((h, w, 3), 0.5, dtype=np.float32)
    dyn = ref.copy()
    dyn[:, : w // 2] *= 1.2  # left half 20 % too bright
    err = pixel_error(dyn, ref)
    np.testing.assert_allclose(err[:, : w // 2], 0.2, rtol=1e-5)
    np.testing.assert_allclose(err[:, w // 2 :], 0.0, atol=1e-7)
    img, stats = comparison_image(dyn, ref, exposure=1.0, vmax=0.2)
    assert stats["vmax"] == 0.2 and stats["max"] == pytest.approx(0.2, rel=1e-5)
    assert img.shape[0] == h and img.shape[1] > 3 * w and img.dtype == np.float32
    np.testing.assert_allclose(img[:, :w], 2.0 * dyn, rtol=1e-6)  # exposure applied to the renders
    gap = max(2, w // 64)
    np.testing.assert_allclose(img[:, w + gap : 2 * w + gap], 2.0 * ref, rtol=1e-6)
    emap = img[:, 2 * (w + gap) : 3 * w + 2 * gap]
    np.testing.assert_allclose(emap[:, : w // 2], np.broadcast_to(false_colour(1.0, 1.0), (h, w // 2, 3)), atol=1e-6)
    np.testing.assert_allclose(emap[:, w // 2 :], np.broadcast_to(false_colour(0.0, 1.0), (h, w // 2, 3)), atol=1e-6)
    with pytest.raises(InvalidInputError):
        comparison_image(dyn, ref[:, :-1])


def test_colour_bar_labels_are_drawn_at_its_ends():
    """The labels ('>20%' at the top, '0%' at the bottom) are OpenImageIO text: white pixels in
    the label column near both ends of the bar, nothing between them."""
    h, w = 160, 120
    ref = np.full((h, w, 3), 0.5, dtype=np.float32)
    img, _ = comparison_image(ref * 1.2, ref, vmax=0.2)
    gap, bar_w = max(2, w // 64), max(8, w // 16)
    labels = img[:, 3 * (w + gap) + bar_w + gap :].max(axis=2)
    ink = np.flatnonzero(labels.max(axis=1) > 0.5)
    size = max(8, h // 16)
    assert len(ink) and ink.min() < size and ink.max() > h - 1 - size
    assert labels[2 * size : h - 2 * size].max() == 0.0
    assert labels.max() <= 1.0 + 1e-6
