"""The error of the far field's answer, measured from its residual, and a tolerance met by sweeps.

The dynamic answer B (the local set from K, every other patch from the far field) is checked
against the radiosity equation itself: its residual

    r = L + P F B - B

is one bounce of F (one sparse product, on the device), and the true error e = B* - B solves
(I - P F) e = r. Norms are area-weighted over patches and channels, ``|x|^2 = sum_i A_i |x_i|^2``,
as :func:`pydynrad.comparison.radiosity_error` weighs its error, and relative to ``|B|``:

* **bound**: with F reciprocal (A_i F_ij = A_j F_ji) and rows summing to at most 1, F is
  self-adjoint in that inner product with norm <= 1, so ``|P F| <= rho_max`` and
  ``|e| <= |r| / (1 - rho_max)`` (hemicube F is reciprocal to its rounding). Safe, and 2-10x
  loose at the albedos of real scenes (0.5-0.9), since a residual that changes sign from
  patch to patch is mostly cancelled by the next bounce;
* **estimate**: ``|e| ~ |r| / (1 - q)`` with ``q = |P F r| / |r|`` the contraction the residual
  itself shows over one more bounce: e = r + P F r + (P F)^2 r + ..., summed as a geometric
  series of ratio q. Measured (bench/farfield_corpus.py, tests/farfield/test_estimate.py)
  within 0.8-1.3x of the true all-patch error on the built-ins, the corpus and the leak scenes.

q costs a second bounce, so it is measured when first needed, whenever the light vector has
changed by more than :data:`REMEASURE_CHANGE` of itself since it was, and on every refinement
sweep (for free: the next sweep's residual is P F r); in between the last q is used.

Refinement (``tolerance``): while the estimate exceeds the tolerance, one sweep
``B <- L + P F B = B + r`` (the residual's own product: no extra pass), the far field's answer
replaced by it outside the local set and the local set solved again from it (its injection: a
product with the kept rows), then the residual of the new answer. A light change starts from its
gather plus the correction the sweeps made to earlier lights' answers, fitted to the new light as
the far field fits its answers (:class:`pydynrad.farfield.history.Answers`; the correction is
linear in L): a sun moving by a degree starts at its last refined answer and costs the residual
alone. A light change whose estimate is under the tolerance pays one bounce and nothing else.

Without F in memory (a store, rows on demand) the residual is sampled: :data:`SAMPLED_ROWS` rows
drawn in proportion to patch area (the mean of their ``|r_i|^2`` is an unbiased estimate of the
area-weighted mean square), held, and multiplied with B again every frame; the interval is the
95% normal interval of that mean, and q is :data:`UNMEASURED_CONTRACTION` (no second bounce is
possible from sampled rows). No refinement there: the tolerance needs F.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..device.csr import DeviceCSR
from ..errors import InvalidInputError
from ..host.colproduct import columns_product
from ..rows.cache import RowCache
from ..rows.sources import CSRRows, read_rows
from .history import Answers

__all__ = [
    "ErrorEstimate",
    "ErrorControl",
    "relative_rms",
    "DEFAULT_TOLERANCE",
    "MAX_REFINE_SWEEPS",
    "SAMPLED_ROWS",
    "UNMEASURED_CONTRACTION",
    "FRAME_HYSTERESIS",
    "REMEASURE_CHANGE",
]

#: The estimated all-patch relative RMS error the far field refines to by default. A tenth of the
#: 1% all-patch target: what the observer sees (dim patches, per pixel) errs 2-7x more than the
#: all-patch norm on the corpus, and the estimate may read half the truth
#: (docs/decisions/0041-far-field-tolerance-and-light-change.md).
DEFAULT_TOLERANCE = 0.001
#: The most refinement sweeps per light change (or frame).
MAX_REFINE_SWEEPS = 16
#: q is capped here (a residual that bounces back whole would divide by zero).
MAX_CONTRACTION = 0.95
#: q for sampled residuals (no second bounce): 1 / (1 - q) = 2, above the 1.2-1.8 measured with F.
UNMEASURED_CONTRACTION = 0.5
#: Rows sampled for the residual without F.
SAMPLED_ROWS = 512
#: A frame whose lights are unchanged (only the local set moved) refines only beyond this many
#: times the tolerance: its estimate moves a little from frame to frame, and a sweep on one frame
#: but not the next would show as a pop.
FRAME_HYSTERESIS = 2.0
#: q is measured again where the light vector moved by more than this (area-weighted relative
#: norm) since it last was.
REMEASURE_CHANGE = 0.5
#: Corrections of earlier light changes kept for the warm start.
CORRECTIONS = 4
#: ... combined only where sum_i |a_i| max|L_i| <= this times max|L| (per channel): a fit that
#: cancels or extrapolates far would start the sweeps from a worse answer than the gather's.
WARM_GAIN = 4.0


def _norm(areas: np.ndarray, x: np.ndarray) -> float:
    return float(np.sqrt(np.einsum("i,ij,ij->", areas, x, x)))


def relative_rms(x: np.ndarray, B: np.ndarray, areas: np.ndarray) -> float:
    """``|x| / |B|``, area-weighted over patches and channels (0 where both are 0)."""
    a = np.asarray(areas, np.float64)
    den = _norm(a, B)
    num = _norm(a, x)
    return 0.0 if num == 0 else (num / den if den > 0 else float("inf"))


@dataclass(frozen=True)
class ErrorEstimate:
    """The far field's error as measured on one answer (:attr:`pydynrad.DynamicRadiosity.error_estimate`).

    All values are area-weighted relative RMS over patches and channels, as
    :func:`pydynrad.comparison.radiosity_error`.
    """

    error: float  # the estimate of the all-patch error: residual / (1 - contraction)
    residual: float  # |L + P F B - B| / |B|
    contraction: float  # q = |P F r| / |r|, measured or carried (``measured``)
    measured: bool  # q measured on this light
    bound: float  # residual / (1 - rho_max): an upper bound for reciprocal F
    sweeps: int  # refinement sweeps this answer took
    sampled: int  # rows the residual was sampled from (0: all of F)
    interval: tuple[float, float] | None  # ~95% interval of the error where sampled
    seconds: float  # wall time of the estimate and its sweeps
    light_change: bool  # made on a light change (else a frame where only the local set moved)

    def __str__(self) -> str:
        s = f"error estimate {self.error:.3%} (residual {self.residual:.3%}, q {self.contraction:.2f}"
        if self.sampled:
            s += f", {self.sampled} sampled rows, 95% in [{self.interval[0]:.3%}, {self.interval[1]:.3%}]"
        return s + (f", {self.sweeps} sweeps)" if self.sweeps else ")")


def _whole_F(local_rows):
    """F in memory behind a dynamic solution's rows (a matrix or CSRRows), or None."""
    if local_rows.csr is not None:
        return local_rows.csr
    inner = local_rows.source
    while inner is not None and not isinstance(inner, CSRRows) and hasattr(inner, "source"):
        inner = inner.source
    return inner.matrix if isinstance(inner, CSRRows) else None


