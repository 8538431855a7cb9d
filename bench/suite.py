"""The benchmark suite: every section on the current OpenCL device, one report.

``python -m bench [--quick | --full] [--sections a,b] [--out DIR]`` runs the sections below
at one size and writes ``<out>/<size>.json`` and ``.md`` with PNG plots (:mod:`bench.report`),
``<out>/<size>-<section>-<section>....{json,md}`` when ``--sections`` picks a subset. ``<out>`` is
``bench/results/<device-slug>/`` unless given, and the index ``bench/results/README.md`` is then
rewritten (:func:`bench.report.write_index`). Sections:

=============  ===========================================================================
pathtracer     the reference path tracer: furnace error vs samples, throughput
formfactors    hemicube form factors vs the analytic plates: error and time per R, subdivision;
               ray throughput against Embree in the same run (bench/formfactors.py)
paper          the paper's Fig. 12/15 comparison on the village: naive full radiosity vs the
               dynamic method's lighting and update time, M = 1024 and 4096
accuracy       the trade curve: error vs frame time per M, update mode, storage, resolution,
               against the path-traced reference and the full radiosity solution
dynamic        update kernels vs copy bandwidth, whole frames, accuracy near the observer, and
               the drift of K over many frames (10,000 at --full) (bench/dynamic.py)
bandwidth      lighting product and solver vs copy bandwidth and numpy/SciPy (bench/radiosity.py)
gather         the far field's patch-to-cluster form factors G: error vs hemicube resolution, time
               per row against F's, precompute share (bench/gather.py)
bake           vertex-colour export and lightmap bake of the village: time, texel coverage, seam
               error against render along chart borders (bench/bake.py)
farfield       the far field: error and frame time off and on, over C and M, Cornell box and village
               at night and under a sun (bench/farfield.py)
farstore       the far field without F (stores, rows on demand): indicator vs linear coarse basis over G's
               hemicube resolution, precompute against F's rows (bench/farstore.py)
cie171         the CIE 171:2006 analytic test cases: reference, ours and error per point (bench/cie171.py)
photometry     sensor throughput, the sky term's cost, the hemicube's error near an area emitter (bench/photometry.py)
objects        moving a block through the Cornell box: move cost and error vs the occlusion budget
               (bench/objects.py)
sampling       area-sampled form-factor rows: the built-ins' energy balance (bias and noise) and the
               plates' error vs samples per row and R (bench/sampling.py)
=============  ===========================================================================

Each section is a function ``section(ctx) -> dict`` (title, description, tables, plots; see
:mod:`bench.report`). A failing section is recorded with its error and the rest still run
(``strict=True`` re-raises instead, as the tests do).
"""

from __future__ import annotations

import datetime
import importlib
import platform
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from .report import device_dir, write_index, write_report

__all__ = ["SIZES", "SECTIONS", "Context", "run_suite", "report_name", "main"]

