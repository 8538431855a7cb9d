"""Large scenes: precompute a village's form-factor store, then walk through it streaming rows.

    python bench/largescale.py --quick        # village(detail=2): about 128,000 patches
    python bench/largescale.py                # village(detail=20): about 1,100,000 patches

Stages (each reported with wall-clock times on this machine):

1. scene: ``pydynrad.scenes.village(detail=D)``; N patches.
2. throughput: ``--sample-blocks`` blocks of the store computed with 1 worker and with 2
   workers (LocalCluster, spawned processes, own OpenCL context each), rows per second,
   cluster start-up included (it is part of what a user waits for).
3. store: the whole store with ``--workers`` workers, resuming whatever ``--store`` holds:
   time and rows/s of this run, bytes on disk, bytes per patch, non-zeros per row.
   ``--max-minutes`` caps this stage (the store stays resumable: run again to finish it).
4. walk: a DynamicRadiosity walk (M = ``--local-size``, exact update, fp32 K) along a
   street, fed from the store through a :class:`~pydynrad.rows.cache.RowCache` smaller than
   the store, prefetching the next candidates, with the far field off (the paper's method) and
   on (the store's clusters and G: left in the store and read per light change, and held on the
   device as before 2026-12-02, ``--far-g``); and the same walk fed from F in memory when F fits in a
   quarter of RAM. Each walk runs in its own process, so its peak RSS is its own (the
   target: the far field on within 1.5x of it off).

With ``--far-field`` (the default) the store also holds the far field's G = F Pr for
``clusters_without_f(scene)`` (N/8 clusters inside the light components of the store's F;
the linear basis: 3C columns), from cluster-id
hemicubes at ``--cluster-resolution`` (default: F's resolution), computed with F by the same
workers; the precompute stage reports G's time against F's.

Writes ``bench/results/<device-slug>/largescale-<size>.{json,md}`` (whole files: temp + rename).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

if not __package__:  # run as a script (python bench/largescale.py): the repo root holds the bench package
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench.report import device_dir, write_index  # noqa: E402

SIZES = {"quick": {"detail": 2.0, "frames": 40}, "full": {"detail": 20.0, "frames": 30}}


def village_spec(detail: float):
    from pydynrad.precompute.distributed import SceneSpec

    return SceneSpec("village", {"detail": detail})


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def rss_mib() -> float:
    import psutil

    return psutil.Process().memory_info().rss / 2**20


def walk_path(scene, frames: int, step: float) -> np.ndarray:
    """Eye positions 1.7 m above the ground along the village's longer horizontal axis (y is up)."""
    lo, hi = scene.bbox.astype(np.float64)
    axis = 0 if hi[0] - lo[0] >= hi[2] - lo[2] else 2
    start = lo + 0.25 * (hi - lo)
    start[1] = lo[1] + 1.7
    eyes = np.repeat(start[None], frames, axis=0)
    eyes[:, axis] += step * np.arange(frames)
    return eyes


