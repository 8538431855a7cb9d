"""Moving objects: the cost of a move against the occlusion budget, and its error.

``python -m bench.objects [--size tiny|quick|full]`` writes ``bench/results/<device-slug>/objects.json`` and
``.md``. The Cornell box with a block moved across it (:class:`pydynrad.RigidObject`), in a
:class:`pydynrad.DynamicRadiosity` with the static scene's hemicube F precomputed:

The far field is on (the default): its coarse level is of the first pose, and the patches
outside the local set are gathered once per frame at the current poses (docs/design.md,
'Moving objects').

* with the static F, the rows a budget leaves stale corrected in ``radiosity`` (the default)
  or not (``occlusion_correction=False``); at budget 0 also with the path's poses precomputed
  (the paper's variant, ``precompute_poses``) and with the issue's 64-patch block;
* a frame without a move (``update`` with the observer walking, so patches swap, then
  ``radiosity`` with a point light) against frames that move the block, per occlusion budget
  (rows refreshed per move): the move's time (the block's and the refreshed rows' hemicubes,
  the swap, waited for);
* the error of B after the moves against the same local set built afresh at the final pose
  (the move's own error) and against a full solve of ``with_objects`` there (fresh
  hemicubes of every patch, same resolution): max over patches relative to max B, and the mean
  relative error over the pixels of a render that see a patch.

Targets (Cornell box with the block, M = 1024): a move at budget 0 within 3x a frame
without one; the error at the default budget <= 2% over visible pixels. The ratio is also
measured by the medians of more frames of each (:func:`in_sequence`). See docs/design.md,
'Moving objects'.
"""

from __future__ import annotations

import time

import numpy as np

from .common import entry_points

__all__ = ["suite_section", "main", "SIZES"]

SIZES = {
    "tiny": {
        "max_edge": 250.0,
        "block": 0,
        "M": 64,
        "R": 16,
        "moves": 2,
        "budgets": (0, 32, None),
        "frames": 4,
        "image": (24, 18),
    },
    "quick": {
        "max_edge": 100.0,
        "block": 1,
        "M": 1024,
        "R": 32,
        "moves": 4,
        "budgets": (0, 32, 64, 128, 256, None),
        "frames": 24,
        "image": (64, 48),
    },
    "full": {
        "max_edge": 50.0,
        "block": 1,
        "M": 1024,
        "R": 64,
        "moves": 6,
        "budgets": (0, 8, 32, 128, 512, None),
        "frames": 48,
        "image": (160, 120),
    },
}
OBSERVER = (278.0, 273.0, -300.0)
#: Observer offsets (mm) of the frames without a move, and the swap size of both kinds of frame.
WALK = [(0.0, 0.0, 40.0 * k) for k in (1, 2, 3, 4, 5)]
SWAPS = 32


def _poses(n: int) -> list[np.ndarray]:
    """The block's path: across the box above the floor, turning, clear of the box's own blocks."""
    out = []
    for s in np.linspace(0.0, 1.0, n + 1):
        a = np.radians(60.0 * s)
        T = np.eye(4)
        T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
        T[:3, 3] = (150.0 + 230.0 * s, 420.0, 420.0 - 280.0 * s)
        out.append(T)
    return out


def _visible_error(scene, B, B_ref, camera, device) -> float:
    """Mean of :func:`pydynrad.comparison.pixel_error` over the pixels that see a patch."""
    import pydynrad as pd
    from pydynrad.comparison import pixel_error

    a = pd.render(scene, B, camera, device=device)
    b = pd.render(scene, B_ref, camera, device=device)
    return float(pixel_error(a, b)[b.sum(axis=2) > 0].mean())


def _walk(dyn, lights) -> tuple[list[float], list[int]]:
    """Frames without a move: the observer walks (patches swap in and out), then radiosity.
    The wall time (s) and the swaps of each."""
    times, swaps = [], []
    for step in WALK:
        t = time.perf_counter()
        swaps.append(dyn.update(np.add(OBSERVER, step)).swaps)
        dyn.radiosity(lights)
        times.append(time.perf_counter() - t)
    return times, swaps


