"""The on-disk form-factor store: round trip, header checks, resume after a crash, corruption."""

import json
import zipfile

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import grid_scene, same_csr, synthetic_rows

from pydynrad import InvalidInputError, RigidObject
from pydynrad.precompute.store import compute_store
from pydynrad.rows.store import FormFactorStore, StoreCorruptError, StoreIncompleteError, StoreMismatchError
from pydynrad.scenes import block


def reference(scene, resolution=8):
    return synthetic_rows(scene, np.arange(len(scene)), resolution)


def test_round_trip(tmp_path):
    scene = grid_scene()  # 72 patches, blocks of 10 rows: 8 blocks, the last one short
    store = compute_store(
        scene, tmp_path / "ff", resolution=8, block_rows=10, progress=False, row_function=synthetic_rows
    )
    ref = reference(scene)
    assert store.complete and store.n_blocks == 8 and store.missing_blocks() == []
    assert same_csr(store.to_csr(), ref)
    idx = np.array([71, 3, 3, 40, 0, 69, 15])  # unordered, repeated, across blocks
    got = store.rows(idx)
    assert got.shape == (7, 72) and got.dtype == np.float32
    assert same_csr(got, ref[idx])
    assert store.rows([]).shape == (0, 72)
    assert store.nbytes_on_disk > 0
    reopened = FormFactorStore.open(scene, tmp_path / "ff", resolution=8)
    assert same_csr(reopened.rows(np.arange(72)), ref)
    header = json.loads((tmp_path / "ff" / "header.json").read_text())
    assert header["geometry_hash"] == scene.geometry_hash() and header["n_patches"] == 72
    assert header["params"]["resolution"] == 8 and header["params"]["pydynrad_version"]
    # A block is a plain .npz: numpy alone reads it.
    with np.load(tmp_path / "ff" / "blocks" / "b000001.npz") as z:
        blk = sp.csr_matrix((z["data"], z["indices"], z["indptr"]), shape=(10, 72))
    assert same_csr(blk, ref[10:20])


def test_header_mismatch_refused(tmp_path):
    scene = grid_scene()
    compute_store(
        scene,
        tmp_path / "ff",
        resolution=8,
        block_rows=16,
        patching={"max_area": 0.5},
        progress=False,
        row_function=synthetic_rows,
    )
    moved = grid_scene(z=1.0)  # same N and topology, other geometry
    with pytest.raises(StoreMismatchError, match="geometry_hash"):
        FormFactorStore.open(moved, tmp_path / "ff", resolution=8, patching={"max_area": 0.5})
    with pytest.raises(StoreMismatchError, match="n_patches"):
        FormFactorStore.open(grid_scene(5), tmp_path / "ff", resolution=8, patching={"max_area": 0.5})
    with pytest.raises(StoreMismatchError, match="resolution: store has 8, requested 16"):
        FormFactorStore.open(scene, tmp_path / "ff", resolution=16, patching={"max_area": 0.5})
    with pytest.raises(StoreMismatchError, match="patching"):
        FormFactorStore.open(scene, tmp_path / "ff", resolution=8, patching={"max_area": 0.25})
    with pytest.raises(StoreMismatchError):  # resuming must not silently mix parameters either
        compute_store(
            scene,
            tmp_path / "ff",
            resolution=4,
            block_rows=16,
            patching={"max_area": 0.5},
            progress=False,
            row_function=synthetic_rows,
        )
    with pytest.raises(StoreMismatchError, match="block_rows"):
        FormFactorStore.create(
            scene, tmp_path / "ff", resolution=8, block_rows=8, patching={"max_area": 0.5}, exist_ok=True
        )
    with pytest.raises(InvalidInputError, match="already exists"):
        FormFactorStore.create(scene, tmp_path / "ff", resolution=8, block_rows=16, patching={"max_area": 0.5})
    assert issubclass(StoreMismatchError, InvalidInputError)
    FormFactorStore.open(scene, tmp_path / "ff", resolution=8, patching={"max_area": 0.5})  # the matching request opens
    with pytest.raises(InvalidInputError, match="no form-factor store"):
        FormFactorStore.open(scene, tmp_path / "elsewhere", resolution=8)