#: Parameters per size; each section reads its own entry ("tiny" is for the tests only). The
#: sections of bench/formfactors.py, bench/dynamic.py, bench/radiosity.py and bench/gather.py keep their own
#: per-size tables (their standalone scripts use them too); an entry here overrides them.
SIZES: dict[str, dict] = {
    "tiny": {
        "pathtracer": {"furnace_subdivisions": 2, "spp": (4, 16, 64), "image": (16, 12), "image_spp": 8},
        "formfactors": {},
        "paper": {"village": {"houses": 1, "detail": 0.25}, "resolution": 16, "M": (64, 128), "frames": 4},
        "accuracy": {
            "max_edge": 250.0,
            "resolutions": (16, 32),
            "M": (48, 96),
            "base_M": 96,
            "frames": 3,
            "ref_spp": 64,
            "image": (24, 18),
        },
        "dynamic": {},
        "bandwidth": {},
        "gather": {},
        "bake": {},
        "farfield": {},
        "farstore": {},
        "cie171": {"resolution": 64, "room_resolution": 32, "room_cell": 0.5},
        "photometry": {
            "cell": 1.0,
            "sensors": 16,
            "resolutions": (16,),
            "sky_resolutions": (8,),
            "distances": (0.1, 1.0),
        },
        "objects": {},
        "sampling": {},
    },
    "quick": {
        "pathtracer": {"furnace_subdivisions": 3, "spp": (4, 16, 64, 256), "image": (64, 48), "image_spp": 64},
        "formfactors": {},
        "paper": {"village": {"houses": 2, "detail": 1.0}, "resolution": 32, "M": (1024,), "frames": 8},
        "accuracy": {
            "max_edge": 100.0,
            "resolutions": (32, 64),
            "M": (256, 512, 768),
            "base_M": 512,
            "frames": 6,
            "ref_spp": 512,
            "image": (64, 48),
        },
        "dynamic": {},
        "bandwidth": {},
        "gather": {},
        "bake": {},
        "farfield": {},
        "farstore": {},
        "cie171": {"resolution": 128, "room_resolution": 64, "room_cell": 0.25},
        "photometry": {
            "cell": 0.25,
            "sensors": 1024,
            "resolutions": (32, 64, 128),
            "sky_resolutions": (32, 64),
            "distances": (0.01, 0.03, 0.1, 0.3, 1.0),
        },
        "objects": {},
        "sampling": {},
    },
    "full": {
        "pathtracer": {
            "furnace_subdivisions": 4,
            "spp": (4, 16, 64, 256, 1024, 4096),
            "image": (320, 240),
            "image_spp": 1024,
        },
        "formfactors": {},
        "paper": {"village": {"houses": 12, "detail": 1.0}, "resolution": 32, "M": (1024, 4096), "frames": 16},
        "accuracy": {
            "max_edge": 50.0,
            "resolutions": (64, 128, 256),
            "M": (1024, 2048, 3072),
            "base_M": 2048,
            "frames": 12,
            "ref_spp": 4096,
            "image": (320, 240),
        },
        "dynamic": {},
        "bandwidth": {},
        "gather": {},
        "bake": {},
        "farfield": {},
        "farstore": {},
        "cie171": {"resolution": 256, "room_resolution": 128, "room_cell": 0.25},
        "photometry": {
            "cell": 0.25,
            "sensors": 4096,
            "resolutions": (32, 64, 128, 256),
            "sky_resolutions": (32, 64, 128),
            "distances": (0.003, 0.01, 0.03, 0.1, 0.3, 1.0),
        },
        "objects": {},
        "sampling": {},
    },
}

#: Section name -> "module:function", in report order.
SECTIONS: dict[str, str] = {
    "pathtracer": "bench.accuracy:pathtracer_section",
    "formfactors": "bench.formfactors:suite_section",
    "paper": "bench.paper:paper_section",
    "accuracy": "bench.accuracy:accuracy_section",
    "dynamic": "bench.dynamic:suite_section",
    "bandwidth": "bench.radiosity:suite_section",
    "gather": "bench.gather:suite_section",
    "bake": "bench.bake:bake_section",
    "farfield": "bench.farfield:farfield_section",
    "farstore": "bench.farstore:farstore_section",
    "cie171": "bench.cie171:cie171_section",
    "photometry": "bench.photometry:photometry_section",
    "objects": "bench.objects:suite_section",
    "sampling": "bench.sampling:suite_section",
    "corpus": "bench.corpus:corpus_section",
    "farfield_corpus": "bench.farfield_corpus:farfield_corpus_section",
}


@dataclass
class Context:
    """What a section gets: its parameters, the device, and a cache shared by sections
    (scenes and form factors are costly and several sections need the same ones)."""

    size: str
    device: object
    progress: bool = True
    cache: dict = field(default_factory=dict)
    section: str = ""
    made_seconds: dict = field(default_factory=dict)  # key -> wall seconds its make() took

    @property
    def params(self) -> dict:
        return SIZES[self.size][self.section]

    def cached(self, key, make):
        """``make()`` once per key for the whole run; ``made_seconds[key]`` is how long it took,
        whichever section asked first (a later section's own timing would see only the lookup)."""
        if key not in self.cache:
            t0 = time.perf_counter()
            self.cache[key] = make()
            self.made_seconds[key] = time.perf_counter() - t0
        return self.cache[key]


