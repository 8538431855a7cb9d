"""Comparing a dynamic (local-matrix) result with the full radiosity solution.

:func:`comparison_image` puts three panels side by side: the dynamic render, the full
render, and a false-colour map of the per-pixel relative error with a labelled colour bar.
The colour map (viridis, tabulated here) is pure numpy, so matplotlib is not needed at run
time. :func:`radiosity_error` measures the same thing on the patch vectors.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidInputError

__all__ = ["radiosity_error", "pixel_error", "false_colour", "comparison_image", "VIRIDIS"]

#: viridis (matplotlib's) sampled at 0, 1/16, ..., 1: sRGB-encoded display colours, interpolated linearly.
VIRIDIS = np.array([
    [0.267004, 0.004874, 0.329415], [0.282327, 0.094955, 0.417331], [0.278826, 0.175490, 0.483397],
    [0.258965, 0.251537, 0.524736], [0.229739, 0.322361, 0.545706], [0.199430, 0.387607, 0.554642],
    [0.172719, 0.448791, 0.557885], [0.149039, 0.508051, 0.557250], [0.127568, 0.566949, 0.550556],
    [0.120638, 0.625828, 0.533488], [0.157851, 0.683765, 0.501686], [0.246070, 0.738910, 0.452024],
    [0.369214, 0.788888, 0.382914], [0.515992, 0.831158, 0.294279], [0.678489, 0.863742, 0.189503],
    [0.845561, 0.887322, 0.099702], [0.993248, 0.906157, 0.143936],
])

# A 3 x 5 pixel font for the colour-bar labels: digits, '.', '%', '>' and space.
_GLYPHS = {
    "0": "111101101101111", "1": "010110010010111", "2": "111001111100111", "3": "111001111001111",
    "4": "101101111001001", "5": "111100111001111", "6": "111100111101111", "7": "111001010010010",
    "8": "111101111101111", "9": "111101111001111", ".": "000000000000010", "%": "101001010100101",
    " ": "000000000000000", ">": "100010001010100",
}


def radiosity_error(radiosity, reference, areas) -> float:
    """Area-weighted relative RMS error ``sqrt(sum A |b - r|^2 / sum A |r|^2)`` over patches
    and channels; ``radiosity`` and ``reference`` (N, 3), ``areas`` (N,)."""
    b, r = np.asarray(radiosity, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    a = np.asarray(areas, dtype=np.float64)
    if b.shape != r.shape or b.ndim != 2 or len(a) != len(b):
        raise InvalidInputError(f"radiosity {b.shape}, reference {r.shape} and areas {a.shape} do not match")
    den = float(np.sum(a[:, None] * r * r))
    if den == 0.0:
        raise InvalidInputError("the reference radiosity is zero everywhere: relative error undefined")
    return float(np.sqrt(np.sum(a[:, None] * (b - r) ** 2) / den))


def pixel_error(image, reference, floor: float = 1e-3) -> np.ndarray:
    """(H, W) relative error ``sum_c |a - r| / max(sum_c |r|, floor * mean)`` per pixel.

    The floor (a fraction of the reference's mean) keeps black pixels from dividing by zero.
    """
    a, r = np.asarray(image, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    if a.shape != r.shape or a.ndim != 3:
        raise InvalidInputError(f"images to compare must have equal (H, W, C) shapes; got {a.shape} and {r.shape}")
    num = np.abs(a - r).sum(axis=2)
    den = np.abs(r).sum(axis=2)
    return num / np.maximum(den, floor * max(float(den.mean()), 1e-30))


def false_colour(values, vmax: float) -> np.ndarray:
    """(..., 3) sRGB-encoded viridis colours of ``values`` scaled to [0, vmax]."""
    t = np.clip(np.asarray(values, dtype=np.float64) / vmax, 0.0, 1.0) * (len(VIRIDIS) - 1)
    i = np.minimum(np.floor(t).astype(int), len(VIRIDIS) - 2)
    f = (t - i)[..., None]
    return (1.0 - f) * VIRIDIS[i] + f * VIRIDIS[i + 1]


def _srgb_decode(c: np.ndarray) -> np.ndarray:
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _text(label: str, scale: int) -> np.ndarray:
    """(5 scale, 4 scale len - scale) bool mask of ``label`` in the 3 x 5 font."""
    cols = []
    for ch in label:
        glyph = np.array([int(b) for b in _GLYPHS[ch]], dtype=bool).reshape(5, 3)
        cols += [glyph, np.zeros((5, 1), dtype=bool)]
    mask = np.concatenate(cols[:-1], axis=1)
    return np.kron(mask, np.ones((scale, scale), dtype=bool))


def _percent(v: float) -> str:
    p = 100.0 * v
    return f"{p:.0f}%" if p >= 10 else f"{p:.1f}%" if p >= 0.1 else f"{p:.2f}%"


def comparison_image(dynamic, reference, exposure: float = 0.0, vmax: float | None = None) -> tuple[np.ndarray, dict]:
    """Side-by-side panels: ``dynamic`` | ``reference`` | relative error map + colour bar.

    Parameters
    ----------
    dynamic, reference : (H, W, 3) float
        Linear renders of the same view (e.g. the local-matrix and the full solution).
    exposure : float
        Stops applied to the two renders here (not to the error map); write the result with
        exposure 0.
    vmax : float, optional
        Relative error shown as the top colour (default: the 99th percentile, at least 1e-3).

    Returns
    -------
    image : (H, 3 W + gaps + bar, 3) float32, linear (the map's colours are sRGB-decoded, so
        :func:`pydynrad.write_image` shows them as tabulated).
    stats : dict with ``mean``, ``p99``, ``max`` of the pixel error and the ``vmax`` used.
    """
    err = pixel_error(dynamic, reference)
    h, w = err.shape
    stats = {"mean": float(err.mean()), "p99": float(np.percentile(err, 99)), "max": float(err.max())}
    if vmax is None:
        vmax = max(stats["p99"], 1e-3)
    if not (np.isfinite(vmax) and vmax > 0):
        raise InvalidInputError(f"vmax must be a positive relative error; got {vmax!r}")
    stats["vmax"] = float(vmax)
    gain = np.float32(2.0**exposure)
    gap = max(2, w // 64)
    scale = max(1, h // 120)
    top, bottom = _text(">" + _percent(vmax), scale), _text("0%", scale)
    bar_w = max(8, w // 16)
    panel_w = bar_w + 2 * gap + max(top.shape[1], bottom.shape[1])
    out = np.zeros((h, 3 * w + 3 * gap + panel_w, 3), dtype=np.float32)
    out[:, :w] = np.asarray(dynamic, dtype=np.float32) * gain
    out[:, w + gap:2 * w + gap] = np.asarray(reference, dtype=np.float32) * gain
    out[:, 2 * (w + gap):3 * w + 2 * gap] = _srgb_decode(false_colour(err, vmax))
    x0 = 3 * (w + gap)
    ramp = np.linspace(vmax, 0.0, h)  # the top of the bar is the largest error
    out[:, x0:x0 + bar_w] = _srgb_decode(false_colour(ramp, vmax))[:, None, :]
    xl = x0 + bar_w + gap
    for mask, y in ((top, 0), (bottom, h - bottom.shape[0])):
        if y >= 0 and mask.shape[0] <= h:
            region = out[y:y + mask.shape[0], xl:xl + mask.shape[1]]
            region[mask] = 1.0
    return out, stats
