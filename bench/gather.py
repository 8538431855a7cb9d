"""Patch-to-cluster form factors G = F Pr (the far field's G): the resolution G needs, its cost.

``python -m bench.gather [--size quick|full|tiny]`` writes ``bench/results/<device-slug>/gather.{json,md}``;
the suite runs the same measurement as its "gather" section.

* Error vs resolution: G from cluster-id hemicubes (``pydynrad.farfield.cluster_form_factors``)
  at R = 8 .. 64 against G from F at a high resolution (``form_factors(R_ref) @ Pr``), row by
  row: relative L1, ||G_R[i] - G_ref[i]||_1 / ||G_ref[i]||_1, over a sample of rows. Both the
  indicator prolongation and an exposure-weighted one (w_i = the fraction of patch i's
  hemisphere open to the sky, from the same hemicubes, plus 0.05; Pr_w[i, c] = w_i / mean_c(w)).
  Also the relative RMS of G x against G_ref x for a random cluster radiosity x: the product
  the far field forms with G.
* The far field's error with that G: B_far = L + P G B_c, B_c = (I - P_c R G)^-1 R L (dense,
  float64) for the scene's own emitters, against the full solve B = L + P F B with F at the
  reference resolution ("vs full": clusters and G's resolution together) and against B_far from
  G = F Pr at the reference resolution ("vs G at ref": G's resolution alone).
* Time per row of F and of G at the same R, and the two ways of weighting G's pixels: on the
  device (what cluster_form_factors does) or F's patch rows times Pr_w on the host.
* Precompute cost: G at its resolution as a share of F at a store's resolution (the issue's
  target: clusters + K_c + G <= 20% of F).

Clusters are the library's (``pydynrad.farfield.cluster_patches`` with the requested patches
per cluster): pure in albedo and emission, one orientation each, compact.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .common import run_standalone, time_call

__all__ = ["SIZES", "indicator", "weighted", "measure", "suite_section", "main"]

SIZES = {
    "tiny": {
        "scenes": {"cornell_box": {"max_edge": 250.0}},
        "resolutions": (4, 8),
        "reference": 16,
        "sample": 32,
        "time_rows": 32,
        "per_cluster": 8,
        "store_resolution": 16,
        "repeats": 1,
    },
    "quick": {
        "scenes": {"cornell_box": {}, "village": {"houses": 2, "detail": 0.5}},
        "resolutions": (8, 16, 24, 32, 64),
        "reference": 128,
        "sample": 256,
        "time_rows": 1024,
        "per_cluster": 8,
        "store_resolution": 64,
        "repeats": 5,
    },
    "full": {
        "scenes": {"cornell_box": {}, "village": {"houses": 12, "detail": 1.0}},
        "resolutions": (8, 16, 24, 32, 64),
        "reference": 128,
        "sample": 1024,
        "time_rows": 4096,
        "per_cluster": 8,
        "store_resolution": 64,
        "repeats": 3,
    },
}


def indicator(labels: np.ndarray) -> sp.csr_matrix:
    """The (N, C) indicator prolongation of ``labels``."""
    n = len(labels)
    return sp.csr_matrix((np.ones(n), (np.arange(n), labels)), shape=(n, labels.max() + 1))


def weighted(labels: np.ndarray, areas: np.ndarray, w: np.ndarray) -> sp.csr_matrix:
    """The exposure-weighted prolongation Pr_w[i, c] = w_i / (area-weighted mean of w over c)."""
    c = labels.max() + 1
    mean = np.bincount(labels, areas * w, c) / np.bincount(labels, areas, c)
    return sp.csr_matrix((w / mean[labels], (np.arange(len(labels)), labels)), shape=(len(labels), c))


def _row_l1(G, ref) -> np.ndarray:
    g, r = G.toarray().astype(np.float64), np.asarray(ref.todense())
    norm = np.abs(r).sum(axis=1)
    keep = norm > 0
    return np.abs(g - r).sum(axis=1)[keep] / norm[keep]


def _transport_error(G, ref, x) -> float:
    """Relative RMS of G x against G_ref x: what the far field does with G (B_far = L + P G B_c)."""
    g, r = G.astype(np.float64) @ x, ref @ x
    return float(np.sqrt(np.mean((g - r) ** 2) / np.mean(r**2)))


def _restriction(labels, areas) -> sp.csr_matrix:
    """(C, N) R[c, i] = A_i / A_c for i in c: the area-weighted average (R Pr = I)."""
    a = np.asarray(areas, dtype=np.float64)
    a_c = np.bincount(labels, a)
    return sp.csr_matrix((a / a_c[labels], (labels, np.arange(len(labels)))), shape=(len(a_c), len(labels)))


def _full_radiosity(F, rho, L, tol=1e-10) -> np.ndarray:
    """B = L + P F B by Jacobi sweeps in float64 (albedo < 1: a contraction)."""
    B = L.copy()
    for _ in range(10_000):
        nxt = L + rho * (F @ B)
        if np.max(np.abs(nxt - B)) <= tol * np.max(np.abs(nxt)):
            return nxt
        B = nxt
    raise RuntimeError("the reference radiosity did not converge")


def _far_radiosity(G, Rm, rho, L) -> np.ndarray:
    """B_far = L + P G B_c with B_c = (I - P_c F_c)^-1 L_c, F_c = R G (pure clusters: P_c = R P):
    the far field's coarse level in dense float64 (docs/design.md, 'Far field')."""
    G = G.astype(np.float64)
    F_c = (Rm @ G).toarray()
    L_c, rho_c = Rm @ L, Rm @ rho
    B_c = np.column_stack(
        [np.linalg.solve(np.eye(len(F_c)) - rho_c[:, [k]] * F_c, L_c[:, k]) for k in range(L.shape[1])]
    )
    return L + rho * (G @ B_c)