def _resolve(spec: str):
    module, func = spec.split(":")
    return getattr(importlib.import_module(module), func)


def run_suite(
    size: str = "quick", sections=None, out_dir=None, device=None, progress: bool = True, strict: bool = False
) -> tuple[dict, dict]:
    """Run the suite and write its report.

    Parameters
    ----------
    size : "tiny" | "quick" | "full"
    sections : iterable of str, optional
        Subset of :data:`SECTIONS` (default: all, in order).
    out_dir : path, optional
        Report folder (default ``bench/results/<device-slug>``, and the index of bench/results is
        rewritten).
    device : pydynrad.device.Device, optional
    progress : bool
        tqdm bars and one status line per section on stderr.
    strict : bool
        Re-raise a section's exception instead of recording it.

    Returns
    -------
    (results, written) : the result dict (see :mod:`bench.report`) and the files written.
    """
    import sys

    import pydynrad

    if size not in SIZES:
        raise ValueError(f"unknown size {size!r}; choose from {', '.join(SIZES)}")
    names = list(SECTIONS) if sections is None else list(sections)
    unknown = [s for s in names if s not in SECTIONS]
    if unknown:
        raise ValueError(f"unknown section(s) {', '.join(unknown)}; choose from {', '.join(SECTIONS)}")
    device = device or pydynrad.default_device()
    info = device.info()
    results = {
        "device": info,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "size": size,
        "host": {
            "machine": platform.machine(),
            "processor": platform.processor(),
            "python": platform.python_version(),
            "pydynrad": pydynrad.__version__,
        },
        "sections": {},
    }
    ctx = Context(size=size, device=device, progress=progress)
    start = time.perf_counter()
    for name in names:
        ctx.section = name
        if progress:
            print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        try:
            body = dict(_resolve(SECTIONS[name])(ctx))
        except Exception as exc:  # recorded in the report; the other sections still run
            if strict:
                raise
            body = {"title": name, "error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(limit=8)}
        body["seconds"] = time.perf_counter() - t0
        results["sections"][name] = body
    results["seconds"] = time.perf_counter() - start
    written = write_report(results, out_dir or device_dir(info), report_name(size, names))
    if out_dir is None:
        write_index()
    return results, written


def report_name(size: str, sections) -> str:
    """The report's file stem: the size, then the sections when they are a subset
    (``"quick"``, ``"quick-dynamic-bandwidth"``), so a partial run never overwrites a whole one."""
    sections = list(sections)
    return size if sections == list(SECTIONS) else "-".join([size, *sections])


def main(argv=None) -> int:
    """Command-line entry point (``python -m bench``; ``pydynrad bench`` calls this too)."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.split("\n\n")[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--quick",
        dest="size",
        action="store_const",
        const="quick",
        help="CI-scale sizes: a few minutes on two CPU cores (default)",
    )
    group.add_argument(
        "--full",
        dest="size",
        action="store_const",
        const="full",
        help="the paper's sizes (village >= 60k patches, M up to 4096, 10,000 drift frames)",
    )
    group.add_argument("--size", choices=list(SIZES), help=argparse.SUPPRESS)
    parser.add_argument("--sections", help=f"comma-separated subset of: {', '.join(SECTIONS)}")
    parser.add_argument("--out", type=Path, default=None, help="report folder (default: bench/results/<device-slug>)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    sections = args.sections.split(",") if args.sections else None
    try:
        results, written = run_suite(args.size or "quick", sections, args.out, progress=not args.no_progress)
    except ValueError as exc:
        parser.error(str(exc))
    failed = [n for n, s in results["sections"].items() if s.get("error")]
    print(f"wrote {written['md']} and {written['json']}")
    for name in failed:
        print(f"section {name} failed: {results['sections'][name]['error']}")
    return 1 if failed else 0
