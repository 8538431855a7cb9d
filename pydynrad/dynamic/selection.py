"""Which M of the N patches are local: the nearest ones to the observer, kept up to date cheaply.

The paper's per-frame loop compares the farthest local patch i with the nearest patch j outside
the local set and swaps while j is closer. :class:`NearestSet` answers both questions without
sorting the N distances:

* farthest local: the M local patches' distances are recomputed each frame (the observer moved,
  so all of them changed) and the k largest found with ``argpartition``: O(M);
* nearest outside: a k-d tree over the N patch centres (built once, O(N log N)) returns the
  M + k patches nearest the observer, sorted, in O((M + k) log N); at most M of them are
  local, so the first k others among them are the k nearest patches outside the set.

So a frame costs O(M + (M + k) log N) here, which is small next to the O(M^2) update of K
(for M = 4096 it is about a millisecond). Distances are from the observer to patch centres.
Pinned patches (emitters, by the authors' rule) are never proposed for eviction.

See docs/design.md, 'Local set'.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["NearestSet"]


class NearestSet:
    """Nearest-M patch selection over fixed patch centres.

    Parameters
    ----------
    centers : (N, 3) float
        Patch centres.
    pinned : (N,) bool, optional
        Patches that, once local, are never evicted.
    """

    def __init__(self, centers: np.ndarray, pinned: np.ndarray | None = None) -> None:
        self.centers = np.asarray(centers, dtype=np.float64)
        self.n = len(self.centers)
        self.pinned = np.zeros(self.n, dtype=bool) if pinned is None else np.asarray(pinned, dtype=bool)
        self._tree = cKDTree(self.centers)
        self._settled: tuple[bytes, int, np.ndarray] | None = None  # (observer, k, local set) that asked for no swap

    def nearest(self, observer: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``count`` patches nearest ``observer`` and their distances, nearest first."""
        count = min(int(count), self.n)
        d, idx = self._tree.query(np.asarray(observer, dtype=np.float64), k=count)
        return np.atleast_1d(idx).astype(np.int64), np.atleast_1d(d)

    def propose(
        self, observer: np.ndarray, local_patches: np.ndarray, local_mask: np.ndarray, k: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Swaps for this frame: (slots to free, patches to add), at most ``k`` of each.

        Repeats the paper's test k times: pair the t-th farthest evictable local patch with the t-th
        nearest patch outside the set and keep the pairs where the outside one is strictly closer.
        ``local_patches`` (M,) holds the patch of each slot, ``local_mask`` (N,) bool marks them.
        """
        obs = np.asarray(observer, dtype=np.float64)
        M = len(local_patches)
        none = np.empty(0, np.int64), np.empty(0, np.int64)
        if M >= self.n or k < 1:
            return none
        # A still observer over the same local set asks for nothing again (the frames of a moving
        # object seen from one place): no query of M + k neighbours (a large share of such a frame).
        asked = (obs.tobytes(), k)  # as asked: k is clamped below
        settled = self._settled
        if settled is not None and settled[:2] == asked and np.array_equal(settled[2], local_patches):
            return none
        d_in = np.linalg.norm(self.centers[local_patches] - obs, axis=1)
        d_in[self.pinned[local_patches]] = -np.inf
        k = min(k, M)
        far = np.argpartition(-d_in, k - 1)[:k] if k < M else np.arange(M)
        far = far[np.argsort(-d_in[far], kind="stable")]
        idx, d = self.nearest(obs, M + k)
        out = ~local_mask[idx]
        near, d_near = idx[out][:k], d[out][:k]
        t = min(len(near), len(far))
        closer = d_near[:t] < d_in[far[:t]]
        # Both lists are monotone, so the pairs that qualify are a prefix.
        n_swap = int(np.argmin(closer)) if not closer.all() else t
        self._settled = (*asked, np.array(local_patches)) if n_swap == 0 else None
        return far[:n_swap].astype(np.int64), near[:n_swap].astype(np.int64)
