"""One table of defaults: every command and function follows pydynrad.defaults,
and docs/guide/defaults.md says the same."""

import inspect
import json
import math
from pathlib import Path

import numpy as np
import pytest

import pydynrad
from pydynrad import defaults
from pydynrad.defaults import auto_exposure, default_local_size
from tests.helpers import run_main

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["cornell_box", "--max-edge", "250", "--resolution", "8", "--quiet"]  # 336 patches


def _parse(argv):
    from pydynrad.cli.main import build_parser

    return build_parser().parse_args(argv)


@pytest.mark.parametrize(
    "argv",
    [
        ["demo"],
        ["walk", "cornell_box", "--path", "p.json"],
        ["compare", "cornell_box", "-o", "c.png"],
        ["render", "cornell_box", "-o", "r.png"],
        ["bake", "cornell_box", "-o", "b.glb"],
    ],
)
def test_the_commands_share_one_set_of_defaults(argv):
    args = _parse(argv)
    assert args.default_resolution == defaults.RESOLUTION == 64
    assert args.exposure == "auto"
    if argv[0] in ("demo", "walk", "compare"):
        assert args.local_size is None  # the rule, printed when used
    if argv[0] in ("compare", "render"):
        assert args.fov_y is None  # DEFAULT_FOV_Y, as in path files
    assert _parse(["formfactors", "cornell_box", "-o", "f"]).resolution == defaults.RESOLUTION


def test_the_functions_share_them():
    from pydynrad.paths import CameraPath, fly_through, orbit
    from pydynrad.precompute.poses import precompute_poses, stored_poses

    sig = lambda f, name: inspect.signature(f).parameters[name].default  # noqa: E731
    assert sig(pydynrad.form_factors, "resolution") == sig(pydynrad.DynamicRadiosity, "resolution") == 64
    assert sig(precompute_poses, "resolution") == sig(stored_poses, "resolution") == 64
    assert sig(pydynrad.illuminance, "resolution") == 64 and sig(pydynrad.illuminance, "emitters") == "auto"
    assert sig(pydynrad.DynamicRadiosity, "local_size") is None and sig(pydynrad.walk, "local_size") is None
    assert sig(pydynrad.walk, "exposure") == "auto"
    assert sig(orbit, "fov_y") == sig(fly_through, "fov_y") == CameraPath.fov_y == defaults.FOV_Y == 39.3


