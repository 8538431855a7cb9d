"""A sparse matrix resident on the device and the bounce product ``y = L + P (A x)`` on it.

One pass over A's values with ``kernels/spmv.cl``'s ``bounce`` kernel per product; rows and
columns need not match (x has A's columns, L, P and y its rows). The full solve iterates it
with A = F (:class:`pydynrad.solution.RadiositySolver`; grey solves on wide-SIMD CPUs use
:mod:`pydynrad.device.sell` instead); the far field with A = F_c (the coarse
sweeps), G (every patch from the clusters) and F (the first bounce and the fine sweeps).
"""

from __future__ import annotations

import threading
import time

import numpy as np
import scipy.sparse as sp

from ..errors import InvalidInputError, OutOfMemoryError
from ..host.anderson import Anderson
from .devices import real_dtype
from .launch import enqueue_kernel, spmv_layout

__all__ = ["DeviceCSR", "row_blocks", "sweeps"]


def row_blocks(indptr: np.ndarray, blocks: int) -> np.ndarray:
    """Row boundaries (blocks + 1,) int32 splitting a CSR matrix into ``blocks`` runs of
    consecutive rows with about equal non-zeros (runs may be empty; together they cover all rows)."""
    n, nnz = len(indptr) - 1, int(indptr[-1])
    targets = np.arange(blocks + 1, dtype=np.float64) * (nnz / blocks)
    blk = np.searchsorted(indptr, targets, side="left").clip(0, n)
    blk[0], blk[-1] = 0, n
    return np.maximum.accumulate(blk).astype(np.int32)


def sweeps(device, bounce, x, y, partial_buf, blocks: int, dtype, tol: float, max_sweeps: int, step=None):
    """Run ``bounce(x, y)`` (enqueue y from x, each block's ``max |y - x|`` and ``max |y|`` into
    ``partial_buf``), swapping x and y, until the relative change ``max|y - x| / max|y|`` is <= tol
    or ``max_sweeps`` ran; ``step(change)``, if given, after each sweep (a progress bar). Returns
    (the buffer holding the last iterate, the last change, every sweep's change)."""
    import pyopencl as cl

    partial = np.empty((blocks, 2), dtype=dtype)
    change = np.inf
    history: list[float] = []
    while len(history) < max_sweeps:
        bounce(x, y)
        x, y = y, x
        cl.enqueue_copy(device.queue, partial, partial_buf, is_blocking=True)
        scale = float(partial[:, 1].max())
        change = float(partial[:, 0].max()) / scale if scale > 0 else 0.0
        history.append(change)
        if step is not None:
            step(change)
        if change <= tol:
            break
    return x, change, history


