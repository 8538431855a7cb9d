"""A square sparse matrix on the device in sliced ELL (SELL-C-sigma) and the Jacobi bounce on it.

The CPU layout of the full solve's F (docs/design.md, 'Full solve'): patches renumbered so
that within each window of ``sigma`` consecutive rows the longer rows come first, then cut
into slices of ``C`` rows (C = the device's SIMD width in REALs) stored column by column,
each slice as wide as its longest row. ``kernels/spmv.cl``'s ``bounce_sell`` then runs one
row per vector lane: contiguous vector loads of values and indices, one gather of x per
channel, no reduction across lanes. Built once per F in O(nnz) numpy.
"""

from __future__ import annotations

import threading

import numpy as np
import scipy.sparse as sp

from ..errors import InvalidInputError, OutOfMemoryError
from .csr import row_blocks, sweeps
from .devices import real_dtype
from .launch import enqueue_kernel

__all__ = ["SellMatrix", "sell_slices", "DeviceSELL"]


class SellMatrix:
    """The host arrays of a SELL-C-sigma matrix: ``perm`` (N,) old row at each new position,
    ``sptr`` (slices + 1,) int32 entry offsets, ``cols`` (int32, renumbered) and ``vals``
    (sptr[-1],) slice by slice, lane fastest; ``c`` rows per slice, ``rows`` = N rounded up to c."""

    def __init__(self, perm, sptr, cols, vals, c: int) -> None:
        self.perm, self.sptr, self.cols, self.vals, self.c = perm, sptr, cols, vals, c
        self.rows = (len(sptr) - 1) * c


def sell_slices(A: sp.csr_matrix, c: int, sigma: int, dtype=np.float32) -> SellMatrix:
    """A (N, N) CSR as SELL-C-sigma: rows sorted by length (longest first) within windows of
    ``sigma`` rows, the system renumbered by that order (columns too), slices of ``c`` rows."""
    n = A.shape[0]
    indptr = A.indptr.astype(np.int64)
    length = np.diff(indptr)
    # Stable sort by (window, -length): long rows first in each window, else the original order.
    perm = np.lexsort((-length, np.arange(n) // max(int(sigma), 1))).astype(np.int64)
    inv = np.empty(n, dtype=np.int64)
    inv[perm] = np.arange(n)
    slices = -(-n // c)
    plen = np.zeros(slices * c, dtype=np.int64)
    plen[:n] = length[perm]
    width = plen.reshape(slices, c).max(axis=1)
    sptr = np.zeros(slices + 1, dtype=np.int64)
    np.cumsum(width * c, out=sptr[1:])
    if sptr[-1] >= 2**31:
        raise OutOfMemoryError(
            f"SELL-{c} of a {A.shape} matrix holds {sptr[-1]} entries; the kernel indexes with 32-bit integers (< 2^31)"
        )
    # Entry k of old row i (new position p = inv[i], its j-th entry) goes to slice p // c at
    # column j, lane p % c; int32 throughout (every offset is below sptr[-1] < 2^31), which
    # halves the O(nnz) temporaries (0.56 GB for the village's 35 M entries).
    rows = np.repeat(np.arange(n, dtype=np.int32), length)
    p = inv.astype(np.int32)[rows]
    j = np.arange(A.nnz, dtype=np.int32) - indptr.astype(np.int32)[rows]
    dest = sptr.astype(np.int32)[p // c] + j * c + p % c
    cols = np.zeros(sptr[-1], dtype=np.int32)
    vals = np.zeros(sptr[-1], dtype=dtype)
    cols[dest] = inv[A.indices]
    vals[dest] = A.data
    return SellMatrix(perm, sptr.astype(np.int32), cols, vals, c)


class DeviceSELL:
    """An (N, N) matrix on the device as SELL-C-sigma (:func:`sell_slices`) with the layout
    ``layout`` (:class:`pydynrad.device.launch.SellLayout`), iterated by :meth:`~pydynrad.device.sell.DeviceSELL.jacobi` like
    :meth:`pydynrad.device.csr.DeviceCSR.jacobi` (same arguments, results in the original patch
    order). ``stored``: entries held, padding included; ``nbytes``: device bytes of F."""

    def __init__(self, device, A: sp.csr_matrix, dtype, layout) -> None:
        A = sp.csr_matrix(A)
        if A.shape[0] != A.shape[1]:  # bounce_sell's residual reads x by row
            raise InvalidInputError(f"DeviceSELL holds a square matrix; got shape {A.shape}")
        self.device, self.shape, self.nnz = device, A.shape, A.nnz
        self.dtype = real_dtype(dtype, device)
        self._layout = layout
        S = sell_slices(A, layout.c, layout.sigma, self.dtype)
        self._perm, self._np, self.stored = S.perm, S.rows, len(S.vals)
        slices = len(S.sptr) - 1
        self._n_blocks = max(1, min(layout.blocks, slices))
        self._blk = device.to_device(row_blocks(S.sptr, self._n_blocks))
        self._sptr, self._cols, self._vals = (device.to_device(a) for a in (S.sptr, S.cols, S.vals))
        self.nbytes = self.stored * (4 + self.dtype.itemsize) + 4 * (slices + 1) + 4 * (self._n_blocks + 1)
        self._kernels = threading.local()

    def packed(self, a: np.ndarray) -> np.ndarray:
        """(np, 1 or 4) array of this matrix's type: a (N, k)'s k = 1 or 3 channels in the
        renumbered order (zero padded)."""
        out = np.zeros((self._np, 1 if a.shape[1] == 1 else 4), dtype=self.dtype)
        out[: self.shape[0], : a.shape[1]] = a[self._perm]
        return out

    def _kernel(self, channels: int):
        kernels: dict = self._kernels.__dict__  # this thread's kernels, keyed by width
        kernel = kernels.get(channels)
        if kernel is None:
            defines = {
                "STORAGE_FP64" if self.dtype == np.float64 else "STORAGE_FP32": 1,
                "NCH": 1 if channels == 1 else 4,
                **self._layout.defines,
            }
            kernel = kernels[channels] = self.device.kernel("spmv.cl", "bounce_sell", defines)
        return kernel

    def jacobi(
        self, L: np.ndarray, rho: np.ndarray, x0: np.ndarray, tol: float, max_sweeps: int, step=None
    ) -> tuple[np.ndarray, int, float, list[float]]:
        """See :meth:`pydynrad.device.csr.DeviceCSR.jacobi`; k = 1 or 3 channels."""
        import pyopencl as cl

        k = x0.shape[1]
        d, nb = self.device, self._n_blocks
        mf = cl.mem_flags
        L_buf, rho_buf = d.to_device(self.packed(L)), d.to_device(self.packed(rho))
        x = cl.Buffer(d.context, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=self.packed(x0))
        y = cl.Buffer(d.context, mf.READ_WRITE, self.packed(x0).nbytes)
        partial_buf = cl.Buffer(d.context, mf.READ_WRITE, 2 * nb * self.dtype.itemsize)
        kernel = self._kernel(k)

        def bounce(x, y):
            enqueue_kernel(
                d, kernel, (nb,), (1,), self._blk, self._sptr, self._cols, self._vals, L_buf, rho_buf, x, y, partial_buf
            )

        x, change, history = sweeps(d, bounce, x, y, partial_buf, nb, self.dtype, tol, max_sweeps, step)
        out = self.packed(x0)
        cl.enqueue_copy(d.queue, out, x, is_blocking=True)
        B = np.empty((self.shape[0], k))
        B[self._perm] = out[: self.shape[0], :k]
        return B, len(history), change, history
