"""A sparse matrix resident on the device and the bounce product ``y = L + P (A x)`` on it.

The far field's heavy per-light-change work is three such products: the coarse Jacobi sweeps
(A = F_c, C x C), the prolongation to every patch (A = G, N x C) and nothing else; each is one
pass over A's values with ``kernels/spmv.cl``'s ``bounce`` kernel (the full solve's kernel:
rows and columns need not match, x has A's columns, L, P and y its rows).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..device import real_dtype
from ..errors import OutOfMemoryError

__all__ = ["DeviceCSR"]


class DeviceCSR:
    """A (rows, cols) CSR matrix on the device, in float32 or float64.

    Vectors travel as (n, 4) RGB(A) or (n, 1) grey arrays (``channels`` 3 or 1).
    """

    def __init__(self, device, A: sp.csr_matrix, dtype=np.float32) -> None:
        from ..solve import _row_blocks, _spmv_layout

        A = sp.csr_matrix(A)
        if A.nnz >= 2**31:
            raise OutOfMemoryError(f"a {A.shape} matrix with {A.nnz} non-zeros: the CSR kernel indexes with 32-bit integers")
        self.device, self.shape, self.nnz = device, A.shape, A.nnz
        self.dtype = real_dtype(dtype, device)
        self._lx, self._n_blocks = _spmv_layout(device, max(A.shape[0], 1), None)
        self._blk = device.to_device(_row_blocks(A.indptr, self._n_blocks))
        self._rowptr = device.to_device(A.indptr.astype(np.int32))
        self._cols = device.to_device(A.indices.astype(np.int32))
        self._vals = device.to_device(A.data.astype(self.dtype))
        self.nbytes = A.nnz * (4 + self.dtype.itemsize) + 4 * (A.shape[0] + 1) + 4 * (self._n_blocks + 1)

    def packed(self, a: np.ndarray, width: int) -> np.ndarray:
        """(n, width) array of this matrix's type holding a's first channels (zeros elsewhere)."""
        out = np.zeros((len(a), width), dtype=self.dtype)
        out[:, : min(width, a.shape[1])] = a[:, :width]
        return out

    def bounce_buffers(self, L_buf, rho_buf, x_buf, y_buf, width: int, partial_buf=None) -> None:
        """Enqueue y = L + P (A x) on device buffers of ``width`` (1 or 4) REALs per row."""
        import pyopencl as cl

        d = self.device
        defines = {"STORAGE_FP64" if self.dtype == np.float64 else "STORAGE_FP32": 1, "NCH": width, "LX": self._lx}
        kernel = d.kernel("spmv.cl", "bounce", defines)
        if partial_buf is None:
            partial_buf = cl.Buffer(d.context, cl.mem_flags.READ_WRITE, 2 * self._n_blocks * self.dtype.itemsize)
        kernel(d.queue, (self._n_blocks * self._lx,), (self._lx,), self._blk, self._rowptr, self._cols, self._vals,
               L_buf, rho_buf, x_buf, y_buf, partial_buf)

    def bounce(self, L: np.ndarray, rho: np.ndarray, x: np.ndarray) -> np.ndarray:
        """y = L + rho * (A x): L, rho (rows, k), x (cols, k), k = 1 or 3; returns (rows, k) float64."""
        import pyopencl as cl

        k = x.shape[1]
        width = 1 if k == 1 else 4
        d = self.device
        bufs = [d.to_device(self.packed(a, width)) for a in (L, rho, x)]
        y = cl.Buffer(d.context, cl.mem_flags.READ_WRITE, max(self.shape[0], 1) * width * self.dtype.itemsize)
        self.bounce_buffers(*bufs, y, width)
        out = np.empty((self.shape[0], width), dtype=self.dtype)
        if self.shape[0]:
            cl.enqueue_copy(d.queue, out, y, is_blocking=True)
        return out[:, :k].astype(np.float64)

    def jacobi(self, L: np.ndarray, rho: np.ndarray, x0: np.ndarray, tol: float, max_sweeps: int) -> tuple[np.ndarray, int, float]:
        """Iterate x <- L + rho * (A x) from x0 (A square) until the relative max-norm change
        is <= tol or ``max_sweeps`` ran. Returns (x, sweeps, last relative change)."""
        import pyopencl as cl

        k = x0.shape[1]
        width = 1 if k == 1 else 4
        d, n, nb = self.device, self.shape[0], self._n_blocks
        L_buf, rho_buf = d.to_device(self.packed(L, width)), d.to_device(self.packed(rho, width))
        mf = cl.mem_flags
        x = cl.Buffer(d.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=self.packed(x0, width))
        y = cl.Buffer(d.context, mf.READ_WRITE, n * width * self.dtype.itemsize)
        partial_buf = cl.Buffer(d.context, mf.READ_WRITE, 2 * nb * self.dtype.itemsize)
        partial = np.empty((nb, 2), dtype=self.dtype)
        change, sweeps = np.inf, 0
        while sweeps < max_sweeps:
            self.bounce_buffers(L_buf, rho_buf, x, y, width, partial_buf)
            x, y = y, x
            sweeps += 1
            cl.enqueue_copy(d.queue, partial, partial_buf, is_blocking=True)
            scale = float(partial[:, 1].max())
            change = float(partial[:, 0].max()) / scale if scale > 0 else 0.0
            if change <= tol:
                break
        out = np.empty((n, width), dtype=self.dtype)
        cl.enqueue_copy(d.queue, out, x, is_blocking=True)
        return out[:, :k].astype(np.float64), sweeps, change
