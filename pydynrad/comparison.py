"""Comparing a dynamic (local-matrix) result with the full radiosity solution.

:func:`comparison_image` puts three panels side by side: the dynamic render, the full
render, and a false-colour map of the per-pixel relative error with a labelled colour bar.
Colours and labels come from OpenImageIO (a core dependency already, so the comparison the
demo writes needs nothing more): ``ImageBufAlgo.color_map`` ("viridis", in linear values,
the same as matplotlib's viridis decoded from sRGB) and ``ImageBufAlgo.render_text`` with
the font OpenImageIO ships. :func:`radiosity_error` measures the same thing on the patch
vectors, and :func:`reference_frame` does both for one frame, as ``walk``'s reference frames
and ``pydynrad compare`` need.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .checks import stops
from .defaults import exposure_or_auto
from .errors import InvalidInputError, PydynradError
from .geometry.loading import checked_scene
from .renderer import Renderer
from .rows.files import whole_matrix
from .solution import solve

__all__ = ["radiosity_error", "pixel_error", "false_colour", "comparison_image", "reference_frame", "ReferenceFrame"]

#: The colour map of the error panel (an OpenImageIO ``color_map`` name).
COLOUR_MAP = "viridis"


def radiosity_error(radiosity, reference, areas, emission=None) -> float:
    """Area-weighted relative RMS error ``sqrt(sum A |b - r|^2 / sum A |r|^2)`` over patches
    and channels; ``radiosity`` and ``reference`` (N, 3), ``areas`` (N,).

    ``emission`` (N, 3), optional: the emitters' own emission within the reference, left out of
    the denominator (``r - E`` there): the error relative to the reflected radiosity, which
    :attr:`pydynrad.DynamicRadiosity.error_estimate` estimates. A bright emitter otherwise makes
    the relative error of everything it lights look small."""
    b, r = np.asarray(radiosity, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    a = np.asarray(areas, dtype=np.float64)
    if b.shape != r.shape or b.ndim != 2 or len(a) != len(b):
        raise InvalidInputError(f"radiosity {b.shape}, reference {r.shape} and areas {a.shape} do not match")
    d = r
    if emission is not None:
        e = np.asarray(emission, dtype=np.float64)
        if e.shape != r.shape:
            raise InvalidInputError(f"emission {e.shape} does not match the reference {r.shape}")
        d = r - e
    den = float(np.sum(a[:, None] * d * d))
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
    """(..., 3) float32 linear viridis colours of ``values`` scaled to [0, vmax] (clipped)."""
    import OpenImageIO as oiio

    t = np.clip(np.asarray(values, dtype=np.float32) / np.float32(vmax), 0.0, 1.0)
    flat = np.ascontiguousarray(t.reshape(1, -1, 1))
    src = oiio.ImageBuf(oiio.ImageSpec(flat.shape[1], 1, 1, oiio.FLOAT))
    src.set_pixels(oiio.ROI(), flat)
    out = oiio.ImageBufAlgo.color_map(src, 0, COLOUR_MAP)
    if out.has_error:
        raise PydynradError(f"OpenImageIO color_map failed: {out.geterror()}")
    return np.asarray(out.get_pixels(oiio.FLOAT), dtype=np.float32).reshape(*t.shape, 3)


def _label(out: np.ndarray, texts, size: int) -> None:
    """Draw ``texts`` ((text, x, y) each: baseline at row ``y`` from column ``x``) in white into
    ``out`` (H, W, 3), C-contiguous, in one round trip through an OpenImageIO buffer."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(oiio.ImageSpec(out.shape[1], out.shape[0], 3, oiio.FLOAT))
    buf.set_pixels(oiio.ROI(), out)
    for text, x, y in texts:
        if not oiio.ImageBufAlgo.render_text(buf, x, y, text, size, "", (1.0, 1.0, 1.0)):
            raise PydynradError(
                f"OpenImageIO could not draw the colour bar's label {text!r} (no font?): "
                f"{buf.geterror() or oiio.geterror()}"
            )
    out[:] = buf.get_pixels(oiio.FLOAT).reshape(out.shape)


