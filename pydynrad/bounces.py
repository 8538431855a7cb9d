"""The multibounce matrix K_S = (I - F_SS P_S)^{-1} F_SS of a patch set S (the paper's [26]).

``K[a, b]`` is all light leaving patch b that reaches patch a over every path whose
intermediate bounces stay inside S; for a light vector L, ``B_S = L_S + P_S K L_S`` (one
matrix-vector product: see :func:`multibounce_radiosity`). K depends on the albedos, so there
is one K per colour channel, and one for a scene whose albedos are all grey.

Method: blocked Gauss-Jordan elimination on the device. The system ``A K = F_SS`` with
``A = I - F_SS P_S`` is solved by eliminating one panel of ``nb`` columns at a time: the host
inverts the nb x nb pivot block (float64) and scales the panel's rows, and the device applies
the rank-nb update ``W -= U V`` to the rest of ``[A | F_SS]`` with a register-blocked GEMM
kernel (``kernels/gemm.cl``). Why this and not a series: the cost is fixed, 3 M^3 flops, for
any albedo, and the result is exact to working precision; a truncated series needs
ln(eps)/ln(rho) bounces (15,000 at rho = 0.999 in float32) and repeated squaring about
2 log2 of that GEMMs (28 at rho = 0.999, 2 M^3 flops each: 19x the work). No pivoting is
needed: every row of A has off-diagonal sum sum_j F_ij rho_j <= max rho < 1 = its diagonal
(strict row diagonal dominance), for which elimination without pivoting is stable (growth
factor <= 2). Accuracy: relative error about cond(A) * eps, cond(A) <= (1 + rho)/(1 - rho);
float32 gives ~1e-5 at rho = 0.9 and ~1e-3 at rho = 0.999; use dtype=np.float64 there.

On a CPU device the same system is solved by the host's LAPACK through ``numpy.linalg.solve``
(LU with partial pivoting, the same flops), and the series by numpy's matrix products:
an OpenCL CPU runtime's GEMM does not reach the BLAS numpy links against (docs/decisions/0009-host-lapack-and-one-blas-thread.md). With no more cores than channels the channels are solved side
by side, one core and one BLAS thread each: a threaded BLAS shares a few cores among its own
threads by spinning, which on a busy machine of few cores made the channels, solved in turn,
several times slower than side by side. GPUs run the kernels; ``backend="device"`` forces them anywhere.

``bounces=n`` instead gives the truncated series sum_{k=0}^{n} (F_SS P_S)^k F_SS (paths of at
most n + 1 hops; what a fixed-bounce renderer computes), one M^3 GEMM per bounce.

See docs/design.md, 'Multibounce build'.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.sparse as sp

from .checks import check_form_factor_rows, check_form_factors, patch_indices
from .device.devices import default_device, device_or_default, real_dtype
from .device.launch import GEMM_GRAIN, PANEL, enqueue_kernel, gemm_layout, round_up
from .device.matrix import DeviceMatrix
from .errors import InvalidInputError, OutOfMemoryError
from .geometry.loading import checked_scene
from .geometry.scene import PrecisionWarning
from .host.blas import one_blas_thread
from .host.memory import available_host_bytes
from .host.shortcuts import host_shortcuts
from .host.threads import cores as host_cores
from .host.threads import pool as host_pool
from .lights.sources import check_radiosity_range, resolve_light
from .progress import progress_bar

__all__ = ["multibounce", "multibounce_block", "multibounce_radiosity", "multibounce_memory"]

OUTPUT_DTYPES = (np.dtype(np.float16), np.dtype(np.float32), np.dtype(np.float64))
BACKENDS = ("auto", "device", "host")


#: Most flops (2 m n kdim) one ``gemm_acc`` launch computes: ~80 ms on a small GPU at
#: 1 TFLOP/s fp32 (the bound in ``kernels/gemm.cl``'s header); longer products go in row blocks.
GEMM_FLOPS_PER_LAUNCH = 8 * 10**10


def _padded(M: int) -> tuple[int, int]:
    """(panel width, padded size): the system is padded with identity rows to a whole number of
    panels, each a multiple of every GEMM tile."""
    nb = min(PANEL, round_up(M, GEMM_GRAIN))
    return nb, round_up(M, nb)


def multibounce_memory(M: int, channels: int, dtype=np.float32, bounces: int | None = None) -> dict[str, int]:
    """Bytes the build of an M-patch K needs: ``host`` (result plus temporaries), ``device``
    (all working buffers) and ``device_buffer`` (the largest single buffer)."""
    out = np.dtype(dtype)
    w = 8 if out == np.float64 else 4
    nb, Mp = _padded(M)
    square = Mp * Mp * w
    host = channels * M * M * out.itemsize + 3 * M * M * 8 + 2 * square
    device = (3 if bounces is not None else 2) * square + (Mp * nb + nb * 2 * Mp) * w
    return {"host": host, "device": device, "device_buffer": square}


def _check_memory(M: int, C: int, out: np.dtype, bounces, device) -> None:
    need = multibounce_memory(M, C, out, bounces)
    gib = 2.0**30
    if need["host"] > available_host_bytes():
        raise OutOfMemoryError(
            f"the multibounce matrix of {M} patches ({C} channel(s), {out.name}) needs {need['host'] / gib:.1f} GiB of "
            f"host memory (the result alone is {C * M * M * out.itemsize / gib:.1f} GiB); "
            f"{available_host_bytes() / gib:.1f} GiB is available. Use fewer patches (DynamicRadiosity keeps a local set)"
        )
    if need["device_buffer"] > device.max_alloc_bytes or need["device"] > device.global_mem_bytes:
        raise OutOfMemoryError(
            f"building the multibounce matrix of {M} patches needs {need['device'] / gib:.2f} GiB of device memory in "
            f"buffers of {need['device_buffer'] / gib:.2f} GiB; {device.name} allows {device.global_mem_bytes / gib:.2f} "
            f"GiB in all and {device.max_alloc_bytes / gib:.2f} GiB per buffer"
        )


def _checked_patches(patches, n: int) -> np.ndarray:
    """The set S: all patches, or ``patches`` (K's rows and columns, so distinct and non-empty)."""
    return np.arange(n) if patches is None else patch_indices(patches, n, "patches", unique=True, nonempty=True)


class _Builder:
    """Device buffers and kernels for one build; one channel at a time."""

    def __init__(self, device, M: int, work: np.dtype) -> None:
        import pyopencl as cl

        self.device, self.M, self.work = device, M, work
        self.nb, self.Mp = _padded(M)
        self.lay = gemm_layout(device, work.itemsize)
        defines = {"STORAGE_FP64" if work == np.float64 else "STORAGE_FP32": 1, **self.lay.defines}
        self.kernel = device.kernel("gemm.cl", "gemm_acc", defines)
        self.square_bytes = self.Mp * self.Mp * work.itemsize
        mf = cl.mem_flags
        self.A = cl.Buffer(device.context, mf.READ_WRITE, self.square_bytes)
        self.F = cl.Buffer(device.context, mf.READ_WRITE, self.square_bytes)

    def padded(self, X: np.ndarray, diagonal: float) -> np.ndarray:
        out = np.zeros((self.Mp, self.Mp), dtype=self.work)
        out[: self.M, : self.M] = X
        out[np.arange(self.M, self.Mp), np.arange(self.M, self.Mp)] = diagonal
        return out

    def gemm(self, m, n, kdim, U, ldu, V, ldv, v_off, base, ldb, b_off, out, ldo, o_off) -> None:
        """out[o_off:] (m x n) = base[b_off:] + U V (see kernels/gemm.cl)."""
        if n == 0:
            return
        i32 = np.int32
        # Launches of whole TM-row blocks of at most GEMM_FLOPS_PER_LAUNCH flops (2 rows n kdim):
        # rows r0 .. r0 + rows - 1 through U's, base's and out's offsets. Every element of out is
        # one work-item's sum over k in order, so the blocks' results are the one launch's.
        tm = self.lay.tm
        rows = max(tm, GEMM_FLOPS_PER_LAUNCH // (2 * n * kdim) // tm * tm)
        for r0 in range(0, m, rows):
            rm = min(rows, m - r0)
            enqueue_kernel(
                self.device,
                self.kernel,
                *self.lay.grid(rm, n),
                i32(rm),
                i32(n),
                i32(kdim),
                U,
                i32(ldu),
                i32(r0 * ldu),
                V,
                i32(ldv),
                i32(v_off),
                base,
                i32(ldb),
                i32(b_off + r0 * ldb),
                out,
                i32(ldo),
                i32(o_off + r0 * ldo),
            )

    def read(self, buf) -> np.ndarray:
        import pyopencl as cl

        out = np.empty((self.Mp, self.Mp), dtype=self.work)
        cl.enqueue_copy(self.device.queue, out, buf, is_blocking=True)
        return out[: self.M, : self.M]

    def gauss_jordan(self, A: np.ndarray, F: np.ndarray, bar) -> np.ndarray:
        """Solve A K = F (A row diagonally dominant) by blocked Gauss-Jordan; returns K (M, M)."""
        import pyopencl as cl

        q, nb, Mp, w = self.device.queue, self.nb, self.Mp, self.work.itemsize
        cl.enqueue_copy(q, self.A, self.padded(A, 1.0))
        cl.enqueue_copy(q, self.F, self.padded(F, 0.0))
        rows_A = np.empty((nb, Mp), dtype=self.work)
        rows_F = np.empty((nb, Mp), dtype=self.work)
        col = np.empty((Mp, nb), dtype=self.work)
        mf = cl.mem_flags
        U = cl.Buffer(self.device.context, mf.READ_ONLY, Mp * nb * w)
        V = cl.Buffer(self.device.context, mf.READ_ONLY, nb * 2 * Mp * w)
        for r0 in range(0, Mp, nb):
            c0 = r0 + nb  # A's columns left of c0 are already eliminated (identity): never touched again
            cl.enqueue_copy(q, rows_A, self.A, src_offset=r0 * Mp * w)
            cl.enqueue_copy(q, rows_F, self.F, src_offset=r0 * Mp * w)
            cl.enqueue_copy(
                q,
                col,
                self.A,
                buffer_origin=(r0 * w, 0),
                host_origin=(0, 0),
                region=(nb * w, Mp),
                buffer_pitches=(Mp * w,),
                host_pitches=(nb * w,),
                is_blocking=True,
            )
            # Pivot rows scaled by the inverse pivot block, in float64 on the host (nb^2 (2M) flops).
            pivot_inv = np.linalg.inv(rows_A[:, r0:c0].astype(np.float64))
            scaled = np.ascontiguousarray(np.hstack([pivot_inv @ rows_A[:, c0:], pivot_inv @ rows_F]), dtype=self.work)
            neg_col = -col
            neg_col[r0:c0] = 0  # the pivot rows are replaced, not updated
            cl.enqueue_copy(q, U, neg_col)
            cl.enqueue_copy(q, V, scaled)
            ldv = scaled.shape[1]
            self.gemm(Mp, Mp - c0, nb, U, nb, V, ldv, 0, self.A, Mp, c0, self.A, Mp, c0)
            self.gemm(Mp, Mp, nb, U, nb, V, ldv, Mp - c0, self.F, Mp, 0, self.F, Mp, 0)
            rows_A[:, c0:] = scaled[:, : Mp - c0]
            cl.enqueue_copy(q, self.A, rows_A, dst_offset=r0 * Mp * w)
            cl.enqueue_copy(q, self.F, np.ascontiguousarray(scaled[:, Mp - c0 :]), dst_offset=r0 * Mp * w)
            q.finish()
            bar.update(1)
        return self.read(self.F)

    def series(self, FP: np.ndarray, F: np.ndarray, bounces: int, bar) -> np.ndarray:
        """sum_{k=0}^{bounces} FP^k F by K <- F + FP K."""
        import pyopencl as cl

        q, Mp = self.device.queue, self.Mp
        cl.enqueue_copy(q, self.A, self.padded(FP, 0.0))
        cl.enqueue_copy(q, self.F, self.padded(F, 0.0))
        K = cl.Buffer(
            self.device.context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=self.padded(F, 0.0)
        )
        K_next = cl.Buffer(self.device.context, cl.mem_flags.READ_WRITE, self.square_bytes)
        for _ in range(bounces):
            self.gemm(Mp, Mp, Mp, self.A, Mp, K, Mp, 0, self.F, Mp, 0, K_next, Mp, 0)
            K, K_next = K_next, K
            q.finish()
            bar.update(1)
        return self.read(K)


def multibounce(
    scene,
    F,
    patches=None,
    bounces: int | None = None,
    dtype=np.float32,
    device=None,
    progress: bool | None = None,
    backend: str = "auto",
) -> np.ndarray:
    """K_S = (I - F_SS P_S)^{-1} F_SS per colour channel.

    Parameters
    ----------
    scene : Scene
    F : (N, N) scipy.sparse or dense
        Gathering form factors (validated: shape, finite, >= 0, rows summing to <= 1).
    patches : (M,) int, optional
        The set S, in the order of K's rows and columns (all patches by default). A caller
        that already holds F_SS passes it to :func:`multibounce_block` instead.
    bounces : int, optional
        None: the exact inverse (blocked Gauss-Jordan). n: the series truncated after n
        reflections, sum_{k<=n} (F P)^k F.
    dtype : np.float16 | np.float32 | np.float64
        Type of the result. Computed in float32 (float16: the float32 result rounded to
        nearest even, the storage rounding) or float64.
    device : Device, optional
    progress : bool, optional
        Show a tqdm bar; None: once the build has taken two seconds (:mod:`pydynrad.progress`).
    backend : "auto" | "device" | "host"
        Who does the O(M^3) work: "device" the OpenCL kernels, "host" numpy (LAPACK/BLAS),
        "auto" the host when ``device`` is a CPU (its traits say so: ``Device.with_traits(cpu=False)`` or
        ``PYDYNRAD_FORCE_DEVICE=1`` takes the device path, :func:`pydynrad.host.shortcuts.host_shortcuts`), else the device.

    Returns
    -------
    (C, M, M) ndarray of ``dtype``, C = 1 if ``scene.is_grey`` else 3 (RGB).

    Raises
    ------
    OutOfMemoryError
        Before allocating anything, when the result or the working buffers would not fit in
        host memory or on the device (e.g. all 63,125 patches of the paper's scene: 44 GiB).
    """
    out, bounces = _checked_options(dtype, bounces, backend)
    device = device_or_default(device)
    scene = checked_scene(scene)
    idx = _checked_patches(patches, len(scene))
    if bounces is None:
        warn_precision(
            float(scene.albedo[idx].max()) if len(idx) else 0.0,
            "float64" if out == np.float64 else "float32",
            stacklevel=2,
        )
    M, C = len(idx), 1 if scene.is_grey else 3
    _check_memory(M, C, out, bounces, device)
    F = check_form_factors(scene, F)
    return _build(F[idx][:, idx], scene.albedo[idx, :C].astype(np.float64), bounces, out, device, progress, backend)


#: The rounding of K's float32 arithmetic, amplified by the albedo (2^-24 / (1 - max albedo)),
#: beyond which a build warns that it wants float64 (max albedo ~0.99994).
PRECISION_LIMIT = 1e-3


def warn_precision(max_albedo: float, arithmetic: str, stacklevel: int = 2) -> bool:
    """Warn (:class:`~pydynrad.geometry.scene.PrecisionWarning`) and return True where float32
    ``arithmetic`` cannot hold K: the series K = F + F P F + ... amplifies rounding by up to
    1 / (1 - max albedo), so float32's 2^-24 becomes ~2^-24 / (1 - rho) of B (a closed box at
    0.9999999 was 3.5% off, at 0.999999 0.09%, in float64 8e-11)."""
    if arithmetic == "float64" or (max_albedo < 1.0 and 2.0**-24 / (1.0 - max_albedo) <= PRECISION_LIMIT):
        return False
    warnings.warn(
        f"an albedo of {max_albedo:.9g} amplifies float32 rounding in K to about "
        f"{2.0**-24 / max(1.0 - max_albedo, 1e-300):.2g} of B: build it in float64 (storage='fp64', "
        "dtype=np.float64)",
        PrecisionWarning,
        stacklevel=stacklevel + 1,
    )
    return True


def multibounce_block(
    F_SS,
    albedo,
    bounces: int | None = None,
    dtype=np.float32,
    device=None,
    progress: bool | None = None,
    backend: str = "auto",
    *,
    checked: bool = False,
) -> np.ndarray:
    """K = (I - F_SS P)^{-1} F_SS from the block of F over the set, for callers that hold it.

    :func:`multibounce` with ``patches`` validates all of F and cuts this block out of it; a
    caller that keeps the set's rows of F (:class:`~pydynrad.DynamicRadiosity` on a refresh)
    passes the block and the set's albedos instead, and only they are checked.

    Parameters
    ----------
    F_SS : (M, M) scipy.sparse or dense
        F's rows and columns of the set, in K's order (validated: finite, >= 0, rows summing
        to <= 1; they are parts of F's rows, whose sums the caller checked when it got them).
    albedo : (M, C) float
        The set's albedo per channel of K (C = 1 for a grey scene, else 3), each in [0, 1).
    bounces, dtype, device, progress, backend
        As in :func:`multibounce`.
    checked : bool
        The caller made ``F_SS`` from validated parts: take it as it is. The far field's coarse
        F_c = R F Pr (a weighted prolongation lets its rows sum above 1, R Pr = I, not
        Pr 1 = 1, while the system stays well posed, which the check would refuse), and
        :class:`~pydynrad.DynamicRadiosity`'s local set, whose rows were validated when fetched.

    Returns
    -------
    (C, M, M) ndarray of ``dtype``.
    """
    out, bounces = _checked_options(dtype, bounces, backend)
    device = device or default_device()
    shape = np.shape(F_SS)
    if len(shape) != 2 or shape[0] != shape[1] or shape[0] == 0:
        raise InvalidInputError(f"F_SS must be a non-empty square (M, M) matrix; got shape {shape}")
    M = shape[0]
    rho = np.asarray(albedo, dtype=np.float64)
    if rho.ndim != 2 or rho.shape[0] != M or rho.shape[1] not in (1, 3):
        raise InvalidInputError(f"albedo must have shape ({M}, 1) or ({M}, 3) for a {M} x {M} block; got {rho.shape}")
    if not np.all(np.isfinite(rho)) or rho.min() < 0 or rho.max() >= 1:
        raise InvalidInputError("albedo must be finite and in [0, 1)")
    _check_memory(M, rho.shape[1], out, bounces, device)
    if checked:
        block = F_SS if sp.issparse(F_SS) else np.asarray(F_SS, dtype=np.float64)
    else:  # a copy: the caller's matrix is never touched
        block = check_form_factor_rows(F_SS, "F_SS")
    return _build(block, rho, bounces, out, device, progress, backend)


def _checked_options(dtype, bounces, backend) -> tuple[np.dtype, int | None]:
    if backend not in BACKENDS:
        raise InvalidInputError(f"backend must be one of {BACKENDS}; got {backend!r}")
    out = np.dtype(dtype)
    if out not in OUTPUT_DTYPES:
        raise InvalidInputError(f"dtype must be float16, float32 or float64; got {out}")
    if bounces is not None and (int(bounces) != bounces or bounces < 0):
        raise InvalidInputError(f"bounces must be None or a non-negative integer; got {bounces!r}")
    return out, None if bounces is None else int(bounces)


def _host_build(FP: np.ndarray, F: np.ndarray, bounces: int | None, bar) -> np.ndarray:
    """K from FP = F_SS P_S and F_SS (M, M) of the working dtype by numpy: the LU solve of
    (I - FP) K = F, or the series K <- F + FP K. FP is overwritten."""
    if bounces is None:
        A = np.negative(FP, out=FP)
        A[np.diag_indices_from(A)] += 1
        K = np.linalg.solve(A, F)
        bar.update(1)
        return K
    K = F
    for _ in range(bounces):
        K = F + FP @ K
        bar.update(1)
    return K


def _host_channels(F_work: np.ndarray, rho: np.ndarray, bounces: int | None, result: np.ndarray, bar) -> None:
    """result[c] = K of channel c by numpy; the channels side by side, one BLAS thread each,
    when there are no more cores than channels (see the module's docstring)."""
    C = rho.shape[1]

    def channel(c: int) -> None:
        # In the working dtype from the start: no float64 pass over M^2 before the solve.
        result[c] = _host_build(F_work * rho[:, c].astype(F_work.dtype)[None, :], F_work, bounces, bar)

    cores = host_cores()
    if C == 1 or cores > C:
        for c in range(C):
            channel(c)
        return

    with one_blas_thread():
        list(host_pool().map(channel, range(C)))


def _build(
    F_SS: np.ndarray, rho: np.ndarray, bounces: int | None, out: np.dtype, device, progress, backend: str = "auto"
) -> np.ndarray:
    """K per channel from a validated F_SS (M, M, sparse or dense; never written) and albedos
    rho (M, C), float64. The host's solve takes F_SS made dense in its working dtype at once
    (a float64 copy first cost a fifth of numpy's own solve at M = 768)."""

    work = real_dtype(np.float64 if out == np.float64 else np.float32, device)
    M, C = rho.shape
    host = backend == "host" or (backend == "auto" and host_shortcuts(device))
    builder = None if host else _Builder(device, M, work)
    if bounces is not None:
        steps = bounces
    else:
        steps = 1 if host else builder.Mp // builder.nb
    result = np.empty((C, M, M), dtype=out)
    with progress_bar(progress, total=C * steps, desc=f"multibounce M={M}", unit="step") as bar:
        if host:
            F_work = F_SS.astype(work).toarray() if sp.issparse(F_SS) else np.array(F_SS, dtype=work)
            _host_channels(F_work, rho, bounces, result, bar)
            return result
        F_SS = F_SS.toarray() if sp.issparse(F_SS) else F_SS
        for c in range(C):
            FP = F_SS * rho[:, c][None, :]  # F_SS P_S: column j scaled by rho_j
            if bounces is None:
                K = builder.gauss_jordan(np.eye(M) - FP, F_SS, bar)
            else:
                K = builder.series(FP, F_SS, bounces, bar)
            result[c] = K
    return result


def multibounce_radiosity(scene, K, lights=(), *, light=None, patches=None, device=None) -> np.ndarray:
    """B (N, 3) float64: L + P K L on the patches of K, L elsewhere (as :meth:`DynamicRadiosity.radiosity`).

    K : (C, M, M) ndarray or :class:`~pydynrad.device.matrix.DeviceMatrix` from :func:`multibounce`
        over ``patches`` (all N patches by default).

    lights : light objects (see :func:`pydynrad.light_vector`), or
    light : a precomputed (N, 3) light vector L of the whole scene.

    Changing a light or an emission changes only L: one light pass plus this one product.
    """

    scene = checked_scene(scene)
    idx = _checked_patches(patches, len(scene))
    L = resolve_light(scene, lights, light, device)
    C, M = (K.C, K.M) if isinstance(K, DeviceMatrix) else (np.shape(K)[0], np.shape(K)[1])
    if M != len(idx) or C not in (1, 3) or (not isinstance(K, DeviceMatrix) and np.shape(K) != (C, M, M)):
        raise InvalidInputError(f"K must be (1 or 3, {len(idx)}, {len(idx)}) for these patches; got {np.shape(K)}")
    LS = L[idx].T  # (3, M)
    if isinstance(K, DeviceMatrix):  # only a device K has a type B could overflow (a host K is float64)
        check_radiosity_range(L[idx], scene.albedo[idx], K.real_dtype)
        KL = K.matmat(LS[None])[0] if C == 1 else K.matvec(LS)  # one K, three colours in one pass
    else:
        Kd = np.asarray(K, dtype=np.float64)
        KL = np.einsum("cij,cj->ci", Kd if C == 3 else np.repeat(Kd, 3, axis=0), LS)
    B = L.copy()
    B[idx] = L[idx] + scene.albedo[idx].astype(np.float64) * KL.T
    return B
