import json

import numpy as np
import pytest
from helpers import box_mesh

import pydynrad
from pydynrad import InvalidInputError, Scene
from pydynrad.image_io import read_image
from pydynrad.lights.sources import PointLight, light_vector
from pydynrad.paths import CameraPath, LightTrack, fly_through, load_path, orbit
from pydynrad.renderer import Renderer
from pydynrad.walks import walk


def test_keyframes_are_hit_and_interpolation_is_smooth():
    keys = np.array([[0, 0, 0], [1, 2, 0], [3, 2, 1], [4, 0, 5]], dtype=float)
    look = keys + [0, 0, -1]
    path = CameraPath(keys, look, frames=3 * 4 + 1)  # every 4th frame is a keyframe
    for i, k in enumerate(keys):
        np.testing.assert_allclose(path.camera(4 * i).position, k, atol=1e-12)
        np.testing.assert_allclose(path.camera(4 * i).look_at, look[i], atol=1e-12)
    # Linear interpolation: frame 2 is halfway between keyframes 0 and 1.
    lin = CameraPath(keys, look, frames=13, interpolation="linear")
    np.testing.assert_allclose(lin.camera(2).position, (keys[0] + keys[1]) / 2, atol=1e-12)
    # Catmull-Rom through equally spaced collinear points moves uniformly along the line.
    line = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], dtype=float)
    cr = CameraPath(line, line + [0, 0, -1], frames=7)
    np.testing.assert_allclose([c.position[0] for c in cr], np.linspace(0, 3, 7), atol=1e-12)


def test_orbit_and_fly_through():
    centre = np.array([1.0, 2.0, 3.0])
    path = orbit(centre, radius=5.0, elevation=1.5, frames=8, width=16, height=12, fov_y=30)
    cams = list(path)
    assert len(cams) == 8 and cams[0].width == 16 and cams[0].fov_y == 30
    pos = np.array([c.position for c in cams])
    np.testing.assert_allclose(pos[:, 1], centre[1] + 1.5)  # y is up
    np.testing.assert_allclose(np.linalg.norm((pos - centre)[:, [0, 2]], axis=1), 5.0, rtol=1e-14)
    np.testing.assert_allclose([c.look_at for c in cams], np.repeat(centre[None], 8, 0))
    assert len({tuple(np.round(p, 9)) for p in pos}) == 8  # a full turn without repeating the start
    fly = fly_through([[0, 0, 0], [0, 0, -4], [0, 0, -8]], frames=5, width=8, height=8)
    for cam in fly:
        np.testing.assert_allclose(cam.basis()[2], [0, 0, -1], atol=1e-9)  # looks along the path


def test_light_track_moves_the_light():
    track = LightTrack(PointLight((0, 0, 0), 5.0), [[0, 0, 0], [2, 0, 0]], interpolation="linear")
    assert track.at(0, 3).position == (0.0, 0.0, 0.0)
    assert track.at(1, 3).position == (1.0, 0.0, 0.0)
    assert track.at(2, 3).intensity == (5.0, 5.0, 5.0)
    with pytest.raises(InvalidInputError):
        track.at(3, 3)


def write_json(tmp_path, doc, name="path.json"):
    p = tmp_path / name
    p.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return p


def test_load_path_file(tmp_path):
    doc = {
        "frames": 5,
        "fov_y": 50,
        "width": 40,
        "height": 30,
        "interpolation": "linear",
        "keyframes": [{"position": [0, 0, 5], "look_at": [0, 0, 0]}, {"position": [2, 0, 5], "look_at": [0, 0, 0]}],
        "lights": [
            {"type": "point", "intensity": [1, 2, 3], "keyframes": [[0, 1, 0], [0, 3, 0]]},
            {"type": "point", "intensity": 4, "keyframes": [[1, 1, 1]]},
            {"type": "directional", "direction": [0, -1, 0], "irradiance": 0.5},
        ],
    }
    path, lights = load_path(write_json(tmp_path, doc))
    assert len(path) == 5 and path.camera(0).shape == (30, 40) and path.camera(0).fov_y == 50
    np.testing.assert_allclose(path.camera(2).position, [1, 0, 5])
    assert isinstance(lights[0], LightTrack) and lights[0].at(4, 5).position == (0.0, 3.0, 0.0)
    assert lights[1].position == (1.0, 1.0, 1.0)
    orbit_doc = {"frames": 4, "orbit": {"center": [0, 0, 0], "radius": 2, "elevation": 1}}
    path, lights = load_path(write_json(tmp_path, orbit_doc, "o.json"))
    assert len(path) == 4 and lights == []


