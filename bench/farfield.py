"""The far field: error and frame time with and without it, over C and M.

For the Cornell box under a point light and the built-in village at night (its lamps) and
under a sun with hard shadows: the observer walks (inside the box; down the village's first
street), then the lights change: they move (timed), then switch to the second set (its error). Against the full solve with the same F
(``pydynrad.solve``, relative residual 1e-6):

* errors: all patches and the local patches (area-weighted relative RMS,
  :func:`pydynrad.comparison.radiosity_error`), mean per-pixel relative error of the observer's view
  (:func:`pydynrad.comparison.pixel_error`), and the all-patch error right after the light change;
* times: a frame with static lights (update + radiosity), a light change (radiosity with a new
  light vector: the coarse solve, B_far and the injection), of which the coarse solve (B_c) and
  all of the far field's light() (B_c and B_far), and the far field's precompute (clusters, G,
  F_c, K_c) against F's own time.

Variants: far_field=False (the paper's method), the default far field (the first-bounce gather)
over C = N/4 .. N/64, and at C = N/8 the shared gather with and without a fine sweep (the
default until 2026-12-02: shared with one fine sweep), the first-bounce gather with a fine
sweep, the plain cluster gather, the exposure-weighted prolongation, and four plain Jacobi
sweeps of the full F (C = N).

A third table separates three kinds of light change for the default far field at C = N/8: back
and forth between the two light sets and the first set dimmed step by step (each light vector
a combination of earlier ones, which the far field answers with the same combination of its
earlier answers: no pass over F or G), and lights that move every change (a lamp stepped by 1%
of the scene's extent, the sun turned by 2 degrees: new sources), with the time of each part of
the far field's light change.

A second table times the coarse solve alone over C, for moving lights: Jacobi sweeps of the sparse F_c
(warm-started) against the dense K_c product in fp16, fp32 and fp64 storage, with K_c's build
time and bytes (dense only up to :data:`DENSE_BENCH_CLUSTERS`: the build is 3 C^3 flops per
channel).
"""

from __future__ import annotations

import gc
import time

import numpy as np

from .common import time_call

__all__ = ["farfield_section", "SIZES", "DENSE_BENCH_CLUSTERS"]

#: The largest C whose dense K_c the coarse table builds.
DENSE_BENCH_CLUSTERS = 2100

#: Light changes timed per variant (alternating the two light vectors; the fastest counts).
CHANGES = 3

SIZES = {
    "tiny": {
        "village": {"houses": 1, "detail": 0.25},
        "resolution": 16,
        "cornell_max_edge": 250.0,
        "M": (64,),
        "per": (4, 16),
        "frames": 3,
        "image": (24, 18),
    },
    "quick": {
        "village": {},
        "resolution": 32,
        "cornell_max_edge": 100.0,
        "M": (1024,),
        "per": (4, 8, 16, 32, 64),
        "frames": 5,
        "cornell_frames": 15,
        "village_frames": 15,
        "image": (96, 64),
    },
    "full": {
        "village": {},
        "resolution": 32,
        "cornell_max_edge": 100.0,
        "M": (1024, 4096),
        "per": (4, 8, 16, 32, 64),
        "frames": 12,
        "image": (320, 240),
    },
}


