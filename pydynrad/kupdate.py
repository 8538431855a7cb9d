"""Device operations on a :class:`~pydynrad.matvec.DeviceMatrix` K for the local update.

Thin wrappers around ``kernels/update.cl`` with numpy in and out (float64 on the host, the
matrix's compute type on the device). Each method works on one channel's buffer in place:

* :meth:`UpdateKernels.gather`: K X and Y K for up to ``max_vectors`` vectors in one read pass;
* :meth:`UpdateKernels.rank_update`: K += A^T B (A, B given as (n, M) rows), one read-write pass;
* :meth:`UpdateKernels.read_slots` / :meth:`UpdateKernels.write_slots`: columns and rows of a
  few slots (O(k M));
* :meth:`UpdateKernels.double_reflection`: the paper's Eq. 1 reduction.
"""

from __future__ import annotations

import numpy as np

from .errors import InvalidInputError

__all__ = ["UpdateKernels", "scratch_nbytes"]


def _layout(device, M: int) -> tuple[int, int, int]:
    """(VW, WG, RB): vector width, gather work-items per row block, rows per block.

    CPU: one item streams whole rows with 16-wide vectors; GPU: 64 items read adjacent 4-wide
    vectors (coalesced). The gather's column partials cost NV*ld REALs per block of RB rows,
    so 64-128-row blocks keep them to ~1% of K's traffic per vector while leaving M/RB groups.
    """
    rb = 64 if M < 2048 else 128
    return (16, 1, rb) if device.is_cpu else (4, 64, rb)


