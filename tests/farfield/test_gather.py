"""Patch-to-cluster form factors G = F Pr from cluster-id hemicubes (pydynrad.farfield.gather).

Truths: G equals ``form_factors(scene, R) @ Pr`` (F's own hemicubes, summed in float64 by
SciPy) to float32 rounding; in a closed box every row sums to 1 like F's, and with the six
walls as clusters the area-weighted wall-to-wall sums are the catalogue form factors of two
unit squares (parallel 0.19982, perpendicular 0.20004; Howell C-11, C-14).
"""

import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from pydynrad import InvalidInputError
from pydynrad import formfactors as ff_module
from pydynrad.farfield import cluster_patches
from pydynrad.farfield.gather import basis_prolongation, cluster_form_factors
from pydynrad.formfactors import form_factors
from pydynrad.scenes.analytic import closed_box
from pydynrad.scenes.cornell import cornell_box

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the bench package lives in the repo root

from bench.gather import indicator, weighted  # noqa: E402  (the two prolongations)
from pydynrad.precompute.store import compute_store
from pydynrad.rows.store import FormFactorStore, StoreCorruptError, StoreIncompleteError, StoreMismatchError

R = 16


@pytest.fixture(scope="module")
def cornell_weighted(device):
    scene = cornell_box()
    labels = cluster_patches(scene).labels
    w = np.random.default_rng(1).uniform(0.1, 2.0, len(scene))
    F = form_factors(scene, resolution=R, device=device).astype(np.float64)
    return scene, labels, w, F


def assert_float32_equal(G, ref):
    """Entries agree to a few float32 ulps of the row's largest entry (observed <= 7e-8 relative)."""
    assert G.dtype == np.float32
    g, r = G.toarray().astype(np.float64), np.asarray(ref.todense() if sp.issparse(ref) else ref)
    scale = np.abs(r).max(axis=1, keepdims=True) + 1e-30
    assert np.max(np.abs(g - r) / scale) < 1e-6


def test_indicator_equals_f_times_pr(cornell_weighted, device):
    scene, labels, _, F = cornell_weighted
    Pr = indicator(labels)
    assert Pr.shape[1] < len(scene) / 4  # clusters really merge patches
    G = cluster_form_factors(scene, Pr, resolution=R, device=device)
    assert G.shape == (len(scene), Pr.shape[1])
    assert_float32_equal(G, F @ Pr)
    # Runs merged on the device: G holds fewer non-zeros than F.
    assert G.nnz < F.nnz / 2


def test_weighted_equals_f_times_pr(cornell_weighted, device):
    scene, labels, w, F = cornell_weighted
    Pr = weighted(labels, scene.areas.astype(np.float64), w)
    G = cluster_form_factors(scene, Pr, resolution=R, device=device)
    assert_float32_equal(G, F @ Pr)


def test_shared_patches_and_dense_input(cornell_weighted, device):
    """A patch in two clusters (two entries in its row) and a dense Pr take the host path, same truth."""
    scene, labels, _, F = cornell_weighted
    Pr = indicator(labels).toarray()
    Pr[::7, 0] += 0.5
    G = cluster_form_factors(scene, Pr, resolution=R, device=device)
    assert_float32_equal(G, F @ Pr)


def test_rows_and_small_blocks(cornell_weighted, device, monkeypatch):
    scene, labels, _, _ = cornell_weighted
    Pr = indicator(labels)
    rows = np.array([5, 900, 17, 5, 300])
    whole = cluster_form_factors(scene, Pr, resolution=R, device=device)
    some = cluster_form_factors(scene, Pr, resolution=R, rows=rows, device=device)
    assert (some != whole[rows]).nnz == 0
    # Three rows per block: the same rows, bit for bit.
    monkeypatch.setattr(ff_module, "BLOCK_BYTES", 3 * 3 * R * R * 8)
    small = cluster_form_factors(scene, Pr, resolution=R, rows=rows, device=device)
    assert (small != some).nnz == 0
    assert cluster_form_factors(scene, Pr, resolution=R, rows=[], device=device).shape == (0, Pr.shape[1])


