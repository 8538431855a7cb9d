"""The benchmark report: one JSON file with every number and a markdown page with tables and
PNG plots, written next to each other as ``bench/results/<device-slug>/<name>.{json,md}``.

Each device has its own folder (:func:`device_dir`, named by :func:`device_slug` from the OpenCL
device name), so runs on different machines never overwrite or mix with each other;
``bench/results/README.md`` (:func:`write_index`) lists the folders and the dates in each.

A result is plain data, so the JSON is the record and the markdown is a view of it::

    {"device": {...}, "date": "...", "size": "quick", "seconds": 123.4,
     "sections": {name: {"title": str, "description": str, "seconds": float,
                         "tables": [{"title", "columns": [...], "rows": [[...]], "note"}],
                         "plots": [{"name", "title", "xlabel", "ylabel", "xscale", "yscale",
                                    "series": [{"label", "x": [...], "y": [...], "style",
                                                "labels": [...] (optional, one per point)}]}],
                         "error": str (only when the section failed)}}}

Files are written whole (temporary file, then rename), so an interrupted run never leaves a
half-written report behind.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

from pydynrad.atomic import write_atomic

__all__ = [
    "RESULTS_ROOT",
    "slugify",
    "device_slug",
    "device_dir",
    "write_report",
    "write_index",
    "markdown",
    "plot_files",
    "format_value",
    "performance_markdown",
    "write_performance_page",
    "README",
    "write_readme_targets",
]

#: The folder holding one sub-folder of reports per device: bench/results next to this file.
RESULTS_ROOT = Path(__file__).resolve().parent / "results"


def slugify(text: str) -> str:
    """A file-name-safe lower-case slug: ``"pthread / cpu-haswell"`` -> ``"pthread-cpu-haswell"``."""
    slug = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")
    return slug[:80] or "device"


def device_slug(info: dict) -> str:
    """The name of a device's results folder (``Device.info()`` as ``info``): the OpenCL device
    name, then for a PoCL CPU device the CPU its compiler targets (the end of the version's
    ``HSTR: pthread-<triple>-<cpu>``), because cloud CPUs report bare model names that several
    generations share (``"pthread-AMD EPYC"`` is a Zen 2, a Zen 3, a Zen 4 and a Zen 5 here). Where
    LLVM did not know the CPU (``generic``), the host's family from /proc/cpuinfo stands in; where it
    named another generation's CPU and pydynrad replaced the name (``compiler_cpu``: a Zen 4 that
    LLVM 14 calls ``znver3``), the family and model do: ``"pthread-AMD EPYC"`` on ``...-znver2`` ->
    ``"pthread-amd-epyc-znver2"``; on ``...-generic``, family 1Ah -> ``"pthread-amd-epyc-family-1ah"``;
    on ``...-znver3`` replaced, family 19h model 11h -> ``"pthread-amd-epyc-family-19h-11h"``."""
    name = info.get("device") or ""
    match = re.search(r"HSTR:\s*pthread-\S+-(\S+)$", info.get("version") or "")
    if match:
        cpu = match.group(1)
        family = str(info.get("cpu_family") or "")
        if cpu == "generic" and family:
            cpu = "family-" + family.split("/")[0]
        elif info.get("compiler_cpu") and family:
            cpu = "family-" + family.replace("/", "-")
        name = f"{name} {cpu}"
    return slugify(name)


def device_dir(info: dict, root=RESULTS_ROOT) -> Path:
    """``root/<device-slug>``: where the reports of the device ``info`` describes go."""
    return Path(root) / device_slug(info)


def format_value(v) -> str:
    """A table cell: floats to 4 significant digits, None as an em dash."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        if v == 0:
            return "0"
        if 1e-3 <= abs(v) < 1e5:
            return f"{v:.4g}"
        return f"{v:.3e}"
    return str(v)