@pytest.mark.parametrize(
    "doc, message",
    [
        ("{not json", "not valid JSON"),
        ([1, 2], "top level"),
        ({"keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]}, "missing field 'frames'"),
        ({"frames": 0, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]}, "frames"),
        ({"frames": 2, "keyframes": [{"position": [0, 0, 1]}]}, "keyframe 0: missing field 'look_at'"),
        ({"frames": 2, "keyframes": []}, "keyframes"),
        ({"frames": 2, "keyframes": [{"position": [0, 0], "look_at": [0, 0, 0]}]}, "x, y, z"),
        ({"frames": 2, "width": 0, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]}, "image width"),
        ({"frames": 2, "fov_y": 200, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]}, "fov_y"),
        # Renamed fields are named with their new names, never silently ignored.
        (
            {"frames": 2, "size": [10, 10], "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]},
            "unknown field 'size'.*'size' is now 'width' and 'height'",
        ),
        (
            {"frames": 2, "fov": 50, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]},
            "unknown field 'fov'.*'fov' is now 'fov_y'",
        ),
        ({"frames": 2, "orbit": {"center": [0, 0, 0], "radius": 1, "height": 2}}, "orbit: unknown field 'height'"),
        (
            {"frames": 2, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0], "fov_y": 3}]},
            "keyframe 0: unknown field 'fov_y'",
        ),
        (
            {
                "frames": 2,
                "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}],
                "lights": [
                    {
                        "type": "spot",
                        "intensity": 1,
                        "direction": [0, -1, 0],
                        "inner_angle_deg": 5,
                        "outer_angle_deg": 10,
                        "keyframes": [[0, 1, 0]],
                        "cone": 3,
                    }
                ],
            },
            "light 0: unknown field 'cone'",
        ),
        (
            {
                "frames": 2,
                "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}],
                "lights": [{"type": "spot", "intensity": 1, "direction": [0, -1, 0], "keyframes": [[0, 1, 0]]}],
            },
            "light 0: missing field 'outer_angle_deg'",
        ),
        (
            {"frames": 2, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}], "lights": [{"type": "area"}]},
            "unknown light type",
        ),
        ({"frames": 2, "orbit": {"radius": 1}}, "missing field 'center'"),
        # Fields that would be ignored are refused (the orbit won, the one-keyframe light kept any name).
        (
            {
                "frames": 2,
                "orbit": {"center": [0, 0, 0], "radius": 1},
                "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}],
            },
            "'orbit' or 'keyframes'.*not both",
        ),
        (
            {
                "frames": 2,
                "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}],
                "lights": [{"type": "point", "intensity": 1, "keyframes": [[0, 1, 0]], "interpolation": "bogus"}],
            },
            "light 0: .*bogus",
        ),
    ],
)
def test_bad_path_files_name_the_file_and_the_problem(tmp_path, doc, message):
    p = write_json(tmp_path, doc)
    with pytest.raises(InvalidInputError, match=message) as info:
        load_path(p)
    assert str(p) in str(info.value)


def test_missing_path_file(tmp_path):
    with pytest.raises(InvalidInputError, match="no such file"):
        load_path(tmp_path / "nope.json")


class DirectOnly:
    """A solver with the DynamicRadiosity interface whose radiosity is the direct light L
    (emission + albedo * shadowed irradiance): no local set, so the loop itself is what is tested."""

    def __init__(self, scene, device):
        self.scene, self.device, self.observers = scene, device, []

    def update(self, position):
        self.observers.append(np.array(position))
        return len(self.observers)

    def radiosity(self, lights=()):
        return light_vector(self.scene, lights, device=self.device)