def test_closed_box_rows_sum_to_one_and_catalogue(device):
    scene = closed_box(1.0, subdivisions=2)
    walls = scene.source_face // 2
    Pr = indicator(walls)
    G = cluster_form_factors(scene, Pr, resolution=32, device=device).toarray().astype(np.float64)
    np.testing.assert_allclose(G.sum(axis=1), 1.0, atol=1e-5)
    assert np.all(G[np.arange(len(scene)), walls] == 0)  # a planar wall does not see itself
    a = scene.areas.astype(np.float64)
    for f in range(6):
        rows = walls == f
        for g in range(6):
            if g != f:
                truth = 0.19982 if f // 2 == g // 2 else 0.20004
                assert a[rows] @ G[rows, g] / a[rows].sum() == pytest.approx(truth, rel=0.02)
    F = form_factors(scene, resolution=32, device=device).astype(np.float64)
    assert_float32_equal(sp.csr_matrix(G.astype(np.float32)), F @ Pr)


def test_bad_input(cornell_weighted, device):
    scene, labels, _, _ = cornell_weighted
    Pr = indicator(labels)
    n, c = Pr.shape
    with pytest.raises(InvalidInputError, match="shape"):
        cluster_form_factors(scene, Pr[:-1], device=device)
    with pytest.raises(InvalidInputError, match="shape"):
        cluster_form_factors(scene, np.ones(n), device=device)
    with pytest.raises(InvalidInputError, match="shape"):
        cluster_form_factors(scene, sp.csr_matrix((n, 0)), device=device)
    bad = Pr.toarray()
    bad[3, 0] = np.nan
    with pytest.raises(InvalidInputError, match="NaN"):
        cluster_form_factors(scene, bad, device=device)
    bad[3, 0] = -1.0
    with pytest.raises(InvalidInputError, match=">= 0"):
        cluster_form_factors(scene, bad, device=device)
    with pytest.raises(InvalidInputError, match="numbers"):
        cluster_form_factors(scene, [["a"] * c] * n, device=device)
    for r in (7, 0, 16.0, True):
        with pytest.raises(InvalidInputError, match="resolution"):
            cluster_form_factors(scene, Pr, resolution=r, device=device)
    with pytest.raises(InvalidInputError, match="rows"):
        cluster_form_factors(scene, Pr, rows=[n], device=device)
    with pytest.raises(InvalidInputError, match="Scene"):
        cluster_form_factors(Pr, Pr, device=device)


# -- G in the form-factor store ----------------------------------------------------------------


