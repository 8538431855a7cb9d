"""Trapped light: the patches whose light a refinement sweep hardly damps, solved directly.

A sweep ``B <- L + P F B`` damps the error on patch i by at most ``rho_i sum_j F_ij`` per
bounce (its albedo times the share of its hemisphere that other patches fill): near 1 where bright
surfaces nearly enclose each other (an alcove, the space under an eave, a box's inside), light
there bounces tens of times before it settles, and sweeps over all of F take as many passes to
follow it. The set Q of patches with ``rho_i sum_j F_ij`` above :data:`TRAPPED` is small on real
scenes, and its block of F sparse, so each sweep solves Q's equations exactly from the rest,

    (I - P_Q F_QQ) B_Q = L_Q + P_Q F_QX B_X,

by a sparse LU factored once (per distinct albedo channel), as the local set is solved from its
injection; what is left to the sweeps contracts fast (the measurements, and the remedies tried:
docs/decisions/0042-far-field-trapped-light.md). Where F among those patches is large (an
interior whose walls all pass the threshold), Q keeps the most trapped patches whose block stays
within :data:`TRAPPED_SHARE` of F's entries: the factorisation's cost grows faster than its
entries.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from ..host.colproduct import rows_product

__all__ = ["TrappedLight", "TRAPPED", "TRAPPED_SHARE"]

#: A patch whose albedo times its row sum of F exceeds this is solved directly in the sweeps.
TRAPPED = 0.7
#: Q's block of F holds at most this share of F's entries (the most trapped patches kept).
TRAPPED_SHARE = 1 / 64


class TrappedLight:
    """The trapped patches of a scene (:attr:`patches`, possibly none) and the exact solve of their
    equations from the rest of an answer.

    Parameters
    ----------
    rho : (N, 3) float
        Albedo per patch and channel.
    row_sums : (N,) float
        ``sum_j F_ij`` per patch (one pass of F over ones).
    rows : callable
        ``rows(idx)`` -> F's rows ``idx`` as CSR (len(idx), N): from F in memory or a store.
    entries : int
        F's non-zeros (the budget's base).
    """

    def __init__(self, rho: np.ndarray, row_sums: np.ndarray, rows, entries: int) -> None:
        rho = np.asarray(rho, np.float64)
        g = rho.max(axis=1) * np.asarray(row_sums, np.float64)
        Q = np.flatnonzero(g > TRAPPED)
        Q = Q[np.argsort(-g[Q], kind="stable")]  # the most trapped first
        self.patches = np.zeros(0, np.int64)
        self.rows: sp.csr_matrix | None = None
        self._lu: list = []
        self._channel = np.zeros(0, np.int64)
        if not len(Q):
            return
        F_Q = sp.csr_matrix(rows(Q), dtype=np.float64)
        # Of Q's first k patches, their block holds the entries whose row and column both rank
        # below k: the largest k within the budget.
        rank = np.full(len(rho), len(Q), np.int64)
        rank[Q] = np.arange(len(Q))
        row_rank = np.repeat(np.arange(len(Q)), np.diff(F_Q.indptr))
        last = np.sort(np.maximum(row_rank, rank[F_Q.indices]))
        last = last[last < len(Q)]
        budget = int(TRAPPED_SHARE * entries)
        k = len(Q) if len(last) <= budget else int(last[budget])
        if k == 0:
            return
        order = np.argsort(Q[:k])
        Q, F_Q = Q[:k][order], F_Q[:k][order]
        self.patches, self.rows = Q, sp.csr_matrix(F_Q)
        F_QQ = sp.csr_matrix(F_Q[:, Q])
        eye = sp.identity(k, format="csr")
        # One factorisation per distinct albedo column of Q (one for a grey scene).
        columns, channel = np.unique(rho[Q].T, axis=0, return_inverse=True)
        self._channel = np.asarray(channel).ravel()
        self._lu = [sla.splu(sp.csc_matrix(eye - sp.diags(c) @ F_QQ)) for c in columns]
        self._rho = rho[Q]
        self._F_QQ = F_QQ

    def __len__(self) -> int:
        return len(self.patches)

    def solve(self, L: np.ndarray, B: np.ndarray) -> np.ndarray:
        """B_Q (len(Q), 3) solving Q's equations exactly from B (N, 3) outside Q, for light L (N, 3)."""
        Q = self.patches
        outside = rows_product(self.rows, B) - rows_product(self._F_QQ, B[Q])  # F_QX B_X
        rhs = L[Q] + self._rho * outside
        return np.stack([self._lu[self._channel[c]].solve(rhs[:, c]) for c in range(B.shape[1])], axis=1)
