"""Reference radiosity against numpy/SciPy doing the same algebra, and kernel bandwidths.

``python -m bench.radiosity [--size tiny|quick|full]`` writes ``bench/results/<device-slug>/radiosity.json`` and
``.md``; the suite (``python -m bench``) runs :func:`suite_section` as its "bandwidth" part.

Measured in one run:

* copy bandwidth of this machine: numpy ``np.copyto`` and an OpenCL buffer copy (read + write);
* ``DeviceMatrix.matvec`` (y = K x, one channel) per storage: GB/s of K streamed, against
  numpy's float32 ``K @ x`` (BLAS gemv), and three vectors in one pass over K (``matmat``);
* the full solver (bounce iteration, CSR kernel, tol 1e-6): time and GB/s of F per bounce,
  against a SciPy sparse Jacobi loop (the same iteration), SciPy GMRES (rtol 1e-6, per
  channel) and numpy's dense LU solve where it fits (N <= 4096);
* the multibounce build K = (I - F P)^{-1} F (blocked Gauss-Jordan on the device, float32)
  against ``numpy.linalg.solve`` on the same dense system in float32 and float64.

Scenes: closed boxes of growing N (and the village when a size asks for it) with hemicube
hemicube form factors from ``pydynrad.form_factors`` (their resolution recorded in the tables).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .common import copy_bandwidth_device, copy_bandwidth_numpy, run_standalone, time_call

__all__ = ["suite_section", "main", "SIZES"]

SIZES = {
    "tiny": {"M": (256,), "N": (1000,), "build_M": (256,), "village": None, "R": 16},
    "quick": {"M": (1024, 2048), "N": (1000, 4000), "build_M": (512, 1024), "village": None, "R": 32},
    "full": {
        "M": (1024, 2048, 4096),
        "N": (1000, 4000, 16000),
        "build_M": (1024, 2048, 4096),
        "village": {"houses": 12, "detail": 1.0},
        "R": 64,
    },
}
TOL = 1e-6


_F_CACHE: dict = {}


def _scene_and_F(n: int, device, village=None, resolution: int = 32, progress: bool = True):
    """A closed box of about n patches (or the village) and its F, with F's provenance (cached)."""
    key = (n, str(village), resolution)
    if key not in _F_CACHE:
        _F_CACHE[key] = _make_scene_and_F(n, device, village, resolution, progress)
    return _F_CACHE[key]


def _make_scene_and_F(n: int, device, village, resolution: int, progress: bool):
    import pydynrad

    if village is not None:
        scene = pydynrad.scenes.village(**village)
    else:
        sub = max(1, round(np.log(n / 12) / np.log(4)))  # 12 * 4^sub triangles
        scene = pydynrad.scenes.closed_box(subdivisions=sub, albedo=0.7, emission=0.0)
        em = np.zeros((len(scene), 3))
        em[: max(1, len(scene) // 50)] = 1.0
        scene = scene.with_materials(emission=em)
    F = pydynrad.form_factors(scene, resolution=resolution, device=device, progress=progress)
    return scene, F, f"hemicube R={resolution}"


def _matvec_rows(device, sizes, copy_gbs):
    from pydynrad.device.matrix import DeviceMatrix

    rows = []
    rng = np.random.default_rng(1)
    for M in sizes:
        K = rng.random((1, M, M), dtype=np.float32)
        x = rng.random(M, dtype=np.float32)
        t_np = time_call(lambda: K[0] @ x)["median_s"]
        for storage in ("fp16", "fp32", "fp64"):
            if storage == "fp64" and not device.supports_fp64:
                continue
            m = DeviceMatrix(device, K, storage)
            xb = device.to_device(np.pad(x, (0, m.ld - M)).astype(m.real_dtype))
            import pyopencl as cl

            yb = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, M * m.real_dtype.itemsize)

            def run():
                m.enqueue_matvec(0, xb, yb)
                device.queue.finish()

            t = time_call(run, repeats=9)
            gbs = m.channel_nbytes / t["median_s"] / 1e9
            x3 = device.to_device(np.zeros((3, m.ld), dtype=m.real_dtype))
            y3 = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, 3 * M * m.real_dtype.itemsize)

            def run3():
                m.enqueue_matvec(0, x3, y3, 3)
                device.queue.finish()

            t3 = time_call(run3, repeats=9)["median_s"]
            rows.append(
                [
                    M,
                    storage,
                    t["median_s"] * 1e3,
                    gbs,
                    gbs / copy_gbs,
                    t3 * 1e3,
                    3 * t["median_s"] / t3,
                    t_np * 1e3,
                    K[0].nbytes / t_np / 1e9,
                    t["warmup_s"] * 1e3,
                ]
            )
    return rows