def _block64(albedo):
    """A 100 mm cube of 64 patches, the issue's block: :func:`pydynrad.scenes.block`'s 48 at
    subdivision 1 (its levels give 12, 48 or 192) with the 8 triangles of its top and of its
    bottom each halved across their longest edge (orientation kept)."""
    import pydynrad as pd

    b = pd.scenes.block(100.0, 1, albedo=albedo)
    v = b.vertices[b.faces]  # (48, 3, 3)
    split = np.abs(b.normals[:, 1]) > 0.5
    t = v[split]
    longest = np.argmax(np.linalg.norm(t - np.roll(t, -1, axis=1), axis=2), axis=1)  # edge k -> k + 1
    t = np.stack([np.roll(x, -k, axis=0) for x, k in zip(t, longest)])  # that edge first, same winding
    mid = 0.5 * (t[:, 0] + t[:, 1])
    halves = np.concatenate([np.stack([t[:, 0], mid, t[:, 2]], 1), np.stack([mid, t[:, 1], t[:, 2]], 1)])
    v = np.concatenate([v[~split], halves])
    return pd.Scene(v.reshape(-1, 3), np.arange(3 * len(v)).reshape(-1, 3), albedo=albedo, name="block")


class _Case:
    """The box, a block, and what a move is measured against: a full solve of the world at the
    block's final pose and the same local set built afresh there."""

    def __init__(self, box, block, p, lights, camera, device) -> None:
        import pydynrad as pd
        from pydynrad.geometry.objects import with_objects

        self.box, self.block, self.lights, self.camera, self.device = box, block, lights, camera, device
        self.R, self.M = p["R"], min(p["M"], len(box) + len(block))
        self.poses = _poses(p["moves"])
        final = pd.RigidObject(block, self.poses[-1])
        self.reference = with_objects(box, [final])
        t0 = time.perf_counter()
        F_ref = pd.form_factors(self.reference, self.R, device=device)
        self.t_full_ff = time.perf_counter() - t0
        self.B_ref = pd.solve(self.reference, F_ref, lights=lights, tol=1e-8, dtype=np.float64, device=device).radiosity
        self.fresh = pd.DynamicRadiosity(
            box,
            None,
            local_size=self.M,
            resolution=self.R,
            objects=pd.MovingObjects([final], occlusion=None),
            observer=OBSERVER,
            device=device,
        ).radiosity(lights, far_field=False)
        self.local_err = float(np.abs(self.fresh - self.B_ref).max() / self.B_ref.max())  # the paper's answer

    def row(self, budget, form_factors, correct: bool, label: str, poses=None) -> list:
        """One row of the table: walk frames, then the moves along the path, then walk frames."""
        import pydynrad as pd

        obj = pd.RigidObject(self.block, self.poses[0])
        dyn = pd.DynamicRadiosity(
            self.box,
            form_factors,
            local_size=self.M,
            resolution=self.R,
            objects=pd.MovingObjects([obj], occlusion=budget, occlusion_correction=correct, poses=poses),
            max_swaps_per_frame=SWAPS,
            observer=OBSERVER,
            device=self.device,
        )
        dyn.radiosity(self.lights)  # compile and warm up
        walk, swaps = _walk(dyn, self.lights)
        dyn.update(OBSERVER)
        moving, t_moves, refreshed = [], [], []
        for T in self.poses[1:]:
            dyn.move(obj, T)
            t = time.perf_counter()
            st = dyn.update(OBSERVER)
            B = dyn.radiosity(self.lights)
            moving.append(time.perf_counter() - t)
            t_moves.append(st.t_move)
            refreshed.append(st.rows_refreshed)
        B_local = dyn.radiosity(self.lights, far_field=False)  # the move's own error: K against a fresh K
        errors = [
            float(np.abs(B_local - self.fresh).max() / self.fresh.max()),
            _visible_error(self.reference, B_local, self.fresh, self.camera, self.device),
            float(np.abs(B - self.B_ref).max() / self.B_ref.max()),
            _visible_error(self.reference, B, self.B_ref, self.camera, self.device),
        ]
        after = _walked(*_walk(dyn, self.lights))  # with the rows the moves left stale (corrected per frame)
        walked = _walked(walk, swaps)
        return [
            "all" if budget is None else budget,
            label,
            len(self.box),
            len(self.block),
            self.M,
            1e3 * min(walked),
            float(np.mean(swaps)),
            1e3 * min(after),
            1e3 * min(moving),
            1e3 * min(t_moves),
            min(moving) / min(walked),
            int(np.median(refreshed)),
            *errors,
        ]


