"""Where one move's time goes, stage by stage, against the device floor of its swap.

``python -m bench.move_stages`` prints a markdown table: the Cornell box of bench/objects.py
(``quick``: M = 1024, R = 32) with the 48-patch block moved at occlusion budget 0 from the
static F (``--correction``: with the rows it leaves stale made and corrected; ``--village``: the
66k village at R = 32 with a 1 m block moved along its first street, under a sun), then the
frame's ``radiosity`` (whose gather of the outside patches at the new pose is a move's cost
too). Each stage is timed with the device queue drained before and after it (so device
work is charged to the stage that queued it); medians and minima over the moves. The floor:
one rank-2k pass and one gather of k vectors per channel at the same M (the swap's two passes
over K), timed alone with the same kernels.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from .objects import OBSERVER, SIZES, SWAPS, _poses


def _timed(owner, name: str, label: str, queue, into: dict) -> None:
    """Replace ``owner.name`` by a wrapper adding its drained wall time (s) to ``into[label]``."""
    fn = getattr(owner, name)

    def wrapper(*args, **kwargs):
        queue.finish()
        t = time.perf_counter()
        out = fn(*args, **kwargs)
        queue.finish()
        into[label] = into.get(label, 0.0) + time.perf_counter() - t
        return out

    setattr(owner, name, wrapper)


def _case(village: bool, moves: int, device):
    """(scene, block, F, R, M, poses, observer, lights): bench/objects.py's Cornell box and block,
    or the 66k village (bench/paper.py's full size) with a 1 m block moved 0.2 m a step along
    its first street."""
    import pydynrad as pd

    if not village:
        p = SIZES["quick"]
        box = pd.scenes.cornell_box(max_edge=p["max_edge"])
        return (
            box,
            pd.scenes.block(100.0, p["block"], albedo=(0.1, 0.6, 0.15)),
            pd.form_factors(box, p["R"], device=device),
            p["R"],
            p["M"],
            _poses(moves),
            OBSERVER,
            [pd.PointLight((278.0, 520.0, 280.0), (0.3, 0.3, 0.3))],
        )
    from .paper import street_walk

    scene = pd.scenes.village(houses=12, detail=1.0)
    poses = []
    for k in range(moves + 1):
        T = np.eye(4)
        T[:3, 3] = (3.0 + 0.2 * k, 0.6, 2.5)
        poses.append(T)
    return (
        scene,
        pd.scenes.block(1.0, 1, albedo=(0.1, 0.6, 0.15)),
        pd.form_factors(scene, 32, device=device),
        32,
        1024,
        poses,
        street_walk(1)[0],
        [pd.DirectionalLight((-0.4, -1.0, -0.3), (100.0,) * 3)],
    )


def stages(
    moves: int = 8, device=None, correction: bool = False, village: bool = False
) -> list[tuple[str, float, float]]:
    """(stage, median ms, min ms) of ``moves`` moves at budget 0 and the radiosity after each;
    ``correction``: with the stale rows made and corrected (``occlusion_correction``), else
    without (the cheapest move); ``village``: on the 66k village (:func:`_case`)."""
    import pydynrad as pd
    from pydynrad.device.devices import default_device
    from pydynrad.dynamic import exact, localrows
    from pydynrad.dynamic import moves as moves_mod

    device = device or default_device()
    box, block, F, R, M, poses, observer, light = _case(village, moves, device)
    obj = pd.RigidObject(block, poses[0])
    dyn = pd.DynamicRadiosity(
        box,
        F,
        local_size=M,
        resolution=R,
        objects=pd.MovingObjects([obj], occlusion=0, occlusion_correction=correction),
        max_swaps_per_frame=SWAPS,
        observer=observer,
        device=device,
    )
    dyn.radiosity(light)
    dyn.update(observer)
    q, times = device.queue, {}
    for owner, name, label in (
        (dyn, "_moved_world", "world at the new pose (instanced scene)"),
        (dyn._ff.source, "refresh", "refresh: object rows (hemicubes), candidates' rows"),
        (localrows, "_replace_rows", "kept rows replaced"),
        (moves_mod, "stale_rows", "stale rows (reciprocal object columns)"),
        (dyn._kernels, "gather_all", "gathers + slot reads, all channels, one read-back"),
        (exact, "batched_swap", "host algebra (batched_swap, all channels)"),
        (dyn._kernels, "update_slots", "rank-2k passes + slot writes"),
        (exact, "exact_swap", "swap total (gathers, algebra, passes)"),
        (dyn._ff.source, "_static_rows", "static rows at the pose from F (move and radiosity)"),
        (dyn._ff.source, "differences", "stale rows: D = rows at the pose - kept (pre-test, D)"),
        (dyn._stale, "put", "stale rows: D held"),
    ):
        _timed(owner, name, label, q, times)
    for owner, name, label in (
        (moves_mod, "hidden_entries", "hidden entries found (candidates' and outside rows)"),
        (moves_mod, "at_pose", "rows assembled at the pose (candidates' and outside rows)"),
        (dyn._ff.source, "gather_outside", "radiosity: outside gathered at the pose (rows and product)"),
        (dyn._stale, "correct", "radiosity: stale rows corrected"),
    ):
        _timed(owner, name, label, q, times)
    runs = []
    for T in poses[1:]:
        times.clear()
        dyn.move(obj, T)
        times["move (t_move)"] = dyn.update(observer).t_move
        q.finish()
        t = time.perf_counter()
        dyn.radiosity(light)
        times["radiosity after the move"] = time.perf_counter() - t
        runs.append(dict(times))
    out = [
        (k, 1e3 * float(np.median([r.get(k, 0.0) for r in runs])), 1e3 * min(r.get(k, 0.0) for r in runs))
        for k in runs[0]
    ]
    return out + _floor(dyn, len(block), device)


def _floor(dyn, k: int, device) -> list[tuple[str, float, float]]:
    """The swap's two passes over K alone, all channels: rank-2k update and k-vector gather."""
    from bench.common import time_call

    kern, M, C = dyn._kernels, dyn.M, dyn.C
    rng = np.random.default_rng(0)
    zero = np.zeros((2 * k, M))  # K += 0: the pass's traffic and FLOPs, K left as it was
    X = rng.random((k, M))

    def rank():
        for c in range(C):
            kern.rank_update(c, zero, zero)
        device.queue.finish()

    rk = time_call(rank, repeats=15)
    ga = time_call(lambda: [kern.gather(c, X, X) for c in range(C)], repeats=15)
    return [
        (f"floor: rank-{2 * k} pass x {C} channels", 1e3 * rk["median_s"], 1e3 * rk["min_s"]),
        (f"floor: gather of {k} vectors x {C} channels", 1e3 * ga["median_s"], 1e3 * ga["min_s"]),
    ]


def main(argv=None) -> int:
    import os
    from datetime import datetime, timezone

    from pydynrad.device.devices import default_device

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--moves", type=int, default=8)
    ap.add_argument("--correction", action="store_true", help="make the stale rows and correct B for them")
    ap.add_argument("--village", action="store_true", help="the 66k village with a 1 m block, not the Cornell box")
    args = ap.parse_args(argv)
    device = default_device()
    load = os.getloadavg()
    rows = stages(args.moves, device, args.correction, args.village)
    print(
        f"Device: {device.name}. Date: {datetime.now(timezone.utc):%Y-%m-%dT%H:%M}Z. "
        f"Load average before: {load[0]:.2f}. {'Village' if args.village else 'Cornell box'}. "
        f"Stale rows {'made and corrected' if args.correction else 'left'}.\n"
    )
    print("| stage | median ms | min ms |\n|---|---|---|")
    for name, med, lo in rows:
        print(f"| {name} | {med:.2f} | {lo:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
