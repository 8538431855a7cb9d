"""The project's numeric targets, each declared once and read from the benchmark reports.

A :class:`Target` names its words, where its number lives in a report (section, table, column;
see bench/report.py for the report format), the threshold and its direction, and ``extract``:
a small function from the table's rows (dicts keyed by column name) to the measured values.
:func:`evaluate` reads, for each device folder of ``bench/results``, the latest report (by its
``date``) that ran the target's section (at the target's size, where it names one) and says, per
device, the values and whether every one of them meets the threshold. README.md's targets table
(:func:`readme_table`, written by ``python -m bench.report --readme``) and the table at the top of
docs/performance.md (:func:`performance_table`) are made from it, so neither can drift from the
results.

The large-scale runs (``bench/largescale.py``) write their own record instead of a report: a JSON
object with ``date``, ``size`` and a ``walks`` list; a target with ``section="largescale"`` reads
those walks as its rows.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "Target",
    "DeviceResult",
    "TargetResult",
    "TARGETS",
    "NOT_MEASURED",
    "rows_of",
    "evaluate",
    "readme_table",
    "performance_table",
    "README_BEGIN",
    "README_END",
    "replace_readme_table",
]

README_BEGIN = "<!-- targets:begin -->"
README_END = "<!-- targets:end -->"
#: The status of a target no report in bench/results measures.
NOT_MEASURED = "not measured in bench/results"


@dataclass(frozen=True)
class Target:
    """One numeric target. ``extract(rows)`` gives the measured values from the rows of the table
    whose title starts with ``table`` in section ``section``; each must satisfy
    ``value <direction> threshold`` for the target to be met on that device. ``section=None``:
    no benchmark records the number (``why`` says so)."""

    words: str
    section: str | None
    table: str
    column: str
    direction: str  # "<=" or ">="
    threshold: float
    unit: str  # "x", "%" or ""
    extract: Callable[[list], list] | None = None
    size: str | None = None  # the report's size ("quick", "full"); None: the latest of any size
    why: str = ""

    def passes(self, value: float) -> bool:
        return value <= self.threshold if self.direction == "<=" else value >= self.threshold


def _where(column: str, **match):
    """``extract`` reading ``column`` from the rows whose other columns equal ``match`` (a tuple
    value: any of those); keyword names use ``_`` for spaces (``pass_``: column ``pass``)."""

    def extract(rows):
        def ok(row):
            for key, want in match.items():
                got = row.get(key.rstrip("_").replace("_", " "))
                if got not in (want if isinstance(want, tuple) else (want,)):
                    return False
            return True

        return [row[column] for row in rows if ok(row) and row.get(column) is not None]

    return extract


def _percent(extract):
    """The same values as fractions turned into percent."""
    return lambda rows: [100.0 * v for v in extract(rows)]


def _store_peak_ratio(rows):
    """Peak RSS of the far-field walk over the walk without it, from the last pair of walks of
    one run (same ``run`` label) over a store of at least 1,000,000 patches."""
    pairs = {}
    for walk in rows:
        if (walk.get("N") or 0) < 1_000_000 or walk.get("source") != "store" or "run" not in walk:
            continue
        ff = str(walk.get("far_field", ""))
        kind = "off" if ff == "off" else "on" if ff.startswith("on (stored") else None
        if kind:
            pairs.setdefault(walk["run"], {})[kind] = walk["peak_rss_mib"]
    complete = [p for p in pairs.values() if "off" in p and "on" in p]
    return [complete[-1]["on"] / complete[-1]["off"]] if complete else []


_DEFAULT_FAR = {"variant": "far field, C = N/8"}

#: Every target, in the order of README's table.
TARGETS: tuple[Target, ...] = (
    Target(
        "a frame with a moving object (budget 0) within 3x a walk frame, by medians",
        "objects",
        "A moving frame against a walk frame",
        "moving / walk, medians",
        "<=",
        3.0,
        "x",
        _where("moving / walk, medians"),
    ),
    Target(
        "pixel error of a moving-object frame against the full solve <= 2%",
        "objects",
        "A move per frame against the occlusion budget",
        "pixel error vs full",
        "<=",
        2.0,
        "%",
        _percent(_where("pixel error vs full", budget=0, rows=("static F", "static F, 64-patch block"))),
    ),
    Target(
        "form factors' hemicube rays >= 2x Embree",
        "formfactors",
        "Ray throughput",
        "form_factors_over_embree",
        ">=",
        2.0,
        "x",
        _where("form_factors_over_embree"),
    ),
    Target(
        "exact update of 8 swaps within 1.5x of its memory bound (M = 1,024, fp16 and fp32)",
        "dynamic",
        "Update kernels and lighting product",
        "copy / ours",
        "<=",
        1.5,
        "x",
        _where(
            "copy / ours",
            M=1024,
            storage=("fp16", "fp32"),
            pass_=("exact update, 8 swaps, 3% non-zero", "exact update, 8 swaps, 10% non-zero"),
        ),
    ),
    Target(
        "exact frame >= 400x naive radiosity (M = 1,024, 66k-patch village)",
        "paper",
        "Naive full radiosity vs the dynamic method",
        "update ratio",
        ">=",
        400.0,
        "x",
        _where("update ratio", M=1024, update=("exact", "exact + far field")),
        size="full",
    ),
    Target(
        "exact frame >= 100x naive radiosity (M = 4,096, 66k-patch village)",
        "paper",
        "Naive full radiosity vs the dynamic method",
        "update ratio",
        ">=",
        100.0,
        "x",
        _where("update ratio", M=4096, update=("exact", "exact + far field")),
        size="full",
    ),
    Target(
        "lighting product within 1.2x of the copy bound (M = 1,024)",
        "dynamic",
        "Update kernels and lighting product",
        "copy / ours",
        "<=",
        1.2,
        "x",
        _where("copy / ours", M=1024, pass_="lighting K x"),
    ),
    Target(
        "full solve's sparse product within 1.5x of the copy bound",
        "paper",
        "Naive full radiosity's SpMV vs the copy bound",
        "copy / its SpMV",
        "<=",
        1.5,
        "x",
        _where("copy / its SpMV"),
        size="full",
    ),
    Target(
        "multibounce build (float32) within 1.2x of `numpy.linalg.solve`",
        "bandwidth",
        "Multibounce build",
        "ours / numpy f32",
        "<=",
        1.2,
        "x",
        _where("ours / numpy f32"),
    ),
    Target(
        "demo: first frame <= 0.5 s, no later frame over 3x the median",
        None,
        "",
        "",
        "<=",
        0.5,
        "",
        why="no benchmark records the demo's frame times",
    ),
    Target(
        "far field (C = N/8): all-patch error <= 1%",
        "farfield",
        "Error against the full solve",
        "all %",
        "<=",
        1.0,
        "%",
        _where("all %", **_DEFAULT_FAR),
    ),
    Target(
        "far field (C = N/8): mean pixel error <= 2%",
        "farfield",
        "Error against the full solve",
        "pixels %",
        "<=",
        2.0,
        "%",
        _where("pixels %", **_DEFAULT_FAR),
    ),
    Target(
        "frame with static lights <= 1.3x the local-only frame",
        "farfield",
        "Error against the full solve",
        "x local-only frame",
        "<=",
        1.3,
        "x",
        _where("x local-only frame", **_DEFAULT_FAR),
    ),
    Target(
        "light change <= 3x a local-only lighting product plus the coarse solve",
        "farfield",
        "Light changes of the default far field",
        "(change - coarse) / local lighting",
        "<=",
        3.0,
        "x",
        _where("(change - coarse) / local lighting"),
    ),
    Target(
        "far-field precompute <= 20% of the form factors' time",
        "farfield",
        "Error against the full solve",
        "precompute % of F",
        "<=",
        20.0,
        "%",
        _where("precompute % of F", **_DEFAULT_FAR),
    ),
    Target(
        "a 1,000,000-patch store walked with the far field within 1.5x the peak memory",
        "largescale",
        "walks",
        "peak_rss_mib",
        "<=",
        1.5,
        "x",
        _store_peak_ratio,
        size="full",
    ),
)


@dataclass
class DeviceResult:
    device: str  # the device folder's name
    date: str
    report: str  # path under bench/results
    values: list
    met: bool


@dataclass
class TargetResult:
    target: Target
    devices: list = field(default_factory=list)  # DeviceResult, one per device that measured it

    @property
    def status(self) -> str:
        if not self.devices:
            return NOT_MEASURED
        met = sum(d.met for d in self.devices)
        if met == len(self.devices):
            return "met"
        if met == 0:
            return "not met"
        return f"met on {met} of {len(self.devices)} devices"


def rows_of(report: dict, target: Target) -> list | None:
    """The rows ``target`` reads in ``report`` (dicts keyed by column; a repeated column name keeps
    its first cell), or None where the report lacks the section or the table."""
    if target.section == "largescale":
        walks = report.get("walks")
        return walks if isinstance(walks, list) else None
    sec = (report.get("sections") or {}).get(target.section)
    if not sec:
        return None
    for table in sec.get("tables", []):
        if str(table.get("title", "")).startswith(target.table):
            rows = []
            for row in table["rows"]:
                cells = {}
                for col, value in zip(table["columns"], row):
                    cells.setdefault(col, value)
                rows.append(cells)
            return rows
    return None


def _date_key(date: str) -> str:
    return date.replace(" ", "T")[:19]


def _records(folder: Path):
    """Every JSON object with a string ``date`` under ``folder``, as (path, data), in path order."""
    for path in sorted(folder.rglob("*.json")):
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):  # unreadable or not JSON: not a record
            continue
        if isinstance(data, dict) and isinstance(data.get("date"), str):
            yield path, data


def _has_section(data: dict, target: Target) -> bool:
    if target.size is not None and data.get("size") != target.size:
        return False
    if target.section == "largescale":
        return isinstance(data.get("walks"), list) and "sections" not in data
    return isinstance(data.get("sections"), dict) and target.section in data["sections"]


def evaluate(root=None, targets=TARGETS) -> list[TargetResult]:
    """Each target against the latest report of each device folder under ``root`` (default
    bench/results) that has the target's section (and size), latest by ``date`` (ties: the later
    path). A device whose latest report lacks the table, or whose rows give no value, did not
    measure the target."""
    from bench.report import RESULTS_ROOT

    root = Path(RESULTS_ROOT if root is None else root)
    folders = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name != "tmp")
    records = {folder: list(_records(folder)) for folder in folders}
    results = []
    for target in targets:
        result = TargetResult(target)
        for folder in folders if target.section else ():
            candidates = [
                (_date_key(d["date"]), p.relative_to(root).as_posix(), d)
                for p, d in records[folder]
                if _has_section(d, target)
            ]
            if not candidates:
                continue
            date, rel, data = max(candidates, key=lambda c: c[:2])
            rows = rows_of(data, target)
            values = [float(v) for v in target.extract(rows)] if rows is not None else []
            if values:
                result.devices.append(
                    DeviceResult(folder.name, data["date"], rel, values, all(target.passes(v) for v in values))
                )
        results.append(result)
    return results


def _number(v: float) -> str:
    return f"{v:.0f}" if abs(v) >= 100 else f"{v:.3g}"


def value_range(values, unit: str) -> str:
    """``[0.91, 0.97]`` with unit ``%`` -> ``0.91-0.97%``; one value (or all equal) alone."""
    lo, hi = _number(min(values)), _number(max(values))
    return (lo if lo == hi else f"{lo}-{hi}") + unit


def readme_table(results=None) -> str:
    """README.md's targets table: one line per target (target, status, values over the devices
    that measured it, those devices); no dates (the performance page has them)."""
    results = evaluate() if results is None else results
    lines = ["| target | status | value | device |", "| --- | --- | --- | --- |"]
    for r in results:
        if r.devices:
            value = value_range([v for d in r.devices for v in d.values], r.target.unit)
            devices = ", ".join(f"`{d.device}`" for d in r.devices)
        else:
            value = devices = "—"
        lines.append(f"| {r.target.words} | {r.status} | {value} | {devices} |")
    return "\n".join(lines) + "\n"


def performance_table(results=None) -> list[str]:
    """The targets table of docs/performance.md, one line per target and device, with the date and
    the report each value comes from (markdown lines)."""
    from bench.report import _date_label

    results = evaluate() if results is None else results
    lines = ["| target | device | status | value | run | report |", "|---|---|---|---|---|---|"]
    for r in results:
        if not r.devices:
            why = f" ({r.target.why})" if r.target.why else ""
            lines.append(f"| {r.target.words} | — | {NOT_MEASURED}{why} | — | — | — |")
        for d in r.devices:
            lines.append(
                f"| {r.target.words} | `{d.device}` | {'met' if d.met else 'not met'} | "
                f"{value_range(d.values, r.target.unit)} | {_date_label(d.date)} | `bench/results/{d.report}` |"
            )
    return lines


def replace_readme_table(text: str, table: str) -> str:
    """``text`` with what lies between README_BEGIN and README_END replaced by ``table``."""
    pattern = re.compile(re.escape(README_BEGIN) + r".*?" + re.escape(README_END), re.S)
    if not pattern.search(text):
        raise ValueError(f"no {README_BEGIN} ... {README_END} markers")
    return pattern.sub(lambda _m: f"{README_BEGIN}\n{table}{README_END}", text, count=1)