def _store_times(scene, labels, resolution: int, device) -> list:
    """Seconds and MiB of a whole store of F at ``resolution`` and of one of G alone at the default
    cluster resolution, each computed in this process into a temporary folder."""
    import tempfile
    import time
    from pathlib import Path

    from pydynrad.formfactors import CLUSTER_RESOLUTION
    from pydynrad.precompute.store import compute_store

    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, kw in (("F", {}), ("G", {"clusters": labels, "compute_f": False})):
            t0 = time.perf_counter()
            store = compute_store(scene, Path(tmp) / name, resolution=resolution, progress=False, device=device, **kw)
            out += [time.perf_counter() - t0, store.nbytes_on_disk / 2**20]
    return [resolution, CLUSTER_RESOLUTION, out[0], out[2], out[2] / out[0], out[1], out[3]]


def _rel_rms(a, b) -> float:
    return float(np.sqrt(np.sum((a - b) ** 2) / np.sum(b**2)))


def measure(size: str, device, overrides: dict | None = None) -> dict:
    """The section at ``size`` (SIZES), its entries replaced by ``overrides``."""
    from pydynrad import scenes
    from pydynrad.farfield import FarField, cluster_patches
    from pydynrad.farfield.gather import cluster_form_factors
    from pydynrad.formfactors import form_factors

    p = {**SIZES[size], **(overrides or {})}
    err_rows, far_rows, time_rows, cost_rows, store_rows = [], [], [], [], []
    plot_series = []
    for name, kwargs in p["scenes"].items():
        scene = getattr(scenes, name)(**kwargs)
        n = len(scene)
        clusters = cluster_patches(scene, patches_per_cluster=p["per_cluster"])
        labels = clusters.labels
        ind = indicator(labels)
        C = ind.shape[1]
        rng = np.random.default_rng(0)
        sample = np.sort(rng.choice(n, min(n, p["sample"]), replace=False))
        timed = np.sort(rng.choice(n, min(n, p["time_rows"]), replace=False))
        r_low = min(p["resolutions"])
        open_sky = 1.0 - np.asarray(cluster_form_factors(scene, ind, r_low, device=device).sum(axis=1)).ravel()
        wtd = weighted(labels, scene.areas.astype(np.float64), np.clip(open_sky, 0, 1) + 0.05)
        F_full = form_factors(scene, p["reference"], device=device).astype(np.float64)
        F_ref = F_full[sample]
        refs = {"indicator": F_ref @ ind, "weighted": F_ref @ wtd}
        x = np.random.default_rng(1).uniform(0.0, 1.0, C)
        # The far field's B_far (plain algebra) against the full solve with the reference F.
        Rm = _restriction(labels, scene.areas)
        rho, L = scene.albedo.astype(np.float64), scene.emission.astype(np.float64)
        B_full = _full_radiosity(F_full, rho, L)
        B_far_ref = {
            kind: _far_radiosity(F_full @ pr, Rm, rho, L) for kind, pr in (("indicator", ind), ("weighted", wtd))
        }
        for R in p["resolutions"]:
            row, far = [name, n, C, R], [name, n, C, R]
            for kind, pr in (("indicator", ind), ("weighted", wtd)):
                G_all = cluster_form_factors(scene, pr, R, device=device)
                G = G_all[sample]
                e = _row_l1(G, refs[kind])
                row += [
                    float(e.mean()),
                    float(np.percentile(e, 95)),
                    float(e.max()),
                    _transport_error(G, refs[kind], x),
                ]
                B_far = _far_radiosity(G_all, Rm, rho, L)
                far += [_rel_rms(B_far, B_full), _rel_rms(B_far, B_far_ref[kind])]
                if kind == "indicator":  # the library's far field on the device, from the same G
                    lib = FarField(scene, None, clusters, G_all, prolongation="indicator", device=device)
                    far.append(_rel_rms(lib.light(L), B_full))
            err_rows.append(row)
            far_rows.append(far)

            def per_row(fn):
                t = time_call(fn, repeats=p["repeats"])
                return t["min_s"] / len(timed) * 1e3, t["result"]

            tf, F = per_row(lambda: form_factors(scene, R, rows=timed, device=device))
            tg, G = per_row(lambda: cluster_form_factors(scene, ind, R, rows=timed, device=device))
            twd, _ = per_row(lambda: cluster_form_factors(scene, wtd, R, rows=timed, device=device))
            twh, _ = per_row(lambda: form_factors(scene, R, rows=timed, device=device) @ wtd)
            time_rows.append([name, n, C, R, tf, tg, twd, twh, F.nnz / len(timed), G.nnz / len(timed)])
        for kind, col in (("indicator", 4), ("weighted", 8)):
            pts = [r for r in err_rows if r[0] == name]
            plot_series.append(
                {
                    "label": f"{name} {kind}",
                    "x": [r[3] for r in pts],
                    "y": [r[col] for r in pts],
                    "style": "o-" if kind == "indicator" else "s--",
                }
            )
        tF = {r[3]: r[4] for r in time_rows if r[0] == name}
        tF_store = tF.get(p["store_resolution"])
        if tF_store is None:
            tF_store = (
                time_call(
                    lambda: form_factors(scene, p["store_resolution"], rows=timed, device=device), repeats=p["repeats"]
                )["min_s"]
                / len(timed)
                * 1e3
            )
        store_rows.append([name, n, C, *_store_times(scene, labels, p["store_resolution"], device)])
        for r in (r for r in time_rows if r[0] == name):
            cost_rows.append(
                [
                    name,
                    p["store_resolution"],
                    r[3],
                    (r[3] / p["store_resolution"]) ** 2,
                    r[5] / tF_store,
                    r[6] / tF_store,
                ]
            )
    e_cols = ["scene", "N", "C", "R"] + [
        f"{k} {s}"
        for k in ("indicator", "weighted")
        for s in ("row L1 mean", "row L1 p95", "row L1 max", "G x rel. RMS")
    ]
    return {
        "title": "Patch-to-cluster form factors G (far field): resolution and cost",
        "description": __doc__.split("\n\n", 1)[1],
        "tables": [
            {
                "title": f"Row-wise relative L1 error of G at R against G = F Pr at R = {p['reference']}",
                "columns": e_cols,
                "rows": err_rows,
                "note": f"{p['sample']} sampled rows per scene; clusters of about {p['per_cluster']} patches; "
                "G x: a random cluster radiosity x in [0, 1) through G",
            },
            {
                "title": "Far-field error: B_far = L + P G B_c with G at R, relative RMS over all patches",
                "columns": [
                    "scene",
                    "N",
                    "C",
                    "R",
                    "indicator vs full solve",
                    "indicator vs G at ref",
                    "FarField (device) vs full solve",
                    "weighted vs full solve",
                    "weighted vs G at ref",
                ],
                "rows": far_rows,
                "note": f"the scene's own emitters; full solve and 'G at ref': F at R = {p['reference']}; the coarse "
                "level solved densely in float64 (the far field's algebra in plain numpy), and by "
                "pydynrad.farfield.FarField from the same G (Jacobi sweeps on the device, tolerance 1e-5)",
            },
            {
                "title": "Time per row (ms) of F and of G at the same resolution, and non-zeros per row",
                "columns": [
                    "scene",
                    "N",
                    "C",
                    "R",
                    "F ms/row",
                    "G indicator ms/row",
                    "G weighted (device) ms/row",
                    "F rows @ Pr_w (host) ms/row",
                    "F nnz/row",
                    "G nnz/row",
                ],
                "rows": time_rows,
                "note": f"fastest of {p['repeats']} runs (a shared 2-core machine: the minimum is the "
                f"least disturbed) over {p['time_rows']} sampled rows (or all), kernel builds "
                "excluded",
            },
            {
                "title": "Precompute: G at R as a fraction of F at the store's resolution",
                "columns": ["scene", "F's R", "G's R", "rays G / F", "G indicator / F (time)", "G weighted / F (time)"],
                "rows": cost_rows,
                "note": "rays: (R_G / R_F)^2, what the times follow where the shared machine is quiet; issue target: "
                "clusters + K_c + G <= 0.2 of F",
            },
            {
                "title": "Whole-store precompute in this process: F at the store's resolution, G alone at the default",
                "columns": ["scene", "N", "C", "F's R", "G's R", "F s", "G s", "G / F", "F MiB", "G MiB"],
                "rows": store_rows,
                "note": "compute_store with the default block and task sizes, one run each",
            },
        ],
        "plots": [
            {
                "name": "error",
                "title": "G's row-wise relative L1 error vs hemicube resolution",
                "xlabel": "resolution R",
                "ylabel": "mean relative L1 error",
                "xscale": "log",
                "yscale": "log",
                "series": plot_series,
            }
        ],
    }


def suite_section(ctx) -> dict:
    """The suite's "gather" section: this size's parameters, overridden by the suite's."""
    return measure(ctx.size, ctx.device, ctx.params)


def main(argv=None) -> int:
    return run_standalone("gather", __doc__, SIZES, measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
