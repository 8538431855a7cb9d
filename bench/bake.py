"""Baking on the village: vertex-colour export and lightmap bake times, texel coverage, and
the lightmap's error against ``render`` along chart borders.

The radiosity baked is the village's light vector under a low sun plus its emission
(``light_vector``: direct light with hard shadows, no bounces): export and bake time do not
depend on the values, and hard shadow edges are the hardest field for a lightmap's
reconstruction (a pessimistic case for the seam error).

Seam error: one view of the village is rendered with smooth shading (``Renderer.shade``) and
again by looking the lightmap up bilinearly (``Lightmap.sample``) at the same surface points
through the lightmap UVs. A pixel is at a chart border when a texel its lookup reads can lie
beyond the chart: its surface point is within one texel of an edge of the chart's outline (a
lightmap triangle edge no other triangle shares); otherwise it is inside. Errors are max over
RGB of |lightmap - render|, relative to the 99th percentile of the rendered values (dark
pixels would make a per-pixel ratio meaningless).
"""

from __future__ import annotations

import time

import numpy as np

from .common import time_call

__all__ = ["bake_section", "SIZES"]

SIZES = {
    "tiny": {"village": {"houses": 1, "detail": 0.25}, "texels_per_unit": (4.0,), "image": (64, 48)},
    "quick": {"village": {"houses": 4, "detail": 1.0}, "texels_per_unit": (4.0, 8.0), "image": (160, 120)},
    "full": {"village": {}, "texels_per_unit": (4.0, 8.0, 16.0), "image": (320, 240)},
}
SUN = dict(direction=(0.5, -0.45, 0.35), irradiance=(900.0, 850.0, 750.0))


def _view(scene, width: int, height: int):
    import pydynrad

    lo, hi = scene.bbox.astype(np.float64)
    centre = (lo + hi) / 2
    extent = float(np.max(hi - lo))
    eye = centre + np.array([-0.45 * extent, 0.25 * extent, -0.45 * extent])
    return pydynrad.Camera(eye, centre, (0, 1, 0), 45.0, width, height)


def _chart_edge_distance(lm, patch, uv) -> np.ndarray:
    """Distance in texels from each point (its patch, its lightmap uv) to the nearest chart
    border edge of its own triangle (inf when the triangle has none)."""
    h, w = lm.shape
    faces = lm.faces
    edges = np.sort(np.stack([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]], axis=1), axis=2)  # (N, 3, 2)
    _, index, counts = np.unique(edges.reshape(-1, 2), axis=0, return_inverse=True, return_counts=True)
    border = (counts[index.reshape(-1)] == 1).reshape(-1, 3)  # an edge no other triangle of the atlas shares
    texel = lm.uv.astype(np.float64) * [w, h]
    p = uv * [w, h]
    best = np.full(len(p), np.inf)
    for k in range(3):
        a, b = texel[edges[patch, k, 0]], texel[edges[patch, k, 1]]
        t = np.clip(np.einsum("pd,pd->p", p - a, b - a) / np.maximum(np.einsum("pd,pd->p", b - a, b - a), 1e-30), 0, 1)
        d = np.linalg.norm(p - (a + t[:, None] * (b - a)), axis=1)
        best = np.where(border[patch, k], np.minimum(best, d), best)
    return best


def _border_errors(scene, lm, B, camera, device) -> dict:
    from pydynrad.renderer import Renderer

    renderer = Renderer(scene, device)
    vis = renderer.visibility(camera)
    ref = renderer.shade(vis, B)[vis.front].astype(np.float64)
    patch = vis.patch[vis.front]
    uv = lm.patch_uv(patch, vis.barycentric[vis.front])
    got = lm.sample(uv)
    inside = _chart_edge_distance(lm, patch, uv) >= 1.0
    scale = max(float(np.percentile(ref.max(axis=1), 99)), 1e-30)
    err = np.abs(got - ref).max(axis=1) / scale

    def stats(mask):
        e = err[mask]
        return (float(e.mean()), float(np.percentile(e, 99)), float(e.max())) if e.size else (0.0, 0.0, 0.0)

    return {
        "pixels": int(len(err)),
        "border_fraction": float(1 - inside.mean()),
        "border": stats(~inside),
        "inside": stats(inside),
    }


def bake_section(ctx) -> dict:
    import os
    import tempfile
    from pathlib import Path

    import pydynrad
    from pydynrad.bake import bake_lightmap, export_mesh

    p = {**SIZES[ctx.size], **ctx.params}
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    key = ("village", tuple(sorted(p["village"].items())))
    scene = ctx.cached(key, lambda: pydynrad.scenes.village(**p["village"]))
    B = pydynrad.light_vector(scene, [pydynrad.DirectionalLight(**SUN)], device=ctx.device)
    camera = _view(scene, *p["image"])
    export_rows, bake_rows = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for ext in (".glb", ".ply"):
            path = Path(tmp) / f"village{ext}"
            t = time_call(lambda: export_mesh(scene, B, path, exposure=-10.0), repeats=3)
            export_rows.append([ext, len(scene), t["warmup_s"], t["median_s"], path.stat().st_size / 2**20])
        for tpu in p["texels_per_unit"]:
            t = time_call(lambda: bake_lightmap(scene, B, tpu, device=ctx.device), repeats=2)
            lm, t_bake = t["result"], t["median_s"]
            t0 = time.perf_counter()
            lm.write(Path(tmp) / "village.exr")
            lm.write_mesh(Path(tmp) / "village-lightmap.glb")
            t_write = time.perf_counter() - t0
            h, w = lm.shape
            e = _border_errors(scene, lm, B, camera, ctx.device)
            bake_rows.append(
                [tpu, w, h, lm.coverage, t_bake, t_write, e["border_fraction"], *e["inside"], *e["border"]]
            )
    return {
        "title": "Baking: vertex colours and lightmaps of the village",
        "description": (
            f"Village, {len(scene)} patches, lengths in metres; the radiosity baked is direct sunlight plus "
            "emission (see bench/bake.py). Export: `export_mesh` to GLB and PLY, cold = first call (smoothing "
            "groups computed), warm = median of 3 (groups cached). Lightmap: `bake_lightmap` (xatlas atlas, "
            "rasterising, dilation; groups cached; median of 2 after one warm-up) and writing its EXR and GLB "
            "(each read back and checked). "
            f"Seam error over {p['image'][0]}x{p['image'][1]} pixels of one view, relative to the render's 99th "
            f"percentile: inside charts vs at chart borders. Host load average at the start: {load:.1f} "
            f"on {os.cpu_count()} CPUs (times on a shared machine vary by 2-3x)."
        ),
        "tables": [
            {
                "title": "Vertex-colour export",
                "columns": ["format", "patches", "cold s", "warm s", "MiB"],
                "rows": export_rows,
            },
            {
                "title": "Lightmap bake, coverage and seam error",
                "columns": [
                    "texels/m",
                    "width",
                    "height",
                    "coverage",
                    "bake s",
                    "write s",
                    "border pixels",
                    "inside mean",
                    "inside p99",
                    "inside max",
                    "border mean",
                    "border p99",
                    "border max",
                ],
                "rows": bake_rows,
            },
        ],
        "numbers": {"patches": len(scene)},
    }