def _jacobi_scipy(F, rho, L):
    B = L.copy()
    for it in range(1, 100001):
        Bn = L + rho * (F @ B)
        r = np.abs(Bn - B).max() / np.abs(Bn).max()
        B = Bn
        if r <= TOL:
            return B, it
    return B, it


def _gmres_scipy(F, rho, L):
    n = F.shape[0]
    A = sp.identity(n, format="csr") - sp.diags(rho[:, 0]) @ F
    return np.stack([spla.gmres(A, L[:, c], rtol=TOL, restart=50)[0] for c in range(L.shape[1])], axis=1)


def _solver_rows(device, Ns, village, resolution, progress):
    import pydynrad
    from pydynrad.solution import RadiositySolver

    rows = []
    cases = [(n, None) for n in Ns] + ([(0, village)] if village else [])
    for n, vil in cases:
        scene, F, source = _scene_and_F(n, device, vil, resolution, progress)
        N = len(scene)
        L = pydynrad.light_vector(scene, device=device)
        rho = scene.albedo[:, :1].astype(np.float64)
        solver = RadiositySolver(scene, F, dtype=np.float32, device=device)
        ours = time_call(lambda: solver.solve(L, tol=TOL), repeats=3)
        sol = ours["result"]
        rgb = time_call(lambda: solver.solve(L * np.array([1.0, 0.6, 0.3]), tol=TOL), repeats=3)["median_s"]
        bytes_per_bounce = F.nnz * 8 + 4 * (N + 1)
        F64 = sp.csr_matrix(F, dtype=np.float64)
        jac = time_call(lambda: _jacobi_scipy(F64, rho, L[:, :1]), repeats=1, warmup=0)
        gm = time_call(lambda: _gmres_scipy(F64, rho, L[:, :1]), repeats=1, warmup=0)
        dense = np.nan
        if N <= 4096:
            dense = time_call(lambda: pydynrad.solve(scene, F, light=L, method="dense"), repeats=1, warmup=0)[
                "median_s"
            ]
        ref = pydynrad.solve(scene, F, light=L, dtype=np.float64, tol=1e-10, device=device).radiosity
        err = np.abs(sol.radiosity - ref).max() / np.abs(ref).max()
        rows.append(
            [
                scene.name,
                N,
                F.nnz,
                source,
                sol.iterations,
                ours["median_s"] * 1e3,
                err,
                bytes_per_bounce * sol.iterations / ours["median_s"] / 1e9,
                rgb * 1e3,
                jac["median_s"] * 1e3,
                jac["result"][1],
                gm["median_s"] * 1e3,
                dense * 1e3,
            ]
        )
    return rows


def _build_rows(device, sizes, resolution, progress):
    from pydynrad.bounces import multibounce_block

    rows = []
    for M in sizes:
        scene, F, source = _scene_and_F(M, device, resolution=resolution, progress=progress)
        idx = np.arange(min(M, len(scene)))
        m = len(idx)
        # The same system from the block of F: multibounce_block is what DynamicRadiosity calls.
        block, rho = F[idx][:, idx], scene.albedo[idx, :1].astype(np.float64)
        Fd = block.toarray().astype(np.float64)
        A = np.eye(m) - Fd * rho[:, 0][None, :]
        A32, F32 = A.astype(np.float32), Fd.astype(np.float32)
        ours, theirs = {}, {}
        for name, dtype, a, f in (("f32", np.float32, A32, F32), ("f64", np.float64, A, Fd)):
            # Alternated, fastest of 3 each: the machine is shared and its load moves.
            for _ in range(3):
                # As DynamicRadiosity builds K: its rows were validated when fetched (checked=True);
                # the public call without it adds an O(nnz) check of the block (~3 ms at M = 768).
                t = time_call(
                    lambda dtype=dtype: multibounce_block(
                        block, rho, dtype=dtype, device=device, progress=False, checked=True
                    ),
                    repeats=1,
                    warmup=0,
                )
                n = time_call(lambda a=a, f=f: np.linalg.solve(a, f), repeats=1, warmup=0)
                ours[name] = min(ours.get(name, np.inf), t["min_s"])
                theirs[name] = min(theirs.get(name, np.inf), n["min_s"])
                ours[name + " K"], theirs[name + " K"] = t["result"][0], n["result"]
        truth = theirs["f64 K"]
        err = np.abs(ours["f32 K"] - truth).max() / np.abs(truth).max()
        flops = 3.0 * m**3
        rows.append(
            [
                m,
                source,
                ours["f32"],
                flops / ours["f32"] / 1e9,
                err,
                theirs["f32"],
                ours["f32"] / theirs["f32"],
                ours["f64"],
                theirs["f64"],
                ours["f64"] / theirs["f64"],
            ]
        )
    return rows