def _table_md(table: dict) -> list[str]:
    lines = []
    if table.get("title"):
        lines += [f"**{table['title']}**", ""]
    cols = table["columns"]
    lines.append("| " + " | ".join(cols) + " |")
    lines.append("|" + "|".join("---" for _ in cols) + "|")
    for row in table["rows"]:
        lines.append("| " + " | ".join(format_value(v) for v in row) + " |")
    if table.get("note"):
        lines += ["", table["note"]]
    lines.append("")
    return lines


def plot_files(slug: str, results: dict) -> dict[tuple[str, str], str]:
    """File name of every plot, keyed by (section, plot name)."""
    return {
        (sec, p["name"]): f"{slug}-{sec}-{p['name']}.png"
        for sec, body in results["sections"].items()
        for p in body.get("plots", [])
    }


def _draw(plot: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=100)
    try:
        for s in plot["series"]:
            ax.plot(s["x"], s["y"], s.get("style", "o-"), label=s.get("label"))
            for x, y, text in zip(s["x"], s["y"], s.get("labels", ())):
                ax.annotate(str(text), (x, y), textcoords="offset points", xytext=(4, 4), fontsize="x-small")
        ax.set_xscale(plot.get("xscale", "linear"))
        ax.set_yscale(plot.get("yscale", "linear"))
        ax.set_xlabel(plot.get("xlabel", ""))
        ax.set_ylabel(plot.get("ylabel", ""))
        ax.set_title(plot.get("title", ""))
        ax.grid(True, which="both", alpha=0.3)
        if any(s.get("label") for s in plot["series"]):
            ax.legend(fontsize="small")
        fig.tight_layout()
        write_atomic(path, lambda tmp: fig.savefig(tmp, format="png"))
    finally:
        plt.close(fig)


def markdown(results: dict, slug: str) -> str:
    """The markdown page for ``results`` (plots referenced by the names of :func:`plot_files`)."""
    dev = results["device"]
    files = plot_files(slug, results)
    lines = [
        f"# pydynrad benchmarks: {dev.get('device', '?')}",
        "",
        f"Device: {dev.get('platform', '?')} / {dev.get('device', '?')} ({dev.get('type', '?')}, "
        f"{dev.get('compute_units', '?')} compute units). Date: {results['date']}. "
        f"Size: `{results['size']}`. Total time: {format_value(results.get('seconds'))} s. "
        f"Produced by `python -m bench --{results['size']} --sections {','.join(results['sections'])}`.",
        "",
    ]
    for name, sec in results["sections"].items():
        lines += [f"## {sec.get('title', name)}", ""]
        if sec.get("description"):
            lines += [sec["description"], ""]
        if sec.get("error"):
            lines += [f"**This section failed:** `{sec['error']}`", ""]
        for table in sec.get("tables", []):
            lines += _table_md(table)
        for plot in sec.get("plots", []):
            lines += [f"![{plot.get('title', plot['name'])}]({files[(name, plot['name'])]})", ""]
        if "seconds" in sec:
            lines += [f"_Section time: {format_value(sec['seconds'])} s._", ""]
    return "\n".join(lines)


def _json_safe(value):
    """NaN and infinities become None (strict JSON has no spelling for them)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # numpy scalars
        return _json_safe(value.item())
    return value


def write_report(results: dict, out_dir, slug: str) -> dict[str, Path]:
    """Write ``<slug>.json``, ``<slug>.md`` and the PNG plots into ``out_dir``.

    Returns the paths written, keyed ``"json"``, ``"md"`` and ``"png:<section>:<plot>"``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results = _json_safe(results)
    written: dict[str, Path] = {}
    files = plot_files(slug, results)
    for sec, body in results["sections"].items():
        for plot in body.get("plots", []):
            path = out / files[(sec, plot["name"])]
            _draw(plot, path)
            written[f"png:{sec}:{plot['name']}"] = path
    json_path, md_path = out / f"{slug}.json", out / f"{slug}.md"
    write_atomic(json_path, json.dumps(results, indent=1, allow_nan=False).encode())
    write_atomic(md_path, markdown(results, slug).encode())
    written["json"], written["md"] = json_path, md_path
    return written


