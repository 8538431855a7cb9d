"""Dynamic radiosity: per-frame cost, kernel bandwidth, accuracy and drift.

``python -m bench.dynamic [--size tiny|quick|full]`` writes ``bench/results/<device-slug>/dynamic.json`` and
``.md``.

Measured in one run:

* copy bandwidth (OpenCL buffer copy, read + write) as the bound for everything on K;
* the update kernels on an M x M K per storage: the rank-one pass (paper mode, one swap), the
  rank-2k pass and the gather pass (K x and y K together for k vectors) of exact mode for
  k = 1, 8, 32 swaps, the sparse gathers of 8 vectors with 3% and 10% non-zero slots (what a
  swap batch's form factors have), the whole exact update of 8 swaps with such form factors
  (columns and rows of the slots, sparse gathers, host algebra, rank-16 pass, slot writes;
  its bound: one read pass plus one read-write pass over K), and the lighting product K x:
  ms (fastest of 7: the machine is shared) and GB/s of K traffic (read + write for the
  updates, read for the others) and the ratio to the copy bandwidth (target: within 1.5x;
  the copy is one OpenCL buffer copy, and K of a few tens of MB may sit in a large
  last-level cache, so a kernel can beat it; the sparse gathers read less than K);
* whole frames of :class:`pydynrad.DynamicRadiosity` along a walk through a closed box, per
  mode and storage: update ms per frame, swaps per frame, lighting ms (B = L + P K L);
* accuracy of B on the patches nearest the observer against the full solution
  (``pydynrad.solve``), per M and mode, with hemicube form factors;
* drift: K against a fresh build over the same set after many frames (10,000 at ``full``),
  with and without ``refresh_tolerance``.

The copy bound and the passes per frame are explained in docs/design.md, 'Cost model'.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .common import copy_bandwidth_device, entry_points, time_call

__all__ = ["suite_section", "main", "SIZES"]

SIZES = {
    "tiny": {"kernel_M": (256,), "frame_M": (128,), "frames": 20, "acc_M": (64,), "acc_sub": 2, "drift": (128, 200)},
    "quick": {
        "kernel_M": (1024, 4096),
        "frame_M": (256, 512),
        "frames": 60,
        "acc_M": (128, 256),
        "acc_sub": 3,
        "drift": (256, 1000),
    },
    "full": {
        "kernel_M": (1024, 2048, 4096),
        "frame_M": (256, 1024, 2048, 4096),
        "frames": 100,
        "acc_M": (256, 512, 1024, 2048),
        "acc_sub": 4,
        "drift": (256, 10000),
    },
}
STORAGES = ("fp16", "fp32", "fp64")
BATCH = 8
#: Refresh threshold of the drift rows: below fp16's accumulated error (~1e-4 on K x after
#: thousands of frames), above fp32's (~1e-7), so the table shows what a refresh buys.
DRIFT_REFRESH_TOLERANCE = 1e-4
#: Swaps per batch in the kernel table: the gather multiplies k vectors on each side, the update is rank 2k.
KERNEL_SWAPS = (1, 8, 32)
#: Non-zero slots of a swap batch's form factors in the sparse rows: a walk through a 6k-patch
#: village had a median of 3% at M = 1024 and 7% at M = 256.
SPARSE_SHARES = (0.03, 0.1)


def _kernel_rows(device, sizes, copy_gbs):
    from pydynrad.device.matrix import DeviceMatrix
    from pydynrad.dynamic.kupdate import UpdateKernels

    rows = []
    rng = np.random.default_rng(0)
    kmax = max(KERNEL_SWAPS)
    for M in sizes:
        for storage in STORAGES:
            m = DeviceMatrix(device, rng.random((1, M, M)) * 1e-3, storage)  # written pages, realistic values
            uk = UpdateKernels(m, kmax)
            uk.warm_up()  # as a DynamicRadiosity does: programs compiled, the sparse gathers' threshold measured
            kb = M * m.ld * m.dtype.itemsize
            a, b = rng.random((2 * kmax, M)) * 1e-9, rng.random((2 * kmax, M))
            x = rng.random((kmax, M))

            def fin(fn):
                def run():
                    fn()
                    device.queue.finish()

                return run

            ops = [("rank-1 update (paper swap)", fin(lambda: uk.rank_update(0, a[:1], b[:1])), 2 * kb)]
            for k in KERNEL_SWAPS:
                ops += [
                    (
                        f"rank-{2 * k} update (exact, k={k})",
                        fin(lambda k=k: uk.rank_update(0, a[: 2 * k], b[: 2 * k])),
                        2 * kb,
                    ),
                    (f"gather K x and y K, {k} vector{'s' * (k > 1)}", fin(lambda k=k: uk.gather(0, x[:k], x[:k])), kb),
                ]
            for share in SPARSE_SHARES:
                xs = _sparse_vectors(rng, BATCH, M, share)
                ops += [
                    (
                        f"sparse gather, {BATCH} vectors, {100 * share:g}% non-zero",
                        fin(lambda xs=xs: uk.gather_all(xs, xs, sparse=True)),
                        kb,
                    ),
                    (
                        f"exact update, {BATCH} swaps, {100 * share:g}% non-zero",
                        fin(lambda xs=xs: _exact_update(uk, rng, xs[0], M)),
                        3 * kb,
                    ),
                ]
            ops.append(("lighting K x", lambda: m.matvec(x[0][None]), kb))
            for name, fn, nbytes in ops:
                t = time_call(fn, repeats=7)
                gbs = nbytes / t["min_s"] / 1e9
                rows.append([M, storage, name, t["min_s"] * 1e3, gbs, copy_gbs / gbs])
    return rows


def _sparse_vectors(rng, n: int, M: int, share: float) -> np.ndarray:
    """(1, n, M) form-factor-like vectors whose union of non-zero slots is ``share`` of M."""
    out = np.zeros((1, n, M))
    nz = rng.choice(M, max(1, int(round(share * M))), replace=False)
    out[0][:, nz] = rng.random((n, len(nz))) * 1e-3  # every vector non-zero on the whole union
    return out


def _exact_update(uk, rng, F, M: int) -> None:
    """One exact batch swap of len(F) patches on channel 0 with form factors F (n, M) both ways:
    slots' columns and rows, the gathers, host algebra, rank-2k pass, slot writes."""
    from pydynrad.dynamic.exact import exact_swap

    k = len(F)
    slots = np.arange(k) * (M // k)
    F_SJ, F_JS = F.T.copy(), F.copy()
    F_SJ[slots] = 0.0
    F_JS[:, slots] = 0.0
    exact_swap(uk, slots, F_SJ, F_JS, np.zeros((k, k)), np.full((1, M), 0.5), np.full((1, k), 0.5))


def _box(sub: int, device, hemicubes: bool):
    import pydynrad

    scene = pydynrad.scenes.closed_box(subdivisions=sub, albedo=0.7, emission=0.0)
    em = np.zeros((len(scene), 3))
    top = np.flatnonzero(scene.centers[:, 1] > 0.999 * scene.centers[:, 1].max())
    em[top[: max(1, len(top) // 8)]] = 5.0
    scene = scene.with_materials(emission=em)
    if hemicubes:
        from pydynrad.formfactors import form_factors

        return scene, form_factors(scene, resolution=64, device=device)
    rng = np.random.default_rng(1)
    N, k = len(scene), min(200, len(scene) - 1)
    cols = (np.arange(N)[:, None] + rng.integers(1, N, (N, k))) % N
    F = sp.csr_matrix((rng.random(N * k), cols.ravel(), np.arange(0, N * k + 1, k)), shape=(N, N))
    F.sum_duplicates()
    return scene, sp.csr_matrix(sp.diags(0.95 / np.asarray(F.sum(axis=1)).ravel()) @ F, dtype=np.float32)


def _sub_for(n: int) -> int:
    """closed_box subdivision levels giving at least n patches (12 * 4^levels)."""
    return max(1, int(np.ceil(np.log(n / 12) / np.log(4))))


def _walk(scene, frames, seed=0):
    lo, hi = scene.vertices.min(axis=0), scene.vertices.max(axis=0)
    p = (lo + hi) / 2
    rng = np.random.default_rng(seed)
    step = 0.03 * (hi - lo)
    for _ in range(frames):
        p = np.clip(p + rng.normal(0, 1, 3) * step, lo + 0.02 * (hi - lo), hi - 0.02 * (hi - lo))
        yield p


def _frame_rows(device, sizes, frames):
    import pydynrad

    rows = []
    for M in sizes:
        scene, F = _box(_sub_for(3 * M), device, hemicubes=False)  # N >= 3 M
        L = np.asarray(scene.emission, dtype=np.float64)
        for mode in ("exact", "paper"):
            for storage in STORAGES:
                dyn = pydynrad.DynamicRadiosity(
                    scene,
                    F,
                    local_size=M,
                    update=mode,
                    storage=storage,
                    max_swaps_per_frame=BATCH,
                    observer=next(_walk(scene, 1)),
                    far_field=False,
                    device=device,
                )
                stats = [dyn.update(p) for p in _walk(scene, frames, seed=1)]
                busy = [s for s in stats if s.swaps]
                light = time_call(lambda: dyn.radiosity(light=L), repeats=5)
                rows.append(
                    [
                        M,
                        len(scene),
                        mode,
                        storage,
                        float(np.mean([s.swaps for s in stats])),
                        1e3 * float(np.mean([s.t_update for s in busy])) if busy else 0.0,
                        1e3 * float(np.mean([s.t_select for s in stats])),
                        1e3 * float(np.mean([s.t_form_factors for s in busy])) if busy else 0.0,
                        light["median_s"] * 1e3,
                    ]
                )
    return rows


def _accuracy_rows(device, sizes, sub):
    import pydynrad

    scene, F = _box(sub, device, hemicubes=True)
    full = pydynrad.solve(scene, F).radiosity
    rows = []
    for M in sizes:
        if M > len(scene):
            continue
        for mode in ("exact", "paper"):
            dyn = pydynrad.DynamicRadiosity(
                scene,
                F,
                local_size=M,
                update=mode,
                storage="fp32",
                max_swaps_per_frame=BATCH,
                observer=next(_walk(scene, 1)),
                far_field=False,
                device=device,
            )
            for p in _walk(scene, 40, seed=2):
                dyn.update(p)
            B = dyn.radiosity()
            near = np.argsort(np.linalg.norm(scene.centers - p, axis=1))[: max(1, M // 4)]
            err = np.abs(B[near] - full[near]).sum() / np.abs(full[near]).sum()
            rows.append([len(scene), M, mode, err, dyn.residual()])
    return rows


def _drift_rows(device, M, frames, progress: bool = True):
    from tqdm import tqdm

    import pydynrad

    scene, F = _box(_sub_for(3 * M), device, hemicubes=False)
    rows = []
    for storage in ("fp16", "fp32"):
        for tol in (None, DRIFT_REFRESH_TOLERANCE):
            dyn = pydynrad.DynamicRadiosity(
                scene,
                F,
                local_size=M,
                update="exact",
                storage=storage,
                max_swaps_per_frame=BATCH,
                refresh_tolerance=tol,
                refresh_interval=100,
                observer=next(_walk(scene, 1)),
                far_field=False,
                device=device,
            )
            swaps = 0
            for p in tqdm(
                _walk(scene, frames, seed=3),
                total=frames,
                desc=f"drift {storage} tol={tol}",
                leave=False,
                disable=not progress,
            ):
                swaps += dyn.update(p).swaps
            K = dyn.matrix.to_host()
            fresh = pydynrad.multibounce(scene, F, patches=dyn.local_patches, dtype=np.float64, device=device)
            err = np.abs(K - fresh).max() / np.abs(fresh).max()
            ones = np.ones(K.shape[-1])  # light leaving every local patch: what B sees of K's error
            light_err = np.linalg.norm(K @ ones - fresh @ ones) / np.linalg.norm(fresh @ ones)
            rows.append(
                [
                    M,
                    storage,
                    frames,
                    swaps,
                    "none" if tol is None else tol,
                    dyn.refreshes,
                    err,
                    light_err,
                    dyn.residual(),
                ]
            )
    return rows


def measure(size: str, device, progress: bool = True) -> dict:
    p = SIZES[size]
    copy_dev = copy_bandwidth_device(device)
    tables = [
        {"title": "Copy bandwidth (OpenCL buffer copy, read + write)", "columns": ["GB/s"], "rows": [[copy_dev]]},
        {
            "title": "Update kernels and lighting product on one channel of K",
            "columns": ["M", "storage", "pass", "ms (fastest of 7)", "GB/s of K", "copy / ours"],
            "rows": _kernel_rows(device, p["kernel_M"], copy_dev),
            "note": "Updates count K read + written, gathers and K x count K read; 'copy / ours' <= 1.5 meets the target.",
        },
        {
            "title": "Whole frames along a walk (closed box, synthetic F, N >= 3 M, grey, up to 8 swaps per frame)",
            "columns": [
                "M",
                "N",
                "mode",
                "storage",
                "swaps/frame",
                "update ms",
                "select ms",
                "form factors ms",
                "lighting ms",
            ],
            "rows": _frame_rows(device, p["frame_M"], p["frames"]),
            "note": "update ms: mean over frames that swapped (host algebra + all device passes, waited for).",
        },
        {
            "title": "Accuracy of B near the observer vs the full solution (hemicube F, R=64)",
            "columns": ["N", "M", "mode", "rel. L1 error (nearest M/4)", "residual()"],
            "rows": _accuracy_rows(device, p["acc_M"], p["acc_sub"]),
            "note": "Both modes ignore light from patches outside the set (the paper's limitation 4): that error shrinks as M grows.",
        },
        {
            "title": "Drift of exact mode: K vs a fresh float64 build over the same set",
            "columns": [
                "M",
                "storage",
                "frames",
                "swaps",
                "refresh_tolerance",
                "refreshes",
                "max rel. error",
                "rel. error of K 1",
                "residual()",
            ],
            "rows": _drift_rows(device, *p["drift"], progress=progress),
            "note": "max rel. error: max |K - K_fresh| / max |K_fresh| (fp16 rounding after every update adds up "
            "entry by entry); rel. error of K 1: the same for the product with a uniform light, what B sees; "
            "residual(): the random-probe estimate the refresh policy checks every 100 frames.",
        },
    ]
    return {"title": "Dynamic radiosity", "description": __doc__.split("\n\n")[1], "tables": tables}


suite_section, main = entry_points("dynamic", __doc__, SIZES, measure)


if __name__ == "__main__":
    raise SystemExit(main())
