"""The defaults every command and function follows, in one place (docs/guide/defaults.md).

Each constant here is the default of every function and command option that has that
parameter; tests/test_defaults.py checks the CLI's options and the functions' signatures
against them and against the table in the docs.

Rules rather than numbers:

- :func:`default_local_size`: the local set M = min(1024, N // 2) (at least the moving objects'
  patches), so at least half of the scene is far field whatever its size;
- :func:`auto_exposure`: the exposure (stops) that maps the log-average luminance of what is
  shown to middle grey 0.18 (Reinhard et al. 2002, "key value"); a walk fixes it once, from its
  first lit frame, so its frames do not flicker.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "RESOLUTION",
    "LOCAL_SIZE_CAP",
    "FOV_Y",
    "WIDTH",
    "HEIGHT",
    "EXPOSURE",
    "KEY_VALUE",
    "PROGRESS_DELAY",
    "default_local_size",
    "auto_exposure",
    "exposure_or_auto",
]

#: Hemicube resolution R (R x R pixels on the top face) of form factors, object rows, gathers.
RESOLUTION = 64
#: The local set's largest default size M (K is M x M).
LOCAL_SIZE_CAP = 1024
#: Vertical field of view in degrees (the Cornell box camera's), on the command line and in path files.
FOV_Y = 39.3
#: Image size in pixels.
WIDTH, HEIGHT = 320, 240
#: The exposure default: chosen by :func:`auto_exposure` ("auto" on the command line).
EXPOSURE = "auto"
#: The luminance the log-average of an auto-exposed image is mapped to.
KEY_VALUE = 0.18
#: Seconds before a progress bar appears (tqdm's ``delay``).
PROGRESS_DELAY = 2.0

# Rec. 709 / sRGB luminance weights of linear R, G, B.
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def default_local_size(n_patches: int, must_hold: int = 0) -> int:
    """The default local set size M for a scene of ``n_patches``: ``min(1024, N // 2)``, at least
    ``must_hold`` (the moving objects' patches, which are always local) and at least 1."""
    n = int(n_patches)
    m = max(1, min(LOCAL_SIZE_CAP, n // 2), int(must_hold))
    return min(m, max(n, 1))


def auto_exposure(values, weights=None) -> float:
    """Stops that map the log-average luminance of ``values`` to :data:`KEY_VALUE`.

    ``values``: linear RGB, (..., 3) (an image, or patch radiosity with ``weights`` = areas).
    Only lit entries (luminance > 0) count; nothing lit gives 0. The log-average is
    ``exp(sum w log Y / sum w)``, and the result is ``log2(KEY_VALUE / that)``, rounded to
    1/100 of a stop (so it prints as it is used).
    """
    v = np.asarray(values, dtype=np.float64).reshape(-1, 3)
    y = v @ _LUMA
    w = (
        np.ones(len(y))
        if weights is None
        else np.broadcast_to(np.asarray(weights, dtype=np.float64).reshape(-1), (len(y),))
    )
    lit = (y > 0) & np.isfinite(y) & (w > 0)
    if not lit.any():
        return 0.0
    log_avg = float(np.exp(np.sum(w[lit] * np.log(y[lit])) / np.sum(w[lit])))
    return round(math.log2(KEY_VALUE / log_avg), 2)


def exposure_or_auto(exposure, values, weights=None) -> float:
    """``exposure`` in stops, or :func:`auto_exposure` of ``values`` where it is None or "auto"."""
    if exposure is None or (isinstance(exposure, str) and exposure == "auto"):
        return auto_exposure(values, weights)
    return exposure
