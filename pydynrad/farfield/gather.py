"""Patch-to-cluster form factors G = F Pr by hemicube, without forming F.

The far field needs every patch's row of F, but only summed over each cluster's patches (see
docs/design.md, 'Far field'). A hemicube that records cluster ids instead of patch ids gives
those sums directly: neighbouring pixels on different patches of one cluster merge into one
run, so a row of G costs the rays of a row of F and far fewer runs. Rows are computed in the
same bounded blocks as F (:func:`pydynrad.formfactors.hemicube_blocks`), so no more than one
block of rows ever exists, whatever N.

Prolongations. ``Pr`` (N, C) maps cluster values to patches: the indicator one (Pr[i, c] = 1
for i in c) or a weighted one (Pr_w[i, c] = w_i / mean_c(w)). With one entry per row, as both
have, the device records cluster ids and weighs each pixel by its patch's entry. A row of G
then costs about what a row of F does at the same resolution (the rays dominate), and less than
F's patch runs weighted on the host (docs/decisions/0021-far-field-without-f.md). A prolongation with several entries in a row (a patch shared by
clusters) takes that host path: F's block, then a sparse product.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..checks import check_form_factor_rows, sparse_structure
from ..errors import InvalidInputError
from ..formfactors import CLUSTER_RESOLUTION, hemicube_blocks, stack_blocks
from ..geometry.loading import checked_scene
from ..progress import progress_bar
from ..rows.prolongation import BASES, as_prolongation, check_prolongation, g_samples, split_prolongation
from ..rows.sources import HemicubeRows
from ..rows.store import FormFactorStore, StoreIncompleteError
from .clusters import Clusters, cluster_patches, free_singletons, linear_basis

__all__ = [
    "cluster_form_factors",
    "cluster_form_factors_for",
    "basis_prolongation",
    "checked_cluster_form_factors",
    "light_components_by_hemicube",
    "clusters_without_f",
    "check_store",
    "COMPONENT_RESOLUTION",
]


#: Hemicube resolution of the pass that finds which patches exchange light when F is never formed:
#: rays only ever join patches that see each other, so a low resolution can split a set of patches
#: that do exchange light (costing accuracy, never leaking light), not join two that do not.
COMPONENT_RESOLUTION = 8


def check_store(scene, store, n: int) -> None:
    """InvalidInputError unless the form-factor ``store`` was made for ``scene`` (N = ``n``): its
    rows index this scene's patches."""
    if store.n_patches != n:
        raise InvalidInputError(f"the form factors have {store.n_patches} rows; the scene has {n} patches")
    if store.header["geometry_hash"] != scene.geometry_hash():
        raise InvalidInputError(f"form-factor store {store.path} was made for another scene geometry")


def light_components_by_hemicube(
    scene, resolution: int = COMPONENT_RESOLUTION, device=None, progress: bool | None = None, store=None
) -> np.ndarray:
    """:func:`pydynrad.farfield.clusters.light_components` of a scene whose F is never formed.

    F's rows at ``resolution`` are traced in the bounded blocks of
    :func:`pydynrad.formfactors.hemicube_blocks` (or, given a form-factor ``store`` holding all
    of F, read from its blocks: no rays) and each is merged into the components found so far (a
    connected-components pass over the current component ids), so memory stays O(N plus one
    block). Clusters made with these labels keep a closed room's inside apart from the world
    around it, as with F in memory; at the default resolution the pass costs about
    (8 / R_G)^2 of G's rays.
    """
    from scipy.sparse.csgraph import connected_components

    scene = checked_scene(scene)
    n = len(scene)
    if store is not None:
        check_store(scene, store, n)
        missing = store.missing_blocks()
        if missing:
            raise StoreIncompleteError(
                f"form-factor store {store.path} holds only part of F ({len(missing)} of "
                f"{store.n_blocks} blocks missing): its light components need all of it"
            )
        blocks = (store.read_block(k) for k in range(store.n_blocks))
    else:
        blocks = hemicube_blocks(scene, resolution, None, device, progress, desc="light components")
    comp = np.arange(n)
    first, edges, held = 0, [], 0

    def merge(comp, edges):
        a, b = np.concatenate([e[0] for e in edges]), np.concatenate([e[1] for e in edges])
        graph = sp.csr_matrix((np.ones(len(a), dtype=np.int8), (comp[a], comp[b])), shape=(n, n))
        return connected_components(graph, directed=True, connection="weak")[1][comp]

    for block in blocks:
        coo = block.tocoo()
        edges.append((first + coo.row, coo.col))
        held += coo.nnz
        first += block.shape[0]
        if held >= 4 * n:  # each merge costs O(N): merge once about 4 N edges are held, not per block
            comp, edges, held = merge(comp, edges), [], 0
    if edges:
        comp = merge(comp, edges)
    return free_singletons(comp)