def in_sequence(box, block, form_factors, p, lights, device, frames: int) -> list:
    """The issue's ratio by medians: one solution (budget 0, static F, corrected) walks
    ``frames`` frames that swap patches with its block still, then keeps the observer still and
    moves the block ``frames`` times along the path there and back. One row: block patches,
    frames, walk and moving frame medians and minima (ms), the ratio of the medians and of the
    minima. (Frames of a walking and a moving solution interleaved in time, tried first, charged
    the walk frames 40% more than a walk alone: each move's aftermath fell on the walk frame
    after it, so the ratio came out low.)"""
    import pydynrad as pd

    poses = _poses(8)
    path = poses[1:] + poses[-2::-1]  # there and back, as long as needed
    dyn = pd.DynamicRadiosity(
        box,
        form_factors,
        local_size=min(p["M"], len(box) + len(block)),
        resolution=p["R"],
        objects=pd.MovingObjects([pd.RigidObject(block, poses[0])], occlusion=0),
        max_swaps_per_frame=SWAPS,
        observer=OBSERVER,
        device=device,
    )
    dyn.radiosity(lights)
    steps = [np.add(OBSERVER, w) for w in WALK + WALK[-2::-1] + [(0.0, 0.0, 0.0)]]
    walk, moving, k = [], [], 0
    while len(walk) < frames:
        t = time.perf_counter()
        swaps = dyn.update(steps[k % len(steps)]).swaps
        dyn.radiosity(lights)
        dt = time.perf_counter() - t
        k += 1
        if swaps:  # else a still frame, not a walk frame
            walk.append(dt)
    dyn.update(OBSERVER)
    dyn.radiosity(lights)
    for k in range(frames):
        t = time.perf_counter()
        dyn.move(dyn.objects[0], path[k % len(path)])
        dyn.update(OBSERVER)
        dyn.radiosity(lights)
        moving.append(time.perf_counter() - t)
    w, m = 1e3 * np.array(walk), 1e3 * np.array(moving)
    return [
        len(block),
        frames,
        float(np.median(w)),
        float(w.min()),
        float(np.median(m)),
        float(m.min()),
        float(np.median(m) / np.median(w)),
        float(m.min() / w.min()),
    ]


def _walked(times: list[float], swaps: list[int]) -> list[float]:
    """The times of the walk frames that swapped patches (all of them if none did): a step
    whose local set does not change is a still frame, not a walk frame."""
    return [t for t, k in zip(times, swaps) if k] or times