def test_walk_drives_solver_moves_lights_and_writes_frames(device, tmp_path):
    pts, tris = box_mesh(n=4, inward=True)
    scene = Scene(pts, tris, albedo=0.5)
    path = CameraPath(
        [[0.5, 0.5, 0.9], [0.4, 0.6, 0.8]],
        [[0.5, 0.5, 0.0], [0.2, 0.4, 0.0]],
        frames=3,
        width=24,
        height=16,
        fov_y=80,
        interpolation="linear",
    )
    track = LightTrack(PointLight((0.2, 0.8, 0.5), 1.0), [[0.2, 0.8, 0.5], [0.8, 0.8, 0.5]], interpolation="linear")
    solver = DirectOnly(scene, device)
    result = walk(
        scene,
        path,
        solver,
        lights=[track],
        output=tmp_path / "frames",
        image_format="exr",
        keep_images=True,
        progress=False,
        device=device,
    )
    np.testing.assert_allclose(np.array(solver.observers), [c.position for c in path])
    assert [f.stats for f in result.frames] == [1, 2, 3]
    renderer = Renderer(scene, device)
    for k, rec in enumerate(result.frames):
        expect = renderer.render(light_vector(scene, [track.at(k, 3)], device=device), path.camera(k))
        np.testing.assert_allclose(read_image(rec.image_path), expect, rtol=1e-6)
        np.testing.assert_array_equal(result.images[k], expect)
        assert set(rec.seconds) == {"update", "lighting", "render", "write"} and min(rec.seconds.values()) >= 0
    assert not np.allclose(result.images[0], result.images[2])  # the light moved
    t = result.timings()
    assert t["render"].shape == (3,)
    assert "median ms" in result.summary() and "render" in result.summary()


def test_walk_rejects_bad_requests(device):
    pts, tris = box_mesh(n=1)
    scene = Scene(pts, tris)
    path = orbit((0.5, 0.5, 0.5), 0.2, 0.0, frames=2, width=8, height=8, fov_y=60)
    with pytest.raises(InvalidInputError, match="form factors"):
        walk(scene, path, progress=False, device=device)
    with pytest.raises(InvalidInputError, match="reference frame"):
        walk(scene, path, DirectOnly(scene, device), reference_frames=[5], form_factors=np.eye(1), progress=False)
    with pytest.raises(InvalidInputError, match="CameraPath"):
        walk(scene, [path.camera(0)], DirectOnly(scene, device), progress=False)


def test_walk_with_dynamic_radiosity_matches_full_solve_when_local_set_is_everything(device, tmp_path):
    from pydynrad.formfactors import form_factors

    pts, tris = box_mesh(n=2, inward=True)
    scene = Scene(pts, tris, albedo=(0.6, 0.5, 0.4))
    scene = scene.with_materials(emission=np.where(scene.centers[:, 1] > 0.99, 1.0, 0.0))  # a glowing ceiling
    F = form_factors(scene, resolution=16, device=device, progress=False)
    path = orbit((0.5, 0.5, 0.5), 0.3, 0.0, frames=3, width=20, height=16, fov_y=90)
    lights = [LightTrack(PointLight((0.3, 0.5, 0.5), 0.2), [[0.3, 0.5, 0.5], [0.7, 0.5, 0.5]])]
    everything = walk(
        scene,
        path,
        lights=lights,
        form_factors=F,
        local_size=len(scene),
        reference_frames=[0, -1],
        output=tmp_path,
        progress=False,
        device=device,
    )
    assert set(everything.errors()) == {0, 2}
    assert max(everything.errors().values()) < 1e-4  # B = L + P K L with K over all patches is the full solution
    assert (tmp_path / "compare_0002.png").is_file() and (tmp_path / "frame_0001.png").is_file()
    part = walk(
        scene,
        path,
        lights=lights,
        form_factors=F,
        local_size=len(scene) // 3,
        reference_frames=[-1],
        solver_options={"far_field": False},
        progress=False,
        device=device,
    )
    assert part.errors()[2] > 10 * everything.errors()[2]  # patches outside the local set lack indirect light
    far = walk(
        scene,
        path,
        lights=lights,
        form_factors=F,
        local_size=len(scene) // 3,
        reference_frames=[-1],
        output=tmp_path / "far",
        progress=False,
        device=device,
    )
    # The same K gives the paper's answer beside the far field's: recorded and compared side by side.
    assert far.frames[2].local_only_error == pytest.approx(part.errors()[2], rel=1e-6)
    assert far.errors()[2] < part.errors()[2] / 5
    assert "local only (the paper's method)" in far.summary()
    both = read_image(tmp_path / "far" / "compare_0002.png")
    assert both.shape[0] > 2 * 16  # two rows of panels