def run_walk(args) -> dict:
    """One walk in this process (called through the ``_walk`` sub-command); returns its numbers."""
    import pydynrad
    from pydynrad.rows.cache import RowCache
    from pydynrad.rows.sources import CSRRows
    from pydynrad.rows.store import FormFactorStore

    spec = village_spec(args.detail)
    scene = spec.build()
    store = FormFactorStore.open(scene, args.store, resolution=args.resolution, patching=spec.recipe())
    base = rss_mib()
    cache = None
    if args.source == "memory":
        source = CSRRows(store.to_csr())
    else:
        source = cache = RowCache(store, max_bytes=int(args.cache_mib * 2**20))
    loaded = rss_mib()
    t0 = time.perf_counter()
    # --far-g held: the store's G read whole onto the device (before 2026-12-02, G stayed in the store).
    G = store.cluster_form_factors() if args.walk_far_field == "on" and args.far_g == "held" else None
    dyn = pydynrad.DynamicRadiosity(
        scene,
        source,
        local_size=args.local_size,
        update="exact",
        storage="fp32",
        max_swaps_per_frame=args.swaps,
        far_field=args.walk_far_field == "on",
        observer=walk_path(scene, 1, args.step)[0],
        cluster_form_factors=G,
    )
    del G
    t_solution = time.perf_counter() - t0
    rss_solution = rss_mib()
    eyes = walk_path(scene, args.frames, args.step)
    times, ff_times, swaps = [], [], []
    t0 = time.perf_counter()
    first = dyn.update(eyes[0])
    t_build = time.perf_counter() - t0
    for eye in eyes[1:]:
        if cache is not None:
            # Prefetch the patches next in line: the nearest ones not yet local.
            near, _ = dyn._select.nearest(eye, args.local_size + 4 * args.swaps)
            cache.prefetch(near[~dyn.local_mask[near]])
        t0 = time.perf_counter()
        st = dyn.update(eye)
        dyn.radiosity()
        times.append(time.perf_counter() - t0)
        ff_times.append(st.t_form_factors)
        swaps.append(st.swaps)
    out = {
        "source": args.source,
        "far_field": args.walk_far_field + (f" ({args.far_g} G)" if dyn.far is not None else ""),
        "N": len(scene),
        "M": args.local_size,
        "frames": len(times),
        "solution_s": t_solution,
        "rss_after_solution_mib": rss_solution,
        "build_s": t_build,
        "build_refreshed": bool(first.refreshed),
        "frame_ms_median": 1e3 * float(np.median(times)),
        "frame_ms_p95": 1e3 * float(np.percentile(times, 95)),
        "rows_ms_median": 1e3 * float(np.median(ff_times)),
        "swaps_per_frame": float(np.mean(swaps)),
        "rss_scene_mib": base,
        "rss_after_source_mib": loaded,
        "peak_rss_mib": peak_rss_mib(),
        "K_mib": dyn.memory_bytes / 2**20 if hasattr(dyn, "memory_bytes") else None,
    }
    if dyn.far is not None:
        out.update(
            C=dyn.far.C,
            G_nnz=dyn.far.G_nnz,
            F_c_nnz=dyn.far.F_c_nnz,
            far_device_mib=dyn.far.device_memory_bytes / 2**20,
            far_host_mib=dyn.far.host_memory_bytes / 2**20,
            far_build_s=dyn.far.seconds_build,
            far_light_s=dyn.far.seconds_light,
            far_coarse_s=dyn.far.seconds_coarse,
        )
    if cache is not None:
        out.update(cache_mib=cache.max_bytes / 2**20, cache_peak_mib=cache.peak_nbytes / 2**20, **cache.stats)
        cache.close()
    return out


def walk_in_subprocess(args, source: str, cache_mib: float, far_field: str = "off", far_g: str = "stored") -> dict:
    cmd = [
        sys.executable,
        __file__,
        "_walk",
        "--source",
        source,
        "--walk-far-field",
        far_field,
        "--far-g",
        far_g,
        "--store",
        str(args.store),
        "--detail",
        str(args.detail),
        "--resolution",
        str(args.resolution),
        "--local-size",
        str(args.local_size),
        "--frames",
        str(args.frames),
        "--step",
        str(args.step),
        "--swaps",
        str(args.swaps),
        "--cache-mib",
        str(cache_mib),
    ]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        return {
            "source": source,
            "far_field": far_field,
            "error": done.stderr.strip().splitlines()[-1] if done.stderr.strip() else "failed",
        }
    return json.loads(done.stdout.strip().splitlines()[-1])


def precompute(args, scene, path: Path, workers: int, blocks=None, clusters=None, compute_f: bool = True) -> float:
    from pydynrad.precompute.distributed import precompute_distributed

    t0 = time.perf_counter()
    precompute_distributed(
        village_spec(args.detail),
        path,
        resolution=args.resolution,
        block_rows=args.block_rows,
        workers=workers,
        blocks=blocks,
        progress=True,
        clusters=clusters,
        cluster_resolution=args.cluster_resolution or args.resolution,
        compute_f=compute_f,
    )
    return time.perf_counter() - t0


