"""Earlier sources of a linear solve and their answers, and the combination that fits a new source.

The far field's answers are linear in their sources: the coarse solution x in its source s
(x = s + P_c F_c x), and B_far in the light vector L (every gather but the shared one). So where
a new source is a combination S a of earlier ones (a light switched back, dimmed, recoloured,
lights summed), the same combination X a of the earlier answers is its answer, and where it is
close to one, X a plus the rest is a good first guess. :class:`Answers` keeps the last few
(source, answer) pairs per colour channel and fits a new source by least squares.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Answers"]


def _max_abs(x: np.ndarray, axis=None):
    """max |x| (along ``axis``) as max and -min: no temporary array of |x|."""
    return np.maximum(x.max(axis=axis), -x.min(axis=axis))


class Answers:
    """The last ``depth`` (source, answer) pairs, each (n, k) with k channels: sources in float64
    (the fit needs them whole), answers in ``dtype`` (they are only combined).

    Pairs of another shape than the last one's start the record afresh (a grey light after a
    coloured one). Stored channel-major, (k, depth, n), so that a channel's sources are one
    contiguous block for the fit.
    """

    def __init__(self, depth: int, dtype=np.float64) -> None:
        self.depth, self.dtype = int(depth), np.dtype(dtype)
        self._S: np.ndarray | None = None  # (k, depth, n) sources
        self._X: np.ndarray | None = None  # (k, depth, n) answers
        self._gram: np.ndarray | None = None  # (k, depth, depth) the sources' dot products
        self._size: np.ndarray | None = None  # (k, depth) max |source| per channel
        self._rest: np.ndarray | None = None  # (k, n) scratch of fit()
        self.count = 0
        self._next = 0

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self._S, self._X, self._gram, self._size, self._rest) if a is not None)

    def add(self, source: np.ndarray, answer: np.ndarray) -> None:
        """Record (source, answer), both (n, k), dropping the oldest pair beyond ``depth``."""
        if self._S is None or self._S.shape[::2] != source.shape[::-1]:
            self._S = np.empty((source.shape[1], self.depth, source.shape[0]))
            self._X = np.empty(self._S.shape, self.dtype)
            self._gram = np.zeros((source.shape[1], self.depth, self.depth))
            self._size = np.zeros((source.shape[1], self.depth))
            self.count = self._next = 0
        j = self._next
        self._S[:, j] = source.T
        self._X[:, j] = answer.T
        self._size[:, j] = _max_abs(self._S[:, j], axis=1)
        used = max(self.count, j + 1)
        self._gram[:, j, :used] = np.einsum("cn,chn->ch", self._S[:, j], self._S[:, :used])
        self._gram[:, :used, j] = self._gram[:, j, :used]
        self._next = (self._next + 1) % self.depth
        self.count = min(self.count + 1, self.depth)

    def fit(self, source: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The best combination of the recorded sources for ``source`` (n, k), per channel:
        (a (k, count) coefficients, X a (n, k) the same combination of the answers, r (n, k) =
        source - S a, a view of scratch that the next fit overwrites, and (k, 2) per channel:
        ``max |r|`` and ``sum_i |a_i| max |S_i|``, both over ``max |source|`` (inf where the source is 0
        and they are not): how far the fit is off, and how much the combination cancels, which
        scales the recorded answers' own errors), or None when nothing of this shape is
        recorded.

        Least squares through the count x count normal equations in float64, the sources' dot
        products kept from :meth:`add`, so a fit reads the sources twice (S s, then r) and the
        answers once; the equations' conditioning only decides how small r gets, and callers
        test r."""
        if self._S is None or self.count == 0 or self._S.shape[::2] != source.shape[::-1]:
            return None
        k, h = source.shape[1], self.count
        a = np.empty((k, h))
        if self._rest is None or self._rest.shape != self._S.shape[::2]:
            self._rest = np.empty(self._S.shape[::2])  # reused: fresh pages cost more than the pass
        combined, off = np.empty(source.shape), np.empty((k, 2))
        for ch in range(k):
            S, rest = self._S[ch, :h], self._rest[ch]
            rest[:] = source[:, ch]
            size = _max_abs(rest)  # on the contiguous copy
            a[ch] = np.linalg.lstsq(self._gram[ch, :h, :h], S @ rest, rcond=None)[0]
            rest -= a[ch] @ S
            terms = np.array([_max_abs(rest), np.abs(a[ch]) @ self._size[ch, :h]])
            off[ch] = terms / size if size > 0 else np.where(terms == 0, 0.0, np.inf)
            combined[:, ch] = a[ch].astype(self.dtype) @ self._X[ch, :h]
        return a, combined, self._rest.T, off
