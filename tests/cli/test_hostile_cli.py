"""Hostile command lines: one clear line for every refusal, before any work."""

import numpy as np
import pytest

import pydynrad
from pydynrad.errors import InvalidInputError
from pydynrad.renderer import Renderer


def test_outputs_in_a_folders_place_and_exposures_are_refused_before_any_work(tmp_path, capsys):
    """A folder where the output file goes, or an exposure beyond float32, is one line from the
    CLI before the solve (once: after it, naming the temporary file, or a raw OverflowError);
    `bake --lightmap` writes its mesh before its lightmap, so a refused mesh leaves neither."""
    from helpers import run_main

    (tmp_path / "d.png").mkdir()
    code, _, err = run_main(["render", "cornell_box", "--max-edge", "250", "-o", str(tmp_path / "d.png")], capsys)
    assert code == 2 and "a folder of that name is in the way" in err
    code, _, err = run_main(["render", "cornell_box", "-o", str(tmp_path / "e.png"), "--exposure", "2000"], capsys)
    assert code == 2 and "within +-126 stops" in err and "Traceback" not in err
    # 126 stops times the lamp's radiosity passes float32 in the mesh's embedded 8-bit image
    # only, found after the solve: the lightmap had been written first, then the mesh refused.
    code, _, err = run_main(
        [
            "bake",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "-o",
            str(tmp_path / "k.glb"),
            "--lightmap",
            str(tmp_path / "l.exr"),
            "--exposure",
            "126",
        ],
        capsys,
    )
    assert code == 2 and "overflows float32" in err and not list(tmp_path.glob("[kl].*"))


def test_one_line_errors_for_wrong_types(closed_box_48, closed_box_48_F, device):
    # Each was a raw TypeError or ValueError from numpy on main.
    with pytest.raises(InvalidInputError, match="refresh_tolerance must be a positive number or None; got '1e-4'"):
        pydynrad.DynamicRadiosity(closed_box_48, closed_box_48_F, local_size=8, refresh_tolerance="1e-4", device=device)
    with pytest.raises(pydynrad.errors.SceneFileError, match="path must be a file name .* got NoneType"):
        pydynrad.load(None)
    with pytest.raises(InvalidInputError, match="vertices must be numbers"):
        pydynrad.Scene([["a", "b", "c"]] * 3, [[0, 1, 2]])


def test_bad_pyopencl_ctx_is_one_line(monkeypatch, capsys):
    from helpers import assert_one_line_error, run_main

    monkeypatch.setattr(pydynrad.device.devices, "_default", None)  # the session's device is built already
    monkeypatch.setenv("PYOPENCL_CTX", "9:0")
    code, _, err = run_main(["info"], capsys)  # main: pyopencl's RuntimeError with a traceback
    assert_one_line_error(code, err, "PYOPENCL_CTX='9:0' selects no OpenCL device", "pydynrad info")


@pytest.mark.parametrize(
    "address, why",
    [("tcp://host:port", "invalid literal"), ("host", "missing port"), ("http://host:8786", "unknown address scheme")],
)
def test_malformed_scheduler_is_one_line(tmp_path, capsys, address, why):
    from helpers import assert_one_line_error, run_main

    code, _, err = run_main(
        [
            "formfactors",
            "closed_box",
            "--resolution",
            "8",
            "--quiet",
            "-o",
            str(tmp_path / "ff"),
            "--scheduler",
            address,
        ],
        capsys,
    )  # main: distributed's ValueError, with a traceback
    assert_one_line_error(code, err, f"malformed scheduler address {address!r}", why, "tcp://host:8786")


def test_malformed_scheduler_leaves_no_half_built_client():
    # distributed's Client refuses the address after starting its IO loop; left to the collector,
    # the half-built Client stopped that loop later from a new LocalCluster's loop thread and
    # failed its start (the next test, in some orders of the suite).
    import gc

    from distributed import Client

    from pydynrad.precompute.distributed import _start_client

    with pytest.raises(InvalidInputError, match="missing port"):
        _start_client(None, "host")
    assert not [o for o in gc.get_objects() if isinstance(o, Client)]


def test_worker_dying_at_start_up_is_one_line(tmp_path, capsys):
    import dask
    from helpers import assert_one_line_error, run_main

    die = tmp_path / "die.py"
    die.write_text("import os\nos._exit(3)\n")  # a worker's preload: the process ends before it serves
    with dask.config.set({"distributed.worker.preload": [str(die)]}):
        code, _, err = run_main(
            ["formfactors", "closed_box", "--resolution", "8", "--quiet", "-o", str(tmp_path / "ff"), "--workers", "1"],
            capsys,
        )  # main: RuntimeError('Nanny failed to start.'), a traceback
    assert_one_line_error(code, err, "the local Dask cluster of 1 workers failed to start (Nanny failed to start.)")