class Crash(RuntimeError):
    pass


def test_killed_writer_resumes(tmp_path):
    scene = grid_scene()
    path = tmp_path / "ff"
    calls = []

    def dies_after_three(scene, rows, resolution, device=None):
        if len(calls) == 3:
            raise Crash("writer killed")
        calls.append(rows[0])
        return synthetic_rows(scene, rows, resolution)

    with pytest.raises(Crash):  # one block per call (task_rows=10), so three blocks get written
        compute_store(
            scene, path, resolution=8, block_rows=10, task_rows=10, progress=False, row_function=dies_after_three
        )
    # A writer killed mid-write leaves a temporary file; it must never count as a block.
    (path / "blocks" / "b000003.npz.tmp-999-deadbeef").write_bytes(b"PK\x03\x04 half a zip")
    store = FormFactorStore.open(scene, path, resolution=8)
    assert store.missing_blocks() == [3, 4, 5, 6, 7] and not store.complete
    ref = reference(scene)
    assert same_csr(store.rows([5, 29]), ref[[5, 29]])
    with pytest.raises(StoreIncompleteError, match="block 3"):
        store.rows([5, 30])

    resumed = []

    def counting(scene, rows, resolution, device=None):
        assert np.array_equal(rows, np.arange(rows[0], rows[-1] + 1))
        resumed.append((int(rows[0]), int(rows[-1]) + 1))
        return synthetic_rows(scene, rows, resolution)

    store = compute_store(scene, path, resolution=8, block_rows=10, task_rows=25, progress=False, row_function=counting)
    assert resumed == [(30, 50), (50, 70), (70, 72)]  # only the missing blocks, two per call (task_rows=25)
    assert store.complete and same_csr(store.to_csr(), ref)
    assert not list((path / "blocks").glob("*.tmp-*"))


def test_corrupt_block_detected_and_repaired(tmp_path):
    scene = grid_scene()
    path = tmp_path / "ff"
    store = compute_store(scene, path, resolution=8, block_rows=10, progress=False, row_function=synthetic_rows)
    ref = reference(scene)

    # Change one stored value and re-zip consistently: the zip CRCs pass, only our SHA-256 can tell.
    f2 = store.block_path(2)
    with np.load(f2) as z:
        arrays = {k: z[k].copy() for k in ("indptr", "indices", "data")}
        meta = z["meta.json"]
    arrays["data"][0] *= 2
    with zipfile.ZipFile(f2, "w") as zf:
        for name, a in arrays.items():
            with zf.open(f"{name}.npy", "w") as f:
                np.lib.format.write_array(f, a)
        zf.writestr("meta.json", meta)
    with pytest.raises(StoreCorruptError, match="checksum"):
        store.rows([25])

    f5 = store.block_path(5)  # truncated file: a torn write from a tool that is not ours
    f5.write_bytes(f5.read_bytes()[:100])
    with pytest.raises(StoreCorruptError, match="corrupt"):
        store.rows([55])

    store.block_path(6).write_bytes(store.block_path(1).read_bytes())  # a whole block under the wrong name
    with pytest.raises(StoreCorruptError):
        store.rows([60])

    assert same_csr(store.rows([0, 39]), ref[[0, 39]])  # intact blocks still serve
    assert store.missing_blocks() == [] and store.missing_blocks(verify=True) == [2, 5, 6]
    store = compute_store(
        scene, path, resolution=8, block_rows=10, progress=False, verify=True, row_function=synthetic_rows
    )
    assert same_csr(store.to_csr(), ref)


