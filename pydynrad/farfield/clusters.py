"""A partition of a scene's patches into clusters for the far field's coarse level.

Every cluster is pure: one albedo, one emission and one orientation (one of 26 normal bins:
the directions ``(a, b, c) / |(a, b, c)|`` with a, b, c in {-1, 0, 1}), and, given F, inside one of
its connected components (so a closed room's inside never shares a cluster with the lit floor
outside: that leaked sunlight into closed rooms in tests/farfield/test_farfield.py), so the coarse albedo is
exact and no cluster mixes emitters of different power (mixing them overestimated lamp-lit
ceilings by 18% in the float64 prototype). Inside each group of equal albedo, emission and
normal bin the patches are split by recursive bisection, k-d style: a segment that must become
k clusters is cut along its widest axis at the quantile k_left / k of its patches, all segments
of a level at once with one sort. The coordinate along the group's normal counts
:data:`NORMAL_WEIGHT` times, so parallel walls a small distance apart separate before a wall is
cut along its length. O(N log N log C), deterministic (stable sorts), no iteration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..checks import integer, number
from ..errors import InvalidInputError
from ..geometry.loading import checked_scene
from ..host.csrgraph import weak_components
from ..rows.prolongation import LINEAR_FUNCTIONS

__all__ = [
    "Clusters",
    "cluster_patches",
    "default_cluster_count",
    "NORMAL_BINS",
    "NORMAL_WEIGHT",
    "DEFAULT_PATCHES_PER_CLUSTER",
    "light_components",
    "linear_basis",
]

#: The 26 unit directions of the normal bins.
NORMAL_BINS = np.array(
    [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)], dtype=np.float64
)
NORMAL_BINS /= np.linalg.norm(NORMAL_BINS, axis=1, keepdims=True)

#: How much more the coordinate along a group's normal counts than the ones across it.
NORMAL_WEIGHT = 4.0

#: The automatic cluster size, N / C (measured in bench/farfield.py: see its error-vs-C table).
DEFAULT_PATCHES_PER_CLUSTER = 8


@dataclass(frozen=True)
class Clusters:
    """A partition of N patches into C clusters.

    labels : (N,) int64, the cluster of each patch, 0..C-1 (every value used)
    count : int, C
    groups : int, how many (albedo, emission, normal bin) groups the scene has (C >= groups)
    scene_hash : str, the scene's :meth:`~pydynrad.Scene.content_hash` (checks a G belongs to it)
    """

    labels: np.ndarray
    count: int
    groups: int
    scene_hash: str

    def __len__(self) -> int:
        return self.count

    @classmethod
    def from_labels(cls, scene, labels) -> Clusters:
        """Clusters from (N,) labels made elsewhere (e.g. the ones a form-factor store's G was
        computed for): every patch in one of 0..C-1, each cluster of one albedo (the coarse
        albedo must be exact)."""
        scene = checked_scene(scene)
        n = len(scene)
        lab = np.asarray(labels)
        if lab.shape != (n,) or not np.issubdtype(lab.dtype, np.integer) or lab.min(initial=0) < 0:
            raise InvalidInputError(
                f"cluster labels must be {n} integers >= 0, one cluster per patch; got {lab.dtype} shape {lab.shape}"
            )
        lab = lab.astype(np.int64)
        C = int(lab.max()) + 1
        if len(np.unique(lab)) != C:
            raise InvalidInputError(f"cluster labels must use every value 0..{C - 1}")
        albedo = scene.albedo.astype(np.float64)
        first = np.zeros(C, dtype=np.int64)
        first[lab[::-1]] = np.arange(n)[::-1]
        mixed = np.flatnonzero(np.any(albedo != albedo[first[lab]], axis=1))
        if len(mixed):
            raise InvalidInputError(
                f"cluster {lab[mixed[0]]} mixes albedos (patches {first[lab[mixed[0]]]} and "
                f"{mixed[0]}); the far field needs clusters pure in albedo"
            )
        groups = int(_groups(scene, np.zeros(n, dtype=np.int64))[0].max()) + 1
        return cls(labels=lab, count=C, groups=groups, scene_hash=scene.content_hash())

    @property
    def sizes(self) -> np.ndarray:
        """(C,) patches per cluster."""
        return np.bincount(self.labels, minlength=self.count)

    def indicator(self) -> sp.csr_matrix:
        """(N, C) CSR: 1 at (i, labels[i]), the indicator prolongation."""
        n = len(self.labels)
        return sp.csr_matrix((np.ones(n), (np.arange(n), self.labels)), shape=(n, self.count))

    def restriction(self, areas: np.ndarray) -> sp.csr_matrix:
        """(C, N) CSR R: R[c, i] = A_i / A_c for i in c, the area-weighted average (R Pr = I)."""
        n = len(self.labels)
        a = np.asarray(areas, dtype=np.float64)
        a_c = np.bincount(self.labels, weights=a, minlength=self.count)
        return sp.csr_matrix((a / a_c[self.labels], (self.labels, np.arange(n))), shape=(self.count, n))


def default_cluster_count(n: int, groups: int) -> int:
    """C for an N-patch scene: N / :data:`DEFAULT_PATCHES_PER_CLUSTER`, at least one per group."""
    return int(min(n, max(groups, -(-n // DEFAULT_PATCHES_PER_CLUSTER))))


def _groups(scene, components) -> np.ndarray:
    """(N,) group id of each patch: equal albedo, equal emission, one normal bin (and one component)."""
    bins = np.argmax(scene.normals.astype(np.float64) @ NORMAL_BINS.T, axis=1)
    key = np.column_stack([scene.albedo.astype(np.float64), scene.emission.astype(np.float64), bins, components])
    _, gid = np.unique(key, axis=0, return_inverse=True)
    return gid.ravel().astype(np.int64), bins


def _shares(sizes: np.ndarray, total: int) -> np.ndarray:
    """Clusters per group, summing to ``total``: at least 1 each, the rest in proportion to
    size (largest remainders), never more than the group's patches."""
    k = np.ones(len(sizes), dtype=np.int64)
    extra = total - len(sizes)
    if extra > 0:
        room = sizes - 1
        ideal = extra * room / max(room.sum(), 1)
        add = np.minimum(np.floor(ideal).astype(np.int64), room)
        left = extra - add.sum()
        order = np.lexsort((np.arange(len(sizes)), -(ideal - add)))
        while left > 0:  # a few passes at most: only groups with room take one more
            take = order[(add[order] < room[order])][:left]
            add[take] += 1
            left -= len(take)
        k += add
    return k


