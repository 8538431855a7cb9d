"""README.md's targets table is generated from bench/results by bench/targets.py (never by hand)."""

import re
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the bench package lives in the repo root
from bench.report import README  # noqa: E402
from bench.targets import (  # noqa: E402
    NOT_MEASURED,
    README_BEGIN,
    README_END,
    TARGETS,
    evaluate,
    readme_table,
    replace_readme_table,
    rows_of,
)


def test_readme_table_is_the_generated_one():
    text = README.read_text()
    assert text.count(README_BEGIN) == 1 and text.count(README_END) == 1
    inside = text.split(README_BEGIN, 1)[1].split(README_END, 1)[0]
    assert inside == "\n" + readme_table(), "run `python -m bench.report --readme`"
    assert replace_readme_table(text, readme_table()) == text
    assert len(text.splitlines()) <= 150


def test_one_line_per_target_with_a_status():
    table = readme_table().splitlines()[2:]
    assert len(table) == len(TARGETS)
    for line, target in zip(table, TARGETS):
        status = line.split(" | ")[1]
        assert line.startswith(f"| {target.words} |")
        assert status in ("met", "not met", NOT_MEASURED) or status.startswith("met on ")
    assert not re.search(r"\d{4}-\d{2}-\d{2}", readme_table())  # no dates in the README


def _target(words_start):
    (target,) = [t for t in TARGETS if t.words.startswith(words_start)]
    return target


def _report(section, title, columns, rows, size="quick"):
    return {
        "date": "2026-01-01T00:00:00+00:00",
        "size": size,
        "sections": {section: {"tables": [{"title": title, "columns": columns, "rows": rows}]}},
    }


OBJ_COLS = ["budget", "rows", "pixel error vs full"]
FAR_COLS = ["scene", "variant", "all %", "pixels %", "x local-only frame", "precompute % of F"]
FAR_ROWS = [
    ["Cornell box", "local only (paper)", 16.9, 49.8, 1.0, None],
    ["Cornell box", "far field, C = N/8", 0.47, 0.61, 1.12, 5.4],
    ["village", "far field, C = N/4", 0.18, 0.12, 1.25, 10.4],
    ["village", "far field, C = N/8", 0.30, 0.20, 1.10, 8.8],
]
UPDATE_COLS = ["M", "storage", "pass", "ms", "GB/s of K", "copy / ours"]
UPDATE_ROWS = [
    [1024, "fp16", "exact update, 8 swaps, 3% non-zero", 1.0, 5.9, 4.38],
    [1024, "fp32", "exact update, 8 swaps, 10% non-zero", 1.1, 10.8, 2.41],
    [1024, "fp64", "exact update, 8 swaps, 3% non-zero", 1.1, 21.7, 1.20],
    [4096, "fp32", "exact update, 8 swaps, 3% non-zero", 7.4, 27.1, 0.96],
    [1024, "fp32", "lighting K x", 0.16, 25.1, 1.04],
    [1024, "fp16", "lighting K x", 0.11, 18.1, 1.44],
]
PAPER_COLS = ["M", "update", "K storage", "lighting ratio", "paper", "update ratio", "paper"]
PAPER_ROWS = [
    [1024, "paper", "fp16", 1270.0, 400.0, 51.5, 200.0],
    [1024, "exact", "fp16", 774.0, 400.0, 92.2, 200.0],
    [1024, "exact + far field", "fp16", 675.0, 400.0, 103.9, 200.0],
    [4096, "exact", "fp16", 139.0, 400.0, 21.2, 200.0],
]

