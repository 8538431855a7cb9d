"""walk(video=...) and `walk --video`: frames through imageio + imageio-ffmpeg (the
`video` extra), MissingExtraError naming the extra when it is absent."""

import json
import sys

import numpy as np
import pytest

import pydynrad
from pydynrad.errors import MissingExtraError
from tests.helpers import run_main


def _walk_setup(device):
    scene = pydynrad.scenes.cornell_box(max_edge=250.0)
    F = pydynrad.form_factors(scene, resolution=8, device=device, progress=False)
    path = pydynrad.CameraPath(
        [[278, 273, -800], [278, 273, -300]], [[278, 273, 0], [278, 273, 300]], 4, width=33, height=25
    )  # odd: padded to even for H.264
    return scene, F, path, [pydynrad.PointLight([278, 450, 280], 0.2)]


def test_walk_writes_a_video_of_its_frames(device, tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")

    scene, F, path, lights = _walk_setup(device)
    result = pydynrad.walk(
        scene,
        path,
        lights=lights,
        form_factors=F,
        video=tmp_path / "w.mp4",
        keep_images=True,
        progress=False,
        device=device,
    )
    reader = imageio_ffmpeg.read_frames(str(tmp_path / "w.mp4"))  # ffmpeg decodes: independent of our writer
    meta = next(reader)
    assert tuple(meta["size"]) == (34, 26)
    frames = [np.frombuffer(f, np.uint8).reshape(26, 34, 3) for f in reader]
    assert len(frames) == 4
    # The frames are the walk's images at its exposure, sRGB-encoded (H.264 is lossy: a loose tolerance).
    from pydynrad.image_io import srgb_encode

    for img, frame in zip(result.images, frames):
        expect = 255 * srgb_encode(img * 2.0**result.exposure)
        assert np.abs(frame[:25, :33].astype(float) - expect).mean() < 12


def test_the_cli_writes_one_too(tmp_path, capsys):
    pytest.importorskip("imageio_ffmpeg")
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
    code, out, err = run_main(
        [
            "walk",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "--quiet",
            "--path",
            str(path),
            "--video",
            str(tmp_path / "w.mp4"),
        ],
        capsys,
    )
    assert code == 0, err
    assert (tmp_path / "w.mp4").stat().st_size > 0 and "wrote" in out and "no --out" not in out


def test_without_the_extra_the_error_names_it(device, tmp_path, monkeypatch):
    scene, F, path, lights = _walk_setup(device)
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if not installed
    with pytest.raises(MissingExtraError, match=r"pydynrad\[video\]") as info:
        pydynrad.walk(
            scene, path, lights=lights, form_factors=F, video=tmp_path / "w.mp4", progress=False, device=device
        )
    assert info.value.extra == "video" and not (tmp_path / "w.mp4").exists()
    with pytest.raises(pydynrad.InvalidInputError, match="must end in"):
        monkeypatch.delitem(sys.modules, "imageio_ffmpeg")
        pytest.importorskip("imageio_ffmpeg")
        pydynrad.walk(scene, path, lights=lights, form_factors=F, video=tmp_path / "w.txt", device=device)
