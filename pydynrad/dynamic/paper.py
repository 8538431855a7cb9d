"""The paper's local update (``update="paper"``), step by step as docs/design.md, 'Paper mode',
reads sections 3-4.

One swap frees slot s (the evicted patch i) and puts patch j there. Per colour channel:

1. clear row s and column s of K (paths through i stay inside K: the paper keeps them);
2. f_c = F[S, j], f_r = F[j, S] over the slots (zero at s);
3. dr = sum_a f_c[a] f_r[a] rho[a]                       (Eq. 1, the ``double_reflection`` kernel);
4. g_c = f_c (1 + rho_j dr),  g_r = f_r (1 + rho_j dr);
5. g'_c = g_c + K (P_S g_c),  g'_r = g_r + (g_r P_S) K     (one gather pass over K);
6. K += rho_j g'_c g'_r^T on the rows the used-patches table allows (one rank-one pass);
7. K[:, s] = g'_c, K[s, :] = g'_r, K[s, s] = dr.

Section 4.1's bitset (:class:`UsedPatches`): for every slot a, the set of patches whose
reflection row a of K already holds. What it masks, precisely: when j enters, every row a
whose set already holds j (j was local before and its paths into a were added then, and
clearing j's row and column on eviction did not remove them) is left out of step 6's
rank-one update, so those paths are not added a second time; afterwards j joins every row's
set. The entering patch's own row (K[s, :] = g'_r) is built from all current local patches (through
K), so its set starts as the whole current local set, j with it. The initial K is the exact
multibounce matrix over the initial set, so every row's set starts as that set.
"""

from __future__ import annotations

import numpy as np

__all__ = ["UsedPatches", "paper_swap"]


class UsedPatches:
    """Per-slot bitsets over the N patches, packed 8 per byte: M * ceil(N / 8) bytes."""

    def __init__(self, M: int, N: int) -> None:
        self.n = int(N)
        self.bits = np.zeros((int(M), -(-int(N) // 8)), dtype=np.uint8)

    @property
    def nbytes(self) -> int:
        return self.bits.nbytes

    def reset_all(self, local_mask: np.ndarray) -> None:
        """Every slot's set := the patches marked in ``local_mask`` (N,) bool."""
        self.bits[:] = np.packbits(local_mask)[None, :]

    def reset(self, slot: int, local_mask: np.ndarray) -> None:
        """Slot ``slot``'s set := the patches marked in ``local_mask``."""
        self.bits[slot] = np.packbits(local_mask)

    def holding(self, patch: int) -> np.ndarray:
        """(M,) bool: the slots whose set holds ``patch``."""
        return (self.bits[:, patch >> 3] >> (7 - (patch & 7))) & 1 == 1

    def add(self, patch: int) -> None:
        """Put ``patch`` into every slot's set."""
        self.bits[:, patch >> 3] |= np.uint8(1 << (7 - (patch & 7)))


def paper_swap(
    kernels, slot: int, f_c: np.ndarray, f_r: np.ndarray, rho_S: np.ndarray, rho_j: np.ndarray, row_mask: np.ndarray
) -> None:
    """Steps 1 and 3-7 above on every channel of the device matrix behind ``kernels``.

    f_c, f_r (M,): F[S, j] and F[j, S] with zeros at ``slot``; rho_S (C, M) the slots' albedo
    per channel; rho_j (C,) the entering patch's; row_mask (M,) bool, False on the rows the
    used-patches table excludes from the rank-one update. The channels' steps are enqueued
    together: two waits per swap (for dr and for the gathers), whatever C is. Each channel's
    rank-one pass and slot write are queued by ``update_slots`` and not waited for.
    """
    C = rho_S.shape[0]
    for c in range(C):
        kernels.clear_slot(c, slot)  # 1. clear i's row and column
    dr = kernels.double_reflection(f_c, f_r, rho_S)  # 3. Eq. 1, (C,)
    g_c = f_c[None] * (1.0 + rho_j * dr)[:, None]  # 4.
    g_r = f_r[None] * (1.0 + rho_j * dr)[:, None]
    KPg, gPK = kernels.gather_all((rho_S * g_c)[:, None], (g_r * rho_S)[:, None])  # 5. one read pass each
    for c in range(C):
        gp_c = g_c[c] + KPg[c, 0]
        gp_r = g_r[c] + gPK[c, 0]
        col, row = gp_c.copy(), gp_r.copy()  # 7. the new column, row and diagonal
        col[slot] = row[slot] = dr[c]
        kernels.update_slots(
            c, rho_j[c] * gp_c * row_mask, gp_r, [slot], col[None], row[None]
        )  # 6. masked rank one, 7.
