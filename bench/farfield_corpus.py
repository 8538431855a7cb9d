"""The far field on real scenes: its error, its own estimate of it, leaks, popping and
the light change's cost, on the corpus of bench/data/corpus and the built-ins, at default settings.

Per scene (its suggested lights: the corpus.json sun for exteriors, the file's own emitters for
interiors; F at resolution R; M = min(1024, N / 4); the observer walks from the suggested
position), against the full solve of the same F (``pydynrad.solve``, tol 1e-8):

* all-patch relative RMS (area-weighted; and of the reflected light, the emitters' own emission
  left out of the norm, as the estimate measures it), per-pixel relative error of the observer's view (mean,
  median, 99th percentile, capped at 100%), dark patches lit (the full solve under 0.1% of the
  mean, the answer over 1%), for ``tolerance=None`` (the coarse level alone) and the default;
* the estimate against the truth (of the reflected light), on the light change and on every walk frame;
* a light change (the sun turned by 1 degree; for interiors a small lamp near the observer moved
  by 1% of the scene), three in a row (each a new light vector), the fastest, with its parts (the far field's light(), its coarse solve, the
  estimate and sweeps) and one bounce of the full solve with F on the device (``DeviceCSR.bounce``);
* popping: frame-to-frame RMS change of B over the walk with static lights, over the RMS of B;
  a static-light frame (update + radiosity) against the local-only frame;
* for some scenes the same walk with F's rows read from a store on disk (``compute_store`` with
  the section's F and clusters, ``open_form_factors``): F is then not in memory, the estimate
  samples rows on frames, and a light change over the tolerance is refined by passes over the
  store's blocks.

``python -m bench.farfield_corpus [size]`` prints the tables.
"""

from __future__ import annotations

import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

__all__ = ["farfield_corpus_section", "SIZES"]

CORPUS = Path(__file__).resolve().parent / "data" / "corpus"

SIZES = {
    "tiny": {
        "resolution": 16,
        "corpus": ("kenney_retro_urban",),
        "max_edge": {},
        "builtins": False,
        "frames": 3,
        "image": (32, 24),
    },
    "quick": {
        "resolution": 24,
        "corpus": ("veach_ajar", "kenney_retro_urban", "kenney_suburb", "cornell_box"),
        "max_edge": {"cornell_box": 0.1, "kenney_retro_urban": 1.0},
        # The same file again, patched past 100,000 patches: the largest scene of the section.
        "large": {"kenney_suburb": 2.0},
        # Walked again with F's rows from a store on disk (F not in memory).
        "stores": ("veach_ajar", "kenney_suburb", "village at night (built-in)"),
        "builtins": True,
        "frames": 8,
        "image": (96, 64),
    },
    "full": {
        "resolution": 32,
        "corpus": ("veach_ajar", "kenney_retro_urban", "kenney_suburb", "cornell_box"),
        "max_edge": {"cornell_box": 0.05, "kenney_retro_urban": 0.5, "kenney_suburb": 1.5},
        "large": {},
        "builtins": True,
        "frames": 16,
        "image": (160, 120),
    },
}


def _sun(elev_deg: float, azim_deg: float, irradiance: float = 100.0):
    """A sun at ``elev_deg`` above the horizon and azimuth clockwise from north (-z), east +x."""
    from pydynrad import DirectionalLight

    e, a = math.radians(elev_deg), math.radians(azim_deg)
    towards = np.array([math.cos(e) * math.sin(a), math.sin(e), -math.cos(e) * math.cos(a)])
    return DirectionalLight(tuple(-towards), (irradiance,) * 3)