def _cases(ctx, p):
    """(name, scene, F, seconds of F, lights, changed lights, observer path, camera per position)."""
    import pydynrad
    from pydynrad import Camera, DirectionalLight, PointLight

    from .accuracy import walk_positions
    from .paper import street_walk

    def cached_F(key, scene, R):
        F = ctx.cached(
            ("F", *key, R), lambda: pydynrad.form_factors(scene, resolution=R, device=ctx.device, progress=ctx.progress)
        )
        return F, ctx.made_seconds[("F", *key, R)]

    w, h = p["image"]
    box = ctx.cached(
        ("cornell", p["cornell_max_edge"]), lambda: pydynrad.scenes.cornell_box(max_edge=p["cornell_max_edge"])
    )
    F, t = cached_F(("cornell", p["cornell_max_edge"]), box, 64)
    # The same path in more, shorter steps (the errors are taken at its end): with 5, the fastest
    # update and radiosity of the box's ~5 ms frames put the far field's static-light frame at
    # 0.87x and 1.50x the local-only one in two runs on an AMD EPYC (2026-12-06).
    path = walk_positions(p.get("cornell_frames", p["frames"]) + 3)
    cam = lambda pos: Camera(pos, pos + np.array([0.0, -60.0, 300.0]), (0.0, 1.0, 0.0), 60.0, w, h)  # noqa: E731
    yield (
        "Cornell box",
        box,
        F,
        t,
        [PointLight((278, 450, 280), (0.2,) * 3)],
        [PointLight((150, 450, 400), (0.2,) * 3)],
        path,
        cam,
    )
    key = tuple(sorted(p["village"].items()))
    village = ctx.cached(("village", key), lambda: pydynrad.scenes.village(**p["village"]))
    F, t = cached_F(("village", key), village, p["resolution"])
    # The street walk's steps are fixed, so more frames are only a longer walk: enough that the
    # fastest update and radiosity of a ~12 ms frame stand clear of the machine's noise (with 5,
    # the far field's static-light frame under a sun came out 1.45x the local-only one in a run on an
    # AMD EPYC, and 1.14x by the same measure over 37 frames the next day).
    path = street_walk(p.get("village_frames", p["frames"]) + 3)
    cam = lambda pos: Camera(pos, pos + np.array([10.0, -0.5, 0.0]), (0.0, 1.0, 0.0), 70.0, w, h)  # noqa: E731
    lamp = PointLight((8.0, 3.0, 8.0), (400.0,) * 3)
    yield "village at night", village, F, t, [], [lamp], path, cam
    yield (
        "village under a sun",
        village,
        F,
        t,
        [DirectionalLight((-0.4, -1.0, -0.3), (100.0,) * 3)],
        [DirectionalLight((0.5, -0.8, -0.2), (100.0,) * 3)],
        path,
        cam,
    )