class DeviceCSR:
    """A (rows, cols) CSR matrix on the device, in float32 or float64.

    Vectors travel as (n, 4) RGB(A) or (n, 1) grey arrays (``channels`` 3 or 1); ``layout``
    overrides the kernel's (LX, blocks) (:func:`pydynrad.device.launch.spmv_layout`).
    """

    def __init__(self, device, A: sp.csr_matrix, dtype=np.float32, layout: tuple[int, int] | None = None) -> None:
        A = sp.csr_matrix(A)
        if A.nnz >= 2**31:
            raise OutOfMemoryError(
                f"a {A.shape} matrix has {A.nnz} non-zeros; the CSR kernel indexes with 32-bit integers (< 2^31)"
            )
        self.device, self.shape, self.nnz = device, A.shape, A.nnz
        self.dtype = real_dtype(dtype, device)
        self._layout = spmv_layout(device, max(A.shape[0], 1), layout)
        self._n_blocks = self._layout.blocks
        self._blk = device.to_device(row_blocks(A.indptr, self._n_blocks))
        self._rowptr = device.to_device(A.indptr.astype(np.int32))
        self._cols = device.to_device(A.indices.astype(np.int32))
        self._vals = device.to_device(A.data.astype(self.dtype))
        self.nbytes = A.nnz * (4 + self.dtype.itemsize) + 4 * (A.shape[0] + 1) + 4 * (self._n_blocks + 1)
        # Kernel objects per channel width, one set per thread (a kernel object holds its
        # arguments): a fresh one per bounce cost host time on the order of a Jacobi sweep
        # (docs/decisions/0005-warm-up-and-fixed-local-sizes.md).
        self._kernels = threading.local()
        #: The fastest :meth:`bounce` so far, in seconds (None before one): a cost model's measure of
        #: a pass over the matrix on this device, uploads and read-back included.
        self.seconds_bounce: float | None = None

    def packed(self, a: np.ndarray, width: int) -> np.ndarray:
        """(n, width) array of this matrix's type holding a's first channels (zeros elsewhere)."""
        out = np.zeros((len(a), width), dtype=self.dtype)
        out[:, : min(width, a.shape[1])] = a[:, :width]
        return out

    def bounce_buffers(self, L_buf, rho_buf, x_buf, y_buf, width: int, partial_buf=None) -> None:
        """Enqueue y = L + P (A x) on device buffers of ``width`` (1 or 4) REALs per row (x per
        column of A); for a square A also each block's ``max |y - x|`` and ``max |y|`` into
        ``partial_buf`` (only ``max |y|`` otherwise: x is not indexed by row)."""
        import pyopencl as cl

        d = self.device
        kernels: dict = self._kernels.__dict__  # this thread's kernels, keyed by width
        kernel = kernels.get(width)
        if kernel is None:
            defines = {
                "STORAGE_FP64" if self.dtype == np.float64 else "STORAGE_FP32": 1,
                "NCH": width,
                **self._layout.defines,
            }
            kernel = kernels[width] = d.kernel("spmv.cl", "bounce", defines)
        if partial_buf is None:
            partial_buf = cl.Buffer(d.context, cl.mem_flags.READ_WRITE, 2 * self._n_blocks * self.dtype.itemsize)
        enqueue_kernel(
            d,
            kernel,
            *self._layout.grid,
            self._blk,
            self._rowptr,
            self._cols,
            self._vals,
            L_buf,
            rho_buf,
            x_buf,
            y_buf,
            partial_buf,
            np.int32(self.shape[0] == self.shape[1]),
            fixed=True,  # reqd_work_group_size(LX): a local-memory reduction over LX items
        )

    def bounce(self, L: np.ndarray, rho: np.ndarray, x: np.ndarray) -> np.ndarray:
        """y = L + rho * (A x): L, rho (rows, k), x (cols, k), k = 1 or 3; returns (rows, k) float64."""
        import pyopencl as cl

        k = x.shape[1]
        if x.shape[0] != self.shape[1] or L.shape != (self.shape[0], k) or rho.shape != (self.shape[0], k):
            raise InvalidInputError(
                f"bounce of a {self.shape} matrix needs L, rho ({self.shape[0]}, {k}) and x "
                f"({self.shape[1]}, {k}); got {L.shape}, {rho.shape}, {x.shape}"
            )
        width = 1 if k == 1 else 4
        d = self.device
        t0 = time.perf_counter()
        bufs = [d.to_device(self.packed(a, width)) for a in (L, rho, x)]
        y = cl.Buffer(d.context, cl.mem_flags.READ_WRITE, max(self.shape[0], 1) * width * self.dtype.itemsize)
        L_buf, rho_buf, x_buf = bufs
        self.bounce_buffers(L_buf, rho_buf, x_buf, y, width)
        out = np.empty((self.shape[0], width), dtype=self.dtype)
        if self.shape[0]:
            cl.enqueue_copy(d.queue, out, y, is_blocking=True)
        seconds = time.perf_counter() - t0
        self.seconds_bounce = seconds if self.seconds_bounce is None else min(self.seconds_bounce, seconds)
        return out[:, :k].astype(np.float64)

    def jacobi(
        self,
        L: np.ndarray,
        rho: np.ndarray,
        x0: np.ndarray,
        tol: float,
        max_sweeps: int,
        mixing: int = 0,
        step=None,
    ) -> tuple[np.ndarray, int, float, list[float]]:
        """Iterate x <- L + rho * (A x) from x0 (A square) until the relative max-norm change
        ``max |x_new - x| / max |x_new|`` is <= tol (never, for tol < 0) or ``max_sweeps`` ran.

        ``mixing`` > 0: each next x is the Anderson mixing (:class:`pydynrad.host.anderson.Anderson`,
        that many earlier steps) of the sweeps' images, on the host in float64 (each sweep then
        reads its image back and uploads the next x: (n, 4) REALs each way); the change is
        that of the last sweep, from its x to its image, which the answer is. ``step(change)``,
        if given, runs after each sweep (a progress bar).

        Returns (x, sweeps, the last relative change, every sweep's relative change); x is
        float64 of x0's shape, computed in this matrix's type.
        """
        import pyopencl as cl

        if self.shape[0] != self.shape[1]:  # x and y swap: each must hold a row per row and column
            raise InvalidInputError(f"jacobi sweeps a square matrix; this one has shape {self.shape}")
        k = x0.shape[1]
        width = 1 if k == 1 else 4
        d, n, nb = self.device, self.shape[0], self._n_blocks
        L_buf, rho_buf = d.to_device(self.packed(L, width)), d.to_device(self.packed(rho, width))
        mf = cl.mem_flags
        x = cl.Buffer(d.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=self.packed(x0, width))
        y = cl.Buffer(d.context, mf.READ_WRITE, n * width * self.dtype.itemsize)
        partial_buf = cl.Buffer(d.context, mf.READ_WRITE, 2 * nb * self.dtype.itemsize)
        out = np.empty((n, width), dtype=self.dtype)
        if mixing > 0:
            return self._mixed(
                L_buf, rho_buf, np.asarray(x0, np.float64), x, y, partial_buf, out, tol, max_sweeps, mixing, step
            )
        x, change, history = sweeps(
            d,
            lambda x, y: self.bounce_buffers(L_buf, rho_buf, x, y, width, partial_buf),
            x,
            y,
            partial_buf,
            nb,
            self.dtype,
            tol,
            max_sweeps,
            step,
        )
        cl.enqueue_copy(d.queue, out, x, is_blocking=True)
        return out[:, :k].astype(np.float64), len(history), change, history

    def _mixed(
        self,
        L_buf,
        rho_buf,
        u: np.ndarray,
        x_buf,
        y_buf,
        partial_buf,
        out: np.ndarray,
        tol: float,
        max_sweeps: int,
        depth: int,
        step,
    ) -> tuple[np.ndarray, int, float, list[float]]:
        """:meth:`jacobi` with Anderson mixing from u (n, k) float64 (already in ``x_buf``)."""
        import pyopencl as cl

        d, k, width = self.device, u.shape[1], out.shape[1]
        mixer, staged = Anderson(depth), np.zeros_like(out)
        history: list[float] = []
        if max_sweeps < 1:  # as the plain sweeps: x0, no change measured
            return u, 0, np.inf, history
        while True:
            self.bounce_buffers(L_buf, rho_buf, x_buf, y_buf, width, partial_buf)
            cl.enqueue_copy(d.queue, out, y_buf, is_blocking=True)
            fu = out[:, :k].astype(np.float64)
            residual = fu - u
            scale = float(np.abs(fu).max())
            change = float(np.abs(residual).max()) / scale if scale > 0 else 0.0
            history.append(change)
            if step is not None:
                step(change)
            if change <= tol or len(history) >= max_sweeps:
                return fu, len(history), change, history
            u = mixer.next(fu, residual)
            staged[:, :k] = u
            cl.enqueue_copy(d.queue, x_buf, staged, is_blocking=True)