def clusters_without_f(scene, clusters=None, device=None, progress: bool | None = None, store=None):
    """:func:`pydynrad.farfield.cluster_patches` (C = ``clusters``, default from N) for a scene
    whose F is not in memory: kept inside the light components of
    :func:`light_components_by_hemicube` (from ``store``'s F where given), so no cluster spans a
    closed room's inside and outside."""
    components = light_components_by_hemicube(scene, device=device, progress=progress, store=store)
    return cluster_patches(scene, clusters, components=components)


def basis_prolongation(scene, clusters, basis: str = "linear") -> sp.csr_matrix:
    """The checked (N, C) or (N, 3C) prolongation of ``basis`` for ``clusters`` ((N,) labels or a
    :class:`pydynrad.farfield.Clusters`): the indicator, or the piecewise-linear
    :func:`pydynrad.farfield.clusters.linear_basis`. An (N, K) matrix is itself the prolongation."""
    if basis not in BASES:
        raise InvalidInputError(f"the coarse basis must be one of {BASES}; got {basis!r}")
    scene = checked_scene(scene)
    n = len(scene)
    pr = as_prolongation(clusters, n)  # the labels checked (one per patch) before the linear basis indexes with them
    if sp.issparse(clusters) or np.ndim(clusters) == 2 or basis == "indicator":
        return pr
    if not isinstance(clusters, Clusters):
        clusters = Clusters.from_labels(scene, pr.indices)
    return check_prolongation(linear_basis(clusters, scene)[0], n)


def cluster_form_factors(
    scene,
    prolongation,
    resolution: int = CLUSTER_RESOLUTION,
    rows=None,
    device=None,
    progress: bool | None = None,
    samples: int = 1,
) -> sp.csr_matrix:
    """Rows of the patch-to-cluster form factors G = F Pr by hemicube, F never formed.

    Parameters
    ----------
    scene : Scene
        N patches.
    prolongation : (N, C) sparse or dense matrix
        Finite entries >= 0: the indicator of each patch's cluster, or a weighted one.
    resolution : int
        Hemicube resolution R (even, >= 2; the rule of :func:`pydynrad.form_factors`); default
        :data:`pydynrad.formfactors.CLUSTER_RESOLUTION`.
    rows : sequence of int, optional
        Patches whose rows of G to compute; all by default.
    device : Device, optional
    progress : bool, optional
        tqdm bar; by default once the run has taken two seconds (:mod:`pydynrad.progress`).
    samples : int
        Hemicubes per row (1, 4, 16, ...), as for :func:`pydynrad.form_factors`.

    Returns
    -------
    scipy.sparse.csr_matrix, float32, shape (len(rows), C)
        Row k: the fraction of the energy leaving patch ``rows[k]`` that arrives at each
        cluster, weighted by Pr; equal to ``form_factors(scene, resolution, rows, samples=samples) @ Pr`` up to
        float32 rounding.
    """
    scene = checked_scene(scene)
    n = len(scene)
    pr = check_prolongation(prolongation, n)
    C = pr.shape[1]
    single = split_prolongation(pr)
    if single is not None:
        blocks = hemicube_blocks(
            scene,
            resolution,
            rows,
            device,
            progress,
            desc="cluster form factors",
            clusters=(*single, C),
            samples=samples,
        )
    else:
        blocks = (
            b @ pr
            for b in hemicube_blocks(
                scene, resolution, rows, device, progress, desc="cluster form factors", samples=samples
            )
        )
    return stack_blocks(blocks, C)


#: Rows per block when G is summed from a row source's rows of F (bounded memory).
SUM_BLOCK_ROWS = 4096