def _corpus_cases(p):
    import pydynrad
    from pydynrad import PointLight

    facts = {s["name"]: s for s in json.loads((CORPUS / "corpus.json").read_text())["scenes"]}
    runs = [(name, name, p["max_edge"].get(name)) for name in p["corpus"]]
    runs += [(f"{name} (max_edge {edge:g})", name, edge) for name, edge in p.get("large", {}).items()]
    for label, name, edge in runs:
        s = facts[name]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = pydynrad.load(CORPUS / s["file"], max_edge=edge)
        obs = s["observer"]
        pos = np.array(obs["position"], float)
        look = np.array(obs["look_at"], float) if "look_at" in obs else pos + np.array(obs["direction"], float)
        light = s["light"]
        if "sun_elevation_deg" in light:
            el, az = light["sun_elevation_deg"], light["sun_azimuth_deg"]
            lights, moved = [_sun(el, az)], [_sun(el + 1.0, az)]
        else:  # the file's emitters, and a small lamp near the observer for the light change
            lamp = PointLight(tuple(pos + [0.0, 0.3, 0.0]), (0.0,) * 3)
            lights = [lamp]
            moved = [PointLight(tuple(pos + [0.01 * scene.scale, 0.3, 0.0]), (0.05,) * 3)]
        yield label, scene, lights, moved, pos, look


def _builtin_cases():
    import pydynrad
    from pydynrad import DirectionalLight, PointLight

    box = pydynrad.scenes.cornell_box(max_edge=100.0)
    yield (
        "Cornell box (built-in)",
        box,
        [PointLight((278, 450, 280), (0.2,) * 3)],
        [PointLight((281, 450, 280), (0.2,) * 3)],
        np.array([278.0, 273.0, -200.0]),
        np.array([278.0, 273.0, 280.0]),
    )
    village = pydynrad.scenes.village(houses=2)
    pos, look = np.array([5.0, 1.7, 5.0]), np.array([15.0, 1.2, 5.0])
    yield (
        "village at night (built-in)",
        village,
        [PointLight((8.0, 3.0, 8.0), (400.0,) * 3)],
        [PointLight((8.3, 3.0, 8.0), (400.0,) * 3)],
        pos,
        look,
    )
    sun = DirectionalLight((-0.4, -1.0, -0.3), (100.0,) * 3)
    d = np.array(sun.direction, float)
    turned = np.array(
        [d[0] * math.cos(0.01745) - d[2] * math.sin(0.01745), d[1], d[0] * math.sin(0.01745) + d[2] * math.cos(0.01745)]
    )
    yield "village under a sun (built-in)", village, [sun], [DirectionalLight(tuple(turned), (100.0,) * 3)], pos, look


def _stepped(lights, moved, k: int) -> list:
    """``lights`` moved k times as far as ``moved`` is from them (directions, positions, powers)."""
    import dataclasses

    out = []
    for a, b in zip(lights, moved):
        if hasattr(a, "direction"):
            d = np.asarray(a.direction, float) + k * (np.asarray(b.direction, float) - np.asarray(a.direction, float))
            out.append(dataclasses.replace(b, direction=tuple(d / np.linalg.norm(d))))
        else:
            pos = np.asarray(a.position, float) + k * (np.asarray(b.position, float) - np.asarray(a.position, float))
            out.append(dataclasses.replace(b, position=tuple(pos)))
    return out


def _pixels(scene, B, ref, camera, device):
    import pydynrad
    from pydynrad.comparison import pixel_error

    a = pydynrad.render(scene, B, camera, device=device)
    r = pydynrad.render(scene, ref, camera, device=device)
    e = np.minimum(pixel_error(a, r), 1.0)
    return float(e.mean()), float(np.median(e)), float(np.percentile(e, 99))