def _report_dates(folder: Path) -> list[str]:
    """The days (YYYY-MM-DD) of the JSON reports anywhere under ``folder``."""
    days = set()
    for path in folder.rglob("*.json"):
        try:
            date = json.loads(path.read_text()).get("date")
        except (OSError, ValueError, AttributeError):  # not a report (or not readable): no date to list
            continue
        if isinstance(date, str) and re.match(r"\d{4}-\d{2}-\d{2}", date):
            days.add(date[:10])
    return sorted(days)


def write_index(root=RESULTS_ROOT) -> Path:
    """Write ``root/README.md``: one line per device folder with the days of its reports and its
    sub-folders (dated or labelled runs). Returns its path."""
    root = Path(root)
    lines = [
        "# Benchmark results, one folder per device",
        "",
        "Written by `python -m bench` (bench/report.py, `write_index`) after each run: the folder is "
        "the OpenCL device name and the CPU PoCL compiles for, as a slug (`device_slug`), the dates are those of the "
        "JSON reports in it (UTC).",
        "",
    ]
    for folder in sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name != "tmp"):
        dates = _report_dates(folder)
        subs = sorted(p.name for p in folder.iterdir() if p.is_dir())
        line = f"- [`{folder.name}/`]({folder.name}/): {', '.join(dates) or 'no dated report'}"
        if subs:
            line += "; sub-folders " + ", ".join(f"`{s}/`" for s in subs)
        lines.append(line)
    path = root / "README.md"
    write_atomic(path, ("\n".join(lines) + "\n").encode())
    return path


# -- the documentation's performance page ----------------------------------------------------
#: Where ``python -m bench.report --docs`` writes the page: docs/performance.md of this checkout.
PERFORMANCE_PAGE = Path(__file__).resolve().parent.parent / "docs" / "performance.md"


def _reports(folder: Path) -> list[tuple[Path, dict]]:
    """Every benchmark report (a JSON object with ``date`` and ``sections``) under ``folder``,
    in path order; other JSON files (the large-scale runs' own records) are left out."""
    found = []
    for path in sorted(folder.rglob("*.json")):
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):  # unreadable or not JSON: not a report
            continue
        if isinstance(data, dict) and isinstance(data.get("date"), str) and isinstance(data.get("sections"), dict):
            found.append((path, data))
    return found


def _cell(value) -> str:
    """A table cell that cannot break the markdown table: pipes escaped, newlines as spaces."""
    return format_value(value).replace("|", "\\|").replace("\n", " ")


def _date_label(date: str) -> str:
    """``2026-12-06T04:56:05+00:00`` -> ``2026-12-06 04:56 UTC`` (reports are dated in UTC)."""
    return f"{date[:10]} {date[11:16]} UTC" if len(date) >= 16 else date


