"""The error of the far field's answer, measured from its residual, and a tolerance met by sweeps.

The dynamic answer B (the local set from K, every other patch from the far field) is checked
against the radiosity equation itself: its residual

    r = L + P F B - B

is one bounce of F (one sparse product, on the device), and the true error e = B* - B solves
(I - P F) e = r. Norms are area-weighted over patches and channels, ``|x|^2 = sum_i A_i |x_i|^2``,
as :func:`pydynrad.comparison.radiosity_error` weighs its error, and relative to the reflected
radiosity ``|B - E|``: the emitters' own emission, in L and exact, is left out of the norm, where
it would hide the error of everything it lights
(docs/decisions/0042-far-field-trapped-light.md):

* with F reciprocal (A_i F_ij = A_j F_ji, hemicube F to its rounding) and rows summing to at most
  1, T = P F is self-adjoint in the inner product weighted by A / rho, per channel, with its
  spectrum in [-rho_max, rho_max]. Then ``|e|^2 = <r, (I - T)^-2 r>`` is an integral over the
  spectral measure of r, whose first moments ``<r, r>``, ``<r, T r>``, ``<T r, T r>`` one
  more bounce ``y = T r`` gives. Quadrature on them (Golub and Meurant, *Matrices, Moments
  and Quadrature*) brackets it: the one-node Gauss rule is a **lower** bound and the Gauss-Radau
  rule with a node fixed at rho_max an **upper** bound (every derivative of (1 - t)^-2 is
  positive below 1) -- where the plain bound ``|r| / (1 - rho_max)`` is 2-25x loose;
* **estimate**: the geometric mean of the two, as a ratio to ``|r|`` (in the A / rho norm, applied to
  the area-weighted ``|r|``). A residual of the oscillating modes (negative eigenvalues: facing
  surfaces) contracts fast in norm yet cancels over the bounces: a norm ratio
  ``|r| / (1 - |T r| / |r|)`` sums it as if it did not, reads it several times too high and buys
  sweeps that are not needed; the bracket sees the cancelling in ``<r, T r>``
  (docs/decisions/0041-far-field-tolerance-and-light-change.md).

The moments cost a bounce, so they are taken when first needed, on a light change whose light
vector moved by more than :data:`REMEASURE_CHANGE` of itself since they were, and on every
sweep (measured on the residual the sweep leaves); in between the last ratio of estimate to
residual is carried (a sun turning by a degree: the residual's spectrum hardly moves).

Refinement (``tolerance``): while the estimate exceeds the tolerance, one sweep
``B <- L + P F B = B + r``, the far field's answer replaced by it outside the local set and the
local set solved again from it (its injection: a product with the kept rows), then the residual
of the new answer: ``F B_next = F B + F r + F[:, S] d`` with ``F r`` the moments' own pass and
``d`` the local set's change by its re-solve (F's columns of S on the host, a pass on a GPU). A light change starts from its
gather plus the correction the sweeps made to earlier lights' answers, fitted to the new light as
the far field fits its answers (:class:`pydynrad.farfield.history.Answers`; the correction is
linear in L): a sun moving by a degree starts at its last refined answer and costs the residual
alone. A light change whose estimate is under the tolerance pays one bounce and nothing else.

Without F in memory, a store behind the rows (:class:`~pydynrad.rows.store.FormFactorStore`)
can still be read whole, block by block: a light change is then checked and refined as with F,
each pass over F a pass over the store's blocks (read from the files on the first pass, kept
after it where they fit the budget: :meth:`ErrorControl._store_pass`), and the frames after it,
whose lights are unchanged, keep its estimate (B_far stands; the local set is solved exactly from it). Rows on demand (no store)
cannot be read whole: the residual is sampled, :data:`SAMPLED_ROWS` rows drawn in proportion to
patch area (the mean of their ``|r_i|^2`` is an unbiased estimate of the area-weighted mean
square), held, and multiplied with B again every frame; the interval is the 95% normal interval
of that mean, the ratio of error to residual ``1 / (1 - UNMEASURED_CONTRACTION)`` (no second
bounce is possible from sampled rows), and nothing is refined. Sampled rows read the residual
of a refined answer poorly: it concentrates on small patches the sample misses.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from ..device.csr import DeviceCSR
from ..errors import InvalidInputError
from ..host.colproduct import columns_product, rows_product
from ..host.memory import available_host_bytes
from ..rows.cache import RowCache
from ..rows.sources import CSRRows, read_rows
from ..rows.store import FormFactorStore
from .history import Answers
from .trapped import TrappedLight

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
    "residual_ratios",
    "COARSE_SHARE",
    "coarse_tolerance",
]

#: The estimated all-patch relative RMS error the far field refines to by default. A tenth of the
#: 1% all-patch target: what the observer sees (dim patches, per pixel) errs several times more
#: than the all-patch norm, and the estimate may read half the truth
#: (docs/decisions/0041-far-field-tolerance-and-light-change.md).
DEFAULT_TOLERANCE = 0.001
#: The most refinement sweeps per light change (or frame).
MAX_REFINE_SWEEPS = 16
#: Sweeps stop where one cut the residual by less than this factor (rounding, or modes a sweep
#: does not damp): a further sweep would cost a bounce for nothing.
MIN_SWEEP_GAIN = 0.95
#: q for sampled residuals (no second bounce): 1 / (1 - q) = 2, above the 1.2-1.8 measured with F.
UNMEASURED_CONTRACTION = 0.5
#: Rows sampled for the residual without F.
SAMPLED_ROWS = 512
#: A frame whose lights are unchanged (only the local set moved) refines only beyond this many
#: times the tolerance: its estimate moves a little from frame to frame, and a sweep on one frame
#: but not the next would show as a pop.
FRAME_HYSTERESIS = 2.0
#: A frame's residual leaves out changes of the local set's answer under this share of the RMS
#: reflected radiosity (per patch, max over channels; carried until they exceed it): most of its
#: patches move by the local solve's rounding alone, every column a pass of its entries. The
#: residual is then that of an answer within the share of the one returned, which changes the
#: estimate by at most twice the share (F's norm in the area weighting is at most 1).
FRAME_FLOOR = 1e-6
#: The moments are measured again on a light change where the light vector moved by more than
#: this (area-weighted relative norm) since they last were; and a warm start scaled from the
#: last correction is taken only where the light is within this of the last one scaled.
REMEASURE_CHANGE = 0.5
#: In a solution that refines, the far field's coarse sweeps stop at a relative change of this many
#: times the tolerance (not at the coarse level's own 1e-4): the coarse level's own error is far
#: above either, the sweeps make up the rest, and warm-started from the last lights' solutions the
#: coarse level then stops after a sweep or two (docs/decisions/0042-far-field-trapped-light.md).
COARSE_SHARE = 10.0
#: Corrections of earlier light changes kept for the warm start.
CORRECTIONS = 4
#: ... combined only where sum_i |a_i| max|L_i| <= this times max|L| (per channel): a fit that
#: cancels or extrapolates far would start the sweeps from a worse answer than the gather's.
WARM_GAIN = 4.0


def _norm(areas: np.ndarray, x: np.ndarray, scratch: np.ndarray | None = None) -> float:
    # The squares' columns against the areas: one matrix-vector product, where einsum's sum over
    # a row of three (and its three-operand form) does not vectorise, and a frame takes two norms.
    # ``scratch`` (x's shape) takes the squares: a fresh (N, 3) array each frame faults its pages in.
    squares = np.multiply(x, x, out=scratch)
    return float(np.sqrt((squares.T @ areas).sum()))


def residual_ratios(r: np.ndarray, y: np.ndarray, areas: np.ndarray, rho: np.ndarray) -> tuple[float, float]:
    """(lower, upper): bounds on ``|e| / |r|`` for the error e = (I - T)^-1 r, from the residual
    r (N, k) and its bounce y = T r = P F r (N, k), in the norm weighted by A / rho per channel,
    in which T is self-adjoint for reciprocal F: the one-node Gauss rule and the two-node
    Gauss-Radau rule with a node at the channel's largest albedo, applied to (1 - t)^-2 over the
    spectral measure of r whose moments are <r, r>, <r, T r>, <T r, T r>. (1.0, 1.0) for r = 0."""
    lower = upper = total = 0.0
    for c in range(r.shape[1]):
        b = float(rho[:, c].max())
        if b <= 0.0:  # no bounce in this channel: e = r
            m0 = float(np.einsum("i,i,i->", areas, r[:, c], r[:, c]))
            lower, upper, total = lower + m0, upper + m0, total + m0
            continue
        # rho = 0 patches have y = 0 and, in every answer checked here, r = 0 (B = L there).
        w = areas / np.maximum(rho[:, c], 1e-12)
        m0 = float(np.einsum("i,i,i->", w, r[:, c], r[:, c]))
        if m0 == 0.0:
            continue
        m1 = float(np.einsum("i,i,i->", w, r[:, c], y[:, c]))
        m2 = float(np.einsum("i,i,i->", w, y[:, c], y[:, c]))
        theta = min(m1 / m0, b)
        lower += m0 / (1.0 - theta) ** 2
        M1, M2 = m1 - b * m0, m2 - 2.0 * b * m1 + b * b * m0  # moments about b (t - b <= 0)
        if M1 < 0.0 and M2 > 0.0:
            t, w1 = b + M2 / M1, M1 * M1 / M2
            upper += w1 / (1.0 - t) ** 2 + max(m0 - w1, 0.0) / (1.0 - b) ** 2
        else:  # all of r's measure at b
            upper += m0 / (1.0 - b) ** 2
        total += m0
    if total == 0.0:
        return 1.0, 1.0
    return float(np.sqrt(lower / total)), float(np.sqrt(upper / total))


def relative_rms(x: np.ndarray, B: np.ndarray, areas: np.ndarray) -> float:
    """``|x| / |B|``, area-weighted over patches and channels (0 where both are 0)."""
    a = np.asarray(areas, np.float64)
    return _relative(a, x, _norm(a, B) ** 2)


def _relative(areas: np.ndarray, x: np.ndarray, size: float, scratch: np.ndarray | None = None) -> float:
    """``|x| / sqrt(size)``, size being ``|B|^2`` (0 where both are 0)."""
    num = _norm(areas, x, scratch)
    return 0.0 if num == 0 else (num / np.sqrt(size) if size > 0 else float("inf"))


@dataclass(frozen=True)
class ErrorEstimate:
    """The far field's error as measured on one answer (:attr:`pydynrad.DynamicRadiosity.error_estimate`).

    All values are area-weighted relative RMS over patches and channels, as
    :func:`pydynrad.comparison.radiosity_error` with ``emission=``: relative to the reflected
    radiosity B - E, the emitters' own emission left out of the norm (module docstring).
    """

    error: float  # the estimate of the all-patch error: residual times the bracket's geometric mean
    residual: float  # |L + P F B - B| / |B - E|
    contraction: float  # q = |P F r| / |r| (the residual's norm over one more bounce)
    measured: bool  # the moments measured on this answer (else carried from the last light change)
    bound: float  # the Gauss-Radau upper bound (residual times its ratio) for reciprocal F
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


def _checked_tolerance(tolerance) -> float | None:
    if tolerance is not None:
        tolerance = float(tolerance)
        if not (np.isfinite(tolerance) and tolerance > 0):
            raise InvalidInputError(f"tolerance must be a positive number or None; got {tolerance!r}")
    return tolerance


def coarse_tolerance(local_rows, tolerance) -> float | None:
    """The relative change at which the far field's coarse sweeps stop, for a solution with these
    rows and ``tolerance``: :data:`COARSE_SHARE` times it where the answers are refined (F in
    memory, or a store behind the rows), None (the far field's own) where they are not."""
    tolerance = _checked_tolerance(tolerance)
    if tolerance is None:
        return None
    F, store = _whole(local_rows)
    return COARSE_SHARE * tolerance if F is not None or store is not None else None


def _whole_F(local_rows):
    """F in memory behind a dynamic solution's rows (a matrix or CSRRows), or None."""
    if local_rows.csr is not None:
        return local_rows.csr
    inner = local_rows.source
    while inner is not None and not isinstance(inner, CSRRows) and hasattr(inner, "source"):
        inner = inner.source
    return inner.matrix if isinstance(inner, CSRRows) else None


def _whole(local_rows) -> tuple:
    """(F in memory, or None; else the store behind the rows, or None): what a pass over all of F
    can read (rows on demand cannot be read whole: a pass would compute all of F)."""
    F = _whole_F(local_rows)
    source = _uncached(local_rows.source) if F is None else None
    return F, (source if isinstance(source, FormFactorStore) else None)


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
        self.tolerance = _checked_tolerance(tolerance)
        self.far, self.device = far, device
        self.areas = np.asarray(scene.areas, np.float64)
        self.rho = np.asarray(scene.albedo, np.float64)
        self.rho_max = float(self.rho.max()) if len(self.rho) else 0.0
        self._total_area = float(self.areas.sum())
        self._squares: np.ndarray | None = None  # the frames' residual norms' scratch
        # The norms leave the emitters' own emission out (module docstring).
        self._emitters = np.flatnonzero(scene.emission.max(axis=1) > 0)
        self._emission = np.asarray(scene.emission, np.float64)[self._emitters]
        self._rows = local_rows
        # Without F in memory, a store behind the rows can still be read whole, block by block: a
        # light change over the tolerance is refined from it.
        self._F, self._store = _whole(local_rows)
        self._F_cols = getattr(far, "_F_cols", None) if self._F is not None else None
        self._F_dev = None  # DeviceCSR of F, made on the first pass (or the far field's own)
        # The store's blocks are kept after the first pass where they fit: within the budget of a
        # row cache in front of the store (the memory given to F's rows), else a quarter of the
        # host memory available then.
        self._store_budget = 0
        if self._store is not None:
            cache = local_rows.source if isinstance(local_rows.source, RowCache) else None
            self._store_budget = cache.max_bytes if cache is not None else available_host_bytes() // 4
        self._store_held: sp.csr_matrix | None = None  # all of F's blocks, where they fit
        self._store_blocks: list | None = None  # the leading blocks kept (after the first pass)
        self._store_entries = 0  # F's non-zeros, counted on the first pass over the store
        self._trapped: TrappedLight | None = None  # made on the first sweep
        self.samples = int(samples)
        self._rng = np.random.default_rng(seed)
        self._sample = None  # (patches, their rows) of the sampled residual
        self._ratios: tuple[float, float, float] | None = None  # (estimate, upper, q) of the last moments
        self._ratios_light: np.ndarray | None = None  # L at which they were measured
        # (a copy of B, its residual, |B|^2) of the last answer checked: frames update them by the
        # patches that changed
        self._held = None
        self._seen = None  # (far.B_far, the local set) of the last answer checked
        self._corrections = Answers(CORRECTIONS)  # (L, refined B_far - gathered B_far)
        self._last_correction = None  # the last (L, correction) recorded
        self.last: ErrorEstimate | None = None

    @property
    def sampled(self) -> bool:
        return self._F is None

    # -- products ------------------------------------------------------------------------------------
    def _bounce(self, x: np.ndarray) -> np.ndarray:
        """F x (N, k) float64: one pass over F on the device (the far field's copy where it has one),
        or over the store's blocks where F is not in memory (:meth:`_store_pass`)."""
        if self._F is None:
            return self._store_pass(x)
        if self._F_dev is None:
            self._F_dev = getattr(self.far, "_F_dev", None) or DeviceCSR(self.device, self._F, np.float32)
            self.far.share_rows(self._F_dev)
        zeros = np.zeros_like(x)
        return self._F_dev.bounce(zeros, np.ones_like(x), x)

    def _store_pass(self, x: np.ndarray) -> np.ndarray:
        """F x from the store's blocks, each read (and its checksum verified) in turn; on the first
        pass the leading blocks that fit the budget are kept, so that the passes of the sweeps
        read memory, not files, for as much of F as fits (all of it: one product over F whole;
        docs/decisions/0041-far-field-tolerance-and-light-change.md)."""
        if self._store_held is not None:
            return rows_product(self._store_held, x)
        store, out, kept, first = self._store, [], self._store_blocks, self._store_blocks is None
        if first:
            kept, size, self._store_entries = [], 0, 0
        for k in range(store.n_blocks):
            if k < len(kept) and not first:
                block = kept[k]
            else:
                block = store.read_block(k)
                if first:
                    self._store_entries += block.nnz
                    size += block.data.nbytes + block.indices.nbytes + block.indptr.nbytes
                    if size <= self._store_budget and len(kept) == k:
                        kept.append(block)
            out.append(rows_product(block, x))
        if first:
            self._store_blocks = kept
            if len(kept) == store.n_blocks:
                self._store_held = sp.csr_matrix(sp.vstack(kept, format="csr"))
        return np.concatenate(out)

    @property
    def trapped(self) -> TrappedLight:
        """The patches each sweep solves directly (:mod:`pydynrad.farfield.trapped`), found on the
        first sweep from F's row sums (a pass over ones) and its rows."""
        if self._trapped is None:
            sums = self._bounce(np.ones((len(self.areas), 1)))[:, 0]
            if self._F is not None:
                rows, entries = (lambda idx: self._F[idx]), self._F.nnz
            else:
                held = self._store_held  # the blocks kept in memory, else read again from the files
                rows = (lambda idx: held[idx]) if held is not None else (lambda idx: read_rows(self._store, idx))
                entries = self._store_entries
            self._trapped = TrappedLight(self.rho, sums, rows, entries)
        return self._trapped

    def _moved(
        self, r: np.ndarray, B_was: np.ndarray, B: np.ndarray, changed: np.ndarray, L: np.ndarray, floor: float = 0.0
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """(the residual, the patches it takes from B): the residual of B from ``r``, that of
        ``B_was`` (added to in place: the caller's to give up), ``r + (P F - I) (B - B_was)``, B
        differing from ``B_was`` among the patches ``changed`` only (the local sets, and in a sweep
        the trapped patches: so no pass over all of B finds them), by F's columns on the host;
        changes of at most ``floor`` (max over channels) are left out, those patches keeping
        ``B_was``'s values. None for the patches: a whole pass ``L + P F B - B``, without F by
        column or where a quarter of the patches moved."""
        if self._F_cols is not None:
            d = B[changed] - B_was[changed]
            moved = np.abs(d).max(axis=1) > floor
            cols, d = changed[moved], d[moved]
            if len(cols) < 0.25 * len(B):
                if len(cols):
                    self._add_columns(r, cols, d)
                    r[cols] -= d
                return r, cols
        return self._residual(L, B), None

    def _add_columns(self, r: np.ndarray, cols: np.ndarray, d: np.ndarray) -> None:
        """r += P F[:, cols] d. Columns with few entries in all (a frame's few patches that
        changed by more than the floor) are added entry by entry to the rows they reach; else
        through a dense product, whose passes over all N rows would otherwise cost more."""
        F = self._F_cols
        starts = F.indptr[cols].astype(np.int64)
        counts = F.indptr[cols + 1] - starts
        total = int(counts.sum())
        if total >= len(r) // 8:
            Fd = columns_product(F, cols, d)
            Fd *= self.rho
            r += Fd
            return
        # The entries' positions: each column's run, laid end to end.
        firsts = np.repeat(starts - np.concatenate(([0], np.cumsum(counts)[:-1])), counts)
        at = firsts + np.arange(total)
        rows = F.indices[at]
        add = F.data[at].astype(np.float64)[:, None] * np.repeat(d, counts, axis=0)
        add *= self.rho[rows]
        np.add.at(r, rows, add)

    def _residual(self, L: np.ndarray, B: np.ndarray) -> np.ndarray:
        """``L + P F B - B`` (N, 3) by a whole pass over F."""
        r = self._bounce(B)
        r *= self.rho
        r += L
        r -= B
        return r

    # -- the estimate --------------------------------------------------------------------------------
    def _emitted(self, L: np.ndarray) -> np.ndarray | None:
        """The emitters' emission within L, min(E, L) on the emitting patches (a light vector
        given without it then loses nothing more than it holds), or None without emitters."""
        if not len(self._emitters):
            return None
        return np.minimum(self._emission, L[self._emitters])

    def _reflected(self, size: float, B: np.ndarray, emitted: np.ndarray | None) -> float:
        """|B - E|^2 from size = |B|^2: only the emitting patches differ."""
        if emitted is None:
            return size
        em, a = self._emitters, self.areas[self._emitters]
        b = B[em]
        return max(size - float(a @ (b * b - (b - emitted) ** 2).sum(axis=1)), 0.0)

    def _sampled(self, L: np.ndarray, B: np.ndarray, light_change: bool, t0: float, emitting: bool) -> ErrorEstimate:
        n = len(B)
        if self._sample is None or (light_change and self._sample[0] is None):
            p = self.areas / self.areas.sum()
            idx = np.sort(self._rng.choice(n, size=min(self.samples, max(n, 1)), p=p))
            # Read behind any cache: the sample is read once, and must not evict the rows a walk prefetched.
            self._sample = (idx, read_rows(_uncached(self._rows.source), idx))
        idx, rows = self._sample
        r = L[idx] + self.rho[idx] * (rows @ B) - B[idx]
        sq = (r * r).sum(axis=1)
        mean_a = self._total_area
        den = np.sqrt(self._reflected(_norm(self.areas, B) ** 2, B, self._emitted(L) if emitting else None))
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

    def _stale(self, L: np.ndarray) -> bool:
        held = self._ratios_light
        if self._ratios is None or held is None or held.shape != L.shape:
            return True
        return relative_rms(L - held, L, self.areas) > REMEASURE_CHANGE

    def _moments(self, r: np.ndarray, L: np.ndarray) -> np.ndarray:
        """y = P F r (one pass), and the ratios of estimate, upper bound and q to the residual from
        it. y is also the residual of the swept answer B + r: L + P F (B + r) - (B + r) = P F r."""
        self._ratios_light = L.copy()
        y = self._bounce(r)
        y *= self.rho
        lower, upper = residual_ratios(r, y, self.areas, self.rho)
        n0 = _norm(self.areas, r)
        q = _norm(self.areas, y) / n0 if n0 > 0 else 0.0
        self._ratios = (float(np.sqrt(lower * upper)), upper, q)
        return y

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

    def check(
        self, L: np.ndarray, B: np.ndarray, members: np.ndarray, gathered: np.ndarray, resolve, emitting: bool = True
    ) -> np.ndarray:
        """The answer B (N, 3) for light L, checked (and refined while over the tolerance);
        sets :attr:`last`. ``gathered``: the far field's answer B stands on, as its ``light(L)``
        returned it (the far field's B_far may since be another solution's, where two share it);
        ``resolve(B_far)`` puts a refined far answer into the far field and returns the whole
        answer with the local set solved from it. ``emitting``: L holds the emitters' emission (a
        light vector of :func:`pydynrad.light_vector`), which the norms leave out; False for a
        reflected light vector (``emitters="analytic"``)."""
        t0 = time.perf_counter()
        seen = self._seen
        # The far field answers a light it has not answered with a new B_far (an unchanged L with the
        # same object), and this check leaves as seen the far answer it ends on: so the object tells.
        light_change = seen is None or seen[0] is not gathered
        if not light_change and np.array_equal(seen[1], members) and self.last is not None:
            return B  # the same lights and local set: the same answer as checked last
        if self.sampled and not (light_change and self.tolerance is not None and self._store is not None):
            last = self.last
            if not light_change and last is not None and not last.sampled:
                # After a light change refined from the store, B_far stands and only the local set
                # moved (solved exactly from it): that change's whole estimate stands too, where
                # sampled rows miss a refined answer's residual, which sits on small patches.
                self.last = replace(
                    last, measured=False, sweeps=0, seconds=time.perf_counter() - t0, light_change=False
                )
            else:
                self.last = self._sampled(L, B, light_change, t0, emitting)
            self._seen = (gathered, np.array(members))
            return B
        sweeps = 0
        answer = gathered  # the far answer B stands on, replaced by each resolve
        if light_change and self.tolerance is not None and self._corrections.count:
            start = self._warm_start(L)
            if start is not None:
                answer = gathered + start
                B = resolve(answer)
        held, self._held = self._held, None  # updated in place below: none kept if this fails midway
        emitted = self._emitted(L) if emitting else None
        if light_change or held is None or held[0].shape != B.shape:
            r = self._residual(L, B)
            kept, size = B.copy(), _norm(self.areas, B) ** 2  # a copy: B goes to the caller
        else:
            # Only the local sets' patches changed (the last one checked and this one), most of
            # them by the rounding of the local solve: changes under FRAME_FLOOR of the RMS
            # radiosity stay out (kept holds the values the residual is of), and |B|^2 follows
            # the patches taken: no pass over all of B.
            kept, r_was, size = held
            floor = FRAME_FLOOR * np.sqrt(self._reflected(size, kept, emitted) / self._total_area)
            r, taken = self._moved(r_was, kept, B, np.union1d(seen[1], members), L, floor)
            if taken is None:  # a whole pass: the residual is B's own
                taken = np.flatnonzero(np.any(kept != B, axis=1))
            size += float(self.areas[taken] @ (B[taken] ** 2 - kept[taken] ** 2).sum(axis=1))
            kept[taken] = B[taken]
        measured = self._ratios is None or (light_change and self._stale(L))
        y = self._moments(r, L) if measured else None
        if self._squares is None or self._squares.shape != r.shape:
            self._squares = np.empty_like(r)
        res = _relative(self.areas, r, self._reflected(size, kept, emitted), self._squares)
        ratio, upper, q = self._ratios
        est = res * ratio
        limit = None if self.tolerance is None else self.tolerance * (1.0 if light_change else FRAME_HYSTERESIS)
        while limit is not None and sweeps < MAX_REFINE_SWEEPS:
            if est <= limit:
                if y is not None or not sweeps:  # the ratio measured on this answer, or carried as it was
                    break
                y = self._moments(r, L)  # the refined answer's own moments: the estimate stands on them
                ratio, upper, q = self._ratios
                est = res * ratio
                continue
            trapped = self.trapped
            # The trapped patches first, solved from the rest, the residual brought to that by
            # their columns: the sweep then carries their change (the largest) to the patches they
            # light, which a solve after the sweep leaves a sweep behind. Without F's columns on
            # the host each update of the residual is a pass: they are solved after the sweep
            # then, with the local set, one pass for both.
            first = len(trapped) and self._F_cols is not None
            if not sweeps:
                # From the answer r is the residual of (B itself, but for a frame's left-out
                # changes): the sweeps re-solve the local set, so nothing of B is lost.
                B = kept.copy()
            if first:
                solved = B.copy()
                solved[trapped.patches] = trapped.solve(L, B)
                B, r, y = solved, self._moved(r, B, solved, trapped.patches, L)[0], None
            if y is None:  # P F r for the sweep, and the moments measured on the way
                y = self._moments(r, L)
                measured = True
            answer = was = B + r
            changed = members
            if len(trapped) and not first:
                answer = was.copy()
                answer[trapped.patches] = trapped.solve(L, was)
                changed = np.union1d(members, trapped.patches)
            B_next = resolve(answer)  # the re-solve changes the local set's patches only
            B, r, y, sweeps = B_next, self._moved(y, was, B_next, changed, L)[0], None, sweeps + 1
            size = _norm(self.areas, B) ** 2
            res, last_res = _relative(self.areas, r, self._reflected(size, B, emitted)), res
            est = res * self._ratios[0]  # the ratio of the sweep's start, until measured again
            if res > MIN_SWEEP_GAIN * last_res:  # the sweeps no longer gain: stop
                break
        if sweeps and y is None:  # stopped by the cap or the gain: the refined answer's own moments
            self._moments(r, L)
            ratio, upper, q = self._ratios
            est = res * ratio
        if sweeps or (light_change and self._corrections.count):
            correction = answer - gathered
            self._corrections.add(L, correction)
            self._last_correction = (L.copy(), correction)
        self._held = (B.copy() if sweeps else kept, r, size)
        self._seen = (answer, np.array(members))
        self.last = ErrorEstimate(
            est,
            res,
            q,
            measured,
            res * upper,
            sweeps,
            0,
            None,
            time.perf_counter() - t0,
            light_change,
        )
        return B
