"""Filling a form-factor store in process: the rows of F (and G) block by block, resumable.

:func:`compute_store` computes every missing block of a :class:`~pydynrad.rows.store.FormFactorStore`
in this process; :func:`~pydynrad.precompute.distributed.precompute_distributed` hands the same
blocks (:func:`task_groups`, :func:`compute_blocks`) to a Dask cluster. The store's layout and
checks are :mod:`pydynrad.rows.store`'s.

See docs/design.md, 'Row sources, stores and caches'.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import scipy.sparse as sp

from ..checks import integer
from ..farfield.gather import basis_prolongation, cluster_form_factors
from ..formfactors import form_factors
from ..geometry.loading import checked_scene
from ..progress import progress_bar
from ..rows.store import DEFAULT_BLOCK_ROWS, DEFAULT_TASK_ROWS, FormFactorStore, RowFunction


def form_factor_rows(scene, rows: np.ndarray, resolution: int, device=None, samples: int = 1) -> sp.csr_matrix:
    """The default row function: hemicube rows from :func:`pydynrad.form_factors`."""

    return form_factors(scene, resolution=resolution, rows=rows, device=device, samples=samples)


def prepare_store(
    scene,
    path,
    *,
    resolution: int,
    block_rows: int,
    patching: dict | None,
    verify: bool,
    blocks: Iterable[int] | None,
    clusters=None,
    cluster_resolution: int | None = None,
    cluster_params: dict | None = None,
    compute_f: bool = True,
    cluster_basis: str = "linear",
    samples: int = 1,
) -> tuple[FormFactorStore, dict[str, list[int]]]:
    """Create or reopen a store for writing: stale temporaries removed, ``clusters`` recorded
    (as the prolongation of ``cluster_basis``, :func:`pydynrad.farfield.gather.basis_prolongation`).

    Returns the store and the blocks to compute per part: {"F": [...], "G": [...]} (G's when
    the store has clusters, recorded now or before; F's unless ``compute_f`` is False).
    """
    store = FormFactorStore.create(
        scene, path, resolution=resolution, block_rows=block_rows, patching=patching, exist_ok=True, samples=samples
    )
    store.remove_stale_temporaries()
    if clusters is not None:
        given = sp.issparse(clusters) or np.ndim(clusters) == 2  # a matrix is its own prolongation
        if cluster_resolution is None:
            # F's own: G is then F Pr of the stored rows, or (--no-f) of the rows a walk computes
            # on demand at that resolution; at another one the two disagree, by far more than
            # the far field's own error (docs/decisions/0021-far-field-without-f.md).
            cluster_resolution = resolution
        store.set_clusters(
            basis_prolongation(scene, clusters, cluster_basis),
            resolution=cluster_resolution,
            params=cluster_params,
            basis="given" if given else cluster_basis,
        )
    todo = {}
    for part in ("F", "G"):
        wanted = part == "G" and store.has_clusters or part == "F" and compute_f
        todo[part] = store.missing_blocks(verify=verify, part=part) if wanted else []
        if blocks is not None:
            todo[part] = sorted(set(todo[part]) & {int(b) for b in blocks})
    return store, todo


def task_groups(store: FormFactorStore, blocks: Iterable[int], task_rows: int) -> list[list[int]]:
    """Blocks grouped into runs of consecutive indices holding at most ``task_rows`` rows (>= 1 block each).

    One row-function call per group: a call has fixed costs (device buffers, per-scene
    set-up), so tasks of a few thousand rows amortise them while blocks stay small for reads.
    """
    integer(task_rows, "task_rows")
    groups: list[list[int]] = []
    for k in sorted(blocks):
        g = groups[-1] if groups else None
        if g and g[-1] == k - 1 and (len(g) + 1) * store.block_rows <= task_rows:
            g.append(k)
        else:
            groups.append([k])
    return groups


def compute_blocks(
    store: FormFactorStore,
    scene,
    group: list[int],
    row_function: RowFunction,
    device=None,
    part: str = "F",
    prolongation=None,
) -> int:
    """Compute the consecutive blocks ``group`` of F (or of G) in one call and write each; returns rows done.

    F's rows come from ``row_function``; G's = F Pr with the store's prolongation (pass it as
    ``prolongation`` to save reading it per group): from the store's own blocks of F where they
    are on disk and G's resolution is F's (no second pass of hemicubes: G then costs a sparse
    product per block, and agrees with the stored F exactly), else from
    :func:`pydynrad.farfield.gather.cluster_form_factors` at G's resolution (with
    :attr:`FormFactorStore.cluster_samples`). ``row_function`` gets ``samples=`` when the
    store's samples are more than 1.
    """
    first, last = store.block_range(group[0]), store.block_range(group[-1])
    rows = np.arange(first.start, last.stop)
    if part == "G":
        pr = store.prolongation() if prolongation is None else prolongation
        if store.cluster_resolution == store.header["params"]["resolution"] and all(
            store.block_path(k).exists() for k in group
        ):
            csr = sp.csr_matrix(sp.vstack([store.read_block(k) for k in group], format="csr") @ pr, dtype=np.float32)
        else:
            csr = cluster_form_factors(
                scene, pr, store.cluster_resolution, rows=rows, device=device, samples=store.cluster_samples
            )
    else:
        # Row functions written before samples existed keep working for single-hemicube stores.
        sampled = {"samples": store.samples} if store.samples > 1 else {}
        csr = sp.csr_matrix(row_function(scene, rows, store.header["params"]["resolution"], device=device, **sampled))
    for k in group:
        r = store.block_range(k)
        store.write_block(k, csr[r.start - first.start : r.stop - first.start], part)
    return last.stop - first.start


def compute_store(
    scene,
    path,
    *,
    resolution: int,
    block_rows: int = DEFAULT_BLOCK_ROWS,
    patching: dict | None = None,
    progress: bool | None = None,
    verify: bool = False,
    row_function: RowFunction = form_factor_rows,
    device=None,
    blocks: Iterable[int] | None = None,
    task_rows: int = DEFAULT_TASK_ROWS,
    clusters=None,
    cluster_resolution: int | None = None,
    cluster_params: dict | None = None,
    compute_f: bool = True,
    cluster_basis: str = "linear",
    samples: int = 1,
) -> FormFactorStore:
    """Create (or resume) the store at ``path`` and compute every missing block in this process.

    ``samples``: hemicubes per row (1, 4, 16, ...: :func:`pydynrad.form_factors`), recorded
    in the header; a resume with other samples (or another resolution) raises
    :class:`~pydynrad.rows.StoreMismatchError`. ``row_function(scene, rows, resolution, device=...)`` (and
    ``samples=`` when ``samples`` > 1) returns the (len(rows), N) CSR
    rows; the default is :func:`form_factor_rows`; it is called on runs of up to
    ``task_rows`` rows. ``verify`` re-checks finished blocks and recomputes corrupt ones.
    ``blocks`` restricts the work to some block indices; ``progress``: a tqdm bar (None: on a
    terminal). Returns the store; interrupting it
    loses at most the blocks of the call in progress.

    The far field's G = F Pr: ``clusters`` (Pr (N, C), (N,) labels or a
    :class:`pydynrad.farfield.Clusters`) records the clusters and computes G beside F, from
    hemicubes of ``cluster_resolution`` (:func:`pydynrad.farfield.gather.cluster_form_factors`;
    default: F's ``resolution``, so G is summed from F's stored rows with no hemicubes of its own,
    and without F it is F Pr of the rows a walk computes on demand at that resolution, with F's
    ``samples``; at another resolution G is of single hemicubes);
    a store with clusters already recorded resumes its G too. ``cluster_basis``: "linear" (the
    default: 3C columns, the far field's piecewise-linear coarse level, what a walk without F
    needs for its accuracy; bench/farstore.py) or "indicator" (C columns) for labels or
    clusters; a given Pr matrix is used as it is. ``compute_f=False`` leaves F's
    rows out (a store of G alone, for walks that compute F's rows on demand).
    """

    scene = checked_scene(scene)
    store, todo = prepare_store(
        scene,
        path,
        resolution=resolution,
        block_rows=block_rows,
        patching=patching,
        verify=verify,
        blocks=blocks,
        clusters=clusters,
        cluster_resolution=cluster_resolution,
        cluster_params=cluster_params,
        compute_f=compute_f,
        cluster_basis=cluster_basis,
        samples=samples,
    )
    pr = store.prolongation() if todo["G"] else None
    for part, desc in (("F", "form factors"), ("G", "cluster form factors")):
        with progress_bar(
            progress if todo[part] else False,
            total=sum(len(store.block_range(k)) for k in todo[part]),
            unit="row",
            desc=desc,
        ) as bar:
            for group in task_groups(store, todo[part], task_rows):
                bar.update(compute_blocks(store, scene, group, row_function, device, part, pr))
    return store