def performance_markdown(root=RESULTS_ROOT) -> str:
    """The documentation's performance page from the reports under ``root``.

    For each device folder (sorted by name) and each benchmark section a report in it ran
    (``paper``, ``dynamic``, ``farfield``, ...) at each size (``quick``, ``full``), the latest
    run by the report's ``date`` (ties: the later path), labelled with the device, the date and
    the report file; its tables as markdown. The output depends only on the files, so the page
    is the same on every machine."""
    root = Path(root)
    lines = [
        "# Performance",
        "",
        "Generated by `python -m bench.report --docs` from the benchmark reports in `bench/results/` "
        "(one folder per device; `python -m bench` writes them). For each device, the latest run of each "
        "benchmark at each size, labelled with the date it ran (UTC) and the report it comes from. "
        "The devices are OpenCL devices: on CPUs, PoCL's `pthread` device and the CPU its compiler targets.",
        "",
    ]
    from bench.targets import evaluate, performance_table

    lines += [
        "## Targets",
        "",
        "Each target (declared in `bench/targets.py`) against the latest report of each device that ran its "
        "benchmark: met when every value read meets the threshold. README.md's targets table is made from the "
        "same evaluation (`python -m bench.report --readme`).",
        "",
    ]
    lines += performance_table(evaluate(root)) + [""]
    folders = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(".") and p.name != "tmp")
    for folder in folders:
        latest: dict[tuple[str, str], tuple[str, str, Path, dict]] = {}
        for path, report in _reports(folder):
            for name in report["sections"]:
                key = (name, str(report.get("size", "")))
                candidate = (report["date"][:19], path.relative_to(root).as_posix(), path, report)
                if key not in latest or candidate[:2] > latest[key][:2]:
                    latest[key] = candidate
        lines += [f"## `{folder.name}`", ""]
        if not latest:
            lines += ["No benchmark report in this folder.", ""]
            continue
        dev = max(latest.values(), key=lambda c: c[:2])[3].get("device", {})
        lines += [
            f"Device: {dev.get('platform', '?')} / {dev.get('device', '?')} ({dev.get('type', '?')}, "
            f"{dev.get('compute_units', '?')} compute units).",
            "",
        ]
        for (name, size), (_date, rel, _path, report) in sorted(latest.items()):
            sec = report["sections"][name]
            lines += [
                f"### {sec.get('title', name)} ({size})",
                "",
                f"Device `{folder.name}`, run {_date_label(report['date'])}, size `{size}`; "
                f"from `bench/results/{rel}`.",
                "",
            ]
            if sec.get("description"):
                lines += [" ".join(str(sec["description"]).split()), ""]
            if sec.get("error"):
                lines += [f"**This section failed:** `{_cell(sec['error'])}`", ""]
            for table in sec.get("tables", []):
                if table.get("title"):
                    lines += [f"**{_cell(table['title'])}**", ""]
                cols = table["columns"]
                lines.append("| " + " | ".join(_cell(c) for c in cols) + " |")
                lines.append("|" + "|".join("---" for _ in cols) + "|")
                for row in table["rows"]:
                    lines.append("| " + " | ".join(_cell(v) for v in row) + " |")
                lines.append("")
                if table.get("note"):
                    lines += [" ".join(str(table["note"]).split()), ""]
    return "\n".join(lines).rstrip("\n") + "\n"


def write_performance_page(path=PERFORMANCE_PAGE, root=RESULTS_ROOT) -> Path:
    """Write :func:`performance_markdown` of ``root`` to ``path`` (whole, or not at all)."""
    path = Path(path)
    write_atomic(path, performance_markdown(root).encode())
    return path


#: The README whose targets table ``python -m bench.report --readme`` rewrites.
README = Path(__file__).resolve().parent.parent / "README.md"


def write_readme_targets(path=README, root=RESULTS_ROOT) -> Path:
    """Rewrite the targets table between ``<!-- targets:begin -->`` and ``<!-- targets:end -->``
    in ``path`` from the reports under ``root`` (:func:`bench.targets.readme_table`)."""
    from bench.targets import evaluate, readme_table, replace_readme_table

    path = Path(path)
    text = replace_readme_table(path.read_text(), readme_table(evaluate(root)))
    write_atomic(path, text.encode())
    return path


def _main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m bench.report", description="Pages made from the benchmark reports in bench/results."
    )
    parser.add_argument(
        "--docs",
        nargs="?",
        const=str(PERFORMANCE_PAGE),
        metavar="PATH",
        help=f"write the documentation's performance page (default {PERFORMANCE_PAGE})",
    )
    parser.add_argument("--index", action="store_true", help="rewrite bench/results/README.md")
    parser.add_argument(
        "--readme",
        nargs="?",
        const=str(README),
        metavar="PATH",
        help=f"rewrite the targets table in the README (default {README})",
    )
    parser.add_argument("--results", default=str(RESULTS_ROOT), metavar="DIR", help="the results folder")
    args = parser.parse_args(argv)
    if not (args.docs or args.index or args.readme):
        parser.error("nothing to do: give --docs, --index and/or --readme")
    if args.docs:
        print(f"wrote {write_performance_page(args.docs, args.results)}")
    if args.index:
        print(f"wrote {write_index(args.results)}")
    if args.readme:
        print(f"wrote {write_readme_targets(args.readme, args.results)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
