"""Corpus section of the suite: the real third-party scenes of bench/data/corpus as read.

Per scene: patches, the load's wall time, the part of it spent sampling textures (each patch's
footprint mean, :func:`pydynrad.geometry.materials.sample_materials`), the form factors' time
on the same patches (hemicube, resolution R), and the area-weighted mean albedo as read.

``python -m bench.corpus [R]`` prints the table alone.
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

__all__ = ["corpus_section", "corpus_rows"]

CORPUS = Path(__file__).resolve().parent / "data" / "corpus"
#: Hemicube resolution of the form factors timed, per suite size.
RESOLUTION = {"tiny": 8, "quick": 16, "full": 32}


def corpus_rows(resolution: int = 16, device=None, names=None) -> list:
    """[scene, patches, load s, texture sampling s, form factors s, sampling / form factors, mean albedo RGB]."""
    import pydynrad
    from pydynrad.geometry import loading

    facts = json.loads((CORPUS / "corpus.json").read_text())["scenes"]
    rows = []
    for s in facts:
        if names is not None and s["name"] not in names:
            continue
        spent = [0.0]
        original = loading.sample_materials

        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                spent[0] += time.perf_counter() - t0

        loading.sample_materials = timed
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                t0 = time.perf_counter()
                scene = pydynrad.load(CORPUS / s["file"])
                load_s = time.perf_counter() - t0
        finally:
            loading.sample_materials = original
        t0 = time.perf_counter()
        pydynrad.form_factors(scene, resolution=resolution, device=device)
        ff_s = time.perf_counter() - t0
        w = scene.areas.astype(np.float64) / scene.areas.sum()
        mean = w @ scene.albedo.astype(np.float64)
        rows.append(
            [s["name"], len(scene), load_s, spent[0], ff_s, spent[0] / ff_s, ", ".join(f"{x:.3f}" for x in mean)]
        )
    return rows


def corpus_section(ctx) -> dict:
    R = RESOLUTION.get(ctx.size, 16)
    names = ["cornell_box", "kenney_retro_urban"] if ctx.size == "tiny" else None
    rows = corpus_rows(R, ctx.device, names)
    return {
        "title": "Real scenes as read (corpus)",
        "description": (
            "The real third-party scenes of bench/data/corpus (licences in its LICENSES.md): patches as loaded "
            "(the files' triangles, zero-area ones dropped), the load's wall time, the part of it spent on "
            "materials (each patch's area mean of factor x vertex colour x texture over its footprint), the "
            f"form factors' time on the same patches (hemicube R = {R}), and the area-weighted mean albedo "
            "(linear RGB) as read."
        ),
        "tables": [
            {
                "title": "Corpus",
                "columns": [
                    "scene",
                    "patches",
                    "load s",
                    "texture sampling s",
                    "form factors s",
                    "sampling / form factors",
                    "mean albedo",
                ],
                "rows": rows,
            }
        ],
    }


if __name__ == "__main__":
    res = int(sys.argv[1]) if len(sys.argv) > 1 else 16
    for row in corpus_rows(res):
        print(" | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in row))