def scratch_nbytes(device, M: int, ld: int, real_itemsize: int, max_vectors: int) -> int:
    """Device bytes of :class:`UpdateKernels`' scratch buffers for these sizes."""
    _, wg, rb = _layout(device, M)
    nv, n_blocks = max_vectors, -(-M // rb)
    reals = nv * ld + nv * M + wg * nv * M + n_blocks * nv * ld + 2 * nv * M + 2 * nv * M + 2 * nv * ld + 3 * M
    return real_itemsize * reals + 4 * nv


class UpdateKernels:
    """Kernels bound to one DeviceMatrix; scratch buffers sized for ``max_vectors`` at a time."""

    def __init__(self, matrix, max_vectors: int) -> None:
        import pyopencl as cl

        if max_vectors < 1:
            raise InvalidInputError(f"max_vectors must be >= 1; got {max_vectors}")
        dev = matrix.device
        self.matrix, self.device, self.nv_max = matrix, dev, int(max_vectors)
        self.M, self.ld = matrix.M, matrix.ld
        self.real = matrix.real_dtype
        cpu = dev.is_cpu
        self.vw, self.wg, self.rb = _layout(dev, self.M)
        self.n_blocks = -(-self.M // self.rb)
        self._rank_g0 = 1 if cpu else self.ld // self.vw
        defines = {**matrix.defines, "VW": self.vw, "WG": self.wg, "NVMAX": self.nv_max, "NAMAX": 2 * self.nv_max}
        prg = dev.program("update.cl", defines)
        self._k = {n: cl.Kernel(prg, n) for n in ("gather_partial", "gather_reduce", "rank_update", "read_slots", "write_slots", "double_reflection")}
        mf, ctx, r = cl.mem_flags, dev.context, self.real.itemsize
        nv, M, ld = self.nv_max, self.M, self.ld
        self._X = cl.Buffer(ctx, mf.READ_ONLY, nv * ld * r)
        self._Y = cl.Buffer(ctx, mf.READ_ONLY, nv * M * r)
        self._rowpart = cl.Buffer(ctx, mf.READ_WRITE, self.wg * nv * M * r)
        self._colpart = cl.Buffer(ctx, mf.READ_WRITE, self.n_blocks * nv * ld * r)
        self._KX = cl.Buffer(ctx, mf.READ_WRITE, nv * M * r)
        self._YK = cl.Buffer(ctx, mf.READ_WRITE, nv * M * r)
        self._A = cl.Buffer(ctx, mf.READ_ONLY, 2 * nv * M * r)
        self._B = cl.Buffer(ctx, mf.READ_ONLY, 2 * nv * ld * r)
        self._slots = cl.Buffer(ctx, mf.READ_ONLY, nv * 4)
        self._out = cl.Buffer(ctx, mf.READ_WRITE, 3 * M * r)

    @property
    def nbytes(self) -> int:
        """Device bytes of the scratch buffers (vectors and partial sums)."""
        return scratch_nbytes(self.device, self.M, self.ld, self.real.itemsize, self.nv_max)

    # -- helpers ---------------------------------------------------------------------------------
    def _put(self, buf, a: np.ndarray, width: int) -> None:
        """Upload rows of a (n, M) float array into buf with row pitch ``width`` (zero padded)."""
        import pyopencl as cl

        a = np.atleast_2d(a)
        host = np.zeros((a.shape[0], width), dtype=self.real)
        host[:, : a.shape[1]] = a
        cl.enqueue_copy(self.device.queue, buf, host)

    def _get(self, buf, n: int) -> np.ndarray:
        import pyopencl as cl

        host = np.empty((n, self.M), dtype=self.real)
        cl.enqueue_copy(self.device.queue, host, buf, is_blocking=True)
        return host.astype(np.float64)

    def _check(self, n: int) -> None:
        if not 1 <= n <= self.nv_max:
            raise InvalidInputError(f"between 1 and {self.nv_max} vectors per call; got {n}")

    def _grid(self, n: int) -> tuple[int, int]:
        return (-(-self.M // 64) * 64, n)

    # -- operations -------------------------------------------------------------------------------
    def gather(self, channel: int, X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K X^T)^T and Y K for X, Y of shape (n, M): returns two (n, M) float64 arrays."""
        X, Y = np.atleast_2d(X), np.atleast_2d(Y)
        n = X.shape[0]
        self._check(n)
        self._put(self._X, X, self.ld)
        self._put(self._Y, Y, self.M)
        q, K = self.device.queue, self.matrix.buffers[channel]
        M, ld, nv = np.int32(self.M), np.int32(self.ld), np.int32(n)
        self._k["gather_partial"](
            q, (self.wg, self.n_blocks), (self.wg, 1), K, M, ld, np.int32(self.rb), nv, self._X, self._Y, self._rowpart, self._colpart
        )
        self._k["gather_reduce"](q, self._grid(n), None, self._rowpart, self._colpart, M, ld, nv, np.int32(self.n_blocks), self._KX, self._YK)
        return self._get(self._KX, n), self._get(self._YK, n)

    def rank_update(self, channel: int, A: np.ndarray, B: np.ndarray) -> None:
        """K += sum_n outer(A[n], B[n]) for A, B of shape (n, M), n <= 2 * max_vectors."""
        A, B = np.atleast_2d(A), np.atleast_2d(B)
        n = A.shape[0]
        if not 1 <= n <= 2 * self.nv_max or B.shape != A.shape:
            raise InvalidInputError(f"rank update needs A, B of equal shape (n <= {2 * self.nv_max}, M); got {A.shape}, {B.shape}")
        self._put(self._A, A, self.M)
        self._put(self._B, B, self.ld)
        self._k["rank_update"](
            self.device.queue, (self._rank_g0, self.M), None, self.matrix.buffers[channel], np.int32(self.M), np.int32(self.ld), np.int32(n), self._A, self._B
        )

    def read_slots(self, channel: int, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Columns K[:, slots] and rows K[slots, :], both as (k, M) float64."""
        import pyopencl as cl

        slots = np.ascontiguousarray(slots, dtype=np.int32)
        self._check(len(slots))
        cl.enqueue_copy(self.device.queue, self._slots, slots)
        k = len(slots)
        cols, rows = self._KX, self._YK
        self._k["read_slots"](self.device.queue, self._grid(k), None, self.matrix.buffers[channel], np.int32(self.M), np.int32(self.ld), self._slots, cols, rows)
        return self._get(cols, k), self._get(rows, k)

    def write_slots(self, channel: int, slots: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> None:
        """K[:, slots[m]] = cols[m], K[slots[m], :] = rows[m]; cols/rows must agree where they cross."""
        import pyopencl as cl

        slots = np.ascontiguousarray(slots, dtype=np.int32)
        k = len(slots)
        self._check(k)
        cl.enqueue_copy(self.device.queue, self._slots, slots)
        self._put(self._A, cols, self.M)
        self._put(self._Y, rows, self.M)
        self._k["write_slots"](
            self.device.queue, self._grid(k), None, self.matrix.buffers[channel], np.int32(self.M), np.int32(self.ld), self._slots, np.int32(k), self._A, self._Y
        )

    def double_reflection(self, f_c: np.ndarray, f_r: np.ndarray, rho: np.ndarray) -> float:
        """Eq. 1: sum_a f_c[a] f_r[a] rho[a] over the M slots, reduced on the device."""
        import pyopencl as cl

        self._put(self._out, np.stack([f_c, f_r, rho]).reshape(1, -1), 3 * self.M)
        self._k["double_reflection"](self.device.queue, (64,), (64,), self._out, np.int32(self.M), self._KX)
        out = np.empty(1, dtype=self.real)
        cl.enqueue_copy(self.device.queue, out, self._KX, is_blocking=True)
        return float(out[0])
