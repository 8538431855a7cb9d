"""G left in its store (:class:`pydynrad.farfield.streamed.StoredG`): the far field it gives is
the one of G held whole, and with every patch its own cluster the full solve."""

import os

import numpy as np
import pytest
from helpers import box_scene, dense_radiosity, reciprocal_F

import pydynrad
from pydynrad import DynamicRadiosity
from pydynrad.farfield import FarField, cluster_patches, level
from pydynrad.farfield import clusters as clusters_module
from pydynrad.farfield.gather import basis_prolongation
from pydynrad.farfield.streamed import StoredG
from pydynrad.precompute.store import compute_store
from pydynrad.rows.store import StoreIncompleteError, StoreMismatchError


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """A 108-patch box, a reciprocal F, its store (blocks of 10 rows) with the linear G for N/4 clusters."""
    palette = np.array([[0.8, 0.2, 0.3], [0.5, 0.5, 0.5], [0.1, 0.7, 0.9]])
    scene = box_scene(3).with_materials(albedo=palette[np.random.default_rng(1).integers(0, 3, 108)])
    F = reciprocal_F(scene.areas, row_sum=0.95, density=0.2, seed=2)
    cl = cluster_patches(scene, len(scene) // 4)
    path = tmp_path_factory.mktemp("stream") / "s"
    store = compute_store(
        scene,
        path,
        resolution=8,
        block_rows=10,
        clusters=cl,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    L = np.random.default_rng(3).random((len(scene), 3))
    return scene, F, cl, store, L


def test_stored_g_gives_the_far_field_of_g_held_whole(stored, device):
    scene, _, cl, store, L = stored
    pr = basis_prolongation(scene, cl)
    whole = FarField(scene, None, cl, G=store.cluster_form_factors(pr), device=device)
    for spill in (True, False):
        G = StoredG(store, pr, chunk_nnz=300, spill=spill)  # several chunks
        streamed = FarField(scene, None, cl, G=G, device=device)
        assert whole.G_nnz == streamed.G_nnz == G.nnz and whole.F_c_nnz == streamed.F_c_nnz
        held = [f.device_memory_bytes + f.host_memory_bytes for f in (streamed, whole)]
        assert held[0] < held[1] - 4 * G.nnz  # G is not held (whole holds it on the host or the device)
        # The first pass (F_c) wrote the chunks unzipped: 8 bytes a non-zero and the row pointers.
        assert G.spilled_bytes == (8 * G.nnz + 8 * (len(scene) + len(G._index)) if spill else 0)
        # The same kernel per chunk, each row summed as in one pass: observed identical (difference 0).
        np.testing.assert_allclose(streamed.light(L), whole.light(L), rtol=1e-6)
        np.testing.assert_allclose(streamed.light(0.5 * L), whole.light(0.5 * L), rtol=1e-6)  # a light change
        G.close()  # back to the store's blocks
        np.testing.assert_allclose(streamed.light(2 * L), whole.light(2 * L), rtol=1e-6)


def test_stored_g_without_room_for_its_temporary_file_still_serves(stored, device, monkeypatch):
    from pydynrad.farfield import streamed

    scene, _, cl, store, L = stored

    if not os.path.exists("/dev/full"):
        pytest.skip("needs /dev/full (a file that is always out of space)")
    monkeypatch.setattr(streamed.tempfile, "TemporaryFile", lambda **_: open("/dev/full", "r+b"))
    pr = basis_prolongation(scene, cl)
    G = StoredG(store, pr, chunk_nnz=300)
    far = FarField(scene, None, cl, G=G, device=device)
    assert G.spilled_bytes == 0 and G._file is None
    whole = FarField(scene, None, cl, G=store.cluster_form_factors(pr), device=device)
    np.testing.assert_allclose(far.light(L), whole.light(L), rtol=1e-6)


def test_stored_g_with_every_patch_its_own_cluster_is_the_full_solve(tmp_path, device):
    scene = box_scene(2).with_materials(albedo=np.random.default_rng(4).uniform(0.1, 0.9, (48, 3)))
    F = reciprocal_F(scene.areas, row_sum=1.0, density=0.3, seed=5)
    cl = cluster_patches(scene, len(scene))
    store = compute_store(
        scene,
        tmp_path / "s",
        resolution=8,
        block_rows=7,
        clusters=cl,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    L = np.random.default_rng(6).random((len(scene), 3))
    far = FarField(
        scene,
        None,
        cl,
        G=StoredG(store, basis_prolongation(scene, cl), chunk_nnz=100),
        tol=1e-14,
        max_sweeps=5000,
        dtype=np.float64,
        device=device,
    )
    # The store keeps F in float32: the truth is the dense solve of that F. Observed 7.5e-16.
    F32 = store.to_csr().astype(np.float64)
    np.testing.assert_allclose(far.light(L), dense_radiosity(scene, F32, L), rtol=1e-12)


def test_a_store_walk_streams_g_and_builds_the_linear_basis_once(stored, device, monkeypatch):
    scene, _, cl, store, L = stored
    built, original = [], clusters_module.linear_basis

    def counted(*args):
        built.append(1)
        return original(*args)

    monkeypatch.setattr(clusters_module, "linear_basis", counted)
    monkeypatch.setattr(level, "linear_basis", counted)
    dyn = DynamicRadiosity(scene, store, local_size=12, observer=[0.1, 0.9, 0.5], device=device)
    assert len(built) == 1 and dyn.far.prolongation == "linear" and dyn.far._G_stream is not None
    monkeypatch.undo()
    whole = FarField(scene, None, dyn.far.clusters, G=store.cluster_form_factors(), device=device)
    np.testing.assert_allclose(dyn.far.light(L), whole.light(L), rtol=1e-6)  # observed identical
    # The store's G passed in is held on the device, with the store's clusters (not new ones).
    held = DynamicRadiosity(
        scene,
        store,
        local_size=12,
        observer=[0.1, 0.9, 0.5],
        device=device,
        cluster_form_factors=store.cluster_form_factors(),
    )
    assert held.far._G_stream is None and np.array_equal(held.far.clusters.labels, dyn.far.clusters.labels)
    np.testing.assert_allclose(held.far.light(L), whole.light(L), rtol=1e-6)


def test_stored_g_refuses_what_it_cannot_serve(stored, tmp_path, device):
    scene, F, cl, store, _ = stored
    pr = basis_prolongation(scene, cl)
    with pytest.raises(StoreMismatchError, match="other clusters"):
        StoredG(store, basis_prolongation(scene, cluster_patches(scene, len(scene) // 3)))
    with pytest.raises(pydynrad.InvalidInputError, match="without F"):
        FarField(scene, F, cl, G=StoredG(store, pr), prolongation="linear", gather="cluster", device=device)
    with pytest.raises(pydynrad.InvalidInputError, match="linear must be"):
        FarField(scene, None, cl, G=StoredG(store, pr), linear=(pr, pr), device=device)
    other = cluster_patches(box_scene(2), 12)  # clusters of another scene: refused before any basis is built on them
    with pytest.raises(pydynrad.InvalidInputError, match="another scene"):
        DynamicRadiosity(scene, store, local_size=12, observer=[0.1, 0.9, 0.5], clusters=other, device=device)
    part = compute_store(
        scene,
        tmp_path / "part",
        resolution=8,
        block_rows=10,
        clusters=cl,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    part.block_path(3, "G").unlink()
    with pytest.raises(StoreIncompleteError, match="1 of 11 blocks of G"):
        StoredG(part, pr)
