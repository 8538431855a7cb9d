"""The benchmark suite at a tiny size: its report's numbers are finite and its files readable.

Speed is never asserted here (that is what the suite measures); these tests check that the
runner, the sections and the report writer produce a complete, well-formed record.
"""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package lives in the repo root

from bench import report, suite  # noqa: E402


def _numbers(rows):
    for row in rows:
        for v in row:
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                yield v


def _check_report(results: dict, written: dict, sections) -> None:
    import matplotlib.image

    data = json.loads(written["json"].read_text())  # strict JSON: NaN would fail to parse back as a number
    assert data["size"] == results["size"] and list(data["sections"]) == list(sections)
    md = written["md"].read_text()
    for name, sec in data["sections"].items():
        assert "error" not in sec, f"section {name} failed: {sec.get('error')}"
        assert sec["title"] in md
        assert sec["tables"], f"section {name} has no table"
        for table in sec["tables"]:
            assert table["rows"]
            numbers = list(_numbers(table["rows"]))
            assert numbers and all(math.isfinite(v) for v in numbers), (name, table["title"])
        for plot in sec.get("plots", []):
            for s in plot["series"]:
                assert len(s["x"]) == len(s["y"]) and all(math.isfinite(v) for v in s["x"] + s["y"])
    pngs = [p for k, p in written.items() if k.startswith("png:")]
    assert len(pngs) == sum(len(s.get("plots", [])) for s in data["sections"].values())
    for path in pngs:
        img = matplotlib.image.imread(path)
        assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
        assert path.name in md


def test_report_writer_round_trip(tmp_path):
    results = {
        "device": {"platform": "P", "device": "D", "type": "CPU", "compute_units": 2},
        "date": "2026-01-01T00:00:00+00:00",
        "size": "tiny",
        "seconds": 1.5,
        "sections": {
            "demo": {
                "title": "Demo section",
                "description": "words",
                "seconds": 0.5,
                "tables": [{"title": "T", "columns": ["a", "b"], "rows": [[1, 0.125], [2, float("nan")]]}],
                "plots": [
                    {
                        "name": "p",
                        "title": "P",
                        "xlabel": "x",
                        "ylabel": "y",
                        "xscale": "log",
                        "series": [{"label": "s", "x": [1, 10], "y": [np.float32(2.0), 3.0]}],
                    }
                ],
            }
        },
    }
    written = report.write_report(results, tmp_path, "dev-slug")
    data = json.loads(written["json"].read_text())
    assert data["sections"]["demo"]["tables"][0]["rows"] == [[1, 0.125], [2, None]]  # NaN -> null
    md = written["md"].read_text()
    assert "| a | b |" in md and "| 2 | — |" in md and "dev-slug-demo-p.png" in md
    assert written["png:demo:p"].stat().st_size > 1000
    assert not list(tmp_path.glob(".*"))  # no temporaries left behind


def test_slug_and_format():
    assert (
        report.slugify("Portable Computing Language / pthread-Intel(R) Xeon(R)")
        == "portable-computing-language-pthread-intel-r-xeon-r"
    )
    assert report.format_value(0.000123456) == "1.235e-04"
    assert report.format_value(12.3456) == "12.35"
    assert report.format_value(None) == "—"


def test_results_per_device_and_index(tmp_path):
    hstr = "OpenCL 3.0 PoCL HSTR: pthread-x86_64-unknown-linux-gnu-"
    xeon = {"device": "pthread-Intel(R) Xeon(R) Processor", "version": hstr + "rocketlake"}
    epyc = {"device": "pthread-AMD EPYC", "version": hstr + "znver2", "cpu_family": "17h/31h"}
    zen5 = {"device": "pthread-AMD EPYC", "version": hstr + "generic", "cpu_family": "1ah/2h"}
    assert report.device_dir(xeon, tmp_path) == tmp_path / "pthread-intel-r-xeon-r-processor-rocketlake"
    assert report.device_slug(zen5) == "pthread-amd-epyc-family-1ah"
    zen4 = {
        "device": "pthread-AMD EPYC",
        "version": hstr + "znver3",
        "cpu_family": "19h/11h",
        "compiler_cpu": "skylake-avx512 (PoCL's LLVM named it znver3)",
    }
    assert report.device_slug(zen4) == "pthread-amd-epyc-family-19h-11h"
    assert report.device_slug({**zen4, "cpu_family": "19h/1h", "compiler_cpu": None}) == "pthread-amd-epyc-znver3"
    assert report.device_slug({"device": "NVIDIA H200", "version": "OpenCL 3.0 CUDA"}) == "nvidia-h200"
    assert report.device_dir(epyc).parent == report.RESULTS_ROOT
    assert suite.report_name("quick", list(suite.SECTIONS)) == "quick"
    assert suite.report_name("quick", ["dynamic", "paper"]) == "quick-dynamic-paper"
    for info, date, sub in (
        (xeon, "2026-11-23T04:04:19+00:00", "full"),
        (xeon, "2026-12-02 02:10", None),
        (epyc, "2026-12-02T06:00:00", None),
    ):
        folder = report.device_dir(info, tmp_path) / (sub or "")
        folder.mkdir(parents=True, exist_ok=True)
        (folder / f"r{len(list(folder.iterdir()))}.json").write_text(json.dumps({"device": info, "date": date}))
    (tmp_path / "pthread-amd-epyc-znver2" / "notes.json").write_text("not a report")  # skipped, not a crash
    lines = report.write_index(tmp_path).read_text().splitlines()
    assert "- [`pthread-amd-epyc-znver2/`](pthread-amd-epyc-znver2/): 2026-12-02" in lines
    assert (
        "- [`pthread-intel-r-xeon-r-processor-rocketlake/`](pthread-intel-r-xeon-r-processor-rocketlake/): "
        "2026-11-23, 2026-12-02; "
        "sub-folders `full/`"
    ) in lines