def _text_box(text: str, size: int) -> tuple[int, int, int]:
    """(width, ascent, descent) in pixels of ``text`` at font ``size``."""
    import OpenImageIO as oiio

    roi = oiio.ImageBufAlgo.text_size(text, size, "")
    return roi.xend - roi.xbegin, -roi.ybegin, roi.yend


def _percent(v: float) -> str:
    p = 100.0 * v
    return f"{p:.0f}%" if p >= 10 else f"{p:.1f}%" if p >= 0.1 else f"{p:.2f}%"


def comparison_image(
    dynamic, reference, exposure: float | str = "auto", vmax: float | None = None, titles=None
) -> tuple[np.ndarray, dict]:
    """Side-by-side panels: ``dynamic`` | ``reference`` | relative error map + colour bar.

    Parameters
    ----------
    dynamic, reference : (H, W, 3) float
        Linear renders of the same view (e.g. the local-matrix and the full solution).
    exposure : float or "auto"
        Stops applied to the two renders here (not to the error map); write the result with
        exposure 0. "auto" (the default): :func:`pydynrad.defaults.auto_exposure` of
        ``reference``.
    vmax : float, optional
        Relative error shown as the top colour (default: the 99th percentile, at least 1e-3).
    titles : three str, optional
        Titles drawn in a band above the three panels (the image is then taller by the band);
        the error panel's title gets the colour bar's range appended.

    Returns
    -------
    image : (H, 3 W + gaps + bar, 3) float32, linear (write it with exposure 0: the map's
        colours are linear values whose sRGB encoding is viridis).
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
    gain = np.float32(2.0 ** stops(exposure_or_auto(exposure, reference)))
    gap = max(2, w // 64)
    size = max(8, h // 16)
    top_text, bottom_text = ">" + _percent(vmax), "0%"
    (tw, t_up, _), (bw, _, b_down) = _text_box(top_text, size), _text_box(bottom_text, size)
    bar_w = max(8, w // 16)
    panel_w = bar_w + 2 * gap + max(tw, bw)
    out = np.zeros((h, 3 * w + 3 * gap + panel_w, 3), dtype=np.float32)
    out[:, :w] = np.asarray(dynamic, dtype=np.float32) * gain
    out[:, w + gap : 2 * w + gap] = np.asarray(reference, dtype=np.float32) * gain
    out[:, 2 * (w + gap) : 3 * w + 2 * gap] = false_colour(err, vmax)
    x0 = 3 * (w + gap)
    ramp = np.linspace(vmax, 0.0, h)  # the top of the bar is the largest error
    out[:, x0 : x0 + bar_w] = false_colour(ramp, vmax)[:, None, :]
    if h >= 2 * (t_up + b_down):  # labels that would overlap are left out (tiny images)
        labels = out[:, x0 + bar_w + gap :].copy()
        _label(labels, [(top_text, 0, t_up), (bottom_text, 0, h - 1 - b_down)], size)
        out[:, x0 + bar_w + gap :] = labels
    if titles is not None:
        out = _with_titles(out, list(titles), w, gap, size, f" (0-{_percent(vmax)})")
    return out, stats


def _with_titles(panels: np.ndarray, titles: list[str], w: int, gap: int, size: int, scale: str) -> np.ndarray:
    """``panels`` below a band holding one title per panel (the last, the error map's, with
    ``scale`` appended); the band is black, the text white."""
    if len(titles) != 3 or not all(isinstance(t, str) for t in titles):
        raise InvalidInputError(f"titles must be three strings (dynamic, reference, error); got {titles!r}")
    titles = titles[:2] + [titles[2] + scale]
    ascent = max(_text_box(t, size)[1] for t in titles)
    descent = max(_text_box(t, size)[2] for t in titles)
    band = np.zeros((ascent + descent + 2 * gap, panels.shape[1], 3), dtype=np.float32)
    _label(band, [(t, k * (w + gap) + gap, gap + ascent) for k, t in enumerate(titles)], size)
    return np.concatenate([band, panels])


@dataclass
class ReferenceFrame:
    """One frame compared with the full solution (:func:`reference_frame`).

    full : (N, 3) float64 full radiosity; error : patch error (:func:`radiosity_error`);
    image : the comparison image (:func:`comparison_image`); pixel_error : its stats;
    local_only_error, local_only_pixel_error : the same for the paper's local-only answer when
    one was given (its comparison is then the image's top row); black: no pixel of the full
    solution's render is lit (the view sees no lit face: its errors say nothing).
    """

    full: np.ndarray
    error: float
    image: np.ndarray
    pixel_error: dict
    local_only_error: float | None = None
    local_only_pixel_error: dict | None = None
    black: bool = False
    exposure: float = 0.0  # the stops the renders in ``image`` were shown at


def reference_frame(
    scene,
    form_factors,
    radiosity,
    camera,
    *,
    lights=(),
    renderer=None,
    image=None,
    shading: str = "smooth",
    exposure: float | str = "auto",
    local_only=None,
    device=None,
) -> ReferenceFrame:
    """Solve the full radiosity for ``lights`` and compare ``radiosity`` (N, 3) with it.

    ``form_factors``: all of F (a matrix, or any row source, read whole); ``camera`` the view
    of the comparison image; ``image``: ``radiosity`` already rendered from it (rendered
    here when None); ``renderer``: a :class:`~pydynrad.renderer.Renderer` of ``scene`` to reuse.
    ``local_only``: the paper's local-only answer (N, 3) beside a far-field ``radiosity``: it is
    compared too, its row (local only | full | error) above the far field's. Every row is titled
    (what it shows, per column) and has its own error scale (its colour bar's range is in the
    error panel's title): the far field's small errors are not lost on the local-only row's
    scale. ``exposure``: stops, or "auto" (the default): from the full solution's render.
    """

    scene = checked_scene(scene)
    auto = exposure is None or (isinstance(exposure, str) and exposure == "auto")
    exposure = None if auto else stops(exposure)  # before the full solve
    renderer = renderer or Renderer(scene, device)
    full = solve(scene, whole_matrix(form_factors), lights, device=device).radiosity
    if image is None:
        image = renderer.render(radiosity, camera, shading)
    full_image = renderer.render(full, camera, shading)
    exposure = exposure_or_auto(exposure, full_image)
    error_title = "relative error"
    if local_only is None:
        composite, stats = comparison_image(image, full_image, exposure, titles=("dynamic", "full solve", error_title))
        return ReferenceFrame(
            full,
            radiosity_error(radiosity, full, scene.areas),
            composite,
            stats,
            black=not full_image.any(),
            exposure=exposure,
        )
    local_image = renderer.render(local_only, camera, shading)
    top, local_stats = comparison_image(
        local_image, full_image, exposure, titles=("local only (paper)", "full solve", error_title)
    )
    bottom, stats = comparison_image(image, full_image, exposure, titles=("with far field", "full solve", error_title))
    width = max(top.shape[1], bottom.shape[1])  # the colour bars' labels differ in width
    top, bottom = (np.pad(x, ((0, 0), (0, width - x.shape[1]), (0, 0))) for x in (top, bottom))
    gap = np.ones((max(2, top.shape[0] // 64), top.shape[1], 3), dtype=top.dtype)
    return ReferenceFrame(
        full,
        radiosity_error(radiosity, full, scene.areas),
        np.concatenate([top, gap, bottom]),
        stats,
        radiosity_error(local_only, full, scene.areas),
        local_stats,
        black=not full_image.any(),
        exposure=exposure,
    )