def _uncached(source):
    """The row source behind any :class:`~pydynrad.rows.cache.RowCache` in front of ``source``."""
    while isinstance(source, RowCache):
        source = source.source
    return source


class ErrorControl:
    """The residual of a :class:`~pydynrad.DynamicRadiosity`'s answers, and the sweeps that bring
    the estimate under ``tolerance`` (None: estimate only). Built by the solution, used under its
    lock and the far field's."""

    def __init__(
        self,
        scene,
        far,
        local_rows,
        device,
        tolerance: float | None = DEFAULT_TOLERANCE,
        samples: int = SAMPLED_ROWS,
        seed: int = 0x5EED,
    ) -> None:
        if tolerance is not None:
            tolerance = float(tolerance)
            if not (np.isfinite(tolerance) and tolerance > 0):
                raise InvalidInputError(f"tolerance must be a positive number or None; got {tolerance!r}")
        self.tolerance = tolerance
        self.far, self.device = far, device
        self.areas = np.asarray(scene.areas, np.float64)
        self.rho = np.asarray(scene.albedo, np.float64)
        self.rho_max = float(self.rho.max()) if len(self.rho) else 0.0
        self._rows = local_rows
        self._F = _whole_F(local_rows)
        self._F_cols = getattr(far, "_F_cols", None) if self._F is not None else None
        self._F_dev = None  # DeviceCSR of F, made on the first pass (or the far field's own)
        self.samples = int(samples)
        self._rng = np.random.default_rng(seed)
        self._sample = None  # (patches, their rows) of the sampled residual
        self.q: float | None = None
        self._q_light: np.ndarray | None = None  # L at which q was measured
        self._FB = None  # (B, F B) of the last answer checked: frames update F B by the columns that changed
        self._seen = None  # (far.B_far, L) of the last answer checked
        self._corrections = Answers(CORRECTIONS)  # (L, refined B_far - gathered B_far)
        self._last_correction = None  # the last (L, correction) recorded
        self.last: ErrorEstimate | None = None

    @property
    def sampled(self) -> bool:
        return self._F is None

    # -- products ------------------------------------------------------------------------------------
    def _bounce(self, x: np.ndarray) -> np.ndarray:
        """F x (N, k) float64: one pass over F on the device (the far field's copy where it has one)."""
        if self._F_dev is None:
            self._F_dev = getattr(self.far, "_F_dev", None) or DeviceCSR(self.device, self._F, np.float32)
            self.far.share_rows(self._F_dev)
        zeros = np.zeros_like(x)
        return self._F_dev.bounce(zeros, np.ones_like(x), x)

    def _updated_FB(self, B: np.ndarray) -> np.ndarray:
        """F B, from the last F B plus F's columns where B changed (F by column on the host),
        or a whole pass."""
        held = self._FB
        if held is not None and self._F_cols is not None and held[0].shape == B.shape:
            d = B - held[0]
            cols = np.flatnonzero(np.any(d != 0, axis=1))
            if len(cols) < 0.25 * len(B):
                return held[1] + columns_product(self._F_cols, cols, d[cols]) if len(cols) else held[1]
        return self._bounce(B)

    # -- the estimate --------------------------------------------------------------------------------
    def _sampled(self, L: np.ndarray, B: np.ndarray, light_change: bool, t0: float) -> ErrorEstimate:
        n = len(B)
        if self._sample is None or (light_change and self._sample[0] is None):
            p = self.areas / self.areas.sum()
            idx = np.sort(self._rng.choice(n, size=min(self.samples, max(n, 1)), p=p))
            # Read behind any cache: the sample is read once, and must not evict the rows a walk prefetched.
            self._sample = (idx, read_rows(_uncached(self._rows.source), idx))
        idx, rows = self._sample
        r = L[idx] + self.rho[idx] * (rows @ B) - B[idx]
        sq = (r * r).sum(axis=1)
        mean_a = float(self.areas.sum())
        den = _norm(self.areas, B)
        ms = float(sq.mean())
        res = np.sqrt(ms * mean_a) / den if den > 0 else 0.0
        se = float(sq.std(ddof=1) / np.sqrt(len(sq))) if len(sq) > 1 else ms
        lo, hi = (np.sqrt(max(ms + z * se, 0.0) * mean_a) / den if den > 0 else 0.0 for z in (-1.96, 1.96))
        f = 1.0 / (1.0 - UNMEASURED_CONTRACTION)
        return ErrorEstimate(
            res * f,
            res,
            UNMEASURED_CONTRACTION,
            False,
            self._bound(res),
            0,
            len(idx),
            (lo * f, hi * f),
            time.perf_counter() - t0,
            light_change,
        )

    def _bound(self, res: float) -> float:
        return res / (1.0 - self.rho_max) if self.rho_max < 1 else float("inf")

    def _measure_q(self, r: np.ndarray, L: np.ndarray) -> None:
        n0 = _norm(self.areas, r)
        if n0 > 0:
            self.q = min(MAX_CONTRACTION, _norm(self.areas, self.rho * self._bounce(r)) / n0)
            self._q_light = L.copy()

    def _q_stale(self, L: np.ndarray) -> bool:
        if self.q is None or self._q_light is None or self._q_light.shape != L.shape:
            return True
        return relative_rms(L - self._q_light, L, self.areas) > REMEASURE_CHANGE

    def _warm_start(self, L: np.ndarray) -> np.ndarray | None:
        """The correction the sweeps made to earlier lights, fitted to L: their best combination
        where it neither cancels nor extrapolates far (:data:`WARM_GAIN`), else the last one
        scaled to L (a light that moves: the fit of several near-parallel lights extrapolates),
        None where neither fits (a light unlike the last)."""
        fit = self._corrections.fit(L)
        if fit is None:
            return None
        if np.all(fit[3][:, 1] <= WARM_GAIN):
            return fit[1]
        if self._last_correction is None or self._last_correction[0].shape != L.shape:
            return None
        last, delta = self._last_correction
        s = np.einsum("i,ij,ij->j", self.areas, L, last) / np.maximum(
            np.einsum("i,ij,ij->j", self.areas, last, last), 1e-300
        )
        off = relative_rms(L - s * last, L, self.areas)
        return s * delta if np.all((s > 0.5) & (s < 2.0)) and off < REMEASURE_CHANGE else None

    def check(self, L: np.ndarray, B: np.ndarray, members: np.ndarray, resolve) -> np.ndarray:
        """The answer B (N, 3) for light L, checked (and refined while over the tolerance);
        sets :attr:`last`. ``resolve(B_far)`` puts a refined far answer into the far field and
        returns the whole answer with the local set solved from it."""
        t0 = time.perf_counter()
        gathered = self.far.B_far
        seen = self._seen
        light_change = seen is None or seen[0] is not gathered or not np.array_equal(seen[1], L)
        if not light_change and np.array_equal(seen[2], members) and self.last is not None:
            return B  # the same lights and local set: the same answer as checked last
        if self.sampled:
            self.last = self._sampled(L, B, light_change, t0)
            self._seen = (gathered, L, np.array(members))
            return B
        sweeps = 0
        if light_change and self.tolerance is not None and self._corrections.count:
            start = self._warm_start(L)
            if start is not None:
                B = resolve(gathered + start)
        FB = self._updated_FB(B) if not light_change else self._bounce(B)
        r = L + self.rho * FB - B
        measured = False
        if light_change and self._q_stale(L):
            self._measure_q(r, L)
            measured = True
        res = relative_rms(r, B, self.areas)
        q = self.q if self.q is not None else UNMEASURED_CONTRACTION
        est = res / (1.0 - q)
        limit = None if self.tolerance is None else self.tolerance * (1.0 if light_change else FRAME_HYSTERESIS)
        while limit is not None and est > limit and sweeps < MAX_REFINE_SWEEPS:
            B_next = resolve(B + r)
            FB = self._bounce(B_next)
            r_next = L + self.rho * FB - B_next
            n_prev = _norm(self.areas, r)
            q = min(MAX_CONTRACTION, _norm(self.areas, r_next) / n_prev) if n_prev > 0 else 0.0
            self.q, self._q_light, measured = q, L.copy(), True
            B, r, sweeps = B_next, r_next, sweeps + 1
            res = relative_rms(r, B, self.areas)
            est = res / (1.0 - q)
            if q >= MAX_CONTRACTION:  # the sweeps no longer gain (rounding): stop
                break
        if sweeps or (light_change and self._corrections.count):
            self._corrections.add(L, self.far.B_far - gathered)
            self._last_correction = (L.copy(), self.far.B_far - gathered)
        self._FB = (B, FB)
        self._seen = (self.far.B_far, L, np.array(members))
        self.last = ErrorEstimate(
            est, res, q, measured, self._bound(res), sweeps, 0, None, time.perf_counter() - t0, light_change
        )
        return B