def test_pathtracer_section_tiny(tmp_path, device):
    results, written = suite.run_suite("tiny", ["pathtracer"], tmp_path, device=device, progress=False, strict=True)
    _check_report(results, written, ["pathtracer"])
    rows = results["sections"]["pathtracer"]["tables"][0]["rows"]
    # Furnace error at the most samples is below the error at the fewest (Monte Carlo converges).
    assert rows[-1][4] < rows[0][4]


def test_gather_section_tiny(tmp_path, device):
    results, written = suite.run_suite("tiny", ["gather"], tmp_path, device=device, progress=False, strict=True)
    _check_report(results, written, ["gather"])
    errors = results["sections"]["gather"]["tables"][0]["rows"]
    # G's error against the high-resolution reference falls as its resolution grows (both prolongations).
    assert errors[-1][3] > errors[0][3] and errors[-1][4] < errors[0][4] and errors[-1][8] < errors[0][8]


def test_unknown_section_or_size_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="unknown section"):
        suite.run_suite("tiny", ["nope"], tmp_path)
    with pytest.raises(ValueError, match="unknown size"):
        suite.run_suite("huge", None, tmp_path)


def test_cli_writes_report(tmp_path, device):
    assert suite.main(["--size", "tiny", "--sections", "pathtracer", "--out", str(tmp_path), "--no-progress"]) == 0
    assert len(list(tmp_path.glob("*.json"))) == 1 and len(list(tmp_path.glob("*.md"))) == 1


@pytest.mark.slow
def test_whole_suite_tiny(tmp_path, device):
    results, written = suite.run_suite("tiny", None, tmp_path, device=device, progress=False, strict=True)
    _check_report(results, written, list(suite.SECTIONS))


def test_bake_section_tiny(tmp_path, device):
    results, written = suite.run_suite("tiny", ["bake"], tmp_path, device=device, progress=False, strict=True)
    _check_report(results, written, ["bake"])
    bake = results["sections"]["bake"]["tables"][1]["rows"][0]
    # Coverage is a fraction, and the seam error inside charts is below the one at their borders.
    assert 0 < bake[3] < 1 and bake[7] < bake[10]


def test_objects_section_tiny(tmp_path, device):
    results, written = suite.run_suite("tiny", ["objects"], tmp_path, device=device, progress=False, strict=True)
    _check_report(results, written, ["objects"])
    table = results["sections"]["objects"]["tables"][0]
    col = {c: k for k, c in enumerate(table["columns"])}
    err = {(r[col["budget"]], r[col["rows"]]): r[col["max rel. error vs fresh"]] for r in table["rows"]}
    full = {(r[col["budget"]], r[col["rows"]]): r[col["max rel. error vs full"]] for r in table["rows"]}
    # Hemicube rows, every row that may see the block refreshed: the local set built afresh at the final pose.
    assert err[("all", "hemicubes")] < 1e-6 < err[(0, "hemicubes")]  # observed 3e-10
    # Rows from the static F: refreshing rows lowers the error against the full solve (observed
    # 0.0049 -> 0.0024 for 32 rows and for all 50; the far field's own error stays); with the
    # stale rows corrected, every budget gives about what all the rows do (observed 0.0025).
    assert full[(0, "static F, uncorrected")] > 1.5 * max(
        full[(32, "static F, uncorrected")], full[("all", "static F")]
    )
    assert full[(0, "static F")] < 1.05 * full[("all", "static F")]
    # The path's poses precomputed: the rows of a fresh build at each pose, so only the correction's
    # tolerance stays between the two (observed 3.9e-6 against 1.0e-4 on the fly).
    assert err[(0, "static F, stored poses")] < 1e-5 < err[(0, "static F")]
    # The ratio by medians: one row for the tiny block (12 patches), its ratios those of its times.
    (sequence,) = results["sections"]["objects"]["tables"][1]["rows"]
    n, frames, walk_med, walk_min, move_med, move_min, ratio_med, ratio_min = sequence
    assert (n, frames) == (12, 4) and 0 < walk_min <= walk_med and 0 < move_min <= move_med
    assert ratio_med == pytest.approx(move_med / walk_med) and ratio_min == pytest.approx(move_min / walk_min)


@pytest.mark.slow
def test_move_stages_times_every_stage(device):
    """bench/move_stages.py wraps the move's functions by name: each must still exist and run."""
    from bench.move_stages import stages

    for correction in (False, True):
        rows = stages(2, device, correction)
        times = {name: med for name, med, _ in rows}
        assert times["move (t_move)"] > 0 and times["radiosity after the move"] > 0
        assert all(med >= 0 for med in times.values())
        assert times["hidden entries found (candidates' and outside rows)"] > 0
        assert (times.get("radiosity: stale rows corrected", 0) > 0) == correction