def far_field_precompute(args, scene, store, f_numbers: dict) -> dict:
    """Clusters and G into the store (the workers of the F stage), timed against F's rows."""
    from pydynrad.farfield.gather import clusters_without_f

    t0 = time.perf_counter()
    clusters = clusters_without_f(scene, store=store if store.complete else None, progress=True)
    t_clusters = time.perf_counter() - t0
    missing = store.missing_blocks(part="G") if store.has_clusters else range(store.n_blocks)
    secs = precompute(args, scene, args.store, args.workers, clusters=clusters.labels, compute_f=False)
    rows = sum(len(store.block_range(k)) for k in missing)
    f_rate = f_numbers.get("rows_per_s_this_run")
    out = {
        "C": clusters.count,
        "cluster_resolution": args.cluster_resolution or args.resolution,
        "clusters_s": t_clusters,
        "G_rows_this_run": rows,
        "G_s_this_run": secs,
        "G_rows_per_s": rows / secs if rows else None,
        "G_bytes_on_disk": sum(p.stat().st_size for p in (args.store / "gblocks").glob("g*.npz")),
    }
    if rows and f_rate:
        # The target: clusters + G within 20% of F's rows (at G's resolution when they are equal).
        out["clusters_plus_G_over_F"] = (t_clusters + secs) / (rows / f_rate)
    return out


