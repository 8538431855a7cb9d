"""Photometry section of the suite: sensor throughput, the cost of the sky term, and the
hemicube's error near an area emitter against the contour integral (where the switch pays)."""

from __future__ import annotations

import math
import time

import numpy as np

from .cie171 import rectangles_scene, room_rectangles

__all__ = ["photometry_section"]


def _timed(fn, repeats: int = 3):
    fn()  # compile and upload outside the timing
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def photometry_section(ctx) -> dict:
    import pydynrad
    from pydynrad.lights import SkyLight
    from pydynrad.photometry import illuminance, work_plane

    p = ctx.params
    dev = ctx.device
    # A lit room: 4 x 4 x 3 m, reflectance 0.5, a ceiling source.
    rects = room_rectangles(ceiling_emitter=(1.5, 2.5, 1.5, 2.5))
    room, _ = rectangles_scene(rects, p["cell"], albedo=0.5, emission=[0.0] * (len(rects) - 1) + [1000.0])
    B = pydynrad.solve(room, pydynrad.form_factors(room, 32, device=dev), device=dev).radiosity
    plane = work_plane([[0, 0], [4, 0], [4, 4], [0, 4]], 0.75, spacing=4.0 / math.sqrt(p["sensors"]))
    sensor_rows = []
    for R in p["resolutions"]:
        _, dt = _timed(lambda: illuminance(room, B, plane.points, plane.normals, resolution=R, device=dev))
        sensor_rows.append([len(plane), R, dt, len(plane) / dt, 3 * R * R * len(plane) / dt / 1e6])
    _, dt_a = _timed(
        lambda: illuminance(
            room, B, plane.points, plane.normals, resolution=p["resolutions"][0], emitters="analytic", device=dev
        )
    )
    # The sky term on patches: a room with a roof opening, per sky-pass resolution, against a point light's pass.
    roofed, _ = rectangles_scene(room_rectangles(opening=(1.5, 2.5, 1.0, 2.0)), p["cell"], albedo=0.5)
    _, dt_point = _timed(
        lambda: pydynrad.lights.direct_irradiance(roofed, [pydynrad.PointLight([2, 2, 2], 100.0)], dev)
    )
    sky_rows = [[len(roofed), "point light", dt_point, dt_point / len(roofed) * 1e6]]
    for R in p["sky_resolutions"]:
        sky = SkyLight("cie_overcast", zenith_luminance=1000.0, resolution=R)
        _, dt = _timed(lambda: pydynrad.lights.direct_irradiance(roofed, [sky], dev))
        sky_rows.append([len(roofed), f"CIE overcast sky, R = {R}", dt, dt / len(roofed) * 1e6])
    # Near an emitter: a 1 x 1 m ceiling source, sensors beside its edge facing it (edge-on) and
    # below its centre facing up, at distances d from its plane.
    emitter = np.array([[0, 0, 1], [0, 1, 1], [1, 1, 1], [1, 0, 1]], float)
    lamp = pydynrad.Scene(emitter, [[0, 1, 2], [0, 2, 3]], albedo=0.0, emission=1000.0)
    Bl = lamp.emission.astype(np.float64)
    near_rows, series = [], {}
    for label, point, normal in (
        ("beside the edge, facing it", lambda d: (1.06, 0.5, 1 - d), (-1, 0, 0)),
        ("below the centre, facing up", lambda d: (0.5, 0.5, 1 - d), (0, 0, 1)),
    ):
        for d in p["distances"]:
            pt = np.array([point(d)])
            exact = illuminance(lamp, None, pt, normal, emitters="analytic", device=dev)[0, 0]
            for R in p["resolutions"]:
                hemi = illuminance(lamp, Bl, pt, normal, resolution=R, device=dev)[0, 0]
                err = abs(hemi - exact) / exact
                near_rows.append([label, d, R, float(exact), float(hemi), float(err)])
                series.setdefault((label, R), []).append(err)
    return {
        "title": "Photometry: sensors, sky, area emitters",
        "description": (
            f"Sensors: a work plane 0.75 m high in a 4 x 4 x 3 m room ({p['cell']} m patches, reflectance 0.5, "
            "a 1 x 1 m "
            "ceiling source), irradiance by a hemicube per sensor (best of 3). Sky: the direct term of a CIE "
            "overcast sky on every patch of the room with a roof opening (one hemicube per patch) against one "
            "point light's shadow-ray pass. Near an emitter: the hemicube's error against the contour integral "
            "(exact for an unoccluded emitter) at distance d from the emitter's plane."
        ),
        "tables": [
            {
                "title": "Sensor throughput",
                "columns": ["sensors", "R", "time s", "sensors/s", "M rays/s"],
                "rows": sensor_rows,
                "note": f"emitters='analytic' at R = {p['resolutions'][0]}: {dt_a:.3g} s for the same sensors.",
            },
            {
                "title": "Direct light on every patch",
                "columns": ["patches", "light", "time s", "us per patch"],
                "rows": sky_rows,
            },
            {
                "title": "Hemicube near an emitter",
                "columns": ["sensor", "d (m)", "R", "contour lx", "hemicube lx", "rel. error"],
                "rows": near_rows,
            },
        ],
        "plots": [
            {
                "name": "near-emitter",
                "title": "Hemicube error near a 1 x 1 m emitter",
                "xlabel": "distance from the emitter plane (m)",
                "ylabel": "relative error",
                "xscale": "log",
                "yscale": "log",
                "series": [
                    {"label": f"{label}, R = {R}", "x": list(p["distances"]), "y": [max(e, 1e-9) for e in errs]}
                    for (label, R), errs in series.items()
                ],
            }
        ],
    }
