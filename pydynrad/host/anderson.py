"""Anderson mixing of a fixed-point iteration u <- f(u), per channel (column).

The next iterate is the combination of the last few f(u) whose residuals f(u) - u cancel best
in least squares (type II, window ``depth``). On an affine map, which every iteration here is
(a radiosity bounce, the correction of rows left stale), it works as GMRES restricted to the last
``depth`` directions, for the cost of keeping them and one small least-squares solve per channel.
Where it is used and what it measured: :mod:`pydynrad.dynamic.stale` (the correction after a
move), :meth:`pydynrad.device.csr.DeviceCSR.jacobi` (the far field's coarse sweeps).
"""

from __future__ import annotations

import numpy as np

from ..checks import integer
from ..errors import InvalidInputError

__all__ = ["Anderson"]


class Anderson:
    """Mixing over the last ``depth`` steps of iterates of shape (n, k), k channels mixed apart."""

    def __init__(self, depth: int) -> None:
        self.depth = integer(depth, "depth", 1)
        self._steps = 0  # differences held (up to depth)
        # Channel-major (k, n) and preallocated: the products below are then batched matrix
        # products, and no step allocates its history (on a VM whose fresh pages fault one by
        # one, the allocations cost as much as the arithmetic).
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # f(u) and residual of the last step
        self._dg: np.ndarray | None = None  # (k, depth, n) differences of f(u), a ring
        self._dr: np.ndarray | None = None  # the same of the residuals

    def next(self, fu: np.ndarray, residual: np.ndarray) -> np.ndarray:
        """The next iterate from f(u) (n, k) and its residual f(u) - u (n, k)."""
        n, k = fu.shape
        if residual.shape != fu.shape or (self._last is not None and self._last[0].shape != (k, n)):
            raise InvalidInputError(
                f"Anderson mixes iterates of one shape: got f(u) {fu.shape}, residual "
                f"{residual.shape}"
                + ("" if self._last is None else f", after ({self._last[0].shape[1]}, {self._last[0].shape[0]})")
            )
        if self._last is None:
            self._last = (np.array(fu.T), np.array(residual.T))
            self._dg, self._dr = np.empty((k, self.depth, n)), np.empty((k, self.depth, n))
            return fu
        assert self._dg is not None and self._dr is not None  # made with _last, on the first step
        slot = self._steps % self.depth
        np.subtract(fu.T, self._last[0], out=self._dg[:, slot])
        np.subtract(residual.T, self._last[1], out=self._dr[:, slot])
        np.copyto(self._last[0], fu.T)
        np.copyto(self._last[1], residual.T)
        self._steps += 1
        m = min(self._steps, self.depth)
        dR, dG = self._dr[:, :m], self._dg[:, :m]  # (k, m, n), in ring order (no matter to least squares)
        # The least squares min |residual - dR gamma| per channel by its m x m normal equations,
        # every channel in one batched solve: lstsq's SVD of each (n, m) column set per channel, and
        # its overhead alone on a small system, were a visible share of a coarse sweep
        # (docs/decisions/0019-far-field-coarse-solve.md). A ridge of 1e-12 of the trace keeps a singular
        # system (a direction repeated; no change at all) solvable; squaring the condition does
        # not matter at a window of a few steps.
        gram = dR @ dR.transpose(0, 2, 1)
        rhs = dR @ self._last[1][:, :, None]
        ridge = 1e-12 * np.trace(gram, axis1=1, axis2=2)[:, None, None] + 1e-300
        gamma = np.linalg.solve(gram + ridge * np.eye(m), rhs)  # (k, m, 1)
        return fu - (gamma.transpose(0, 2, 1) @ dG)[:, 0, :].T