# (target, report, the values read by hand from the rows above)
CASES = [
    (
        "a frame with a moving object",
        _report(
            "objects",
            "A moving frame against a walk frame, by medians",
            ["block patches", "moving / walk, medians", "moving / walk, minima"],
            [[48, 2.68, 2.56], [64, 2.99, 3.09]],
        ),
        [2.68, 2.99],
    ),
    (
        "pixel error of a moving-object",
        _report(
            "objects",
            "A move per frame against the occlusion budget",
            OBJ_COLS,
            [
                [0, "static F", 0.0091],
                [0, "static F, uncorrected", 0.078],
                [0, "static F, 64-patch block", 0.0097],
                [32, "static F", 0.0090],
            ],
        ),
        [0.91, 0.97],
    ),
    (
        "form factors' hemicube rays",
        _report(
            "formfactors",
            "Ray throughput (rays/s)",
            ["scene", "form_factors_over_embree", "hemicube_runs_over_embree"],
            [["village", 2.51, 3.03], ["bunny", 2.60, 2.21]],
        ),
        [2.51, 2.60],
    ),
    (
        "exact update of 8 swaps",
        _report("dynamic", "Update kernels and lighting product on one channel of K", UPDATE_COLS, UPDATE_ROWS),
        [4.38, 2.41],
    ),
    (
        "lighting product within 1.2x",
        _report("dynamic", "Update kernels and lighting product on one channel of K", UPDATE_COLS, UPDATE_ROWS),
        [1.04, 1.44],
    ),
    (
        "exact frame >= 400x",
        _report("paper", "Naive full radiosity vs the dynamic method", PAPER_COLS, PAPER_ROWS, "full"),
        [92.2, 103.9],
    ),
    (
        "exact frame >= 100x",
        _report("paper", "Naive full radiosity vs the dynamic method", PAPER_COLS, PAPER_ROWS, "full"),
        [21.2],
    ),
    (
        "full solve's sparse product",
        _report(
            "paper",
            "Naive full radiosity's SpMV vs the copy bound",
            ["N", "copy / SpMV", "copy / its SpMV"],
            [[66154, 2.2, 1.22]],
            "full",
        ),
        [1.22],
    ),
    (
        "multibounce build",
        _report(
            "bandwidth",
            "Multibounce build K = (I - F P)^-1 F (grey)",
            ["M", "ours / numpy f32", "ours / numpy f64"],
            [[512, 1.12, 1.14], [768, 1.07, 1.09]],
        ),
        [1.12, 1.07],
    ),
    (
        "far field (C = N/8): all-patch",
        _report("farfield", "Error against the full solve and time", FAR_COLS, FAR_ROWS),
        [0.47, 0.30],
    ),
    (
        "far field (C = N/8): mean pixel",
        _report("farfield", "Error against the full solve and time", FAR_COLS, FAR_ROWS),
        [0.61, 0.20],
    ),
    (
        "frame with static lights",
        _report("farfield", "Error against the full solve and time", FAR_COLS, FAR_ROWS),
        [1.12, 1.10],
    ),
    (
        "far-field precompute",
        _report("farfield", "Error against the full solve and time", FAR_COLS, FAR_ROWS),
        [5.4, 8.8],
    ),
    (
        "light change <= 3x",
        _report(
            "farfield",
            "Light changes of the default far field (C = N/8)",
            ["scene", "changes", "(change - coarse) / local lighting"],
            [["Cornell box", "dimmed", 4.01], ["village", "moving lights", 26.5]],
        ),
        [4.01, 26.5],
    ),
    (
        "a 1,000,000-patch store",
        {
            "date": "2026-01-01 00:00",
            "size": "full",
            "walks": [
                {"source": "store", "far_field": "off", "N": 1065668, "peak_rss_mib": 2000.0, "run": "1"},
                {"source": "store", "far_field": "on (stored G)", "N": 1065668, "peak_rss_mib": 4000.0, "run": "1"},
                {"source": "store", "far_field": "on (held G)", "N": 1065668, "peak_rss_mib": 8000.0, "run": "2"},
                {"source": "store", "far_field": "off", "N": 1065668, "peak_rss_mib": 2400.0, "run": "3"},
                {"source": "store", "far_field": "on (stored G)", "N": 1065668, "peak_rss_mib": 3000.0, "run": "3"},
                {"source": "store", "far_field": "off", "N": 115146, "peak_rss_mib": 100.0, "run": "4"},
                {"source": "store", "far_field": "on (stored G)", "N": 115146, "peak_rss_mib": 900.0, "run": "4"},
            ],
        },
        [1.25],
    ),
]


@pytest.mark.parametrize("words, report, expected", CASES, ids=[c[0] for c in CASES])
def test_extraction_reads_the_values_by_hand(words, report, expected):
    target = _target(words)
    assert target.extract(rows_of(report, target)) == pytest.approx(expected)


def test_every_measured_target_has_a_case():
    covered = {_target(words).words for words, _, _ in CASES}
    assert covered == {t.words for t in TARGETS if t.section is not None}


def test_latest_report_per_device_decides(tmp_path):
    import json

    target = _target("multibounce build")
    cols = ["M", "ours / numpy f32"]
    old = _report("bandwidth", "Multibounce build", cols, [[512, 1.1]])
    new = _report("bandwidth", "Multibounce build", cols, [[512, 1.3]])
    new["date"] = "2026-02-01T00:00:00+00:00"
    other = _report("paper", "Naive", ["M"], [[1]])
    other["date"] = "2026-03-01T00:00:00+00:00"  # later, but without the section
    (tmp_path / "dev-a" / "sub").mkdir(parents=True)
    (tmp_path / "dev-b").mkdir()
    (tmp_path / "dev-a" / "sub" / "new.json").write_text(json.dumps(new))
    (tmp_path / "dev-a" / "old.json").write_text(json.dumps(old))
    (tmp_path / "dev-a" / "other.json").write_text(json.dumps(other))
    (tmp_path / "dev-b" / "old.json").write_text(json.dumps(old))
    (result,) = evaluate(tmp_path, (target,))
    assert [(d.device, d.values, d.met, d.report) for d in result.devices] == [
        ("dev-a", [1.3], False, "dev-a/sub/new.json"),
        ("dev-b", [1.1], True, "dev-b/old.json"),
    ]
    assert result.status == "met on 1 of 2 devices"
    (empty,) = evaluate(tmp_path, (_target("demo"),))
    assert empty.status == NOT_MEASURED
