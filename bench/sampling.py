"""Area-sampled form-factor rows: energy balance of the built-in scenes and the plates' error vs samples.

``python -m bench.sampling [--size tiny|quick|full]`` writes ``bench/results/<device-slug>/sampling.json`` and
``.md``; the suite runs the same measurement as its "sampling" section.

A hemicube row is a one-point rule for F[i, j], the area average over patch i of the
point-to-patch factor: at the centre it is biased where that factor is peaked (under a small
source), and no resolution removes the bias. ``form_factors(samples=K)`` averages K hemicubes
at the centroids of K equal strata of the patch, each of resolution R / sqrt(K), so a row
costs the same rays (pydynrad/formfactors.py). Measured here, per resolution R and K:

* the energy balance of each built-in scene after a full solve, sum_j B_j (A_j sum_k F_jk -
  sum_i A_i F_ij) / emitted (zero for a reciprocal F): its mean over patch orders (the hemicube
  rotations are keyed by patch index, so a permuted scene draws new ones) is the bias, its
  standard deviation the hemicube's noise; worst RGB channel;
* the unit plates' form factor against Howell's closed forms (as in bench/formfactors.py).
"""

from __future__ import annotations

import time

import numpy as np

from .common import entry_points

__all__ = ["SIZES", "energy_balance", "plates", "measure", "suite_section", "main"]

SIZES = {
    "tiny": {
        "scenes": {"cornell_box": {"max_edge": 250.0}},
        "configs": ((16, 1), (16, 4)),
        "orders": 1,
        "plate_subdivisions": (1,),
        "plate_configs": ((16, 1), (16, 4)),
    },
    "quick": {
        "scenes": {"cornell_box": {}, "village": {"houses": 1, "detail": 0.25}},
        "configs": ((32, 1), (32, 4), (64, 1), (64, 4), (64, 16), (128, 1), (128, 4), (128, 16), (256, 16)),
        "orders": 3,
        "plate_subdivisions": (1, 2),
        "plate_configs": ((32, 1), (32, 4), (64, 4), (128, 1), (128, 4), (128, 16)),
    },
    "full": {
        "scenes": {"cornell_box": {}, "village": {"houses": 1, "detail": 0.25}},
        "configs": ((32, 1), (64, 1), (64, 4), (128, 1), (128, 4), (128, 16), (256, 1), (256, 16), (256, 64)),
        "orders": 4,
        "plate_subdivisions": (1, 2, 3),
        "plate_configs": ((32, 1), (64, 4), (128, 1), (128, 16), (256, 16), (256, 64)),
    },
}


def _reordered(scene, seed: int):
    """``scene`` with its patches in another order (the same geometry, other hemicube rotations)."""
    from pydynrad.geometry.scene import Scene

    if seed == 0:
        return scene
    p = np.random.default_rng(seed).permutation(len(scene))
    return Scene(scene.vertices, scene.faces[p], albedo=scene.albedo[p], emission=scene.emission[p], name=scene.name)


def energy_balance(scene, resolution: int, samples: int, device) -> tuple[np.ndarray, float]:
    """((3,) signed imbalance / emitted after a full solve, seconds of form factors)."""
    import pydynrad

    pydynrad.form_factors(scene, resolution=resolution, rows=[0], samples=samples, device=device)  # kernel build
    t = time.perf_counter()
    F = pydynrad.form_factors(scene, resolution=resolution, samples=samples, device=device, progress=False)
    seconds = time.perf_counter() - t
    F = F.astype(np.float64)
    B = pydynrad.solve(scene, F, device=device).radiosity
    A = scene.areas.astype(np.float64)[:, None]
    share = B * (A * np.asarray(F.sum(axis=1)) - F.T @ A)
    return share.sum(axis=0) / (A * scene.emission).sum(axis=0), seconds


def plates(subdivisions, configs, device) -> list[list]:
    """Rows (case, subdivisions, patches, R, samples, rel. error) of the unit plates, per (R, samples) in ``configs``."""
    from .formfactors import accuracy

    rows = [
        [r["case"], r["subdivisions"], r["patches"], r["R"], r["samples"], r["rel_error"]]
        for R, K in configs
        for r in accuracy((R,), subdivisions, device, samples=K)
    ]
    return sorted(rows, key=lambda r: (r[0], r[1]))  # by case and subdivision, configs in order


def measure(size: str, device, progress: bool = False) -> dict:
    from pydynrad.scenes.byname import scene_by_name

    p = SIZES[size]
    rows = []
    for name, kw in p["scenes"].items():
        base = scene_by_name(name, **kw)
        for R, K in p["configs"]:
            runs = [energy_balance(_reordered(base, seed), R, K, device) for seed in range(p["orders"])]
            b = np.array([r[0] for r in runs])
            mean, sd = b.mean(axis=0), (b.std(axis=0, ddof=1) if len(b) > 1 else np.full(3, np.nan))
            c = int(np.argmax(np.abs(mean)))
            rows.append(
                [
                    base.name,
                    len(base),
                    R,
                    K,
                    R // int(round(np.sqrt(K))),
                    float(mean[c]),
                    float(sd[c]),
                    float(np.abs(b).max()),
                    float(np.median([r[1] for r in runs])),
                ]
            )
    balance = {
        "title": "Energy balance after a full solve: (emitted - absorbed - escaped) / emitted",
        "columns": [
            "scene",
            "N",
            "R",
            "samples",
            "R per sample",
            "mean (bias)",
            "sd (noise)",
            "max |.| over orders",
            "form factors s",
        ],
        "rows": rows,
        "note": f"Over {p['orders']} patch orders (new hemicube rotations each); worst RGB channel of the "
        "mean, its sd, and the largest |imbalance| of any order and channel.",
    }
    plate = {
        "title": "Unit plates: relative error of the plate-to-plate form factor (Howell)",
        "columns": ["case", "subdivisions", "patches", "R", "samples", "rel. error"],
        "rows": plates(p["plate_subdivisions"], p["plate_configs"], device),
    }
    return {
        "title": "Area-sampled form-factor rows",
        "description": "\n\n".join(__doc__.split("\n\n")[2:]),
        "tables": [balance, plate],
    }


suite_section, main = entry_points("sampling", __doc__, SIZES, measure)


if __name__ == "__main__":
    raise SystemExit(main())