def test_walk_reading_a_store_equals_walk_reading_the_file(device, tmp_path):
    """The same F as a .npz file and as a store behind a row cache a third of its size: the same
    frames, and the cache's prefetch of the next frame's entering rows is what serves them."""
    from pydynrad.farfield import FarField, cluster_patches
    from pydynrad.farfield.gather import basis_prolongation
    from pydynrad.formfactors import form_factors
    from pydynrad.precompute.store import compute_store
    from pydynrad.rows.files import open_form_factors, save_form_factors
    from pydynrad.rows.sources import CSRRows

    pts, tris = box_mesh(n=4, inward=True)
    scene = Scene(pts, tris, albedo=(0.6, 0.5, 0.4))
    scene = scene.with_materials(emission=np.where(scene.centers[:, 1] > 0.99, 1.0, 0.0))
    F = form_factors(scene, resolution=16, device=device, progress=False)  # hemicube F: not reciprocal
    save_form_factors(scene, tmp_path / "f.npz", F, resolution=16)
    compute_store(
        scene,
        tmp_path / "ff",
        resolution=16,
        block_rows=32,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    path = fly_through([[0.1, 0.5, 0.1], [0.5, 0.5, 0.5], [0.9, 0.5, 0.9]], frames=10, width=20, height=16, fov_y=90)
    lights = [LightTrack(PointLight((0.3, 0.5, 0.5), 0.2), [[0.3, 0.5, 0.5], [0.7, 0.5, 0.5]])]
    # Equal far fields for both (from G, as a store has it: the linear basis; fresh, since the coarse solve starts
    # from the previous one), so only the rows' origin differs.
    clusters = cluster_patches(scene)
    G = F @ basis_prolongation(scene, clusters)
    # tolerance=None: F in memory refines the far field by sweeps, rows from a store do not.
    options = {"storage": "fp64", "max_swaps_per_frame": 4, "tolerance": None}
    cache = open_form_factors(scene, tmp_path / "ff", cache_bytes=CSRRows(F).nbytes // 3)
    walks = {
        name: walk(
            scene,
            path,
            lights=lights,
            form_factors=src,
            local_size=48,
            solver_options={**options, "far_field": FarField(scene, None, clusters, G, device=device)},
            reference_frames=[-1],
            keep_images=True,
            progress=False,
            device=device,
        )
        for name, src in (("file", open_form_factors(scene, tmp_path / "f.npz")), ("store", cache))
    }
    cache.close()
    entering = sum(len(f.stats.added) for f in walks["store"].frames)
    assert entering >= 10  # the local set did move
    for a, b in zip(walks["file"].frames, walks["store"].frames):
        np.testing.assert_array_equal(a.stats.added, b.stats.added)
    # The same rows in the same arithmetic on the same device: bit for bit.
    np.testing.assert_array_equal(walks["store"].radiosity, walks["file"].radiosity)
    for a, b in zip(walks["file"].images, walks["store"].images):
        np.testing.assert_array_equal(b, a)
    assert walks["store"].errors()[9] == walks["file"].errors()[9]
    # Foreground reads: the first frame's M rows; the entering rows were nearly all prefetched.
    assert cache.stats["prefetch_hits"] >= 0.75 * entering and cache.stats["misses"] <= 48 + entering // 4
    assert cache.peak_nbytes <= cache.max_bytes


def test_path_files_track_spot_lights(tmp_path, device):
    """A spot light in a path file moves through its keyframes like a point light (its docstring
    promised it; the parser knew only point and directional) and keeps its cone: a walk with
    the local set holding every patch gives the full solution for the spot at each frame."""
    from pydynrad.formfactors import form_factors
    from pydynrad.lights.sources import SpotLight
    from pydynrad.paths import lights_at

    doc = {
        "frames": 3,
        "width": 12,
        "height": 10,
        "fov_y": 80,
        "keyframes": [{"position": [0.5, 0.5, 0.1], "look_at": [0.5, 0.5, 0.9]}],
        "lights": [
            {
                "type": "spot",
                "direction": [0, -1, 0],
                "intensity": [0.3, 0.2, 0.1],
                "inner_angle_deg": 10.0,
                "outer_angle_deg": 30.0,
                "interpolation": "linear",
                "keyframes": [[0.2, 0.8, 0.5], [0.8, 0.8, 0.5]],
            }
        ],
    }
    path, lights = load_path(write_json(tmp_path, doc))
    (track,) = lights
    assert isinstance(track, LightTrack) and isinstance(track.light, SpotLight)
    cone = float(np.radians(10.0)), float(np.radians(30.0))  # degrees in the file, radians in SpotLight
    expect = [SpotLight((x, 0.8, 0.5), (0, -1, 0), (0.3, 0.2, 0.1), *cone) for x in (0.2, 0.5, 0.8)]
    for k in range(3):
        (spot,) = lights_at(lights, k, 3)
        assert spot == expect[k]
    pts, tris = box_mesh(n=2, inward=True)
    scene = Scene(pts, tris, albedo=(0.6, 0.5, 0.4))
    F = form_factors(scene, resolution=16, device=device, progress=False)
    result = walk(
        scene,
        path,
        lights=lights,
        form_factors=F,
        local_size=len(scene),
        keep_images=True,
        progress=False,
        device=device,
    )
    full = pydynrad.solve(scene, F, lights=[expect[-1]], device=device).radiosity
    assert full.max() > 0 and np.abs(result.radiosity - full).max() < 1e-5 * full.max()
    first = pydynrad.solve(scene, F, lights=[expect[0]], device=device).radiosity
    assert np.abs(first - full).max() > 0.1 * full.max()  # the spot did move


def test_path_file_fields_are_named_and_endless_files_refused(tmp_path):
    """Orbit fields, up and light types of the wrong kind are named (numpy's and Python's own
    messages had come through, an up of zeros blamed the keyframes); /dev/zero is not read."""
    cases = [
        ({"orbit": {"center": [0, 0, 0], "radius": "800"}}, "orbit radius must be one finite number"),
        ({"orbit": {"center": [0, 0, 0], "radius": 8, "elevation": None}}, "orbit elevation"),
        ({"orbit": {"center": [0, 0, 0], "radius": 8, "start_angle": [1, 2]}}, "orbit start_angle"),
        ({"up": [0, 0, 0], "orbit": {"center": [0, 0, 0], "radius": 8}}, "up must be a non-zero vector"),
        ({"up": None, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]}, "up must be a 3-vector"),
        (
            {"keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}], "lights": [{"type": ["point"]}]},
            "unknown light type",
        ),
        ({"frames": 10**40, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]}, "41-digit number"),
    ]
    for doc, message in cases:
        path = tmp_path / "p.json"
        path.write_text(json.dumps({"frames": 2, **doc}))
        with pytest.raises(InvalidInputError, match=message):
            pydynrad.walks.load_walk(path)
    for endless in ("/dev/zero", tmp_path):
        with pytest.raises(InvalidInputError, match="not a regular file"):
            pydynrad.walks.load_walk(endless)
    with pytest.raises(InvalidInputError, match="not a regular file"):
        pydynrad.lights.read_ies("/dev/zero")
