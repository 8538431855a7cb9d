"""Accuracy sections of the suite: the path tracer's own convergence, and the speed/accuracy
trade curve of the dynamic method.

The trade curve walks an observer through the Cornell box and, for each setting (local size
M, update mode, storage precision, hemicube resolution R), measures the frame time (update
plus lighting) and the error of the result near the observer against

* the full radiosity solution at the same R (``pydynrad.solve`` on the full sparse F: what
  the local matrix approximates),
* the path-traced reference (patch radiosities gathered at patch centres, and the image),
  whose own noise is estimated from two independent halves and reported as the floor.

Errors are area-weighted relative RMS over the local patches (``pydynrad.comparison.radiosity_error``)
and relative RMS over the image's pixels.
"""

from __future__ import annotations

import time

import numpy as np

from .common import time_call

__all__ = ["pathtracer_section", "accuracy_section", "relative_image_error", "walk_positions", "timed_walk"]

#: The furnace of the path-tracer section: closed unit box, albedo and emission.
FURNACE_ALBEDO, FURNACE_EMISSION = 0.6, 1.0


def relative_image_error(image: np.ndarray, reference: np.ndarray) -> float:
    """Relative RMS error over all pixels and channels (unweighted)."""
    from pydynrad.comparison import radiosity_error

    return float(radiosity_error(image.reshape(-1, 3), reference.reshape(-1, 3), np.ones(image.size // 3)))


def _two_halves(fn, spp: int) -> tuple[np.ndarray, float]:
    """Run ``fn(spp, seed)`` twice with spp/2 samples and independent seeds; return the
    average and its own relative RMS noise (half the RMS difference of the halves)."""
    from pydynrad.comparison import radiosity_error

    half = max(1, spp // 2)
    a, b = fn(half, 1), fn(half, 2)
    mean = 0.5 * (a + b)
    noise = 0.5 * radiosity_error(a.reshape(-1, 3), b.reshape(-1, 3), np.ones(a.size // 3))
    return mean, float(noise)


def pathtracer_section(ctx) -> dict:
    """Furnace error vs samples per patch (should fall as 1/sqrt(spp)) and throughput."""
    import pydynrad

    p = ctx.params
    scene = pydynrad.scenes.closed_box(
        1.0, subdivisions=p["furnace_subdivisions"], albedo=FURNACE_ALBEDO, emission=FURNACE_EMISSION
    )
    truth = FURNACE_EMISSION / (1.0 - FURNACE_ALBEDO)
    rows, errs = [], []
    pydynrad.pathtracer.path_trace_patches(scene, spp=1, device=ctx.device)  # compile outside the timings
    for spp in p["spp"]:
        t0 = time.perf_counter()
        b = pydynrad.pathtracer.path_trace_patches(scene, spp=spp, seed=spp, device=ctx.device)
        dt = time.perf_counter() - t0
        err = float(np.sqrt(np.mean((b - truth) ** 2)) / truth)
        errs.append(err)
        rows.append([spp, len(scene), float(b.mean()), truth, err, dt, len(scene) * spp / dt / 1e6])
    cornell = pydynrad.scenes.cornell_box()
    w, h = p["image"]
    cam = _box_camera(w, h)
    pydynrad.path_trace(cornell, cam, spp=1, device=ctx.device)  # warm-up: compile, upload the BVH
    t0 = time.perf_counter()
    pydynrad.path_trace(cornell, cam, spp=p["image_spp"], device=ctx.device, progress=ctx.progress)
    dt = time.perf_counter() - t0
    spp = np.array(p["spp"], dtype=float)
    return {
        "title": "Reference path tracer",
        "description": (
            f"Furnace: a closed unit box (inward walls, {len(scene)} patches), albedo "
            f"{FURNACE_ALBEDO}, emission {FURNACE_EMISSION}: every patch's radiosity is E/(1-rho) = {truth:g}. "
            "`path_trace_patches` gathers at patch centres (NEE to emitters and cosine-sampled "
            "bounces combined by MIS, Russian roulette). The RMS error over patches should fall as 1/sqrt(spp). "
            "Throughput counts paths (a path is one sample at one patch, with all its bounces)."
        ),
        "tables": [
            {
                "title": "Furnace convergence",
                "columns": ["spp", "patches", "mean B", "analytic B", "rel. RMS error", "time s", "M paths/s"],
                "rows": rows,
            },
            {
                "title": "Cornell box image",
                "columns": ["width", "height", "spp", "time s", "M paths/s"],
                "rows": [[w, h, p["image_spp"], dt, w * h * p["image_spp"] / dt / 1e6]],
            },
        ],
        "plots": [
            {
                "name": "furnace",
                "title": "Path tracer: furnace error vs samples",
                "xlabel": "samples per patch",
                "ylabel": "relative RMS error",
                "xscale": "log",
                "yscale": "log",
                "series": [
                    {"label": "measured", "x": list(spp), "y": errs},
                    {
                        "label": "1/sqrt(spp) through the first point",
                        "style": "--",
                        "x": list(spp),
                        "y": list(errs[0] * np.sqrt(spp[0] / spp)),
                    },
                ],
            }
        ],
    }


def _box_camera(width: int, height: int):
    """The Cornell box's published camera (from the open front, looking in)."""
    from pydynrad import Camera

    return Camera((278.0, 273.0, -800.0), (278.0, 273.0, 0.0), (0.0, 1.0, 0.0), 39.3, width, height)


def walk_positions(frames: int) -> np.ndarray:
    """(frames, 3) observer positions inside the Cornell box, front to back along its middle."""
    t = np.linspace(0.0, 1.0, max(1, frames))[:, None]
    return (1 - t) * np.array([278.0, 250.0, 60.0]) + t * np.array([278.0, 420.0, 200.0])


def _settings(p: dict) -> list[dict]:
    """One-factor-at-a-time around the base setting (largest R, exact, fp32, base M, the paper's
    local-only answer), then the M series again with the far field."""
    base = {"M": p["base_M"], "update": "exact", "storage": "fp32", "R": max(p["resolutions"]), "far_field": False}
    out = [dict(base)]
    for key, values in (
        ("M", p["M"]),
        ("update", ("paper", "exact")),
        ("storage", ("fp16", "fp32", "fp64")),
        ("R", p["resolutions"]),
    ):
        for v in values:
            s = {**base, key: v}
            if s not in out:
                out.append(s)
    out += [{**base, "M": m, "far_field": True} for m in sorted({*p["M"], p["base_M"]})]
    return out


def timed_walk(dyn, path: np.ndarray, warm: int = 2) -> tuple[float, list]:
    """Walk ``dyn`` (a fresh DynamicRadiosity) along ``path``.

    The first frame builds K; the next ``warm`` frames build the update kernels (once per
    device and layout) and are left out of the timings. Returns (build seconds,
    [(seconds, FrameStats) for each timed frame]).
    """
    t_build = time_call(lambda: dyn.update(path[0]), repeats=1, warmup=0)["median_s"]
    for pos in path[1 : 1 + warm]:
        dyn.update(pos)
    frames = []
    for pos in path[1 + warm :]:
        t = time_call(lambda: dyn.update(pos), repeats=1, warmup=0)
        frames.append((t["median_s"], t["result"]))
    return t_build, frames


def accuracy_section(ctx) -> dict:
    """The trade curve: error vs frame time per M, update mode, storage and resolution."""
    import pydynrad
    from pydynrad.comparison import radiosity_error
    from pydynrad.renderer import Renderer

    p = ctx.params
    scene = ctx.cached(("cornell", p["max_edge"]), lambda: pydynrad.scenes.cornell_box(max_edge=p["max_edge"]))
    n = len(scene)
    path = walk_positions(p["frames"] + 3)  # + the build and two warm-up frames
    w, h = p["image"]
    # The observer's view at the end of the walk: into the box, towards the back wall.
    cam = _box_camera(w, h).with_view(path[-1], path[-1] + np.array([0.0, -60.0, 300.0]))

    def form_factors(R):
        return ctx.cached(
            ("F", "cornell", p["max_edge"], R),
            lambda: pydynrad.form_factors(scene, resolution=R, device=ctx.device, progress=ctx.progress),
        )

    full = {}
    for R in p["resolutions"]:
        F = form_factors(R)
        sol = pydynrad.solve(scene, F, device=ctx.device)
        t = time_call(lambda: pydynrad.solve(scene, F, device=ctx.device), repeats=3)
        full[R] = (sol.radiosity, t["median_s"])
    ref_patches, noise_patches = _two_halves(
        lambda spp, seed: pydynrad.pathtracer.path_trace_patches(
            scene, spp=spp, seed=seed, device=ctx.device, progress=ctx.progress
        ),
        p["ref_spp"],
    )
    ref_image, noise_image = _two_halves(
        lambda spp, seed: pydynrad.path_trace(scene, cam, spp=spp, seed=seed, device=ctx.device, progress=ctx.progress),
        p["ref_spp"],
    )

    renderer = Renderer(scene, ctx.device)
    vis = renderer.visibility(cam)  # one primary-ray pass serves every image below
    rows, points, full_images = [], [], {}
    for R in p["resolutions"]:
        b, t_solve = full[R]
        img = full_images[R] = renderer.shade(vis, b)
        err_img = relative_image_error(img, ref_image)
        rows.append(
            [
                "full radiosity",
                n,
                "—",
                "fp32",
                R,
                None,
                t_solve * 1e3,
                t_solve * 1e3,
                0.0,
                radiosity_error(b, ref_patches, scene.areas),
                0.0,
                err_img,
                err_img,
                None,
            ]
        )
    for s in _settings(p):
        M = min(s["M"], n)
        F = form_factors(s["R"])
        dyn = pydynrad.DynamicRadiosity(
            scene,
            F,
            local_size=M,
            update=s["update"],
            storage=s["storage"],
            far_field=s["far_field"],
            device=ctx.device,
        )
        _, frames = timed_walk(dyn, path)
        t_update = [dt for dt, _ in frames]
        b, t_light = dyn.radiosity(), time_call(dyn.radiosity)["median_s"]
        local = np.asarray(dyn.local_patches)
        img = renderer.shade(vis, b)
        near = np.isin(vis.patch, local)  # pixels that see a local patch
        frame = (float(np.median(t_update)) if t_update else 0.0) + t_light
        err_full = radiosity_error(b[local], full[s["R"]][0][local], scene.areas[local])
        err_pt = radiosity_error(b[local], ref_patches[local], scene.areas[local])
        err_img = relative_image_error(img, ref_image)
        label = f"M={M} {s['update']} {s['storage']} R={s['R']}" + (" far field" if s["far_field"] else "")
        rows.append(
            [
                label,
                M,
                s["update"],
                s["storage"],
                s["R"],
                float(np.median(t_update)) * 1e3 if t_update else None,
                t_light * 1e3,
                frame * 1e3,
                err_full,
                err_pt,
                relative_image_error(img, full_images[s["R"]]),
                err_img,
                relative_image_error(img[near], ref_image[near]) if near.any() else None,
                dyn.memory_bytes / 2**20,
            ]
        )
        points.append((s, frame, {"path traced": err_pt, "full": err_full}))

    base = _settings(p)[0]

    def curve(reference: str) -> list[dict]:
        """One series per factor: the settings that differ from the base in that factor only."""
        series = []
        for key in ("M", "update", "storage", "R"):
            pts = sorted(
                (f, e[reference], s[key]) for s, f, e in points if all(s[k] == v for k, v in base.items() if k != key)
            )
            series.append(
                {
                    "label": f"vary {key}",
                    "style": "o-" if key in ("M", "R") else "o",
                    "x": [f * 1e3 for f, _, _ in pts],
                    "y": [e for _, e, _ in pts],
                    "labels": [f"{key}={v}" for _, _, v in pts],
                }
            )
        pts = sorted((f, e[reference], s["M"]) for s, f, e in points if s["far_field"])
        series.append(
            {
                "label": "vary M, far field",
                "style": "s-",
                "x": [f * 1e3 for f, _, _ in pts],
                "y": [e for _, e, _ in pts],
                "labels": [f"M={v}" for _, _, v in pts],
            }
        )
        return series

    return {
        "title": "Accuracy vs frame time (the trade curve)",
        "description": (
            f"Cornell box, {n} patches (max edge {p['max_edge']} mm). The observer walks through the box; "
            f"frame time = median update time over {p['frames']} frames (after the one that builds K and two "
            "warm-up frames that build the kernels) "
            "plus one lighting product. Errors are over the local patches at the end of the walk "
            "(area-weighted relative RMS, all channels): against the full radiosity solution at the "
            "same R (`pydynrad.solve` on the full sparse F) and against the path-traced reference "
            f"({p['ref_spp']} spp gathered at patch centres). The image error compares `render` (smooth "
            f"shading) with the full solution's image and with a {p['ref_spp']}-spp path-traced image of "
            f"the same camera, {w} x {h}; outside the local set the paper's method shows only emitted and "
            "direct light (its limitation 4), which dominates the image error; the last error "
            "column keeps only the pixels that see a local patch. The far-field rows (pydynrad.farfield, "
            "default clusters) light every patch and inject the far light into the local set. "
            f"Reference noise (from two independent halves): patches {noise_patches:.2%}, image "
            f"{noise_image:.2%}; errors near these are noise-limited. Settings vary one factor at a "
            "time around the first setting row (M, exact, fp32, largest R)."
        ),
        "tables": [
            {
                "title": "Error and cost per setting",
                "columns": [
                    "setting",
                    "M",
                    "update",
                    "storage",
                    "R",
                    "update ms/frame",
                    "lighting ms",
                    "frame ms",
                    "err vs full",
                    "err vs path traced",
                    "image err vs full",
                    "image err vs path traced",
                    "same, local pixels only",
                    "device MiB (K, far field)",
                ],
                "rows": rows,
                "note": "Full-radiosity rows: frame time is one full solve; errors over all patches.",
            }
        ],
        "plots": [
            {
                "name": f"trade-{ref.replace(' ', '-')}",
                "title": f"Error vs frame time (local patches, vs {ref})",
                "xlabel": "frame time (ms)",
                "ylabel": f"relative error vs {ref}",
                "xscale": "log",
                "yscale": "log",
                "series": curve(ref),
            }
            for ref in ("path traced", "full")
        ],
        "numbers": {"reference_noise_patches": noise_patches, "reference_noise_image": noise_image},
    }