def scene_rows(name, scene, lights, moved, pos, look, p, device):
    import pydynrad
    from pydynrad import Camera, DynamicRadiosity
    from pydynrad.comparison import radiosity_error
    from pydynrad.device.csr import DeviceCSR

    n = len(scene)
    t0 = time.perf_counter()
    F = pydynrad.form_factors(scene, resolution=p["resolution"], device=device, progress=False)
    t_F = time.perf_counter() - t0
    L = pydynrad.light_vector(scene, lights, device=device)
    ref = pydynrad.solve(scene, F, light=L, tol=1e-8, device=device, progress=False).radiosity
    emitted = np.minimum(scene.emission, L)  # the emitters' own light: the estimate's norm leaves it out
    mean = ref.mean()
    dark = ref.max(axis=1) < 1e-3 * mean
    M = min(1024, n // 4)
    w, h = p["image"]
    up = (0.0, 1.0, 0.0)
    step = (look - pos) / max(np.linalg.norm(look - pos), 1e-9) * 0.02 * scene.scale
    path = [pos + k * step for k in range(p["frames"])]
    cam = Camera(path[-1], path[-1] + (look - pos), up, 60.0, w, h)
    dev_F = DeviceCSR(device, F)
    ones = np.ones((n, 3))
    dev_F.bounce(L, ones, L)
    t_b = []
    for _ in range(3):
        t1 = time.perf_counter()
        dev_F.bounce(L, ones, L)
        t_b.append(time.perf_counter() - t1)
    bounce = min(t_b)
    rows = []
    paper = DynamicRadiosity(scene, F, local_size=M, observer=pos, device=device, far_field=False)
    for label, tol in (("coarse level alone (tolerance=None)", None), ("default tolerance", "default")):
        kw = {} if tol == "default" else {"tolerance": None}
        dyn = DynamicRadiosity(scene, F, local_size=M, observer=pos, device=device, **kw)
        B = dyn.radiosity(light=L)
        ratios, pops, prev, t_frame, t_local = [], [], None, [], []
        rms_ref = float(np.sqrt((ref**2).mean()))
        paper.update(pos)
        for o in path:
            t1 = time.perf_counter()
            dyn.update(o)
            B = dyn.radiosity(light=L)
            t_frame.append(time.perf_counter() - t1)
            t1 = time.perf_counter()
            paper.update(o)
            paper.radiosity(light=L)
            t_local.append(time.perf_counter() - t1)
            err = radiosity_error(B, ref, scene.areas, emission=emitted)
            ratios.append(dyn.error_estimate.error / err if err > 0 else float("nan"))
            if prev is not None:
                pops.append(float(np.sqrt(((B - prev) ** 2).mean())) / rms_ref)
            prev = B
        err = radiosity_error(B, ref, scene.areas)
        err_reflected = radiosity_error(B, ref, scene.areas, emission=emitted)
        pix = _pixels(scene, B, ref, cam, device)
        lit = _lit(B, dark, mean)
        # The light change: back and forth between the lights and the moved ones, best of 3.
        changes = []
        for k in range(1, 4):  # the lights moved by k steps: new light vectors, none a combination of earlier ones
            Lx = pydynrad.light_vector(scene, _stepped(lights, moved, k), device=device)
            t1 = time.perf_counter()
            dyn.radiosity(light=Lx)
            changes.append(
                (
                    time.perf_counter() - t1,
                    dyn.far.seconds_light,
                    dyn.far.seconds_coarse,
                    dyn.error_estimate.seconds,
                    dyn.error_estimate.sweeps,
                )
            )
        best = min(changes)
        est = dyn.error_estimate
        rows.append(
            [
                name,
                n,
                label,
                100 * err,
                100 * err_reflected,
                *(100 * x for x in pix),
                lit,
                int(dark.sum()),
                float(np.nanmin(ratios)),
                float(np.nanmax(ratios)),
                1e3 * best[0],
                1e3 * best[1],
                1e3 * best[2],
                1e3 * best[3],
                best[4],
                best[0] / bounce,
                1e3 * bounce,
                100 * float(np.median(pops)) if pops else float("nan"),
                100 * float(max(pops)) if pops else float("nan"),
                float(np.median(t_frame) / np.median(t_local)),
                t_F,
                str(est),
            ]
        )
    stored = _store_rows(name, scene, F, L, ref, lights, moved, pos, path, cam, M, bounce, p, device)
    return rows, stored


def _lit(B, dark, mean) -> int:
    return int((B[dark].max(axis=1) > 1e-2 * mean).sum()) if dark.any() else 0


def _store_rows(name, scene, F, L, ref, lights, moved, pos, path, cam, M, bounce, p, device) -> list:
    """The walk and the light change again with F's rows from a store on disk."""
    import tempfile

    import pydynrad
    from pydynrad import DynamicRadiosity
    from pydynrad.comparison import radiosity_error
    from pydynrad.farfield.clusters import cluster_patches
    from pydynrad.precompute.store import compute_store
    from pydynrad.rows.files import open_form_factors

    if name not in p.get("stores", ()):
        return []
    out, mean = [], ref.mean()
    dark = ref.max(axis=1) < 1e-3 * mean
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "ff"
        compute_store(
            scene,
            folder,
            resolution=p["resolution"],
            clusters=cluster_patches(scene),
            progress=False,
            row_function=lambda scene, rows, resolution, device=None: F[rows],
        )
        for label, tol in (("store, tolerance=None", None), ("store, default tolerance", "default")):
            kw = {} if tol == "default" else {"tolerance": None}
            rows = open_form_factors(scene, folder)
            dyn = DynamicRadiosity(scene, rows, local_size=M, observer=pos, device=device, **kw)
            t1 = time.perf_counter()
            dyn.radiosity(light=L)
            first = time.perf_counter() - t1
            first_sweeps = dyn.error_estimate.sweeps
            for o in path:
                dyn.update(o)
                B = dyn.radiosity(light=L)
            err = radiosity_error(B, ref, scene.areas)
            err_reflected = radiosity_error(B, ref, scene.areas, emission=np.minimum(scene.emission, L))
            walk_est = dyn.error_estimate
            changes = []
            for k in range(1, 4):
                Lx = pydynrad.light_vector(scene, _stepped(lights, moved, k), device=device)
                t1 = time.perf_counter()
                dyn.radiosity(light=Lx)
                changes.append((time.perf_counter() - t1, dyn.error_estimate.sweeps))
            best = min(changes)
            out.append(
                [
                    name,
                    len(scene),
                    label,
                    100 * err,
                    100 * err_reflected,
                    100 * _pixels(scene, B, ref, cam, device)[0],
                    _lit(B, dark, mean),
                    int(dark.sum()),
                    walk_est.error / err_reflected if err_reflected > 0 else float("nan"),
                    1e3 * first,
                    first_sweeps,
                    1e3 * best[0],
                    best[1],
                    best[0] / bounce,
                    str(walk_est),
                ]
            )
            if hasattr(rows, "close"):
                rows.close()
    return out


#: The columns both tables begin with.
_ERROR_HEADERS = ["scene", "N", "far field", "all-patch %", "of reflected %", "pixel mean %"]

STORE_HEADERS = [
    *_ERROR_HEADERS,
    "dark lit",
    "dark",
    "walk's estimate / true",
    "first light ms",
    "first light sweeps",
    "light change ms",
    "sweeps",
    "light change / bounce of F on the device",
    "walk's last estimate",
]


HEADERS = [
    *_ERROR_HEADERS,
    "pixel median %",
    "pixel p99 %",
    "dark lit",
    "dark",
    "estimate / true min",
    "estimate / true max",
    "light change ms",
    "far light() ms",
    "coarse ms",
    "estimate + sweeps ms",
    "sweeps",
    "light change / bounce",
    "bounce ms",
    "popping median %",
    "popping max %",
    "frame / local-only frame",
    "F s",
    "last estimate",
]


def farfield_corpus_section(ctx) -> dict:
    p = SIZES[ctx.size]
    rows, stored = [], []
    cases = list(_corpus_cases(p)) + (list(_builtin_cases()) if p["builtins"] else [])
    for case in cases:
        more, more_stored = scene_rows(*case, p, ctx.device)
        rows, stored = rows + more, stored + more_stored
    tables = [
        {
            "title": f"Corpus and built-ins, R = {p['resolution']}, default far field",
            "columns": HEADERS,
            "rows": rows,
        }
    ]
    if stored:
        tables.append(
            {"title": "The same walks with F's rows from a store on disk", "columns": STORE_HEADERS, "rows": stored}
        )
    return {
        "title": "The far field on real scenes: error, estimate, leaks, popping, light change",
        "description": __doc__.split("\n\n", 1)[1],
        "tables": tables,
    }


if __name__ == "__main__":
    import pydynrad

    size = sys.argv[1] if len(sys.argv) > 1 else "quick"

    class _Ctx:
        pass

    ctx = _Ctx()
    ctx.size, ctx.device = size, pydynrad.default_device()
    out = farfield_corpus_section(ctx)
    for table in out["tables"]:
        print(" | ".join(table["columns"]))
        for r in table["rows"]:
            print(" | ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in r), flush=True)
