import subprocess
import sys

import numpy as np
import pytest
import scipy.sparse as sp

from pydynrad import InvalidInputError, Scene
from pydynrad.cli import build_parser, load_form_factors, main, save_form_factors

from test_render import grid_box


def run_main(argv, capsys):
    """main(argv) -> (exit code, stdout, stderr); argparse's own exits count as exit codes."""
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, *needles):
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], lines[0]


def test_every_option_of_every_subcommand_is_explained():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) == {"info", "demo", "formfactors", "render", "walk", "compare"}
    for name, p in sub.choices.items():
        assert p.description, name
        for action in p._actions:
            assert action.help and len(action.help) > 10, (name, action.dest)
        assert p.format_help().count("\n") > 5


@pytest.mark.parametrize(
    "argv, needles",
    [
        (["render", "nosuch.obj", "-o", "x.png"], ["no such file"]),
        (["render", "not_a_scene", "-o", "x.png"], ["neither a mesh file nor a built-in"]),
        (["render", "cornell_box", "-o", "/no/such/folder/x.png"], ["does not exist"]),
        (["render", "cornell_box", "-o", "x.xyz"], ["extensions"]),
        (["formfactors", "cornell_box", "-o", "f.txt"], [".npz"]),
        (["walk", "cornell_box", "--path", "missing.json"], ["no such file"]),
    ],
)
def test_user_errors_give_one_line(capsys, argv, needles):
    assert_one_line_error(*run_main(argv, capsys)[::2], *needles)


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["render", "cornell_box", "-o", "x.png", "--size", "0x5"], "WIDTHxHEIGHT"),
        (["render", "cornell_box", "-o", "x.png", "--fov", "abc"], "positive number"),
        (["render", "cornell_box", "-o", "x.png", "--position", "1,2"], "three finite numbers"),
        (["render", "cornell_box", "-o", "x.png", "--light", "1,2,3"], "X,Y,Z:R,G,B"),
        (["render", "cornell_box"], "required"),
        (["demo", "--frames", "-3"], "--frames"),
        (["explode"], "invalid choice"),
    ],
)
def test_bad_options_give_one_line(capsys, argv, needle):
    code, _, err = run_main(argv, capsys)
    assert_one_line_error(code, err, needle)


def test_unreadable_mesh(capsys, tmp_path):
    bad = tmp_path / "bad.ply"
    bad.write_bytes(b"ply\nformat nonsense\n\x00\x01\x02")
    code, _, err = run_main(["render", str(bad), "-o", str(tmp_path / "x.png")], capsys)
    assert_one_line_error(code, err, "bad.ply")
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    code, _, err = run_main(["formfactors", str(empty), "-o", str(tmp_path / "f.npz")], capsys)
    assert_one_line_error(code, err, "empty.obj")


def test_errors_through_the_installed_entry_point(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "pydynrad", "render", str(tmp_path / "none.obj"), "-o",
                           str(tmp_path / "x.png")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "no such file" in proc.stderr and "Traceback" not in proc.stderr


def small_scene():
    pts, tris = grid_box(n=1)
    return Scene(pts, tris, albedo=0.5, name="cube")


def test_form_factor_file_round_trip_and_checks(tmp_path, capsys):
    scene = small_scene()
    rng = np.random.default_rng(1)
    F = sp.random(len(scene), len(scene), density=0.3, random_state=rng, format="csr", dtype=np.float32)
    path = save_form_factors(tmp_path / "f.npz", F, scene, resolution=32)
    G, header = load_form_factors(path, scene)
    assert (G != F).nnz == 0 and header["resolution"] == 32 and header["n_patches"] == len(scene)
    assert [p.name for p in tmp_path.iterdir()] == ["f.npz"]  # no temporary left behind
    other = Scene(*grid_box(n=2), name="other")
    with pytest.raises(InvalidInputError, match="another scene geometry"):
        load_form_factors(path, other)
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(InvalidInputError, match="not a pydynrad form-factor file"):
        load_form_factors(junk, scene)
    np.savez(tmp_path / "alien.npz", x=np.zeros(3))
    with pytest.raises(InvalidInputError, match="not a pydynrad form-factor file"):
        load_form_factors(tmp_path / "alien.npz", scene)


def test_demo_runs_reduced_and_writes_readable_images(tmp_path, capsys):
    from pydynrad import read_image

    out = tmp_path / "demo"
    code, stdout, err = run_main(["demo", "--frames", "3", "--size", "40x30", "--max-edge", "250", "--resolution", "8",
                                  "--local-size", "40", "--out", str(out), "--quiet"], capsys)
    assert code == 0, err
    for k in range(3):
        img = read_image(out / f"frame_{k:04d}.png")
        assert img.shape == (30, 40, 3) and np.all(np.isfinite(img)) and img.std() > 0.01
    for k in (0, 2):  # first and last frames carry the full solve and a comparison image
        cmp_img = read_image(out / f"compare_{k:04d}.png")
        assert cmp_img.shape[0] == 30 and cmp_img.shape[1] > 3 * 40 and cmp_img.std() > 0.01
    summary = (out / "summary.txt").read_text()
    for stage in ("update", "lighting", "render", "write", "median ms", "local vs full radiosity at frame 2"):
        assert stage in summary and stage in stdout


def test_formfactors_render_walk_compare_chain(tmp_path, capsys):
    import json

    from pydynrad import read_image

    ff = tmp_path / "cbox.npz"
    small = ["--max-edge", "250"]
    assert run_main(["formfactors", "cornell_box", *small, "--resolution", "8", "-o", str(ff), "--quiet"], capsys)[0] == 0
    code, out, err = run_main(["render", "cornell_box", *small, "--form-factors", str(ff), "--size", "32x24",
                               "--light", "278,400,280:5e4", "-o", str(tmp_path / "r.exr")], capsys)
    assert code == 0, err
    img = read_image(tmp_path / "r.exr")
    assert img.shape == (24, 32, 3) and img.max() > 0
    # The file belongs to this patching only: another one is refused with one clear line.
    code, _, err = run_main(["render", "cornell_box", "--max-edge", "200", "--form-factors", str(ff), "-o",
                             str(tmp_path / "x.png")], capsys)
    assert_one_line_error(code, err, "another scene geometry")
    path = tmp_path / "path.json"
    path.write_text(json.dumps({"frames": 2, "size": [24, 16], "fov": 40, "keyframes": [
        {"position": [278, 273, -800], "look_at": [278, 273, 0]}, {"position": [278, 273, -300], "look_at": [278, 273, 0]}]}))
    code, out, err = run_main(["walk", "cornell_box", *small, "--form-factors", str(ff), "--path", str(path),
                               "--local-size", "20", "--out", str(tmp_path / "w"), "--reference-frames", "-1", "--quiet"],
                              capsys)
    assert code == 0, err
    assert read_image(tmp_path / "w" / "frame_0001.png").shape == (16, 24, 3)
    assert "local vs full radiosity at frame 1" in out
    code, out, err = run_main(["compare", "cornell_box", *small, "--form-factors", str(ff), "--local-size", "20",
                               "--size", "24x16", "-o", str(tmp_path / "c.png")], capsys)
    assert code == 0, err
    assert read_image(tmp_path / "c.png").shape[1] > 3 * 24 and "relative RMS error" in out
