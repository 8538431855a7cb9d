"""Precomputed poses (pydynrad.precompute.poses): rows of every pose in memory or in a store, taken by moves to those poses."""

import numpy as np
import pytest
from helpers import END, MIDDLE, START, rel
from helpers import MOVING_LIGHTS as LIGHTS
from helpers import MOVING_OBSERVER as OBSERVER
from helpers import MOVING_R as R
from helpers import moving_full_solve as full_solve

import pydynrad as pd


def test_precomputed_poses(cornell_384, green_block, device):
    """The paper's variant: rows of each pose precomputed; a move there takes them (no hemicube
    for a row the store holds) and gives what hemicubes at the move would."""
    n = len(cornell_384) + len(green_block)
    poses = pd.precompute.precompute_poses(
        cornell_384, [pd.RigidObject(green_block)], [START, END], resolution=R, device=device
    )
    assert len(poses) == 2 and poses.nbytes > 0
    runs = []
    for stored in (poses, None):
        obj = pd.RigidObject(green_block, START)
        dyn = pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=n,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=None, poses=stored),
            observer=OBSERVER,
            device=device,
        )
        stats = []
        for T in (END, MIDDLE, START):
            dyn.move(obj, T)
            stats.append(dyn.update(OBSERVER))
        runs.append((dyn.radiosity(LIGHTS), stats))
    (B, st), (B_hc, st_hc) = runs
    np.testing.assert_array_equal(B, B_hc)  # the same rows, the same swaps
    assert st_hc[0].hemicubes == len(green_block) + st_hc[0].rows_refreshed
    # Stored poses: hemicubes only for the rows that saw the old pose and not this one.
    assert st[0].hemicubes < st_hc[0].hemicubes // 2 and st[2].hemicubes < st_hc[2].hemicubes // 2
    assert st[1].hemicubes == st_hc[1].hemicubes  # MIDDLE was not precomputed
    with pytest.raises(pd.InvalidInputError, match="R = 32"):
        pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=n,
            resolution=32,
            objects=pd.MovingObjects([pd.RigidObject(green_block, START)], poses=poses),
            device=device,
        )
    with pytest.raises(pd.InvalidInputError, match="this scene with its objects has 384 patches"):
        pd.DynamicRadiosity(
            cornell_384, None, local_size=n, resolution=R, device=device, objects=pd.MovingObjects([], poses=poses)
        )


def test_poses_in_store(cornell_384, green_block, device, tmp_path):
    """Per-pose rows in a form-factor store: a pose from the store gives the same K as from
    hemicubes; a store of another scene, or of poses of other objects, is refused; a file
    tampered with fails its checksum."""
    store = pd.FormFactorStore.create(cornell_384, tmp_path / "ff", resolution=R)
    poses = pd.precompute.precompute_poses(
        cornell_384, [pd.RigidObject(green_block)], [START, END], resolution=R, device=device, store=store
    )
    assert len(poses) == 2 and poses.nbytes == 0  # on disk, not in memory
    reopened = pd.precompute.stored_poses(
        cornell_384,
        [pd.RigidObject(green_block)],
        pd.FormFactorStore.open(cornell_384, tmp_path / "ff", resolution=R),
        R,
    )
    n = len(cornell_384) + len(green_block)
    K, hemicubes = [], []
    for stored in (reopened, None):
        obj = pd.RigidObject(green_block, START)
        dyn = pd.DynamicRadiosity(
            cornell_384,
            None,
            local_size=n,
            resolution=R,
            objects=pd.MovingObjects([obj], occlusion=None, poses=stored),
            observer=OBSERVER,
            device=device,
        )
        dyn.move(obj, END)
        hemicubes.append(dyn.update(OBSERVER).hemicubes)
        K.append(dyn.matrix.to_host())
    np.testing.assert_array_equal(K[0], K[1])  # the same float32 rows, the same swap
    assert hemicubes[0] < hemicubes[1] // 2
    # Resuming writes nothing new; other objects, another resolution, another scene: refused.
    assert (
        len(
            pd.precompute.precompute_poses(
                cornell_384, [pd.RigidObject(green_block)], [END], resolution=R, device=device, store=store
            )
        )
        == 2
    )
    other = pd.scenes.block(50.0, 1)
    with pytest.raises(pd.rows.StoreMismatchError, match="other objects"):
        pd.precompute.stored_poses(cornell_384, [pd.RigidObject(other)], store, R)
    with pytest.raises(pd.rows.StoreMismatchError, match="other objects"):
        pd.precompute.stored_poses(cornell_384, [pd.RigidObject(green_block)], store, 2 * R)
    with pytest.raises(pd.rows.StoreMismatchError, match="another scene"):
        pd.precompute.stored_poses(pd.scenes.cornell_box(max_edge=250.0), [pd.RigidObject(green_block)], store, R)
    files = sorted((tmp_path / "ff" / "poses").glob("p*.npz"))
    files[1].write_bytes(files[0].read_bytes())  # one configuration's file under another's name
    with pytest.raises(pd.rows.StoreCorruptError, match="checksum"):
        [reopened.get(T) for T in (pd.RigidObject(green_block, START).transform[None], END[None])]


def test_precomputed_poses_with_static_form_factors(cornell_384, green_block, device):
    """With a static F too, a move to a stored pose takes from the store the rows of every patch
    it holds there (hemicubes of the world, not rows estimated from F; no hemicube at all), and
    at budget 0 the correction solves with them. The rows at the pose are then those of a full
    build of the world there: the store's bit for bit, F's for the patches that cannot see the
    block up to the cap to a sum of 1 (a float32 row may sum to 1 + 5e-9: 8e-10 on the bench's
    box, none here), and B is its solve."""
    F_static = pd.form_factors(cornell_384, R, device=device)
    n = len(cornell_384) + len(green_block)
    poses = pd.precompute.precompute_poses(
        cornell_384, [pd.RigidObject(green_block)], [END], resolution=R, device=device
    )
    obj = pd.RigidObject(green_block, START)
    dyn = pd.DynamicRadiosity(
        cornell_384,
        F_static,
        local_size=n,
        resolution=R,
        objects=pd.MovingObjects([obj], occlusion=0, poses=poses),
        observer=OBSERVER,
        device=device,
    )
    dyn.radiosity(LIGHTS)
    dyn.move(obj, END)
    assert dyn.update(OBSERVER).hemicubes == 0
    patches, stored = poses.get(dyn.scene.bvh.transforms)
    source = dyn._ff.source
    np.testing.assert_array_equal(source.rows(patches).toarray(), stored.toarray())
    _, F_full, full = full_solve(cornell_384, [pd.RigidObject(green_block, END)], device)
    np.testing.assert_allclose(source.rows(np.arange(n)).toarray(), F_full.toarray(), rtol=0, atol=1e-8)  # observed 0
    # The correction stops at an estimated error of 2e-4 of max B; observed 2.4e-5 (PoCL, Zen 4).
    assert rel(dyn.radiosity(LIGHTS, far_field=False), full) < 1e-4
