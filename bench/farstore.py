"""The far field without F: the coarse basis and the resolution G needs.

Stores and rows on demand never hold F, so their far field has only G = F Pr, from
cluster-id hemicubes at resolution R_G (:func:`pydynrad.farfield.cluster_form_factors`). For the
Cornell box under a point light and the built-in village at night (a lamp) and under a sun
with hard shadows (the cases of bench/farfield.py), the observer walks and the dynamic solution
(M local patches, its rows from F in memory: the same rows a store serves) gets the F-less far
field FarField(scene, None, clusters, G=..., prolongation=basis). Against the full solve with F:

* basis: "indicator" (one value per cluster, C columns of G) and "linear" (three hat functions
  per cluster, :func:`pydynrad.farfield.clusters.linear_basis`, 3C columns; after the coarse
  solve 2 sweeps of the linear level by default, 0 and 4 as well with G = F Pr);
* R_G over a range, and G = F Pr from F itself (R_G = F's resolution, no extra error);
* errors: all patches (area-weighted relative RMS) and mean per-pixel relative error;
* precompute: clusters + G (+ F_c) against F's own rows at G's resolution (the issue's target
  for rows on demand: <= 20%) and against F at its resolution; G's nnz per row; the coarse
  solve's time and sweeps per light change.
"""

from __future__ import annotations

import time

__all__ = ["farstore_section", "SIZES"]

SIZES = {
    "tiny": {
        "village": {"houses": 1, "detail": 0.25},
        "resolution": 16,
        "cornell_max_edge": 250.0,
        "M": 64,
        "R_G": (8,),
        "frames": 3,
        "image": (24, 18),
        "per": 8,
    },
    "quick": {
        "village": {},
        "resolution": 32,
        "cornell_max_edge": 100.0,
        "M": 1024,
        "R_G": (24, 48),
        "frames": 5,
        "image": (96, 64),
        "per": 8,
    },
    "full": {
        "village": {},
        "resolution": 32,
        "cornell_max_edge": 100.0,
        "M": 1024,
        "R_G": (8, 16, 24, 32, 48),
        "frames": 12,
        "image": (320, 240),
        "per": 8,
    },
}


def farstore_section(ctx) -> dict:
    import pydynrad
    from pydynrad.comparison import pixel_error, radiosity_error
    from pydynrad.farfield import FarField, cluster_form_factors, cluster_patches
    from pydynrad.farfield.gather import basis_prolongation
    from pydynrad.renderer import Renderer

    from .farfield import _cases

    p = {**SIZES[ctx.size], **(ctx.params or {})}
    rows = []
    for name, scene, F, t_F, lights, _, path, cam in _cases(ctx, p):
        n = len(scene)
        R_F = 64 if name == "Cornell box" else p["resolution"]
        L = pydynrad.light_vector(scene, lights, device=ctx.device)
        ref = pydynrad.solve(scene, F, light=L, device=ctx.device).radiosity
        renderer = Renderer(scene, ctx.device)
        vis = renderer.visibility(cam(path[-1]))
        ref_img = renderer.shade(vis, ref)
        M = min(p["M"], n // 2)
        t0 = time.perf_counter()
        clusters = cluster_patches(scene, patches_per_cluster=p["per"])
        t_clusters = time.perf_counter() - t0
        t_rows = {}
        for R_G in (*p["R_G"], "F"):
            if R_G != "F" and R_G not in t_rows:
                t0 = time.perf_counter()
                pydynrad.form_factors(scene, resolution=R_G, device=ctx.device, progress=False)
                t_rows[R_G] = time.perf_counter() - t0
            variants = [("indicator", None), ("linear", None)]
            if R_G == "F":  # the linear level's sweeps after the coarse solve (default 2)
                variants += [("linear", 0), ("linear", 4)]
            for basis, sweeps in variants:
                pr = basis_prolongation(scene, clusters, basis)
                t0 = time.perf_counter()
                G = F @ pr if R_G == "F" else cluster_form_factors(scene, pr, R_G, device=ctx.device, progress=False)
                t_G = time.perf_counter() - t0
                t0 = time.perf_counter()
                far = FarField(scene, None, clusters, G=G, prolongation=basis, fine_sweeps=sweeps, device=ctx.device)
                t_level = time.perf_counter() - t0
                dyn = pydynrad.DynamicRadiosity(
                    scene, F, local_size=M, storage="fp32", far_field=far, observer=path[0], device=ctx.device
                )
                for pos in path[1:]:
                    dyn.update(pos)
                B = dyn.radiosity(light=L)
                img = renderer.shade(vis, B)
                pre = t_clusters + t_G + t_level
                rows.append(
                    [
                        name,
                        n,
                        M,
                        clusters.count,
                        basis,
                        far.fine_sweeps if basis == "linear" else "—",
                        "F Pr" if R_G == "F" else R_G,
                        100 * radiosity_error(B, ref, scene.areas),
                        100 * float(pixel_error(img, ref_img).mean()),
                        G.nnz / n,
                        far.F_c_nnz,
                        1e3 * far.seconds_coarse,
                        1e3 * far.seconds_light,
                        far.sweeps,
                        pre,
                        None if R_G == "F" else 100 * pre / t_rows[R_G],
                        100 * pre / t_F if R_G != "F" else None,
                        R_F,
                    ]
                )
    return {
        "title": "The far field without F: coarse basis and G's resolution",
        "description": __doc__.split("\n\n", 1)[1].strip(),
        "tables": [
            {
                "title": "F-less far field: error against the full solve, G's size and precompute",
                "columns": [
                    "scene",
                    "N",
                    "M",
                    "C",
                    "basis",
                    "linear sweeps",
                    "R_G",
                    "all %",
                    "pixels %",
                    "nnz(G) per row",
                    "nnz(F_c)",
                    "coarse solve ms",
                    "light change ms",
                    "coarse sweeps",
                    "precompute s (clusters + G + F_c)",
                    "% of F's rows at R_G",
                    "% of F at R_F",
                    "R_F",
                ],
                "rows": rows,
                "note": "Rows of the local set come from F in memory (as a store serves them); only the far field "
                "is F-less. 'F Pr' is G from F itself (what G tends to as R_G reaches F's resolution).",
            }
        ],
        "plots": [],
    }
