"""Distributed precomputation on a LocalCluster of 2 spawned workers equals the single-process store."""

import sys

import cloudpickle
import numpy as np
import pytest
import trimesh
from helpers import grid_scene, same_csr, synthetic_rows

from pydynrad import InvalidInputError
from pydynrad.precompute.distributed import _WORKER_SCENE, SceneSpec, _worker_scene, precompute_distributed
from pydynrad.precompute.store import compute_store
from pydynrad.rows.store import FormFactorStore, StoreMismatchError

# Workers unpickle the synthetic row function by value: they need not import the tests' helpers.
cloudpickle.register_pickle_by_value(sys.modules["helpers"])


def test_local_cluster_resumes_and_equals_single_process(tmp_path):
    """2 workers, a store left half-done (blocks missing, one corrupt, a stale temp file)."""
    scene = grid_scene(8)  # 128 patches, 8 blocks of 16 rows
    single = compute_store(
        scene, tmp_path / "single", resolution=8, block_rows=16, progress=False, row_function=synthetic_rows
    )
    part = compute_store(
        scene,
        tmp_path / "dist",
        resolution=8,
        block_rows=16,
        progress=False,
        row_function=synthetic_rows,
        blocks=[0, 1, 2, 5],
    )
    part.block_path(1).write_bytes(b"torn")
    (part.block_path(3).parent / "b000003.npz.tmp-1-abc").write_bytes(b"half")
    finished = {k: part.block_path(k).stat().st_mtime_ns for k in (0, 2, 5)}
    store = precompute_distributed(
        scene,
        tmp_path / "dist",
        resolution=8,
        block_rows=16,
        workers=2,
        verify=True,
        progress=False,
        row_function=synthetic_rows,
    )
    assert store.complete and not list(store.block_path(0).parent.glob("*.tmp-*"))
    assert {k: store.block_path(k).stat().st_mtime_ns for k in (0, 2, 5)} == finished  # kept, not recomputed
    for k in range(store.n_blocks):  # bit for bit, block file payloads included
        assert same_csr(store.read_block(k), single.read_block(k))
    assert same_csr(store.to_csr(), single.to_csr())


@pytest.mark.slow
def test_real_form_factors_distributed_equal_single_process(tmp_path):
    """Hemicube rows from a mesh-file SceneSpec on 2 workers (own OpenCL contexts) = one process."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    box.invert()  # normals inwards: a closed room
    mesh_file = tmp_path / "room.obj"
    box.export(mesh_file)
    spec = SceneSpec(str(mesh_file), {"max_patch_area": 0.05})
    scene = spec.build()
    single = compute_store(
        scene,
        tmp_path / "single",
        resolution=16,
        block_rows=32,
        progress=False,
        patching=spec.recipe() | {"scene": str(mesh_file.resolve())},
    )
    store = precompute_distributed(spec, tmp_path / "dist", resolution=16, block_rows=32, workers=2, progress=False)
    assert store.complete
    f = store.to_csr()
    assert same_csr(f, single.to_csr())
    np.testing.assert_allclose(
        np.asarray(f.sum(axis=1)).ravel(), 1.0, atol=1e-5
    )  # closed room: rows sum to 1 (observed 1.2e-7)


def test_worker_refuses_a_scene_with_other_geometry():
    scene, moved = grid_scene(3), grid_scene(3, z=2.0)
    _WORKER_SCENE.clear()
    with pytest.raises(InvalidInputError, match="geometry hash"):
        _worker_scene((moved.vertices, moved.faces), scene.geometry_hash())
    assert _worker_scene((scene.vertices, scene.faces), scene.geometry_hash()).geometry_hash() == scene.geometry_hash()


def test_bad_arguments(tmp_path):
    scene = grid_scene(3)
    with pytest.raises(InvalidInputError, match="neither a built-in"):
        precompute_distributed("no_such_scene_or_file", tmp_path / "a", resolution=8, progress=False)
    with pytest.raises(InvalidInputError, match="scene_spec"):
        precompute_distributed(42, tmp_path / "a", resolution=8, progress=False)
    with pytest.raises(InvalidInputError, match="JSON"):
        SceneSpec("cornell_box", {"f": object()})
    with pytest.raises(InvalidInputError, match="not both"):
        precompute_distributed(
            scene,
            tmp_path / "b",
            resolution=8,
            workers=2,
            scheduler="tcp://127.0.0.1:1",
            progress=False,
            row_function=synthetic_rows,
        )
    with pytest.raises(InvalidInputError, match="workers"):
        precompute_distributed(
            scene, tmp_path / "c", resolution=8, workers=0, progress=False, row_function=synthetic_rows
        )
    compute_store(scene, tmp_path / "d", resolution=8, block_rows=4, progress=False, row_function=synthetic_rows)
    with pytest.raises(StoreMismatchError):  # refused on the client, before any cluster starts
        precompute_distributed(scene, tmp_path / "d", resolution=16, block_rows=4, progress=False)
    done = precompute_distributed(scene, tmp_path / "d", resolution=8, block_rows=4, progress=False)
    assert isinstance(done, FormFactorStore) and done.complete  # nothing to do: no cluster started


def test_cluster_form_factors_distributed_equal_single_process(tmp_path):
    """G alone (no F rows) on 2 workers, finishing a store begun in this process: workers read the
    prolongation from the store and their G blocks equal the single-process ones bit for bit."""
    spec = SceneSpec("closed_box", {"subdivisions": 2})
    scene = spec.build()
    walls = scene.source_face // 2
    kw = dict(resolution=8, block_rows=32, clusters=walls, cluster_resolution=8, compute_f=False, progress=False)
    single = compute_store(scene, tmp_path / "single", patching=spec.recipe(), **kw)
    compute_store(scene, tmp_path / "dist", patching=spec.recipe(), blocks=[1, 4], **kw)
    store = precompute_distributed(spec, tmp_path / "dist", workers=2, **kw)
    assert store.complete_clusters and store.missing_blocks() == list(range(store.n_blocks))
    for k in range(store.n_blocks):
        assert same_csr(store.read_block(k, "G"), single.read_block(k, "G"))
    # The default basis is linear (3 functions per wall, summing to 1 on every patch): rows of G sum as F's do.
    assert store.cluster_basis == "linear" and store.n_clusters == 3 * (walls.max() + 1)
    np.testing.assert_array_equal(store.cluster_labels(), walls)
    np.testing.assert_allclose(np.asarray(store.cluster_form_factors().sum(axis=1)).ravel(), 1.0, atol=1e-5)