def _bisect(points: np.ndarray, seg: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Labels 0..k.sum()-1 for ``points`` (N, 3) whose segment ``seg`` (N,) must become
    ``k[seg]`` clusters each, by recursive widest-axis median splits (all segments of a level
    at once)."""
    n = len(points)
    # order: patches sorted by segment; each segment is a run [start, start + len) with a count.
    order = np.argsort(seg, kind="stable")
    starts = np.searchsorted(seg[order], np.arange(len(k)))
    lens = np.bincount(seg, minlength=len(k))
    counts = k.astype(np.int64).copy()
    while np.any(counts > 1):
        run = np.repeat(np.arange(len(starts)), lens)  # segment of each position in order
        p = points[order]
        lo = np.minimum.reduceat(p, starts, axis=0) if n else p
        hi = np.maximum.reduceat(p, starts, axis=0) if n else p
        axis = np.argmax(hi - lo, axis=1)
        split = counts > 1
        # Sort inside each splitting segment by its widest axis (a stable lexsort keeps ties deterministic).
        coord = np.where(split[run], p[np.arange(n), axis[run]], 0.0)
        order = order[np.lexsort((coord, run))]
        k_left = counts // 2
        # Each side keeps at least one patch per cluster it must still become.
        cut = np.clip(np.round(lens * k_left / counts).astype(np.int64), k_left, lens - (counts - k_left))
        len_left = np.where(split, cut, lens)
        new_starts = np.column_stack([starts, starts + len_left])
        new_lens = np.column_stack([len_left, lens - len_left])
        new_counts = np.column_stack([np.where(split, k_left, counts), counts - np.where(split, k_left, counts)])
        keep = np.column_stack([np.ones(len(starts), bool), split])
        starts, lens, counts = new_starts[keep], new_lens[keep], new_counts[keep]
    labels = np.empty(n, dtype=np.int64)
    labels[order] = np.repeat(np.arange(len(starts)), lens)
    return labels


def light_components(F) -> np.ndarray:
    """(N,) connected component of each patch in the graph of F (i and j joined when F[i, j] or
    F[j, i] > 0): sets of patches that exchange no light at all, such as a closed room's inside
    and the world around it. A cluster spanning two would leak light from one into the other.
    Patches alone in their component get label -1 (no constraint)."""
    return free_singletons(weak_components(sp.csr_matrix(F)))


def free_singletons(components: np.ndarray) -> np.ndarray:
    """(N,) int64 copy of the component labels ``components`` with -1 for every patch alone in
    its component: a patch exchanging no light with anything (e.g. a face lying on the floor)
    may join any cluster."""
    labels = np.asarray(components).astype(np.int64)
    labels[np.bincount(labels)[labels] == 1] = -1
    return labels


def cluster_patches(
    scene, clusters: int | None = None, patches_per_cluster: float | None = None, components=None
) -> Clusters:
    """Partition the patches of ``scene`` into pure, compact clusters.

    Parameters
    ----------
    scene : pydynrad.Scene
    clusters : int, optional
        C, the number of clusters: at least the number of (albedo, emission, normal bin) groups
        of the scene, at most N. Default: :func:`default_cluster_count`.
    patches_per_cluster : float, optional
        Instead of ``clusters``: C = ceil(N / patches_per_cluster) (raised to the group count).
    components : (N,) int, optional
        Labels no cluster may span (:func:`light_components` of F: closed rooms stay apart).

    Returns
    -------
    Clusters
    """
    scene = checked_scene(scene)
    n = len(scene)
    if components is None:
        components = np.zeros(n, dtype=np.int64)
    components = np.asarray(components)
    if components.shape != (n,) or not np.issubdtype(components.dtype, np.integer):
        raise InvalidInputError(f"components must be ({n},) integers; got {components.dtype} {components.shape}")
    gid, bins = _groups(scene, components)
    n_groups = int(gid.max()) + 1
    if clusters is not None and patches_per_cluster is not None:
        raise InvalidInputError("pass clusters= or patches_per_cluster=, not both")
    if clusters is not None:
        C = integer(clusters, "clusters (C)", 1, n)
        if C < n_groups:
            raise InvalidInputError(
                f"clusters={C} is below the {n_groups} groups of equal albedo, emission and orientation this "
                f"scene has; a cluster must be pure, so C must lie in {n_groups}..{n}"
            )
    elif patches_per_cluster is not None:
        ppc = number(patches_per_cluster, "patches_per_cluster")
        if not 1.0 <= ppc <= n:
            raise InvalidInputError(f"patches_per_cluster must lie in 1..{n}; got {patches_per_cluster!r}")
        C = int(min(n, max(n_groups, np.ceil(n / ppc))))
    else:
        C = default_cluster_count(n, n_groups)
    k = _shares(np.bincount(gid, minlength=n_groups), C)
    centres = scene.centers.astype(np.float64)
    normal = NORMAL_BINS[bins]
    # Stretch the coordinate along the group's normal so parallel walls separate first.
    points = centres + (NORMAL_WEIGHT - 1.0) * np.sum(centres * normal, axis=1, keepdims=True) * normal
    labels = _bisect(points, gid, k)
    return Clusters(labels=labels, count=C, groups=n_groups, scene_hash=scene.content_hash())


def _tangents(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each of ``normals`` (N, 3) and to each other."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(normals, t1)


#: Spans of a cluster's projections below this times its largest centre norm are rounding
#: (float64 dot products err by a few 1e-16 of it): the direction is dropped.
SPAN_ROUNDING = 1e-12


def linear_basis(clusters: Clusters, scene) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """A piecewise-linear coarse basis: (N, 3C) prolongation Pr and (3C, N) restriction R.

    Each cluster carries three functions of its patches' centres, the hat functions
    psi_1 = u / 2, psi_2 = v / 2 and psi_0 = 1 - psi_1 - psi_2 of the coordinates u, v in [0, 1]
    across the cluster along two tangents of its normal bin: they span {1, u, v}, so a cluster's
    radiosity may vary linearly over it instead of being one constant. They are >= 0 and sum to
    1 on every patch, so a row of G = F Pr sums to the row of F (a valid row of form factors)
    and a constant field maps to itself. Column c + k C is function k of cluster c. R is the
    area-weighted least-squares fit of a field onto the basis, cluster by cluster (R Pr = I
    where a cluster's functions are independent; a cluster too small or flat for them, e.g. one
    patch, gets the minimum-norm fit). Measured in bench/farstore.py: with G alone (no F) it
    cuts the far field's all-patch error 3-5x against the indicator at the same C.
    """
    n, C = len(clusters.labels), clusters.count
    lab = clusters.labels
    bins = np.argmax(scene.normals.astype(np.float64) @ NORMAL_BINS.T, axis=1)
    centres = scene.centers.astype(np.float64)
    # A span within the rounding of the projections (centres on a line, far from the origin)
    # is no direction: normalised, its noise would become a coordinate in [0, 1].
    reach = np.zeros(C)
    np.maximum.at(reach, lab, np.linalg.norm(centres, axis=1))
    flat = SPAN_ROUNDING * reach
    hats = []
    for t in _tangents(NORMAL_BINS[bins]):
        u = np.sum(centres * t, axis=1)
        lo = np.full(C, np.inf)
        hi = np.full(C, -np.inf)
        np.minimum.at(lo, lab, u)
        np.maximum.at(hi, lab, u)
        span = np.where(hi - lo > flat, hi - lo, 0.0)
        hats.append(np.where(span[lab] > 0, (u - lo[lab]) / np.where(span > 0, span, 1.0)[lab], 0.0) / 2)
    # Rounded to float32, the precision a store records Pr in: G on the spot and from a store agree bit for bit.
    psi = np.column_stack([1.0 - hats[0] - hats[1], *hats]).astype(np.float32).astype(np.float64)  # (N, 3)
    rows = np.repeat(np.arange(n), LINEAR_FUNCTIONS)
    cols = (lab[:, None] + C * np.arange(LINEAR_FUNCTIONS)).ravel()
    Pr = sp.csr_matrix((psi.ravel(), (rows, cols)), shape=(n, LINEAR_FUNCTIONS * C))
    Pr.eliminate_zeros()
    a = np.asarray(scene.areas, dtype=np.float64)
    gram = np.zeros((C, LINEAR_FUNCTIONS, LINEAR_FUNCTIONS))
    for p in range(LINEAR_FUNCTIONS):
        for q in range(LINEAR_FUNCTIONS):
            gram[:, p, q] = np.bincount(lab, weights=a * psi[:, p] * psi[:, q], minlength=C)
    coef = np.einsum("ikq,iq->ik", np.linalg.pinv(gram, rcond=1e-9)[lab], a[:, None] * psi)  # (N, 3)
    R = sp.csr_matrix(
        (
            coef.T.ravel(),
            (np.add.outer(C * np.arange(LINEAR_FUNCTIONS), lab).ravel(), np.tile(np.arange(n), LINEAR_FUNCTIONS)),
        ),
        shape=(LINEAR_FUNCTIONS * C, n),
    )
    R.eliminate_zeros()
    return Pr, R