def measure(size: str, device, progress: bool = True) -> dict:
    import pydynrad as pd
    from pydynrad.dynamic.radiosity import MOVE_SWAPS_LIMIT

    p = SIZES[size]
    box = pd.scenes.cornell_box(max_edge=p["max_edge"])
    albedo = (0.1, 0.6, 0.15)
    block = pd.scenes.block(100.0, p["block"], albedo=albedo)  # 48 patches at subdivision 1
    block64 = _block64(albedo) if p["block"] == 1 else None  # the block: 64 patches
    lights = [pd.PointLight((278.0, 520.0, 280.0), (0.3, 0.3, 0.3))]
    camera = pd.Camera(
        position=(278.0, 273.0, -800.0),
        look_at=(278.0, 273.0, 280.0),
        fov_y=40,
        width=p["image"][0],
        height=p["image"][1],
    )
    case = _Case(box, block, p, lights, camera, device)
    R, M, poses = case.R, case.M, case.poses
    F_static = pd.form_factors(box, R, device=device)
    # The paper's variant: every pose of the path known in advance, its rows precomputed.
    t0 = time.perf_counter()
    stored = pd.precompute.precompute_poses(box, [pd.RigidObject(block)], poses, resolution=R, device=device)
    t_poses = time.perf_counter() - t0
    rows = []
    for budget in p["budgets"]:
        # Hemicube rows (every refresh a hemicube) at the two ends of the trade only: slow in
        # between; the static F's rows uncorrected where the correction changes anything.
        rows.append(case.row(budget, F_static, True, "static F"))
        if budget == 0:
            rows.append(case.row(budget, F_static, True, "static F, stored poses", stored))
            if block64 is not None:
                rows.append(
                    _Case(box, block64, p, lights, camera, device).row(
                        budget, F_static, True, "static F, 64-patch block"
                    )
                )
        if budget is not None:
            rows.append(case.row(budget, F_static, False, "static F, uncorrected"))
        if budget in (0, None):
            rows.append(case.row(budget, None, True, "hemicubes"))
    t_full_ff, local_err = case.t_full_ff, case.local_err
    blocks = [block] if block64 is None else [block, block64]
    sequence = [in_sequence(box, b, F_static, p, lights, device, p["frames"]) for b in blocks]
    table = {
        "title": "A move per frame against the occlusion budget (Cornell box, moving block, point light)",
        "columns": [
            "budget",
            "rows",
            "N",
            "block patches",
            "M",
            "walk frame ms",
            "swaps/walk frame",
            "walk frame after the moves ms",
            "moving frame ms",
            "move ms",
            "moving / walk",
            "rows refreshed",
            "max rel. error vs fresh",
            "pixel error vs fresh",
            "max rel. error vs full",
            "pixel error vs full",
        ],
        "rows": rows,
        "note": f"'fresh': the same M local patches built at the final pose from hemicubes, both without the "
        f"far field (the move's own error, in K); 'full': a full solve of with_objects there (R = {R}; "
        f"its form factors took {t_full_ff:.2f} s) against the answer with the far field (without it the "
        f"fresh local set alone is {local_err:.3g} max rel. off for M = {M}). Times: the fastest of the "
        f"{len(WALK)} walk frames that swapped patches and of the {p['moves']} moves (the machine is shared). "
        f"Walk frame: update with the observer stepping 40 mm (up to {SWAPS} swaps) and radiosity "
        f"with the light, no move (before the moves, and after them: then with the stale rows' "
        f"correction, where there is one); moving frame: the same with the observer still and one move "
        f"(its slots swapped in batches of up to MOVE_SWAPS_LIMIT = {MOVE_SWAPS_LIMIT}: the block's in one). 'static F': the static scene's precomputed F; refreshed rows "
        "come from it at the new pose (entries the block hides dropped, its columns by reciprocity), "
        "ranked by the change in the light they gather; the rows of every other patch that may see the "
        "block are made too and B corrected for them in radiosity (occlusion_correction, the default; "
        "'uncorrected': without, those rows stay stale); '64-patch block': the same at budget 0 with "
        "the issue's block, 64 patches (the 48-patch block's top and bottom triangles halved; its errors "
        "against its own full solve and fresh build); 'stored poses': the paper's variant, the "
        f"rows of every pose of the path precomputed by hemicube (pydynrad.precompute.precompute_poses: "
        f"{len(stored)} poses in {t_poses:.2f} s, {stored.nbytes / 2**20:.1f} MiB), so a move "
        "takes the block's rows and those of every patch that may see it from there; 'hemicubes': "
        "every row a hemicube of the world as it is, ranked by the solid angle of the block's bounds "
        "(budget 'all' is then exact).",
    }
    col = {c: k for k, c in enumerate(table["columns"])}
    series = {}
    for r in rows:
        v = series.setdefault(r[col["rows"]], {"x": [], "y": [], "labels": []})
        v["x"].append(r[col["moving frame ms"]])
        v["y"].append(100.0 * r[col["pixel error vs full"]])
        v["labels"].append(str(r[col["budget"]]))
    plot = {
        "name": "trade",
        "title": "A move's frame time vs its error, per occlusion budget (labels)",
        "xlabel": "moving frame ms (update with the move + radiosity)",
        "ylabel": "mean pixel error vs full solve, %",
        "xscale": "log",
        "yscale": "log",
        "series": [
            {"label": k, "x": v["x"], "y": v["y"], "labels": v["labels"], "style": "o-"} for k, v in series.items()
        ],
    }
    ratio = {
        "title": "A moving frame against a walk frame, by medians (budget 0, static F, corrected; target: 3x)",
        "columns": [
            "block patches",
            "frames of each",
            "walk frame median ms",
            "walk frame min ms",
            "moving frame median ms",
            "moving frame min ms",
            "moving / walk, medians",
            "moving / walk, minima",
        ],
        "rows": sequence,
        "note": "One solution of the box and block (M, R and swaps as above) walks its frames that swap patches "
        "with the block still, then keeps the observer still and moves the block along the path there "
        "and back, a move a frame.",
    }
    return {
        "title": "Moving objects",
        "description": __doc__.split("\n\n")[1],
        "tables": [table, ratio],
        "plots": [plot],
    }


suite_section, main = entry_points("objects", __doc__, SIZES, measure)


if __name__ == "__main__":
    raise SystemExit(main())
