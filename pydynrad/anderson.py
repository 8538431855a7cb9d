"""Anderson mixing of a fixed-point iteration u <- f(u), per channel (column).

The next iterate is the combination of the last few f(u) whose residuals f(u) - u cancel best
in least squares (type II, window ``depth``). On an affine map, which every iteration here is
(a radiosity bounce, the correction of rows left stale), it works as GMRES restricted to the last
``depth`` directions, for the cost of keeping them and one small least-squares solve per channel.
Where it is used and what it measured: :mod:`pydynrad.dynamic.stale` (the correction after a
move), :meth:`pydynrad.devicecsr.DeviceCSR.jacobi` (the far field's coarse sweeps).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Anderson"]


class Anderson:
    """Mixing over the last ``depth`` steps of iterates of shape (n, k), k channels mixed apart."""

    def __init__(self, depth: int) -> None:
        self.depth = depth
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # (f(u), residual) of the last step
        self._dg: list[np.ndarray] = []  # differences of f(u), (k, n) each
        self._dr: list[np.ndarray] = []  # differences of the residuals

    def next(self, fu: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """The next iterate from f(u) (n, k) and its residual f(u) - u (n, k)."""
        # Kept channel-major, (k, n): the products below are then batched matrix products.
        fu_t, r_t = np.ascontiguousarray(fu.T), np.ascontiguousarray(residual.T)
        if self._last is not None:
            self._dg.append(fu_t - self._last[0])
            self._dr.append(r_t - self._last[1])
            del self._dg[: -self.depth], self._dr[: -self.depth]
        self._last = (fu_t, r_t)
        if not self._dr:
            return fu
        # The least squares min |residual - dR gamma| per channel by its m x m normal equations:
        # lstsq's SVD of each (n, m) column set cost ~0.3 ms a channel at n = 8,269 (the
        # village's coarse level), as much as a third of the sweep it accelerates. The small
        # systems go through lstsq too, so a singular one (a direction repeated) is no error;
        # squaring their condition does not matter at a window of a few steps.
        dR, dG = np.stack(self._dr, axis=1), np.stack(self._dg, axis=1)  # (k, m, n)
        gram = dR @ dR.transpose(0, 2, 1)
        rhs = (dR @ r_t[:, :, None])[:, :, 0]
        gamma = np.stack([np.linalg.lstsq(gram[c], rhs[c], rcond=None)[0] for c in range(len(gram))])  # (k, m)
        return fu - (gamma[:, None, :] @ dG)[:, 0, :].T