def test_oversize_image_is_refused_before_the_solve(monkeypatch, capsys, closed_box_48, device):
    from helpers import assert_one_line_error, run_main

    monkeypatch.setattr(pydynrad.geometry.camera, "available_host_bytes", lambda: 8 * 2**30)  # a 24 GiB machine, in use
    code, _, err = run_main(["render", "cornell_box", "-o", "x.png", "--width", "16384", "--height", "16384"], capsys)
    assert_one_line_error(code, err, "rendering a 16384 x 16384 image needs about 32.0 GiB of host memory; 8.0 GiB")
    camera = pydynrad.Camera((0.5, 0.5, 0.5), (0.5, 0.5, 0.0), width=16384, height=8192)
    with pytest.raises(pydynrad.errors.OutOfMemoryError, match="16384 x 8192 image needs about 16.0 GiB"):
        Renderer(closed_box_48, device).render(np.ones((len(closed_box_48), 3)), camera)
    with pytest.raises(
        pydynrad.errors.OutOfMemoryError, match="path tracing a 16384 x 8192 image needs about 10.0 GiB"
    ):
        pydynrad.path_trace(closed_box_48, camera, spp=1, device=device)


def test_bake_and_store_arguments_are_refused_before_the_solve(tmp_path, capsys, monkeypatch):
    """Values only found after the form factors and the solve (or, for a store, after it was
    half made) are refused by the parser, and an unwritable folder before any work."""
    from helpers import run_main

    bake = ["bake", "parallel_plates", "--resolution", "8", "-o", str(tmp_path / "m.glb")]
    for extra, message in (
        (["--crease-angle", "nan"], "expected a number in 0..180"),
        (["--lightmap", str(tmp_path / "l.exr"), "--padding", "100"], "whole number in 1..64"),
        (["--lightmap", str(tmp_path / "l.exr"), "--texels-per-unit", "1e9"], "texels"),
    ):
        code, out, err = run_main(bake + extra, capsys)
        assert code == 2 and message in err and "solved" not in out, (extra, err)
    code, _, err = run_main(
        [
            "formfactors",
            "parallel_plates",
            "-o",
            str(tmp_path / "store"),
            "--clusters",
            "4",
            "--cluster-resolution",
            "7",
            "--resolution",
            "8",
        ],
        capsys,
    )
    assert code == 2 and "even" in err and not (tmp_path / "store").exists()
    assert not list(tmp_path.iterdir())
    # A folder the process may not write into (root passes permission bits, so it is simulated).
    import pydynrad.atomic as atomic

    monkeypatch.setattr(atomic.os, "access", lambda path, mode, **kw: False)
    code, out, err = run_main(bake, capsys)
    assert code == 2 and "is not writable" in err and "solved" not in out


def test_review_of_the_days_fixes(tmp_path, capsys, device):
    """What a review of this landing's fixes found they had broken, each kept working."""
    from helpers import run_main

    from pydynrad.atomic import write_atomic
    from pydynrad.lights import LuminaireLight, PhotometricDistribution
    from pydynrad.lights.sources import check_radiosity_range

    # A grazing point light of 1e37 W/sr 1 mm over a unit floor: I / r^2 passes float32 before
    # the cosine comes in; the irradiance itself (I cos / r^2 at most 2.4e37) does not.
    plates = pydynrad.scenes.parallel_plates(subdivisions=2)
    for light in (
        pydynrad.PointLight((0.5, 0.5, 0.001), 1e37),
        LuminaireLight((0.5, 0.5, 0.001), PhotometricDistribution.isotropic(1e37)),
    ):
        E = pydynrad.lights.direct_irradiance(plates, [light], device).astype(np.float64)
        assert np.isfinite(E).all() and 1e35 < E.max() < 3.4e38
    # The radiosity bound grows with the albedo: a higher albedo never passes where a lower fails.
    L = np.full((4, 3), 1e33)
    refused = []
    for rho in (0.998, 0.999, 0.9990009, 0.99901, 0.9995, 0.99999):
        try:
            check_radiosity_range(L, np.full((4, 3), rho), np.float32)
            refused.append(False)
        except InvalidInputError:
            refused.append(True)
    assert refused == sorted(refused), refused

    # A write that fails for another file, or is already worded, passes through as it is.
    def other(tmp):
        raise FileNotFoundError(2, "No such file or directory", "/elsewhere/source.png")

    with pytest.raises(FileNotFoundError) as info:
        write_atomic(tmp_path / "x.png", other)
    assert info.value.filename == "/elsewhere/source.png"
    long_name = tmp_path / ("a" * 240 + ".npz")
    write_atomic(long_name, b"data")
    assert long_name.read_bytes() == b"data"
    # The CLI's numbers: whitespace around them is fine, underscores are not.
    code, _, err = run_main(
        [
            "render",
            "cornell_box",
            "--max-edge",
            "250",
            "--resolution",
            "8",
            "--size",
            "16x12",
            "--position",
            "278,\t273,-800",
            "-o",
            str(tmp_path / "c.png"),
        ],
        capsys,
    )
    assert code == 0, err
    code, _, err = run_main(
        [
            "bake",
            "parallel_plates",
            "--resolution",
            "8",
            "-o",
            str(tmp_path / "m.glb"),
            "--lightmap",
            str(tmp_path / "l.exr"),
            "--padding",
            "1_0",
        ],
        capsys,
    )
    assert code == 2 and "whole number in 1..64" in err
    # A scene with no light at all is black for that reason, not the camera's.
    code, _, err = run_main(
        ["render", "parallel_plates", "--resolution", "8", "--size", "16x12", "-o", str(tmp_path / "p.png")], capsys
    )
    assert code == 0 and "the scene has no light" in err
