"""Long paths are checked before their first frame, fast: a 10^6-frame path must not sit silent
for minutes before writing its first frame (docs/decisions/0034-robustness-limits.md)."""

import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import pydynrad
from pydynrad.errors import InvalidInputError
from pydynrad.geometry.objects import MAX_REACH, RigidObject
from pydynrad.paths import MAX_FRAMES, CameraPath, ObjectTrack, block
from pydynrad.walks import _check_frame_files, _check_reach


def _pose(x, angles=(0.0, 0.0, 0.0)):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    T[:3, 3] = x
    return T


@pytest.mark.parametrize("interpolation", ["catmull-rom", "linear"])
def test_views_and_poses_at_once_are_the_frames_own(interpolation):
    keys = np.random.default_rng(3).normal(size=(5, 3))
    looks = keys + np.array([0.0, 0.0, 3.0])
    for path in (
        CameraPath(keys, looks, 37, interpolation=interpolation),
        CameraPath(keys, None, 37, interpolation=interpolation),
    ):
        eye, target = path.views(3, 30)
        for j, k in enumerate(range(3, 30)):
            cam = path.camera(k)
            np.testing.assert_array_equal(eye[j], cam.position)
            np.testing.assert_array_equal(target[j], cam.look_at)
    obj = RigidObject(block([0.1, 0.1, 0.1], 0), _pose([0.3] * 3), name="b")
    track = ObjectTrack(obj, [_pose([0.3] * 3), _pose([0.6, 0.5, 0.4], (10, 50, 30)), _pose([0.2] * 3, (-40, 5, 90))])
    track = ObjectTrack(obj, track.transforms, interpolation)
    poses = track.poses(23)
    for k in range(23):
        np.testing.assert_allclose(poses[k], track.at(k, 23), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(poses[[0, 11, 22]], track.transforms)  # keyframes exactly
    np.testing.assert_array_equal(
        ObjectTrack(obj, track.transforms[:1]).poses(4), np.repeat(track.transforms[:1], 4, 0)
    )


def test_a_million_frames_are_checked_in_seconds():
    path = CameraPath([[0.5, 0.5, 0.1], [0.5, 0.6, 0.2], [0.4, 0.5, 0.15]], [[0.5, 0.5, 0.9]] * 3, MAX_FRAMES)
    t = time.perf_counter()
    path.check(progress=False)
    assert time.perf_counter() - t < 10.0  # about 1 s here; the per-frame checks had taken minutes


def test_a_bad_frame_deep_in_a_long_path_is_named():
    # the eye walks through the point it looks at, at the middle frame only
    n = 200_001
    path = CameraPath([[0, 0, 0], [2, 0, 0]], [[1, 0, 0], [1, 0, 0]], n, interpolation="linear")
    with pytest.raises(InvalidInputError, match=rf"^frame 100000 of {n}: camera look_at .* must differ"):
        path.check(progress=False)
    # the view straight up the up vector, at one frame of 150,001
    path = CameraPath([[0, 0, 0], [0, 0, 0]], [[1, 0, 0], [-1, 0, 0]], 150_001, up=(0, 0, 1), interpolation="linear")
    with pytest.raises(InvalidInputError, match="^frame 75000 of 150001: camera look_at"):
        path.check(progress=False)
    path = CameraPath([[0, 0, 0], [0, 0, 0]], [[1, 0, -1], [1, 0, 1]], 150_001, up=(0, 0, 1), interpolation="linear")
    path.check(progress=False)  # passes through the up direction's side, never along it
    path = CameraPath([[0, 0, 0], [0, 0, 0]], [[0, -1, -1], [0, -1, 1]], 150_001, up=(0, 1, 0), interpolation="linear")
    with pytest.raises(InvalidInputError, match="^frame 75000 of 150001: camera up must not be zero or parallel"):
        path.check(progress=False)


def test_reach_is_checked_at_every_pose_and_the_first_one_beyond_is_named():
    scene = pydynrad.scenes.closed_box(subdivisions=1)
    obj = RigidObject(block([0.1, 0.1, 0.1], 0), _pose([0.3] * 3), name="b")
    far = MAX_REACH * scene.ray_scale * 2.0
    track = ObjectTrack(obj, [_pose([0.3] * 3), _pose([far, 0.3, 0.3])], "linear")
    n = 100_001
    _check_reach(scene, [ObjectTrack(obj, [_pose([0.3] * 3), _pose([0.6] * 3)])], n, False)
    with pytest.raises(InvalidInputError, match="object 'b' at this pose reaches"):
        _check_reach(scene, [track], n, False)
    # the first frame beyond: its pose, as the walk would place it, is the one refused
    limit = MAX_REACH * scene.ray_scale
    c, r = obj.bounding_sphere(np.eye(4))
    reach = np.array(
        [
            np.linalg.norm(track.at(k, n)[:3, :3] @ c + track.at(k, n)[:3, 3] - scene.frame.origin) + r
            for k in (0, n - 1)
        ]
    )
    assert reach[0] < limit < reach[1]


def test_frame_files_are_checked_by_one_listing(tmp_path):
    _check_frame_files(tmp_path, 10**6, "png", {3})
    (tmp_path / "frame_0042.png").mkdir()
    (tmp_path / "frame_00042.png").mkdir()  # not a name the walk writes
    (tmp_path / "frame_0007.jpg").mkdir()  # another format's
    (tmp_path / "frame_1000000.png").mkdir()  # past the last frame
    with pytest.raises(InvalidInputError, match="frame_0042.png': a folder of that name is in the way"):
        _check_frame_files(tmp_path, 10**6, "png", {3})
    _check_frame_files(tmp_path, 42, "png", {3})
    (tmp_path / "compare_0003.png").mkdir()
    with pytest.raises(InvalidInputError, match="compare_0003.png': a folder of that name is in the way"):
        _check_frame_files(tmp_path, 42, "png", {3})


def test_a_long_walk_reaches_its_first_frame_quickly(tmp_path, monkeypatch):
    """walk() on a 10^5-frame path with a moving object writes its first frame within seconds
    (a Camera, a slerp and two file look-ups per frame had taken a minute)."""
    import scipy.sparse as sp

    import pydynrad.walks as walks

    scene = pydynrad.scenes.closed_box(subdivisions=1)
    F = sp.csr_matrix((len(scene), len(scene)), dtype=np.float32)
    obj = RigidObject(block([0.1, 0.1, 0.1], 0), _pose([0.3] * 3), name="b")
    track = ObjectTrack(obj, [_pose([0.3] * 3), _pose([0.6, 0.5, 0.4], (10, 50, 30)), _pose([0.3] * 3)])
    path = CameraPath([[0.5, 0.5, 0.1], [0.5, 0.6, 0.2]], [[0.5, 0.5, 0.9]] * 2, 100_000, width=8, height=6)

    class First(Exception):
        pass

    def first(*args, **kwargs):
        raise First

    monkeypatch.setattr(walks, "write_image", first)
    t = time.perf_counter()
    with pytest.raises(First):
        walks.walk(scene, path, form_factors=F, objects=[track], output=tmp_path, local_size=24, progress=False)
    assert time.perf_counter() - t < 15.0
