"""Every kernel of kernels/ launched on tiny inputs, for a run under Oclgrind (test_oclgrind.py).

Run as a script in a process whose OpenCL device is Oclgrind (``PYOPENCL_CTX=oclgrind``, its
``OCLGRIND_*`` settings, ``PYDYNRAD_FORCE_DEVICE=1``). Oclgrind reports what it finds on file
descriptor 2, so this script sends Python's own stderr to stdout: every line left on fd 2 is
Oclgrind's (its instruction counts, which name the kernels launched, and any diagnostic).

Each case runs twice where the kernels differ by device family: with the device's own traits
(Oclgrind says it is a GPU, so the GPU layouts and kernels) and with CPU traits
(``Device.with_traits(cpu=True, ...)``: the CPU kernels, the SELL solve), where
``PYDYNRAD_FORCE_DEVICE=1`` keeps every product on the device. The answers are checked against
numpy loosely (the point is the simulator's checks, the numerics are tested on PoCL).
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np
import scipy.sparse as sp


def close(got, want, tol, what):
    got, want = np.asarray(got, np.float64), np.asarray(want, np.float64)
    err = float(np.max(np.abs(got - want))) / max(1e-30, float(np.max(np.abs(want))))
    if not err <= tol:
        raise AssertionError(f"{what}: relative error {err:.3g} > {tol:g}")


def selftest(dev):
    import pyopencl as cl

    x = np.arange(64, dtype=np.float32)
    buf = cl.Buffer(dev.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=x)
    dev.kernel("selftest.cl", "scale")(dev.queue, (64,), (64,), buf)
    out = np.empty_like(x)
    cl.enqueue_copy(dev.queue, out, buf, is_blocking=True)
    close(out, 2 * x, 0, "selftest scale")


def matrices(dev, label):
    """matvec (1-4 right-hand sides), rmatvec_partial and _reduce in every storage."""
    from pydynrad.device.matrix import DeviceMatrix

    rng = np.random.default_rng(1)
    M = 70  # ld = 128: padding columns and a row count that is no multiple of any work-group
    K = rng.random((2, M, M)) / M
    X = rng.random((2, 3, M))
    for storage, tol in (("fp16", 2e-3), ("fp32", 1e-5), ("fp64", 1e-12)):
        m = DeviceMatrix(dev, K, storage)
        close(m.matvec(X[:, 0]), np.einsum("cij,cj->ci", K, X[:, 0]), tol, f"{label} matvec {storage}")
        close(m.matmat(X), np.einsum("cij,cqj->cqi", K, X), tol, f"{label} matmat {storage}")
        close(m.rmatvec(X[:, 0]), np.einsum("cij,ci->cj", K, X[:, 0]), tol, f"{label} rmatvec {storage}")


def updates(dev, label, cpu_kernels):
    """Every kernel of update.cl: gathers dense and sparse, rank updates, slots, Eq. 1."""
    from pydynrad.device.matrix import DeviceMatrix
    from pydynrad.dynamic.kupdate import UpdateKernels

    rng = np.random.default_rng(2)
    M = 70
    K = rng.random((1, M, M)) / M
    for storage, tol in (("fp16", 3e-3), ("fp32", 1e-5)):
        m = DeviceMatrix(dev, K, storage)
        want = m.to_host()[0].astype(np.float64)
        uk = UpdateKernels(m, 4, cpu_kernels=cpu_kernels)
        X, Y = rng.random((3, M)), rng.random((3, M))
        KX, YK = uk.gather(0, X, Y)
        close(KX, X @ want.T, tol, f"{label} gather KX {storage}")
        close(YK, Y @ want, tol, f"{label} gather YK {storage}")
        Xs, Ys = np.zeros((1, 2, M)), np.zeros((1, 2, M))
        Xs[0, :, [3, 40]], Ys[0, :, [5]] = 1.0, 2.0
        slots = np.array([1, 66], np.int32)
        KXs, YKs, cols, rows = uk.gather_all(Xs, Ys, slots, sparse=True)
        close(KXs[0], Xs[0] @ want.T, tol, f"{label} sparse gather {storage}")
        close(YKs[0], Ys[0] @ want, tol, f"{label} sparse gather {storage}")
        close(cols[0], want[:, slots].T, tol, f"{label} read_slots {storage}")
        A, B = rng.random((5, M)) * 0.01, rng.random((5, M)) * 0.01
        uk.rank_update(0, A, B)
        want = want + A.T @ B
        new_cols, new_rows = rng.random((2, M)), rng.random((2, M))
        new_rows[:, slots] = new_cols[:, slots].T  # they agree where they cross
        uk.update_slots(0, A[:2], B[:2], slots, new_cols, new_rows)
        want = want + A[:2].T @ B[:2]
        want[slots, :] = new_rows
        want[:, slots] = new_cols.T
        uk.write_slots(0, slots[:1], new_cols[:1], new_rows[:1])
        uk.clear_slot(0, 7)
        want[7, :] = want[:, 7] = 0
        close(m.to_host()[0], want, 5 * tol, f"{label} rank update and slots {storage}")
        f_c, f_r, rho = rng.random((3, M))
        close(uk.double_reflection(f_c, f_r, rho), np.sum(f_c * f_r * rho), 1e-5, f"{label} double_reflection")


def scene_cases(dev, label):
    """Form factors, both solves, multibounce, lights, gathers, rays, render, path tracer, lightmap."""
    import pydynrad
    from pydynrad.bake import bake_lightmap
    from pydynrad.bounces import multibounce
    from pydynrad.device.csr import DeviceCSR
    from pydynrad.device.launch import sell_layout
    from pydynrad.device.sell import DeviceSELL
    from pydynrad.geometry.bvh import cast_rays, occluded
    from pydynrad.lights.areas import emitter_irradiance
    from pydynrad.pathtracer import path_trace_patches
    from pydynrad.scenes.analytic import closed_box

    box = closed_box(subdivisions=1)  # 48 patches
    N = len(box)
    emission = np.zeros((N, 3))
    emission[np.argmax(box.centers[:, 1])] = 1.0  # one patch of the ceiling glows
    box = box.with_materials(emission=emission)
    light = pydynrad.PointLight((0.5, 0.7, 0.5), (1.0, 1.0, 1.0))
    F = pydynrad.form_factors(box, resolution=8, device=dev)
    rowsum = np.asarray(F.sum(axis=1)).ravel()
    if not np.all(np.abs(rowsum - 1) < 0.05):
        raise AssertionError(f"{label} form factor rows sum to {rowsum.min():.3f}..{rowsum.max():.3f} in a closed box")
    sol = pydynrad.solve(box, F, [light], device=dev)  # bounce, direct_irradiance
    B = sol.radiosity
    # The same solve as a grey SELL (CPU traits only) and a grey CSR: bounce_sell / bounce NCH = 1.
    grey = sp.csr_matrix(F, dtype=np.float64)
    L, rho = np.ones((N, 1)), np.full((N, 1), 0.5)
    want = np.linalg.solve(np.eye(N) - 0.5 * grey.toarray(), L)
    csr = DeviceCSR(dev, grey, np.float32)
    close(csr.jacobi(L, rho, L, 1e-6, 200)[0], want, 1e-4, f"{label} grey CSR solve")
    sell = sell_layout(dev, 4, 1)
    if sell is not None:
        close(
            DeviceSELL(dev, grey, np.float32, sell).jacobi(L, rho, L, 1e-6, 200)[0], want, 1e-4, f"{label} SELL solve"
        )
    K = multibounce(box, F, patches=np.arange(0, N, 2), device=dev)  # gemm_acc (device path forced on a CPU)
    S = np.arange(0, N, 2)
    FSS = F.toarray()[np.ix_(S, S)]
    close(K[0], np.linalg.solve(np.eye(len(S)) - FSS * box.albedo[S, 0][None, :], FSS), 1e-4, f"{label} multibounce")
    pts = np.array([[0.5, 0.2, 0.5], [0.3, 0.5, 0.6]])
    up = np.array([0.0, 1.0, 0.0])
    pydynrad.illuminance(box, B, pts, up, [light], resolution=8, device=dev)  # hemicube_gather, direct_irradiance
    emitter_irradiance(box, pts, up, grid=2, device=dev)
    o = np.tile([0.5, 0.5, 0.5], (70, 1))
    d = np.random.default_rng(3).normal(size=(70, 3))
    hit, t, _front = cast_rays(box, o, d, device=dev)
    if np.any(hit < 0):
        raise AssertionError(f"{label} a ray from inside a closed box escaped")
    occluded(box, o, d, tmax=0.01, device=dev)
    cam = pydynrad.Camera((0.5, 0.5, 0.95), (0.5, 0.5, 0.0), fov_y=60, width=12, height=9)
    pydynrad.render(box, B, cam, device=dev)  # primary_visibility
    pydynrad.path_trace(box, cam, spp=1, lights=[light], max_depth=3, device=dev, progress=False)  # trace_pixels
    path_trace_patches(box, patches=[0, 5], spp=1, lights=[light], max_depth=3, device=dev, progress=False)
    bake_lightmap(box, B, texels_per_unit=4.0, device=dev)  # lightmap_best, lightmap_owner


def dynamic_walk(dev, label):
    """A few frames of the exact fp16 walk: the update kernels as the frame loop drives them."""
    import pydynrad
    from pydynrad.scenes.analytic import closed_box

    box = closed_box(subdivisions=2)  # 192 patches
    F = pydynrad.form_factors(box, resolution=8, device=dev)
    dyn = pydynrad.DynamicRadiosity(
        box,
        F,
        local_size=64,
        update="exact",
        storage="fp16",
        max_swaps_per_frame=4,
        observer=[0.2, 0.5, 0.2],
        far_field=False,
        device=dev,
    )
    for p in ([0.3, 0.5, 0.3], [0.5, 0.5, 0.5], [0.8, 0.5, 0.8]):
        dyn.update(p)
    dyn.radiosity([pydynrad.PointLight((0.5, 0.7, 0.5), (1.0, 1.0, 1.0))])


def main() -> int:
    sys.stderr = sys.stdout  # fd 2 is left to Oclgrind (see the module's docstring)
    import pydynrad

    gpu = pydynrad.default_device()
    print(f"device: {gpu.name}; traits {gpu.traits}", flush=True)
    cpu = gpu.with_traits(cpu=True, compute_units=2, float_width=16, double_width=8)
    cases = [
        ("selftest", lambda: selftest(gpu)),
        ("matrices gpu", lambda: matrices(gpu, "gpu")),
        ("matrices cpu", lambda: matrices(cpu, "cpu")),
        ("updates gpu", lambda: updates(gpu, "gpu", False)),
        ("updates cpu", lambda: updates(cpu, "cpu", True)),
        ("scene gpu", lambda: scene_cases(gpu, "gpu")),
        ("scene cpu", lambda: scene_cases(cpu, "cpu")),
        ("dynamic walk gpu", lambda: dynamic_walk(gpu, "gpu")),
    ]
    only = set(os.environ.get("OCLGRIND_CASES", "").split(",")) - {""}
    failed = 0
    for name, run in cases:
        if only and name not in only:
            continue
        t0 = time.perf_counter()
        try:
            run()
        except Exception as exc:  # report every case, then fail
            failed += 1
            print(f"CASE FAILED {name}: {type(exc).__name__}: {exc}", flush=True)
        print(f"case {name}: {time.perf_counter() - t0:.1f} s", flush=True)
    out = os.environ.get("PYDYNRAD_PROGRAMS_OUT")
    if out:  # every (file, -D options) built, for the syntax-only build without cl_khr_fp64
        import json

        with open(out, "w") as f:
            json.dump(sorted([name, list(opts)] for name, opts in gpu._programs), f)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
