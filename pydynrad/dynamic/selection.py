"""Which M of the N patches are local: the nearest ones to the observer, kept up to date cheaply.

The paper's per-frame loop compares the farthest included patch i with the nearest excluded
patch j and swaps while j is closer. :class:`NearestSet` answers both questions without
sorting the N distances:

* farthest included: the M included distances are recomputed each frame (the observer moved,
  so all of them changed) and the k largest found with ``argpartition``: O(M);
* nearest excluded: a k-d tree over the N patch centres (built once, O(N log N)) returns the
  M + k patches nearest the observer, sorted, in O((M + k) log N); at most M of them are
  included, so the first k excluded ones among them are the k nearest excluded patches.

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
        Patches that, once included, are never evicted.
    """

    def __init__(self, centers: np.ndarray, pinned: np.ndarray | None = None) -> None:
        self.centers = np.asarray(centers, dtype=np.float64)
        self.n = len(self.centers)
        self.pinned = np.zeros(self.n, dtype=bool) if pinned is None else np.asarray(pinned, dtype=bool)
        self._tree = cKDTree(self.centers)

    def nearest(self, observer: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``count`` patches nearest ``observer`` and their distances, nearest first."""
        count = min(int(count), self.n)
        d, idx = self._tree.query(np.asarray(observer, dtype=np.float64), k=count)
        return np.atleast_1d(idx).astype(np.int64), np.atleast_1d(d)

    def propose(self, observer: np.ndarray, members: np.ndarray, included: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Swaps for this frame: (slots to free, patches to add), at most ``k`` of each.

        Repeats the paper's test k times: pair the t-th farthest evictable member with the t-th
        nearest excluded patch and keep the pairs where the excluded one is strictly closer.
        ``members`` (M,) holds the patch of each slot, ``included`` (N,) bool marks them.
        """
        obs = np.asarray(observer, dtype=np.float64)
        M = len(members)
        if M >= self.n or k < 1:
            return np.empty(0, np.int64), np.empty(0, np.int64)
        d_in = np.linalg.norm(self.centers[members] - obs, axis=1)
        d_in[self.pinned[members]] = -np.inf
        k = min(k, M)
        far = np.argpartition(-d_in, k - 1)[:k] if k < M else np.arange(M)
        far = far[np.argsort(-d_in[far], kind="stable")]
        idx, d = self.nearest(obs, M + k)
        out = ~included[idx]
        near, d_near = idx[out][:k], d[out][:k]
        t = min(len(near), len(far))
        closer = d_near[:t] < d_in[far[:t]]
        # Both lists are monotone, so the pairs that qualify are a prefix.
        n_swap = int(np.argmin(closer)) if not closer.all() else t
        return far[:n_swap].astype(np.int64), near[:n_swap].astype(np.int64)