def test_path_files_default_to_the_command_line_fov(tmp_path):
    from pydynrad.paths import load_walk

    (tmp_path / "p.json").write_text(
        json.dumps({"frames": 2, "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}]})
    )
    assert load_walk(tmp_path / "p.json").path.fov_y == defaults.FOV_Y
    from pydynrad.cli.main import DEFAULT_FOV_Y

    assert DEFAULT_FOV_Y == defaults.FOV_Y


def test_spot_angles_in_path_files_are_degrees_and_the_radians_keys_warn(tmp_path):
    from pydynrad.paths import load_walk

    def spot(**angles):
        doc = {
            "frames": 2,
            "keyframes": [{"position": [0, 0, 1], "look_at": [0, 0, 0]}],
            "lights": [{"type": "spot", "direction": [0, -1, 0], "intensity": 1, "keyframes": [[0, 1, 0]], **angles}],
        }
        (tmp_path / "p.json").write_text(json.dumps(doc))
        (light,) = load_walk(tmp_path / "p.json").lights
        return light

    light = spot(outer_angle_deg=30, inner_angle_deg=20)
    assert light.outer_angle == pytest.approx(math.pi / 6) and light.inner_angle == pytest.approx(math.pi / 9)
    assert spot(outer_angle_deg=30).inner_angle == pytest.approx(math.pi / 6)  # a hard edge, as spot:outer=30
    with pytest.warns(DeprecationWarning, match="outer_angle_deg"):
        old = spot(outer_angle=0.5, inner_angle=0.25)
    assert (old.outer_angle, old.inner_angle) == (0.5, 0.25)
    with pytest.raises(pydynrad.InvalidInputError, match="not both"):
        spot(outer_angle=0.5, outer_angle_deg=30)


def test_the_local_size_rule_always_leaves_a_far_field():
    assert default_local_size(1128) == 564 and default_local_size(100_000) == 1024
    assert default_local_size(3) == 1 and default_local_size(1) == 1
    assert default_local_size(1000, must_hold=700) == 700
    for n in (2, 10, 336, 1128, 2048, 5000):
        assert n - default_local_size(n) >= n // 2


def test_dynamic_radiosity_takes_the_rule(device):
    scene = pydynrad.scenes.cornell_box(max_edge=250.0)
    F = pydynrad.form_factors(scene, resolution=8, device=device, progress=False)
    dyn = pydynrad.DynamicRadiosity(scene, F, device=device)
    assert dyn.M == len(scene) // 2


def test_auto_exposure_maps_the_log_average_to_middle_grey():
    # A grey image of luminance Y: exposure log2(0.18 / Y); two halves: the geometric mean.
    assert auto_exposure(np.full((4, 4, 3), 0.72)) == pytest.approx(-2.0)
    img = np.zeros((2, 2, 3))
    img[0], img[1] = 0.09, 0.36  # geometric mean 0.18: 0 stops
    assert auto_exposure(img) == pytest.approx(0.0, abs=1e-12)
    img[1, 1] = 0.0  # unlit pixels do not count
    assert auto_exposure(img) == pytest.approx(round(math.log2(0.18 / (0.09**2 * 0.36) ** (1 / 3)), 2))
    # Luminance weights: pure green at Y = 0.7152 * g.
    assert auto_exposure([[0.0, 0.18 / 0.7152, 0.0]]) == pytest.approx(0.0, abs=1e-12)
    # Area weights (patches): the larger patch dominates.
    assert auto_exposure([[0.09] * 3, [0.36] * 3], weights=[1.0, 1.0]) == pytest.approx(0.0, abs=1e-12)
    assert auto_exposure([[0.09] * 3, [0.36] * 3], weights=[0.0, 1.0]) == pytest.approx(-1.0)
    assert auto_exposure(np.zeros((3, 3, 3))) == 0.0


def test_the_docs_table_says_what_the_code_does():
    page = (ROOT / "docs" / "guide" / "defaults.md").read_text()
    assert "defaults" in (ROOT / "docs" / "guide" / "index.md").read_text()
    for text in (
        f"**{defaults.RESOLUTION}**",
        f"min({defaults.LOCAL_SIZE_CAP}, N // 2)",
        f"**{defaults.FOV_Y} degrees**",
        f"**{defaults.WIDTH} x {defaults.HEIGHT}**",
        "**auto**",
        f"{defaults.KEY_VALUE}",
        f"after {defaults.PROGRESS_DELAY:g} s",
    ):
        assert text in page, text


def test_version(capsys):
    code, out, _ = run_main(["--version"], capsys)
    assert code == 0 and out.strip() == f"pydynrad {pydynrad.__version__}"


def test_formfactors_store_computes_in_process_by_default(tmp_path, capsys, monkeypatch):
    import importlib

    cli = importlib.import_module("pydynrad.cli.main")

    def no_dask(*a, **k):
        raise AssertionError("Dask was started")

    monkeypatch.setattr(cli, "precompute_distributed", no_dask)
    code, out, err = run_main(["formfactors", *SMALL, "-o", str(tmp_path / "store")], capsys)
    assert code == 0, err
    assert "this process (no Dask" in out


def test_compare_and_walk_say_what_they_chose(tmp_path, capsys):
    code, out, err = run_main(
        ["compare", *SMALL, "-o", str(tmp_path / "c.png"), "--width", "40", "--height", "30"], capsys
    )
    assert code == 0, err
    assert "local set: 168 of 336 patches" in out and "exposure: " in out
    path = tmp_path / "p.json"
    path.write_text(
        json.dumps(
            {
                "frames": 3,
                "width": 40,
                "height": 30,
                "keyframes": [{"position": [278, 273, -800], "look_at": [278, 273, 0]}],
            }
        )
    )
    code, out, err = run_main(["walk", *SMALL, "--path", str(path)], capsys)
    assert code == 0, err
    assert "no --out: each frame is solved (update + lighting) and timed, not rendered" in out
    assert "nothing rendered" in out and "\nrender " not in out
    code, out, err = run_main(["walk", *SMALL, "--path", str(path), "--out", str(tmp_path / "w")], capsys)
    assert code == 0, err
    assert "exposure: " in out and "\nrender " in out and (tmp_path / "w" / "frame_0002.png").is_file()


def test_walk_without_rendering_times_only_the_solver(device):
    scene = pydynrad.scenes.cornell_box(max_edge=250.0)
    F = pydynrad.form_factors(scene, resolution=8, device=device, progress=False)
    path = pydynrad.CameraPath(
        [[278, 273, -800], [278, 273, 0]], [[278, 273, 0], [278, 273, 400]], 3, width=20, height=16
    )
    light = pydynrad.PointLight([278, 450, 280], 0.2)
    result = pydynrad.walk(scene, path, lights=[light], form_factors=F, render=False, progress=False, device=device)
    assert result.image is None and all(f.seconds["render"] < 1e-3 for f in result.frames)
    assert not result.rendered and "nothing rendered" in result.summary()
    with pytest.raises(pydynrad.InvalidInputError, match="render=False"):
        pydynrad.walk(scene, path, lights=[light], form_factors=F, render=False, keep_images=True, device=device)
    # The auto exposure is fixed once: every frame written with the first lit frame's.
    shown = pydynrad.walk(scene, path, lights=[light], form_factors=F, keep_images=True, progress=False, device=device)
    assert shown.exposure == auto_exposure(shown.images[0])


def test_progress_bars_follow_tqdms_rules(capsys):
    import io
    import time

    from tqdm.auto import tqdm

    from pydynrad.progress import progress_bar

    bar = progress_bar(None, total=3)
    assert isinstance(bar, tqdm) and bar.delay == defaults.PROGRESS_DELAY == 2.0 and not bar.disable
    bar.close()
    assert progress_bar(False, total=3).disable and progress_bar(True, total=3).delay == 0
    # On any stream, not only a terminal: shown once the delay has passed, nothing before.
    quick, slow = io.StringIO(), io.StringIO()
    for _ in progress_bar(None, iterable=range(3), file=quick):
        pass
    assert quick.getvalue() == ""
    for _ in progress_bar(None, iterable=range(3), file=slow, delay=0.05, mininterval=0):
        time.sleep(0.04)
    assert "3/3" in slow.getvalue()