def test_bad_input(tmp_path):
    scene = grid_scene(3)  # 18 patches
    store = FormFactorStore.create(scene, tmp_path / "ff", resolution=8, block_rows=8)
    with pytest.raises(InvalidInputError, match="shape"):
        store.write_block(0, sp.csr_matrix((7, 18), dtype=np.float32))
    with pytest.raises(InvalidInputError, match="shape"):
        store.write_block(2, sp.csr_matrix((8, 18), dtype=np.float32))  # the last block has 2 rows
    bad = sp.csr_matrix(np.full((8, 18), np.nan, dtype=np.float32))
    with pytest.raises(InvalidInputError, match="NaN"):
        store.write_block(0, bad)
    with pytest.raises(InvalidInputError, match="block index"):
        store.write_block(3, sp.csr_matrix((2, 18)))
    assert store.missing_blocks() == [0, 1, 2]
    with pytest.raises(InvalidInputError, match="0..17"):
        store.rows([18])
    with pytest.raises(InvalidInputError, match="integer"):
        store.rows([0.5])
    with pytest.raises(InvalidInputError, match="resolution"):
        FormFactorStore.create(scene, tmp_path / "g", resolution=0)
    with pytest.raises(InvalidInputError, match="block_rows"):
        FormFactorStore.create(scene, tmp_path / "g", resolution=8, block_rows=0)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x.txt").write_text("x")
    with pytest.raises(InvalidInputError, match="empty folder"):
        FormFactorStore.create(scene, tmp_path / "full", resolution=8)


def test_write_block_canonicalises_a_copy(tmp_path):
    scene = grid_scene(2)  # 8 patches, one block
    store = FormFactorStore.create(scene, tmp_path / "ff", resolution=8, block_rows=8)
    # Unsorted columns and a duplicate entry (1, 5) twice: stored summed and sorted.
    m = sp.csr_matrix(
        (np.array([0.3, 0.1, 0.2, 0.05], np.float32), np.array([5, 2, 5, 1]), [0, 0, 4, 4, 4, 4, 4, 4, 4]), shape=(8, 8)
    )
    before = (m.data.copy(), m.indices.copy())
    store.write_block(0, m)
    got = store.read_block(0)
    assert got.has_sorted_indices and got[1].indices.tolist() == [1, 2, 5]
    np.testing.assert_array_equal(got.toarray(), m.toarray())
    assert np.array_equal(m.data, before[0]) and np.array_equal(m.indices, before[1])  # caller's matrix untouched


def test_cluster_and_pose_headers_are_checked_when_read(tmp_path):
    """A store's clusters.json and poses.json hold what readers take, or name what they lack
    ({}, [1], a count as text, a list for the objects had crashed them with KeyError, TypeError
    or AttributeError)."""
    scene = grid_scene()
    compute_store(scene, tmp_path / "ff", resolution=8, block_rows=10, progress=False, row_function=synthetic_rows)
    good = {"n_clusters": 12, "resolution": 8, "prolongation_sha256": "ab", "basis": "indicator", "params": {}}
    for bad, message in (
        ({}, "n_clusters must be a positive integer"),
        ([1], "must hold a JSON object"),
        ({**good, "n_clusters": "48"}, "n_clusters"),
        ({**good, "n_clusters": 10**30}, "n_clusters"),
        ({k: v for k, v in good.items() if k != "prolongation_sha256"}, "prolongation_sha256"),
        ({**good, "basis": "cubic"}, "basis must be one of"),
    ):
        (tmp_path / "ff" / "clusters.json").write_text(json.dumps(bad))
        with pytest.raises(StoreCorruptError, match=message):
            FormFactorStore.open(scene, tmp_path / "ff", resolution=8)
    (tmp_path / "ff" / "clusters.json").write_text(json.dumps(good))
    store = FormFactorStore.open(scene, tmp_path / "ff", resolution=8)
    assert store.n_clusters == 12
    (tmp_path / "ff" / "poses.json").write_text("[1]")
    with pytest.raises(StoreCorruptError, match="list of 'objects'"):
        store.check_pose_objects([RigidObject(block(10.0, 0))], resolution=8)