def measure(size: str, device, progress: bool = True) -> dict:
    """All tables for one size (see the module notes); ``progress``: tqdm bars while F is computed."""
    p = SIZES[size]
    copy_np, copy_dev = copy_bandwidth_numpy(), copy_bandwidth_device(device)
    tables = [
        {
            "title": "Copy bandwidth of this machine (read + write)",
            "columns": ["copy", "GB/s"],
            "rows": [["numpy np.copyto, 256 MiB", copy_np], ["OpenCL buffer copy, 256 MiB", copy_dev]],
        },
        {
            "title": "Lighting product y = K x (one channel)",
            "columns": [
                "M",
                "storage",
                "ms",
                "GB/s of K",
                "/ device copy",
                "3 vectors, one pass ms",
                "3 x one-vector / one pass",
                "numpy f32 gemv ms",
                "numpy GB/s",
                "first call ms",
            ],
            "rows": _matvec_rows(device, p["M"], copy_dev),
            "note": "K is read once per product; compare its GB/s with the copy bandwidth (read + write) above. "
            "'3 vectors, one pass': DeviceMatrix.matmat's kernel multiplying three vectors (RGB light "
            "under a grey K) while streaming K once.",
        },
        {
            "title": "Full radiosity solve (bounce iteration, float32, tol 1e-6) vs SciPy/numpy",
            "columns": [
                "scene",
                "N",
                "nnz(F)",
                "F",
                "bounces",
                "ours ms",
                "rel. error",
                "SpMV GB/s",
                "ours RGB ms",
                "SciPy Jacobi ms",
                "SciPy bounces",
                "SciPy GMRES ms",
                "numpy dense ms",
            ],
            "rows": _solver_rows(device, p["N"], p["village"], p["R"], progress),
            "note": "SciPy runs one channel (the scenes are grey), float64. rel. error vs a float64 solve at tol 1e-10. "
            "'ours RGB ms': the same scene under a coloured light (three channels, still one pass over F "
            "per bounce).",
        },
        {
            "title": "Multibounce build K = (I - F P)^-1 F (grey) vs numpy.linalg.solve on the same system",
            "columns": [
                "M",
                "F",
                "ours f32 s",
                "GFLOP/s (3 M^3)",
                "rel. error vs f64",
                "numpy f32 s",
                "ours / numpy f32",
                "ours f64 s",
                "numpy f64 s",
                "ours / numpy f64",
            ],
            "note": "ours: multibounce_block (on a CPU device numpy's LAPACK, on a GPU the OpenCL Gauss-Jordan) on the "
            "block as DynamicRadiosity passes it (checked=True: its rows were validated when fetched; called "
            "without, the block's O(nnz) check adds ~3 ms at M = 768); fastest of 3, alternated with numpy's.",
            "rows": _build_rows(device, p["build_M"], p["R"], progress),
        },
    ]
    return {
        "title": "Reference radiosity and kernel bandwidth",
        "description": "\n\n".join(__doc__.split("\n\n")[2:4]),
        "tables": tables,
    }


def suite_section(ctx) -> dict:
    """The suite's "bandwidth" section: matvec sizes from the suite's parameters."""
    size = ctx.size if ctx.size in SIZES else "quick"
    p = dict(SIZES[size])
    p["M"] = tuple(ctx.params.get("M", p["M"]))
    SIZES["_suite"] = p
    try:
        return measure("_suite", ctx.device, ctx.progress)
    finally:
        del SIZES["_suite"]


def main(argv=None) -> int:
    return run_standalone("radiosity", __doc__, SIZES, measure, argv)


if __name__ == "__main__":
    raise SystemExit(main())
