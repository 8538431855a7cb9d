"""Hemicube form factors: ray throughput against Embree, and accuracy against analytic plates.

``python -m bench.formfactors [--size quick|full|tiny] [--scenes cornell_box,village,stanford_bunny]
[--resolution R] [--rows N] [--out DIR]`` writes ``bench/results/<device-slug>/formfactors.{json,md}``; the suite runs the
same measurement as its "formfactors" section. ``--scenes`` also takes mesh files (any format :func:`pydynrad.load` reads).

Throughput: for a sample of patches of each scene, the hemicube rays that
``kernels/hemicube.cl`` casts (same origins, per-patch rotations and pixel directions,
rebuilt here in numpy) are cast four ways, the four calls taking turns in one loop so that
each sees the same load on the machine:

* ``form_factors(rows=sample)``: the whole pipeline (rays generated on the device and traced in
  tiles of BVH_PACKET rays, run-length scanlines, the host's CSR): the hemicube rays as a user
  gets them;
* ``pydynrad.formfactors.hemicube_runs``: the same without the host's CSR (tracing, run-length
  scanlines and their read-back): the ray tracing alone;
* ``pydynrad.geometry.bvh.cast_rays``: our BVH kernel alone on the explicit rays (validation and upload
  included), BVH_PACKET consecutive rays per work-item as one packet (kernels/bvh.cl
  bvh_closest_packet, one origin per lane);
* Embree (``embreex``, closest hit, driven from Python): the peer to beat.

Each gets the same rays and the same triangles (same_hit_fraction: how often Embree and
cast_rays return the same patch). PoCL runs ours on every compute unit of the device while
embreex casts on one thread, as the comparison is meant; besides rays per wall-clock second the
table gives rays per CPU-second (process user + system time, PoCL's threads included): work per
core, the measure that a loaded machine disturbs least. ``*_cpu_use`` is CPU seconds per wall
second of each call (2 on two idle cores), and ``load_average`` the machine's one-minute load
when the scene's measurement began: other processes take cores from both sides.

The real third-party mesh: ``stanford_bunny`` is the Stanford Bunny (Turk and Levoy 1994, from the
Stanford 3D Scanning Repository, graphics.stanford.edu/data/3Dscanrep: the "bun_zipper"
reconstruction, 35,947 vertices and 69,451 triangles), shipped gzipped as
``bench/data/stanford-bunny.obj.gz``, the copy in the alecjacobson/common-3d-test-models
repository (data/stanford-bunny.obj, exported by Meshlab). The Stanford repository lets the
models be used and redistributed for research with acknowledgement of the source (above); it
asks that they not be used commercially without permission. One open scanned surface: most
of its hemicube rays leave the scene after a short walk, unlike the village's.

BVH build: the native binned-SAH builder on random triangles (the issue's yardstick: 1,000,000
triangles in under 2 s), through ``BVH.build`` as a user calls it.

Accuracy: the plate-to-plate form factor of the unit parallel and perpendicular plates
against Howell's closed forms, per resolution R and subdivision, with the time each took.
"""

from __future__ import annotations

import argparse
import gzip
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pydynrad.scenes.byname import scene_by_name

from .common import time_call

__all__ = [
    "SIZES",
    "BUNNY",
    "bench_scene",
    "hemicube_rays",
    "throughput",
    "bvh_build",
    "accuracy",
    "measure",
    "suite_section",
    "main",
]

#: The Stanford Bunny (see the module docstring for its origin and licence).
BUNNY = Path(__file__).resolve().parent / "data" / "stanford-bunny.obj.gz"

SIZES = {
    "tiny": {
        "bvh_triangles": 100_000,
        "scenes": ("cornell_box",),
        "ray_rows": 16,
        "ray_resolution": 16,
        "resolutions": (16, 32),
        "subdivisions": (2,),
    },
    "quick": {
        "bvh_triangles": 1_000_000,
        "scenes": ("cornell_box", "village", "stanford_bunny"),
        "ray_rows": 200,
        "ray_resolution": 32,
        "resolutions": (16, 32, 64, 128),
        "subdivisions": (1, 2, 3, 4),
    },
    "full": {
        "bvh_triangles": 1_000_000,
        "scenes": ("cornell_box", "village", "stanford_bunny"),
        "ray_rows": 1000,
        "ray_resolution": 64,
        "resolutions": (16, 32, 64, 128, 256, 512),
        "subdivisions": (1, 2, 3, 4, 5),
    },
}


