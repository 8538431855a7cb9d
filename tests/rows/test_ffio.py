"""Form-factor I/O: the single .npz file and open_form_factors over a file or a store folder."""

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import box_mesh, grid_scene, same_csr, synthetic_rows

from pydynrad import InvalidInputError, Scene
from pydynrad.precompute.store import compute_store
from pydynrad.rows.cache import RowCache
from pydynrad.rows.files import load_form_factors, open_form_factors, save_form_factors, whole_matrix
from pydynrad.rows.sources import CSRRows
from pydynrad.rows.store import FormFactorStore, StoreIncompleteError, StoreMismatchError


def small_scene():
    pts, tris = box_mesh(n=1)
    return Scene(pts, tris, albedo=0.5, name="cube")


def test_form_factor_file_round_trip_and_checks(tmp_path):
    scene = small_scene()
    rng = np.random.default_rng(1)
    F = sp.random(len(scene), len(scene), density=0.3, random_state=rng, format="csr", dtype=np.float32)
    path = save_form_factors(scene, tmp_path / "f.npz", F, resolution=32)
    G, header = load_form_factors(scene, path)
    assert same_csr(G, F) and header["resolution"] == 32 and header["n_patches"] == len(scene)
    assert [p.name for p in tmp_path.iterdir()] == ["f.npz"]  # no temporary left behind
    assert same_csr(open_form_factors(scene, path), F)
    assert same_csr(open_form_factors(scene, path, cache_bytes=1000), F)  # a file is in memory whole
    other = Scene(*box_mesh(n=2), name="other")
    with pytest.raises(InvalidInputError, match="another scene geometry"):
        open_form_factors(other, path)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(InvalidInputError, match="not a pydynrad form-factor file"):
        load_form_factors(scene, junk)
    with pytest.raises(InvalidInputError, match="form-factor file .*: not a regular file"):  # a folder
        load_form_factors(scene, tmp_path)
    np.savez(tmp_path / "alien.npz", x=np.zeros(3))
    with pytest.raises(InvalidInputError, match="not a pydynrad form-factor file"):
        open_form_factors(scene, tmp_path / "alien.npz")


def test_save_refuses_bad_targets_and_shapes(tmp_path):
    scene = small_scene()
    F = sp.eye(len(scene), format="csr", dtype=np.float32) * 0.1
    with pytest.raises(InvalidInputError, match="does not exist"):
        save_form_factors(scene, tmp_path / "no" / "f.npz", F, 8)
    with pytest.raises(InvalidInputError, match=r"\.npz"):
        save_form_factors(scene, tmp_path / "f.txt", F, 8)
    with pytest.raises(InvalidInputError, match="shape"):
        save_form_factors(scene, tmp_path / "f.npz", sp.eye(3, format="csr"), 8)
    assert not list(tmp_path.iterdir())


def test_open_store_plain_and_cached(tmp_path):
    scene = grid_scene(6)  # 72 patches
    compute_store(
        scene,
        tmp_path / "ff",
        resolution=8,
        block_rows=16,
        progress=False,
        row_function=synthetic_rows,
        patching={"scene": "grid"},
    )
    truth = synthetic_rows(scene, np.arange(len(scene)), 8)
    store = open_form_factors(scene, tmp_path / "ff")
    assert isinstance(store, FormFactorStore)
    idx = np.array([70, 3, 17, 3])
    assert same_csr(store.rows(idx), truth[idx])
    with open_form_factors(scene, tmp_path / "ff", cache_bytes=4096) as cache:
        assert isinstance(cache, RowCache) and cache.max_bytes == 4096 and cache.source.path == tmp_path / "ff"
        assert same_csr(cache.rows(idx), truth[idx]) and same_csr(cache.rows(idx), truth[idx])
        assert cache.stats["hits"] == 3 and cache.stats["misses"] == 3
        assert same_csr(whole_matrix(cache), truth)
        assert cache.stats["requested"] == 6  # whole_matrix read the store, not through the cache
    assert same_csr(whole_matrix(store), truth) and same_csr(whole_matrix(CSRRows(truth)), truth)


def test_open_refuses_missing_wrong_and_unfinished(tmp_path):
    scene = grid_scene(6)
    with pytest.raises(InvalidInputError, match="no such file or store folder"):
        open_form_factors(scene, tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InvalidInputError, match="no form-factor store"):
        open_form_factors(scene, tmp_path / "empty")
    compute_store(
        scene, tmp_path / "ff", resolution=8, block_rows=16, progress=False, row_function=synthetic_rows, blocks=[0, 2]
    )
    with pytest.raises(StoreMismatchError, match="geometry_hash"):
        open_form_factors(grid_scene(6, z=1.0), tmp_path / "ff")
    with pytest.raises(StoreIncompleteError, match="3 of 5 blocks missing"):
        open_form_factors(scene, tmp_path / "ff")


def test_scene_comes_first_and_the_old_order_is_named(tmp_path):
    """(scene, path) everywhere: the old (path, scene) order fails with a message that says so."""
    scene = small_scene()
    F = sp.csr_matrix((len(scene), len(scene)), dtype=np.float32)
    path = save_form_factors(scene, tmp_path / "f.npz", F, 8)
    calls = [
        lambda: save_form_factors(tmp_path / "g.npz", scene, F, 8),
        lambda: load_form_factors(path, scene),
        lambda: open_form_factors(path, scene),
        lambda: FormFactorStore.create(tmp_path / "s", scene, resolution=8),
        lambda: FormFactorStore.open(tmp_path / "s", scene, resolution=8),
        lambda: compute_store(tmp_path / "s", scene, resolution=8),
    ]
    for call in calls:
        with pytest.raises(
            InvalidInputError,
            match=r"scene must be a pydynrad.Scene or a trimesh mesh; got \w*Path \(the scene comes first",
        ):
            call()