def checked_cluster_form_factors(G, shape: tuple[int, int]) -> sp.csr_matrix:
    """A given G checked as rows of F are (:func:`pydynrad.checks.check_form_factor_rows`: the
    structure, ``shape``, finite entries >= 0, rows summing to at most 1), without a float64 copy
    of the whole: a float32 or float64 CSR G is checked :data:`SUM_BLOCK_ROWS` rows at a time and
    returned as it is, not copied (a million-patch store's G is most of the far field's memory);
    any other matrix is returned as the checked float64 CSR copy."""
    if not (sp.issparse(G) and G.format == "csr" and G.dtype in (np.float32, np.float64)):
        return check_form_factor_rows(G, "G", shape=shape)
    if G.shape != tuple(shape):
        raise InvalidInputError(f"G must have shape {tuple(shape)}; got {G.shape}")
    sparse_structure(G.indptr, G.indices, G.shape, "G", nnz=len(G.data))
    for first in range(0, G.shape[0], SUM_BLOCK_ROWS):
        rows = np.arange(first, min(G.shape[0], first + SUM_BLOCK_ROWS))
        check_form_factor_rows(G[first : rows[-1] + 1], "G", rows)
    return G


def cluster_form_factors_for(
    scene, source, clusters, resolution: int | None = None, device=None, progress: bool | None = None
) -> sp.csr_matrix:
    """The whole (N, C) G for a dynamic solution's source of F's rows, F never held whole.

    ``source`` is what :class:`~pydynrad.DynamicRadiosity` reads F's rows from:

    * a :class:`~pydynrad.rows.store.FormFactorStore` (or a :class:`~pydynrad.rows.RowCache` over
      one) holding G gives its G, checked to be for these clusters
      (:class:`~pydynrad.rows.StoreMismatchError` otherwise);
    * the on-demand :class:`~pydynrad.rows.HemicubeRows` gets G from cluster-id hemicubes of
      ``resolution`` (:func:`cluster_form_factors`), by default the rows' own (with their
      ``samples``): then G is F Pr of the very rows the local set reads (to float32 rounding). A lower one is cheaper but
      disagrees with them: where the far field carries most of the light (at night, one lamp)
      the mismatch is many times the error of G = F Pr
      (docs/decisions/0021-far-field-without-f.md);
    * any other source (F in memory, a store of F without G) gets F Pr from its own rows,
      :data:`SUM_BLOCK_ROWS` at a time, so G agrees with that F; a store with neither G nor all
      of F raises :class:`~pydynrad.rows.StoreIncompleteError`.

    ``clusters``: Pr (N, C), (N,) labels or a :class:`pydynrad.farfield.Clusters`.
    Returns float32 CSR.
    """

    scene = checked_scene(scene)
    n = len(scene)
    pr = as_prolongation(clusters, n)
    inner = source
    while not isinstance(inner, (FormFactorStore, HemicubeRows)) and hasattr(inner, "source"):
        inner = inner.source  # through row caches: a whole pass over F would only evict them
    if isinstance(inner, FormFactorStore):
        check_store(scene, inner, n)
    elif getattr(inner, "n_patches", None) != n:
        raise InvalidInputError(
            f"the form factors have {getattr(inner, 'n_patches', None)} rows; the scene has {n} patches"
        )
    if isinstance(inner, HemicubeRows):
        R = inner.resolution if resolution is None else resolution
        return cluster_form_factors(
            scene, pr, R, device=device, progress=progress, samples=g_samples(inner.resolution, inner.samples, R)
        )
    if isinstance(inner, FormFactorStore):
        if inner.has_clusters:
            return inner.cluster_form_factors(pr)
        missing = inner.missing_blocks()
        if missing:
            raise StoreIncompleteError(
                f"form-factor store {inner.path} holds no patch-to-cluster form factors G and only part of F "
                f"({len(missing)} of {inner.n_blocks} blocks missing); add G with compute_store(..., clusters=...) or "
                "`pydynrad formfactors SCENE -o STORE --clusters ...`"
            )
    starts = range(0, n, SUM_BLOCK_ROWS)
    with progress_bar(progress, total=n, unit="row", desc="far field G") as bar:
        blocks = []
        for first in starts:
            rows = np.arange(first, min(n, first + SUM_BLOCK_ROWS))
            # A source's rows are checked before scipy's kernels touch them (bad indices crash them).
            block = check_form_factor_rows(inner.rows(rows), "form-factor rows", rows, (len(rows), n))
            blocks.append(block @ pr)
            bar.update(len(rows))
    return stack_blocks(blocks, pr.shape[1])