def store_numbers(store) -> dict:
    done = [k for k in range(store.n_blocks) if store.block_path(k).exists()]
    rows = sum(len(store.block_range(k)) for k in done)
    nnz = sum(store.read_block(k).nnz for k in done[:: max(1, len(done) // 64)])
    sampled_rows = sum(len(store.block_range(k)) for k in done[:: max(1, len(done) // 64)])
    return {
        "blocks_done": len(done),
        "blocks": store.n_blocks,
        "rows_done": rows,
        "bytes_on_disk": store.nbytes_on_disk,
        "bytes_per_patch": store.nbytes_on_disk / max(rows, 1),
        "nnz_per_row": nnz / max(sampled_rows, 1),
        "in_memory_bytes_est": rows and (nnz / sampled_rows) * 8 * store.n_patches,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("stage", nargs="?", default="all", choices=["all", "_walk"])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--detail", type=float, help="village detail (patch density); overrides the size's default")
    ap.add_argument("--resolution", type=int, default=16, help="hemicube resolution (top-face pixels per side)")
    ap.add_argument("--block-rows", type=int, default=256)
    ap.add_argument("--sample-blocks", type=int, default=64, help="blocks per throughput measurement")
    ap.add_argument("--workers", type=int, default=2, help="workers for the whole store")
    ap.add_argument("--max-minutes", type=float, default=None, help="stop the whole-store stage after this long")
    ap.add_argument("--store", type=Path, default=None, help="store folder (default: a temporary one, kept)")
    ap.add_argument("--local-size", type=int, default=4096)
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--step", type=float, default=0.5, help="observer step per frame in metres")
    ap.add_argument("--swaps", type=int, default=32, help="max_swaps_per_frame")
    ap.add_argument("--cache-mib", type=float, default=None, help="row cache size (default: a quarter of F's RAM size)")
    ap.add_argument("--source", choices=["store", "memory"], default="store")
    ap.add_argument(
        "--far-field",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="store G beside F and walk with the far field on as well as off",
    )
    ap.add_argument("--cluster-resolution", type=int, default=None, help="G's hemicube resolution (default: F's)")
    ap.add_argument(
        "--walks",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="walk the store once it is complete (--no-walks: precompute only)",
    )
    ap.add_argument(
        "--far-g",
        choices=["stored", "held"],
        default="stored",
        help="the far field's G in its store, read per light change (default), or held on the device",
    )
    ap.add_argument("--walk-far-field", choices=["on", "off"], default="off", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    size = "quick" if args.quick else "full"
    args.detail = args.detail or SIZES[size]["detail"]
    if args.detail != SIZES[size]["detail"]:
        size = f"detail{args.detail:g}"  # its own report: never over the default size's
        SIZES.setdefault(size, {"detail": args.detail, "frames": SIZES["full"]["frames"]})
    args.frames = args.frames or SIZES[size]["frames"]
    if args.stage == "_walk":
        print(json.dumps(run_walk(args)))
        return 0

    from pydynrad.rows.store import FormFactorStore

    report = {
        "size": size,
        "detail": args.detail,
        "resolution": args.resolution,
        "block_rows": args.block_rows,
        "cpu_count": os.cpu_count(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
    }
    t0 = time.perf_counter()
    scene = village_spec(args.detail).build()
    report["scene"] = {"N": len(scene), "build_s": time.perf_counter() - t0}
    print(f"village(detail={args.detail}): {len(scene)} patches", flush=True)
    args.store = args.store or Path(tempfile.mkdtemp(prefix=f"largescale-{size}-")) / "store"

    tp = {}
    sample = list(range(min(args.sample_blocks, -(-len(scene) // args.block_rows))))
    rows = len(scene) if len(sample) * args.block_rows > len(scene) else len(sample) * args.block_rows
    for w in (1, 2):
        # Scratch stores, so a resumed run measures again instead of finding the blocks done.
        path = args.store.parent / f"sample-{w}-workers"
        shutil.rmtree(path, ignore_errors=True)
        secs = precompute(args, scene, path, w, blocks=sample)
        shutil.rmtree(path, ignore_errors=True)
        tp[w] = {"workers": w, "rows": rows, "seconds": secs, "rows_per_s": rows / secs}
        print(f"throughput, {w} worker(s): {rows / secs:.1f} rows/s", flush=True)
    report["throughput"] = list(tp.values())

    todo = FormFactorStore.create(
        scene,
        args.store,
        resolution=args.resolution,
        block_rows=args.block_rows,
        patching=village_spec(args.detail).recipe(),
        exist_ok=True,
    ).missing_blocks()
    if args.max_minutes is not None:
        per_block = tp[2]["seconds"] / len(sample)
        todo = todo[: max(0, int(args.max_minutes * 60 / per_block))]
    rows_todo = sum(len(range(k * args.block_rows, min(len(scene), (k + 1) * args.block_rows))) for k in todo)
    secs = precompute(args, scene, args.store, args.workers, blocks=todo) if todo else 0.0
    store = FormFactorStore.open(
        scene, args.store, resolution=args.resolution, patching=village_spec(args.detail).recipe()
    )
    report["store"] = {
        "path": str(args.store),
        "workers": args.workers,
        "rows_this_run": rows_todo,
        "seconds_this_run": secs,
        "rows_per_s_this_run": rows_todo / secs if secs else None,
        "complete": store.complete,
        **store_numbers(store),
    }
    print(json.dumps(report["store"], indent=1), flush=True)
    if args.far_field:
        report["far_field_precompute"] = far_field_precompute(args, scene, store, report["store"])
        print(json.dumps(report["far_field_precompute"], indent=1), flush=True)

    if store.complete and args.walks:
        f_bytes = report["store"]["in_memory_bytes_est"]
        cache_mib = args.cache_mib or f_bytes / 4 / 2**20
        walks = [walk_in_subprocess(args, "store", cache_mib)]
        if args.far_field:
            walks += [walk_in_subprocess(args, "store", cache_mib, far_field="on", far_g=g) for g in ("stored", "held")]
        import psutil

        if f_bytes < psutil.virtual_memory().total / 4:
            walks.append(walk_in_subprocess(args, "memory", cache_mib))
        report["walks"] = walks
    write_report(report, size)
    return 0


def _table(title: str, rows: list[dict]) -> list[str]:
    if not rows:
        return []
    cols = list(dict.fromkeys(k for r in rows for k in r))
    fmt = lambda v: f"{v:.4g}" if isinstance(v, float) else str(v)  # noqa: E731
    return [
        f"**{title}**",
        "",
        "| " + " | ".join(cols) + " |",
        "|" + "---|" * len(cols),
        *("| " + " | ".join(fmt(r.get(c, "")) for c in cols) + " |" for r in rows),
        "",
    ]


def write_report(report: dict, size: str) -> None:
    import pydynrad
    from pydynrad.atomic import write_atomic

    # The walks ran in sub-processes on the default device: the report goes into its folder.
    report["device"] = pydynrad.default_device().info()
    out = device_dir(report["device"])
    out.mkdir(parents=True, exist_ok=True)
    md = [
        f"# Large scenes ({size}, {report['date']}, {report['device']['device']})",
        "",
        f"village(detail={report['detail']}): N = {report['scene']['N']} patches; hemicube resolution "
        f"{report['resolution']}; blocks of {report['block_rows']} rows; {report['cpu_count']} CPU cores.",
        "",
        *_table("Precompute throughput (cluster start-up included)", report["throughput"]),
        *_table("Store", [report["store"]]),
        *_table("Walks (each in its own process)", report.get("walks", [])),
    ]
    for name, text in (
        (f"largescale-{size}.json", json.dumps(report, indent=1)),
        (f"largescale-{size}.md", "\n".join(md)),
    ):
        write_atomic(out / name, text.encode())
    write_index()


if __name__ == "__main__":
    sys.exit(main())