@pytest.fixture(scope="module")
def box(device):
    """A closed box of 192 patches in 8 clusters (the walls, four of them split along a diagonal), its G at R = 8."""
    scene = closed_box(1.0, subdivisions=2)
    labels = (scene.source_face // 2) * 2 + (scene.centers[:, 0] + scene.centers[:, 1] > 1.0)
    labels = np.unique(labels, return_inverse=True)[1].ravel()
    return scene, labels, cluster_form_factors(scene, indicator(labels), resolution=8, device=device)


def same_csr(a, b) -> bool:
    return a.shape == b.shape and a.dtype == b.dtype and (a != b).nnz == 0


def test_store_holds_g_beside_f(box, tmp_path, device):
    scene, labels, G = box
    store = compute_store(
        scene,
        tmp_path / "s",
        resolution=8,
        block_rows=10,
        clusters=labels,
        cluster_basis="indicator",
        cluster_params={"method": "diagonals"},
        progress=False,
        device=device,
    )
    assert store.complete and store.complete_clusters and store.n_clusters == labels.max() + 1
    assert store.cluster_resolution == 8  # F's: G summed from the stored rows of F, no hemicubes of its own
    F = store.to_csr()
    assert same_csr(F, form_factors(scene, resolution=8, device=device))
    G = store.cluster_form_factors(labels)
    assert same_csr(G, sp.csr_matrix(F @ indicator(labels).astype(np.float32)))  # F Pr of the stored F, exactly
    assert_float32_equal(G, box[2])  # and the cluster-id hemicubes' G to float32 rounding
    idx = np.array([95, 3, 3, 40, 0])
    assert same_csr(store.cluster_rows(idx), G[idx])
    np.testing.assert_array_equal(store.cluster_labels(), labels)
    assert same_csr(store.prolongation(), indicator(labels).astype(np.float32))
    again = FormFactorStore.open(scene, tmp_path / "s", resolution=8)
    assert again.cluster_resolution == 8 and again.cluster_params == {"method": "diagonals"} and "G: C=" in repr(again)
    assert same_csr(again.cluster_form_factors(), G)


def test_store_of_g_alone_and_resume(box, tmp_path, device):
    scene, labels, G = box
    path = tmp_path / "g"
    store = compute_store(
        scene,
        path,
        resolution=8,
        block_rows=16,
        clusters=indicator(labels),
        cluster_resolution=8,
        compute_f=False,
        progress=False,
        device=device,
    )
    assert store.complete_clusters and not store.complete and store.missing_blocks() == list(range(12))
    with pytest.raises(StoreIncompleteError, match="block 0"):
        store.rows([0])
    store.block_path(2, "G").unlink()
    store.block_path(4, "G").write_bytes(b"torn")
    with pytest.raises(StoreIncompleteError, match="1 of 12 blocks of G"):
        store.cluster_form_factors()
    with pytest.raises(StoreCorruptError):
        store.cluster_rows([70])
    # Resumed without naming the clusters again: the recorded ones finish G.
    store = compute_store(
        scene, path, resolution=8, block_rows=16, compute_f=False, verify=True, progress=False, device=device
    )
    assert same_csr(store.cluster_form_factors(), G)


def test_store_refuses_other_clusters(box, tmp_path, device):
    scene, labels, _ = box
    store = compute_store(
        scene,
        tmp_path / "s",
        resolution=8,
        block_rows=48,
        clusters=labels,
        cluster_resolution=8,
        cluster_basis="indicator",
        compute_f=False,
        progress=False,
        device=device,
    )
    other = labels.copy()
    other[[0, 1]] = other[[1, 0]] if other[0] != other[1] else (other[0] + 1) % (labels.max() + 1)
    for bad in (other, scene.source_face // 2, weighted(labels, scene.areas, np.linspace(1, 2, len(scene)))):
        with pytest.raises(StoreMismatchError, match="other clusters"):
            store.cluster_form_factors(bad)
        with pytest.raises(StoreMismatchError, match="prolongation_sha256"):
            compute_store(
                scene,
                tmp_path / "s",
                resolution=8,
                block_rows=48,
                clusters=bad,
                cluster_resolution=8,
                compute_f=False,
                progress=False,
                device=device,
            )
    with pytest.raises(StoreMismatchError, match="resolution"):
        store.set_clusters(labels, resolution=16)
    with pytest.raises(StoreMismatchError, match="geometry_hash"):  # G of another scene: the store refuses the scene
        FormFactorStore.open(closed_box(2.0, subdivisions=2), tmp_path / "s", resolution=8)
    with pytest.raises(InvalidInputError, match="labels"):
        store.check_clusters(labels[:-1])
    plain = compute_store(scene, tmp_path / "f", resolution=8, block_rows=48, progress=False, device=device)
    assert not plain.has_clusters
    with pytest.raises(StoreIncompleteError, match="holds no patch-to-cluster"):
        plain.cluster_rows([0])


def test_g_for_each_kind_of_row_source(box, tmp_path, device, monkeypatch):
    """A store's own G (also through a row cache), cluster-id hemicubes for on-demand rows, and
    F Pr from the source's own rows otherwise (F in memory, a store of F alone); a store with
    neither G nor all of F, one of another scene or other clusters is refused."""
    from pydynrad.farfield import gather
    from pydynrad.rows import CSRRows, HemicubeRows, RowCache

    scene, labels, G = box
    store = compute_store(
        scene,
        tmp_path / "s",
        resolution=8,
        block_rows=48,
        clusters=labels,
        cluster_resolution=8,
        cluster_basis="indicator",
        compute_f=False,
        progress=False,
        device=device,
    )
    assert same_csr(gather.cluster_form_factors_for(scene, store, labels), G)
    assert same_csr(gather.cluster_form_factors_for(scene, RowCache(store, 2**20), labels), G)
    on_demand = HemicubeRows(scene, 64, device)
    assert same_csr(gather.cluster_form_factors_for(scene, on_demand, labels, resolution=8, device=device), G)
    # By default at the rows' own resolution: G is then F Pr of the rows the local set reads.
    assert_float32_equal(
        gather.cluster_form_factors_for(scene, HemicubeRows(scene, 8, device), labels, device=device),
        form_factors(scene, resolution=8, device=device).astype(np.float64) @ indicator(labels),
    )
    F = form_factors(scene, resolution=8, device=device)
    Pr = indicator(labels)
    assert_float32_equal(gather.cluster_form_factors_for(scene, CSRRows(F), labels), F.astype(np.float64) @ Pr)
    plain = compute_store(scene, tmp_path / "f", resolution=8, block_rows=48, progress=False, device=device)
    monkeypatch.setattr(gather, "SUM_BLOCK_ROWS", 40)  # several blocks, across the store's blocks of 48 rows
    summed = gather.cluster_form_factors_for(scene, RowCache(plain, 2**20), labels)
    assert same_csr(summed, gather.cluster_form_factors_for(scene, CSRRows(F), labels))
    with pytest.raises(StoreMismatchError, match="other clusters"):
        gather.cluster_form_factors_for(scene, store, scene.source_face // 2)
    plain.block_path(1).unlink()
    with pytest.raises(StoreIncompleteError, match="holds no patch-to-cluster form factors G and only part of F"):
        gather.cluster_form_factors_for(scene, plain, labels)
    with pytest.raises(InvalidInputError, match="another scene"):
        gather.cluster_form_factors_for(closed_box(2.0, subdivisions=2), store, labels)
    with pytest.raises(InvalidInputError, match="rows; the scene has"):
        gather.cluster_form_factors_for(scene, CSRRows(F[:10, :10]), labels)


def test_store_of_g_alone_lights_a_walk_with_rows_on_demand(tmp_path, device):
    """A store holding only G (no F rows) plus F's rows on demand: the same far field, bit for
    bit, as G computed by hemicubes on the spot, and close to the full solve."""
    from pydynrad import DynamicRadiosity, PointLight, light_vector, solve
    from pydynrad.farfield import Clusters, cluster_patches

    scene = cornell_box(max_edge=250)
    cl = cluster_patches(scene)
    store = compute_store(
        scene, tmp_path / "g", resolution=32, clusters=cl, compute_f=False, progress=False, device=device
    )
    assert not store.complete and store.complete_clusters
    kw = dict(local_size=30, observer=[278, 273, 280], resolution=32, device=device)
    from_store = DynamicRadiosity(
        scene,
        None,
        clusters=Clusters.from_labels(scene, store.cluster_labels()),
        cluster_form_factors=store.cluster_form_factors(basis_prolongation(scene, cl)),
        **kw,
    )
    on_the_spot = DynamicRadiosity(scene, None, clusters=cl, **kw)
    lights = [PointLight(position=[278, 450, 280], intensity=[2e5] * 3)]
    B = from_store.radiosity(lights)
    np.testing.assert_array_equal(B, on_the_spot.radiosity(lights))
    L = light_vector(scene, lights, device=device)
    full = solve(
        scene, form_factors(scene, resolution=32, device=device), light=L, dtype=np.float64, tol=1e-10, device=device
    ).radiosity

    def error(b):
        return np.sqrt(np.sum((b - full) ** 2) / np.sum(full**2))

    # Observed 2.8% (42 clusters, no first bounce without F), local only 22.1% (M = 30 of 336;
    # with the floor running on under the blocks, 226 patches: 3.5% and 18.8%).
    assert error(B) < 0.05 and error(B) < error(from_store.radiosity(lights, far_field=False)) / 4


def test_g_from_a_broken_row_source_is_refused_not_crashed(box, device):
    """A custom source's rows are checked before they are summed: an out-of-range column index
    (which scipy's product would follow past memory) is named with its patch."""
    from pydynrad.farfield.gather import cluster_form_factors_for

    scene, labels, _ = box
    F = form_factors(scene, resolution=8, device=device)

    class Broken:
        n_patches = len(scene)

        def rows(self, idx):
            block = sp.csr_matrix(F[idx], copy=True)
            k = int(np.flatnonzero(np.asarray(idx) == 30)[0])
            block.indices[block.indptr[k]] = len(scene) + 7
            return block

    with pytest.raises(InvalidInputError, match=r"row 30 has column index 199 outside 0\.\.191"):
        cluster_form_factors_for(scene, Broken(), labels)
