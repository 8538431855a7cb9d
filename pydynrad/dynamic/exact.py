"""Host-side algebra of the exact local update (``update="exact"``), per colour channel.

K = K_S = (I - F_SS P_S)^{-1} F_SS over the slots S of the local set. A batch
swap removes the patches in slots ``I`` and puts k new patches J into those slots. The device
supplies, from one read pass over K, the columns U = K[:, I], the rows V = K[I, :] and the
products K (P_S F_SJ) and (F_JS P_S) K; everything here is O(M k + k^3) on the host. The
result is a rank-2k update ``K += A B`` (one read-write pass) followed by writing J's columns
and rows into I's slots. With k = 1 this is exactly the Sherman-Morrison downdate of the
removed patch followed by the bordering update of the added one (tests/dynamic/test_dynamic.py
transcribes both and checks it).

Shapes: M slots, k swaps. F_SJ (M, k) holds F[S[a], J[m]] with the rows of the slots I
zeroed; F_JS (k, M) holds F[J[m], S[a]] with the columns of I zeroed; F_JJ (k, k).

See docs/design.md, 'Exact mode' and 'Batched swap'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..host.blas import blas_beside

__all__ = ["SwapUpdate", "batched_swap", "exact_swap"]


@dataclass
class SwapUpdate:
    """What the device applies: ``K += A @ B``, then columns/rows of ``slots``.

    A : (M, 2k), B : (2k, M)
        The rank-2k update (left and right factors).
    cols : (k, M)
        cols[m] is the new column of slot ``slots[m]`` (K[:, slots[m]]).
    rows : (k, M)
        rows[m] is the new row of slot ``slots[m]``; cols and rows agree where they cross.
    """

    A: np.ndarray
    B: np.ndarray
    cols: np.ndarray
    rows: np.ndarray


def batched_swap(
    U: np.ndarray,
    V: np.ndarray,
    KPF: np.ndarray,
    FPK: np.ndarray,
    F_SJ: np.ndarray,
    F_JS: np.ndarray,
    F_JJ: np.ndarray,
    rho_S: np.ndarray,
    rho_J: np.ndarray,
    slots: np.ndarray,
) -> SwapUpdate:
    """Factors of the exact remove-I / add-J update of one channel (docs/design.md, 'Batched swap').

    U = K[:, I] (M, k); V = K[I, :] (k, M); KPF = K (P_S F_SJ) (M, k); FPK = (F_JS P_S) K (k, M);
    rho_S (M,) albedo of the current slots (those of I are never used: F_SJ/F_JS are zero there);
    rho_J (k,) albedo of the entering patches; slots (k,) the slot indices of I.
    """
    k = len(slots)
    eye = np.eye(k)
    rho_I = rho_S[slots]
    K_II = U[slots, :]
    # W = P_I (I + K_II P_I)^{-1}: the Sherman-Morrison-Woodbury factor that removes I.
    W = rho_I[:, None] * np.linalg.solve((eye + K_II * rho_I[None, :]).T, eye).T
    PF = rho_S[:, None] * F_SJ
    FP = F_JS * rho_S[None, :]
    X = KPF - U @ (W @ (V @ PF))  # K_removed (P_S F_SJ), without forming K_removed
    Y = FPK - ((FP @ U) @ W) @ V  # (F_JS P_S) K_removed
    C = F_SJ + X
    R = F_JS + Y
    Lam = F_JJ + R @ PF
    PJ = np.diag(rho_J)
    T = np.linalg.inv(eye - Lam @ PJ)
    TLam = T @ Lam
    CPT = C @ (PJ @ T)
    # (C (I - P_J Lam)^{-1})^T with (I - P_J Lam)^{-1} = I + P_J T Lam: k x k products, where a
    # solve with M right-hand sides took a third of this function's time at M = 4096.
    cols = (C + CPT @ Lam).T
    rows = T @ R
    cols[:, slots] = TLam.T  # cols[m][slots[a]] = K[J_a, J_m]
    rows[:, slots] = TLam  # rows[m][slots[a]] = K[J_m, J_a]
    A = np.concatenate([U, CPT], axis=1)
    B = np.concatenate([-(W @ V), R], axis=0)
    return SwapUpdate(A=A, B=B, cols=cols, rows=rows)


def exact_swap(
    kernels,
    slots: np.ndarray,
    F_SJ: np.ndarray,
    F_JS: np.ndarray,
    F_JJ: np.ndarray,
    rho_S: np.ndarray,
    rho_J: np.ndarray,
) -> None:
    """Apply the exact batch swap to every channel of the device matrix behind ``kernels``.

    rho_S (C, M) and rho_J (C, k): the albedo per channel. Device work per channel: the
    slots' columns and rows (O(k M)) and one read pass (gather), all channels enqueued
    before one read-back; then per channel the host algebra (beside the previous channel's
    passes on the device), one read-write pass (rank 2k) and J's columns and rows written
    into the slots, queued together and not waited for.
    """
    X = rho_S[:, None, :] * F_SJ.T[None]  # (P_S F_SJ)^T per channel
    Y = F_JS[None] * rho_S[:, None, :]  # F_JS P_S per channel
    KPF, FPK, cols_I, rows_I = kernels.gather_all(X, Y, slots)
    with blas_beside(kernels.device):  # the previous channel's passes hold the device's cores
        for c in range(len(rho_S)):
            upd = batched_swap(cols_I[c].T, rows_I[c], KPF[c].T, FPK[c], F_SJ, F_JS, F_JJ, rho_S[c], rho_J[c], slots)
            kernels.update_slots(c, upd.A.T, upd.B, slots, upd.cols, upd.rows)