def _variants(n: int, per) -> list[tuple[str, int, dict | None]]:
    """(label, C, FarField options or None for far_field=False)."""
    out = [("local only (paper)", 0, None)]
    out += [(f"far field, C = N/{k}", max(1, n // k), {}) for k in per]
    c8 = max(1, n // 8)
    out += [
        ("C = N/8, shared + 1 fine sweep (old default)", c8, {"gather": "shared", "fine_sweeps": 1}),
        ("C = N/8, shared", c8, {"gather": "shared"}),
        ("C = N/8, first bounce + 1 fine sweep", c8, {"fine_sweeps": 1}),
        ("C = N/8, plain cluster gather", c8, {"gather": "cluster"}),
        ("C = N/8, exposure-weighted", c8, {"gather": "cluster", "prolongation": "exposure"}),
        ("4 Jacobi sweeps of F", n, {"gather": "cluster", "coarse": "sweeps", "max_sweeps": 4, "tol": 0.0}),
    ]
    return out


def _moved(lights, step: int, extent: float) -> list:
    """``lights`` moved ``step`` times: point lights along x by 1% of ``extent``, suns turned 2 degrees about y."""
    import dataclasses

    from pydynrad import DirectionalLight

    out = []
    for light in lights:
        if isinstance(light, DirectionalLight):
            a = np.radians(2.0 * step)
            x, y, z = light.direction
            out.append(
                dataclasses.replace(light, direction=(np.cos(a) * x - np.sin(a) * z, y, np.sin(a) * x + np.cos(a) * z))
            )
        else:
            out.append(dataclasses.replace(light, position=tuple(np.add(light.position, (0.01 * extent * step, 0, 0)))))
    return out


def _moving_lights(ctx, scene, lights) -> list[np.ndarray]:
    """Light vectors of ``lights`` moved 1 .. 2 CHANGES + 1 steps (:func:`_moved`): every one new."""
    import pydynrad

    extent = float(np.linalg.norm(np.subtract(*scene.bbox.astype(np.float64))))
    return [
        pydynrad.light_vector(scene, _moved(lights, i, extent), device=ctx.device) for i in range(1, 2 * CHANGES + 2)
    ]


def _change_rows(ctx, name, scene, F, L, L2, moving, path, M) -> list[list]:
    """The default far field's light changes, back and forth, dimmed and with moving lights, part by part."""
    import pydynrad
    from pydynrad.comparison import radiosity_error
    from pydynrad.farfield import FarField

    n = len(scene)
    base = pydynrad.DynamicRadiosity(
        scene, F, local_size=M, storage="fp32", far_field=False, observer=path[0], device=ctx.device
    )
    far = FarField(scene, F, clusters=max(1, n // 8), device=ctx.device, checked=True)
    dyn = pydynrad.DynamicRadiosity(
        scene, F, local_size=M, storage="fp32", far_field=far, observer=path[0], device=ctx.device
    )
    for d in (base, dyn):
        d.update(path[1])
        d.radiosity(light=L)
    lighting = time_call(lambda: base.radiosity(light=L), repeats=5)["min_s"]
    rows = []
    dimmed = [L * (1.0 - 0.05 * i) for i in range(1, 2 * CHANGES + 1)]
    for kind, seq in (("back and forth", [L2, L] * CHANGES), ("dimmed", dimmed), ("moving lights", moving)):
        parts = []
        for x in seq:
            t = time.perf_counter()
            dyn.radiosity(light=x)
            parts.append((time.perf_counter() - t, far.seconds_coarse, far.seconds_light, far.sweeps, far.combined))
        parts = np.array(parts[1:], dtype=np.float64)  # the first change of each kind follows another kind's lights
        ref = pydynrad.solve(scene, F, light=seq[-1], device=ctx.device).radiosity
        change, coarse, light, sweeps, _ = np.median(parts, axis=0)
        rows.append(
            [
                name,
                n,
                M,
                far.C,
                kind,
                f"{int(parts[:, 4].sum())}/{len(parts)}",
                1e3 * change,
                1e3 * coarse,
                sweeps,
                1e3 * (light - coarse),
                1e3 * (change - light),
                1e3 * lighting,
                (change - coarse) / lighting,
                100 * radiosity_error(dyn.radiosity(light=seq[-1]), ref, scene.areas),
            ]
        )
    return rows


def _coarse_rows(ctx, name, scene, F, L, moving, ref_last, per) -> list[list]:
    """The coarse solve alone over C: sweeps of F_c against the dense K_c per storage, for moving
    lights (each change new: back and forth, the sweeps' warm start would make each a repeat)."""
    from pydynrad.comparison import radiosity_error
    from pydynrad.farfield import FarField, cluster_patches
    from pydynrad.host.product import HostMatrix

    n, rows = len(scene), []
    groups = cluster_patches(scene, n).groups
    for k in per:
        C = max(1, n // k)
        if C < groups:
            continue
        kinds = [("sweeps", None)]
        if C <= DENSE_BENCH_CLUSTERS:
            kinds += [("dense", s) for s in (("fp16", "fp32", "fp64") if k == max(per) or n < 10_000 else ("fp32",))]
        for coarse, storage in kinds:
            t0 = time.perf_counter()
            far = FarField(scene, F, clusters=C, coarse=coarse, coarse_storage=storage, device=ctx.device, checked=True)
            t_build = time.perf_counter() - t0
            far.light(L)
            best = (np.inf, 0)
            for x in moving:
                far.light(x)
                best = min(best, (far.seconds_coarse, far.sweeps))
            held = far.K_c.nbytes if far.K_c is not None else far.F_c.nnz * 8
            where = "host" if isinstance(far.K_c, HostMatrix) else "device"
            rows.append(
                [
                    name,
                    n,
                    C,
                    coarse,
                    storage or "fp32 F_c",
                    where,
                    t_build,
                    held / 2**20,
                    1e3 * best[0],
                    best[1],
                    100 * radiosity_error(far.light(moving[-1]), ref_last, scene.areas),
                ]
            )
    return rows


def farfield_section(ctx) -> dict:
    import pydynrad
    from pydynrad.comparison import pixel_error, radiosity_error
    from pydynrad.farfield import FarField
    from pydynrad.renderer import Renderer

    p = {**SIZES[ctx.size], **(ctx.params or {})}
    rows, coarse_rows, change_rows, series = [], [], [], {}
    for name, scene, F, t_ff, lights, lights2, path, cam in _cases(ctx, p):
        n = len(scene)
        L, L2 = (pydynrad.light_vector(scene, x, device=ctx.device) for x in (lights, lights2))
        ref, ref2 = (pydynrad.solve(scene, F, light=x, device=ctx.device).radiosity for x in (L, L2))
        renderer = Renderer(scene, ctx.device)
        view = cam(path[-1])
        vis = renderer.visibility(view)
        ref_img = renderer.shade(vis, ref)
        moving = _moving_lights(ctx, scene, lights2)
        ref_last = pydynrad.solve(scene, F, light=moving[-1], device=ctx.device).radiosity
        coarse_rows += _coarse_rows(ctx, name, scene, F, L, moving, ref_last, p["per"])
        change_rows += _change_rows(ctx, name, scene, F, L, L2, moving, path, min(p["M"][0], n // 2))
        for M in p["M"]:
            M = min(M, n // 2)
            for label, C, opts in _variants(n, p["per"]):
                if C and C < pydynrad.farfield.cluster_patches(scene, n).groups:
                    continue
                # The last variant's solution (hundreds of MB on the village) goes first, so the
                # build's time is its own, not that of allocating beside or collecting the last one.
                far = dyn = None
                gc.collect()
                t0 = time.perf_counter()
                # F came from form_factors: validated once, as DynamicRadiosity does for its own far field.
                far = False if opts is None else FarField(scene, F, clusters=C, device=ctx.device, checked=True, **opts)
                t_pre = time.perf_counter() - t0
                dyn = pydynrad.DynamicRadiosity(
                    scene, F, local_size=M, storage="fp32", far_field=far, observer=path[0], device=ctx.device
                )
                for pos in path[1:3]:  # warm-up: kernel builds, the first light
                    dyn.update(pos)
                    dyn.radiosity(light=L)
                t_update, t_radiosity = [], []
                for pos in path[3:]:
                    t = time.perf_counter()
                    dyn.update(pos)
                    t_update.append(time.perf_counter() - t)
                    t = time.perf_counter()
                    B = dyn.radiosity(light=L)
                    t_radiosity.append(time.perf_counter() - t)
                # The fastest of each part: on a shared machine the median moves with other work.
                t_frame = float(np.min(t_update) + np.min(t_radiosity))
                S = dyn.local_patches
                img = renderer.shade(vis, B)
                t_light = time_call(lambda: dyn.radiosity(light=L), repeats=5)["min_s"]  # static: cached B_far
                if opts is None:
                    base_frame, base_light = t_frame, t_light
                # Light changes of moving lights (each new: back and forth, the coarse sweeps' warm
                # start would combine earlier solutions into the answer); the fastest counts, with
                # its coarse solve and light().
                best = (np.inf, 0.0, 0.0, 0)
                for x in moving:
                    t = time.perf_counter()
                    dyn.radiosity(light=x)
                    t_change = time.perf_counter() - t
                    parts = (far.seconds_coarse, far.seconds_light, far.sweeps) if far else (0.0, 0.0, 0)
                    best = min(best, (t_change, *parts))
                B2 = dyn.radiosity(light=L2)
                t_change, t_coarse, t_far, sweeps = best
                row = [
                    name,
                    n,
                    M,
                    label,
                    C or "—",
                    100 * radiosity_error(B, ref, scene.areas),
                    100 * radiosity_error(B[S], ref[S], scene.areas[S]),
                    100 * float(pixel_error(img, ref_img).mean()),
                    100 * radiosity_error(B2, ref2, scene.areas),
                    1e3 * t_frame,
                    t_frame / base_frame,
                    1e3 * t_light,
                    1e3 * t_change,
                    1e3 * t_coarse,
                    1e3 * t_far,
                    (t_change - t_coarse) / base_light,
                    (t_change - t_far) / base_light,
                    sweeps,
                    t_pre,
                    100 * t_pre / t_ff if opts is not None else None,
                    far.G.nnz if far else 0,
                    far.coarse if far else "—",
                ]
                rows.append(row)
                key = f"{name}, M = {M}"
                series.setdefault(key, {"x": [], "y": [], "labels": []})
                series[key]["x"].append(row[9])
                series[key]["y"].append(max(row[5], 1e-3))
                series[key]["labels"].append(label.replace("far field, ", ""))
    return {
        "title": "The far field: every patch lit, not just the local set",
        "description": __doc__.split("\n\n", 1)[1].strip(),
        "tables": [
            {
                "title": "Error against the full solve and time, far field off and on",
                "columns": [
                    "scene",
                    "N",
                    "M",
                    "variant",
                    "C",
                    "all %",
                    "local %",
                    "pixels %",
                    "after light change %",
                    "frame ms (static lights)",
                    "x local-only frame",
                    "lighting ms",
                    "light change ms",
                    "coarse solve ms",
                    "far light() ms",
                    "(change - coarse) / local lighting",
                    "(change - light()) / local lighting",
                    "sweeps",
                    "precompute s",
                    "precompute % of F",
                    "nnz(G)",
                    "coarse",
                ],
                "rows": rows,
                "note": "frame = update + radiosity while walking (the fastest update plus the fastest radiosity "
                "of the walk's frames, every one of which swaps patches); lighting = radiosity() with unchanged lights "
                "(the local product plus the injection); light change = radiosity() with new lights (the fastest "
                f"of {2 * CHANGES + 1} changes of moving lights, as in the third table), of which the coarse "
                "solve (B_c: the dense K_c product or Jacobi sweeps of F_c, warm-started) and the far field's whole light() (B_c and B_far); the "
                "issue's target for a light change is (change - coarse) <= 3 local-only lighting products. "
                "Precompute = clusters + G + F_c + K_c (+ the exposure weights' sky solve), against F's own "
                "hemicube time.",
            },
            {
                "title": "The coarse solve over C: sweeps of the sparse F_c against the dense K_c",
                "columns": [
                    "scene",
                    "N",
                    "C",
                    "coarse",
                    "storage",
                    "held on",
                    "far field build s",
                    "K_c or F_c MiB",
                    "coarse solve ms (light change)",
                    "sweeps",
                    "all % after the last change",
                ],
                "rows": coarse_rows,
                "note": f"coarse solve = B_c for a light change (the fastest of {2 * CHANGES + 1} changes of moving "
                "lights, as in the third table; sweeps warm-started, FarField's default tol); all % after the "
                "last of them; build = the whole FarField (clusters, "
                "G, F_c and K_c: LU of I - F_c P_c per channel, by the host's LAPACK on a CPU device); "
                "F_c MiB counts 8 bytes a non-zero (fp32 value and index); held on: where the products run "
                "(a K_c of at most 4 MiB beside a CPU device on the host, in the type it computes in: fp16 "
                "storage then takes fp32's bytes; pydynrad.host.product). Default gather (first bounce).",
            },
            {
                "title": "Light changes of the default far field (C = N/8): back and forth, dimmed, and moving lights",
                "columns": [
                    "scene",
                    "N",
                    "M",
                    "C",
                    "changes",
                    "combined",
                    "light change ms",
                    "coarse solve ms",
                    "sweeps",
                    "first bounce + gather ms",
                    "injection + local ms",
                    "local-only lighting ms",
                    "(change - coarse) / local lighting",
                    "all % after the last change",
                ],
                "rows": change_rows,
                "note": f"medians over {2 * CHANGES - 1} changes after the first of each kind; back and forth: "
                "between the case's two light sets; dimmed: the first set at 95%, 90%, ... of its power; "
                "combined: the changes the far field answered as a combination of its last answers (the light "
                "vector a combination of the last ones: no pass over F or G, no coarse solve; FarField._combined); "
                "moving: a lamp stepped 1% of the scene's extent along x, the sun turned 2 degrees "
                "about the vertical, per change (new sources). first bounce + gather = the far field's light() "
                "less the coarse solve (P F L over the lit columns, R D1, the pass over G; the combination when "
                "combined).",
            },
        ],
        "plots": [
            {
                "name": "trade",
                "title": "All-patch error vs frame time (far field off and on)",
                "xlabel": "frame ms (update + radiosity)",
                "ylabel": "relative RMS error over all patches, %",
                "xscale": "log",
                "yscale": "log",
                "series": [
                    {"label": k, "x": v["x"], "y": v["y"], "labels": v["labels"], "style": "o-"}
                    for k, v in series.items()
                ],
            }
        ],
    }