def _hash(x: np.ndarray) -> np.ndarray:
    """kernels/hemicube.cl's hc_hash (lowbias32) in uint32 arithmetic."""
    x = x.astype(np.uint32)
    x ^= x >> np.uint32(16)
    x *= np.uint32(0x7FEB352D)
    x ^= x >> np.uint32(15)
    x *= np.uint32(0x846CA68B)
    x ^= x >> np.uint32(16)
    return x


def hemicube_rays(scene, rows: np.ndarray, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Origins and directions, (len(rows) * 3R * R, 3) float32 each, of the rays that
    ``kernels/hemicube.cl`` casts for these patches, in its (row, scanline, pixel) order."""
    from pydynrad.geometry.scene import SURFACE_OFFSET

    R, H = resolution, resolution // 2
    n = scene.normals[rows].astype(np.float64)
    sg = np.copysign(1.0, n[:, 2])
    a = -1.0 / (sg + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    t0 = np.stack([1 + sg * n[:, 0] ** 2 * a, sg * b, -sg * n[:, 0]], axis=1)
    b0 = np.stack([b, sg + n[:, 1] ** 2 * a, -n[:, 1]], axis=1)
    ang = _hash(rows).astype(np.float64) * (2 * np.pi / 2**32)
    cs, sn = np.cos(ang)[:, None], np.sin(ang)[:, None]
    T, B = cs * t0 + sn * b0, cs * b0 - sn * t0
    c = (np.arange(R) + 0.5) * 2 / R - 1  # pixel centres across a face
    h = (np.arange(H) + 0.5) * 2 / R  # pixel centres up a side
    # Local (tangent, bitangent, normal) coordinates of every pixel, scanline-major.
    top = np.stack(np.broadcast_arrays(c[None, :], c[:, None], 1.0), -1).reshape(-1, 3)
    side = [
        np.stack(np.broadcast_arrays(*comp), -1).reshape(-1, 3)
        for comp in (
            (1.0, c[None, :], h[:, None]),
            (-1.0, -c[None, :], h[:, None]),
            (-c[None, :], 1.0, h[:, None]),
            (c[None, :], -1.0, h[:, None]),
        )
    ]
    local = np.concatenate([top, *side])  # (3R * R, 3)
    d = local[None, :, 0:1] * T[:, None] + local[None, :, 1:2] * B[:, None] + local[None, :, 2:3] * n[:, None]
    o = scene.centers[rows].astype(np.float64) + SURFACE_OFFSET * scene.scale * n
    o = np.broadcast_to(o[:, None], d.shape)
    return o.reshape(-1, 3).astype(np.float32), d.reshape(-1, 3).astype(np.float32)


def _embree(scene):
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    es = rtcore_scene.EmbreeScene()
    TriangleMesh(scene=es, vertices=scene.vertices.astype(np.float32), indices=scene.faces.astype(np.int32))
    return es


def bench_scene(name: str):
    """A scene by name: ``stanford_bunny`` (:data:`BUNNY`, read from the package's gzipped copy),
    else :func:`pydynrad.scenes.byname.scene_by_name` (built-ins and mesh files)."""
    if name != "stanford_bunny":
        return scene_by_name(name)
    from pydynrad import load

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "stanford-bunny.obj"
        path.write_bytes(gzip.decompress(BUNNY.read_bytes()))
        return load(path)


def _cpu_seconds() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)  # every thread of this process, PoCL's included
    return r.ru_utime + r.ru_stime


def _taking_turns(calls: dict, repeats: int) -> dict:
    """{name: (median wall s, median CPU s, last result)}: one untimed call each, then
    ``repeats`` rounds in which every call runs once in turn."""
    results = {name: fn() for name, fn in calls.items()}
    wall = {name: [] for name in calls}
    cpu = {name: [] for name in calls}
    for _ in range(repeats):
        for name, fn in calls.items():
            c, t = _cpu_seconds(), time.perf_counter()
            results[name] = fn()
            wall[name].append(time.perf_counter() - t)
            cpu[name].append(_cpu_seconds() - c)
    return {name: (float(np.median(wall[name])), float(np.median(cpu[name])), results[name]) for name in calls}


def throughput(scene, n_rows: int, resolution: int, device, repeats: int = 3) -> dict:
    """Rays per second of the three ray casters on one scene's hemicube rays."""
    from pydynrad.device.launch import bvh_packet
    from pydynrad.formfactors import form_factors, hemicube_runs
    from pydynrad.geometry.bvh import cast_rays

    rows = np.linspace(0, len(scene) - 1, min(n_rows, len(scene))).astype(np.int32)
    o, d = hemicube_rays(scene, rows, resolution)
    n_rays = len(o)
    t_bvh = time.perf_counter()
    scene.bvh.buffers(device)
    t_bvh = time.perf_counter() - t_bvh
    t_embree_build = time.perf_counter()
    es = _embree(scene)
    t_embree_build = time.perf_counter() - t_embree_build
    load = os.getloadavg()[0]
    t = _taking_turns(
        {
            "form_factors": lambda: form_factors(
                scene, resolution=resolution, rows=rows, device=device, progress=False
            ),
            "hemicube_runs": lambda: sum(
                len(c) for *_, c in hemicube_runs(scene, resolution, rows, device, progress=False)
            ),
            "cast_rays": lambda: cast_rays(scene, o, d, device=device)[0],
            "embree": lambda: np.asarray(es.run(o, d)),
        },
        repeats,
    )
    (ff, ff_cpu, _), (hc, hc_cpu, _) = t["form_factors"], t["hemicube_runs"]
    (ours, ours_cpu, patch_ours), (emb, emb_cpu, patch_emb) = t["cast_rays"], t["embree"]
    return {
        "scene": scene.name,
        "patches": len(scene),
        "rows": len(rows),
        "R": resolution,
        "rays": n_rays,
        "packet": bvh_packet(device),
        "load_average": load,
        "form_factors_rays_per_s": n_rays / ff,
        "hemicube_runs_rays_per_s": n_rays / hc,
        "cast_rays_per_s": n_rays / ours,
        "embree_rays_per_s": n_rays / emb,
        "form_factors_over_embree": emb / ff,
        "hemicube_runs_over_embree": emb / hc,
        "cast_rays_over_embree": emb / ours,
        "form_factors_over_embree_per_cpu_s": emb_cpu / ff_cpu,
        "hemicube_runs_over_embree_per_cpu_s": emb_cpu / hc_cpu,
        "cast_rays_over_embree_per_cpu_s": emb_cpu / ours_cpu,
        "form_factors_cpu_use": ff_cpu / ff,
        "hemicube_runs_cpu_use": hc_cpu / hc,
        "cast_rays_cpu_use": ours_cpu / ours,
        "embree_cpu_use": emb_cpu / emb,
        "same_hit_fraction": float(np.mean(patch_ours == patch_emb)),
        "bvh_upload_s": t_bvh,
        "embree_build_s": t_embree_build,
    }


def bvh_build(n: int, repeats: int = 3) -> dict:
    """Seconds to build the BVH over n random triangles (unit-ish triangles in a 100^3 box)."""
    from pydynrad.geometry.bvh import BVH

    rng = np.random.default_rng(0)
    v = (rng.uniform(0, 100, (n, 1, 3)) + rng.normal(scale=0.3, size=(n, 3, 3))).astype(np.float32)
    t = time_call(lambda: BVH.build(v), repeats=repeats, warmup=0)
    return {
        "triangles": n,
        "median_s": t["median_s"],
        "min_s": t["min_s"],
        "nodes": t["result"].n_nodes,
        "triangles_per_s": n / t["median_s"],
    }


def _howell_parallel(a, b, c):
    X, Y = a / c, b / c
    x1, y1 = np.sqrt(1 + X**2), np.sqrt(1 + Y**2)
    return (2 / (np.pi * X * Y)) * (
        np.log(x1**2 * y1**2 / (x1**2 + y1**2 - 1)) / 2
        + X * y1 * np.arctan(X / y1)
        + Y * x1 * np.arctan(Y / x1)
        - X * np.arctan(X)
        - Y * np.arctan(Y)
    )


def _howell_perpendicular(l, w, h):
    H, W = h / l, w / l
    s = H**2 + W**2
    log = np.log(
        (1 + W**2)
        * (1 + H**2)
        / (1 + s)
        * (W**2 * (1 + s) / ((1 + W**2) * s)) ** (W**2)
        * (H**2 * (1 + s) / ((1 + H**2) * s)) ** (H**2)
    )
    return (W * np.arctan(1 / W) + H * np.arctan(1 / H) - np.sqrt(s) * np.arctan(1 / np.sqrt(s)) + log / 4) / (
        np.pi * W
    )


def accuracy(resolutions, subdivisions, device, samples: int = 1) -> list[dict]:
    """Plate-to-plate error and time per configuration, R and subdivision (``samples`` hemicubes per row)."""
    from pydynrad.formfactors import form_factors
    from pydynrad.scenes.analytic import parallel_plates, perpendicular_plates

    out = []
    for name, make, truth in (
        ("parallel", parallel_plates, _howell_parallel(1, 1, 1)),
        ("perpendicular", perpendicular_plates, _howell_perpendicular(1, 1, 1)),
    ):
        for sub in subdivisions:
            scene = make(subdivisions=sub)
            a = scene.areas.astype(np.float64)
            src, dst = scene.source_face // 2 == 0, scene.source_face // 2 == 1
            for R in resolutions:
                form_factors(
                    scene, resolution=R, rows=[0], samples=samples, device=device
                )  # kernel build outside the timing
                t = time.perf_counter()
                F = form_factors(scene, resolution=R, samples=samples, device=device, progress=False)
                dt = time.perf_counter() - t
                got = float(a[src] @ np.asarray(F[src][:, dst].sum(axis=1)).ravel() / a[src].sum())
                out.append(
                    {
                        "case": name,
                        "subdivisions": sub,
                        "patches": len(scene),
                        "R": R,
                        "samples": samples,
                        "F": got,
                        "truth": float(truth),
                        "rel_error": got / truth - 1,
                        "seconds": dt,
                        "rays_per_s": len(scene) * 3 * R * R / dt,
                    }
                )
    return out


def measure(params: dict, device) -> dict:
    """The section dict (see bench.report) for one parameter set."""
    tp = [
        throughput(bench_scene(name), params["ray_rows"], params["ray_resolution"], device) for name in params["scenes"]
    ]
    acc = accuracy(params["resolutions"], params["subdivisions"], device)
    build = bvh_build(int(params.get("bvh_triangles", 1_000_000)))
    build_cols = ["triangles", "median_s", "min_s", "nodes", "triangles_per_s"]
    tp_cols = [
        "scene",
        "patches",
        "rows",
        "R",
        "rays",
        "packet",
        "load_average",
        "form_factors_rays_per_s",
        "hemicube_runs_rays_per_s",
        "cast_rays_per_s",
        "embree_rays_per_s",
        "form_factors_over_embree",
        "hemicube_runs_over_embree",
        "cast_rays_over_embree",
        "form_factors_over_embree_per_cpu_s",
        "hemicube_runs_over_embree_per_cpu_s",
        "cast_rays_over_embree_per_cpu_s",
        "form_factors_cpu_use",
        "hemicube_runs_cpu_use",
        "cast_rays_cpu_use",
        "embree_cpu_use",
        "same_hit_fraction",
    ]
    acc_cols = ["case", "subdivisions", "patches", "R", "F", "truth", "rel_error", "seconds", "rays_per_s"]
    plots = [
        {
            "name": f"error-{case}",
            "title": f"{case} unit plates: |relative error| vs R",
            "xlabel": "R",
            "ylabel": "|F / F_exact - 1|",
            "xscale": "log",
            "yscale": "log",
            "series": [
                {
                    "label": f"subdivisions {s}",
                    "x": [r["R"] for r in acc if r["case"] == case and r["subdivisions"] == s],
                    "y": [max(abs(r["rel_error"]), 1e-7) for r in acc if r["case"] == case and r["subdivisions"] == s],
                }
                for s in params["subdivisions"]
            ],
        }
        for case in ("parallel", "perpendicular")
    ]
    return {
        "title": "Hemicube form factors",
        "description": (
            "Ray throughput on each scene's hemicube rays (a sample of patches, resolution R), the three "
            "callers taking turns in one loop: the full form_factors pipeline (rays made on the device, traced in "
            "tiles of `packet` rays, CSR on the host), the same without the CSR (hemicube_runs: the tracing and "
            "its read-back), our BVH kernel alone on the explicit rays (cast_rays: "
            "`packet`-ray packets, upload included) and Embree (embreex, closest hit from Python, one thread) on "
            "the same rays; ours use every compute unit. Per wall-clock second and per CPU-second of the process; "
            "*_cpu_use is CPU seconds per wall second (2 on two idle cores), load_average the machine's "
            "one-minute load at the start; same_hit_fraction is how often cast_rays and Embree return the same "
            "patch. stanford_bunny is the Stanford Bunny (Stanford 3D Scanning Repository). Then the unit "
            "plates' form factor against Howell's closed forms."
        ),
        "tables": [
            {"title": "Ray throughput (rays/s)", "columns": tp_cols, "rows": [[r[c] for c in tp_cols] for r in tp]},
            {
                "title": "Accuracy vs the analytic plates",
                "columns": acc_cols,
                "rows": [[r[c] for c in acc_cols] for r in acc],
            },
            {
                "title": "BVH build (native binned SAH, random triangles)",
                "columns": build_cols,
                "rows": [[build[c] for c in build_cols]],
            },
        ],
        "plots": plots,
        "throughput": tp,
        "accuracy": acc,
        "bvh_build": build,
    }


def suite_section(ctx) -> dict:
    """The suite's "formfactors" section: this size's defaults, overridden by the suite's parameters."""
    params = dict(SIZES.get(ctx.size, SIZES["quick"]))
    params.update({k: tuple(v) if isinstance(v, (list, tuple)) else v for k, v in ctx.params.items()})
    return measure(params, ctx.device)


def main(argv=None) -> int:
    import datetime

    import pydynrad

    from .report import device_dir, write_index, write_report

    ap = argparse.ArgumentParser(prog="python -m bench.formfactors", description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", choices=list(SIZES), default="quick")
    ap.add_argument("--scenes", help="comma-separated scene names or mesh files (default: the size's)")
    ap.add_argument("--resolution", type=int, help="hemicube resolution of the throughput rays (default: the size's)")
    ap.add_argument("--rows", type=int, help="patches whose hemicube rays are cast, per scene (default: the size's)")
    ap.add_argument("--out", default=None, help="report folder (default: bench/results/<device-slug>)")
    args = ap.parse_args(argv)
    params = dict(SIZES[args.size])
    if args.scenes:
        params["scenes"] = tuple(args.scenes.split(","))
    if args.resolution:
        params["ray_resolution"] = args.resolution
    if args.rows:
        params["ray_rows"] = args.rows
    device = pydynrad.default_device()
    t0 = time.perf_counter()
    section = measure(params, device)
    results = {
        "device": device.info(),
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "size": args.size,
        "params": {k: list(v) if isinstance(v, tuple) else v for k, v in params.items()},
        "sections": {"formfactors": section},
        "seconds": time.perf_counter() - t0,
    }
    written = write_report(results, args.out or device_dir(results["device"]), "formfactors")
    if args.out is None:
        write_index()
    print("\n".join(str(p) for p in written.values()), file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
