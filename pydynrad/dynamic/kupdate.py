"""Device operations on a :class:`~pydynrad.matvec.DeviceMatrix` K for the local update.

Thin wrappers around ``kernels/update.cl`` with numpy in and out (float64 on the host, the
matrix's compute type on the device). Each method works on one channel's buffer in place:

* :meth:`UpdateKernels.gather`: K X and Y K for up to ``max_vectors`` vectors in one read pass;
  :meth:`UpdateKernels.gather_all` takes the sparse kernels instead when the vectors are
  mostly zero (a swap batch's form factors), touching only their non-zero slots' part of K;
* :meth:`UpdateKernels.rank_update`: K += A^T B (A, B given as (n, M) rows), one read-write pass;
* :meth:`UpdateKernels.read_slots` / :meth:`UpdateKernels.write_slots`: columns and rows of a
  few slots (O(k M)); :meth:`UpdateKernels.update_slots`: a rank update and a slot write
  queued together;
* :meth:`UpdateKernels.double_reflection`: the paper's Eq. 1 reduction.

See docs/design.md, 'Cost model', and kernels/README.md for the kernels' defines and guarantees.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError
from ..launch import CPU_ROWS, WG, UpdateLayout, global_size, round_up

__all__ = ["UpdateKernels", "scratch_nbytes", "SPARSE_DENSITY"]

#: The sparse gathers run when the vectors' non-zero slots, on both sides together, are at
#: most this share of 2 M. Measured (PoCL CPU, Xeon 2 cores, 2026-12-02, 8 vectors): 0.4-0.7x
#: the dense pass's time at 2-10% non-zero slots, about even at 15-20%, slower above; a swap
#: batch along a walk through a 6k-patch village had a median of 3% (M = 1024), 7% (M = 256).
SPARSE_DENSITY = 0.15


def scratch_nbytes(device, M: int, ld: int, k_itemsize: int, real_itemsize: int, max_vectors: int,
                   channels: int = 1) -> int:
    """Device bytes of :class:`UpdateKernels`' scratch buffers for these sizes."""
    lay = UpdateLayout.make(device, M, ld, k_itemsize, real_itemsize)
    nv = max_vectors
    # row and column partials, zeros (for clearing a slot), f_c, f_r and rho of Eq. 1
    shared = lay.parts * nv * M + lay.max_partial_blocks(nv) * ld + M + 3 * M
    # X and Y (the gathers' vectors, then the rank update's factors), K X, Y K, slot columns and rows
    per_channel = max(2 * nv * M, nv * ld) + 2 * nv * ld + 4 * nv * M
    return real_itemsize * (shared + channels * per_channel) + 4 * nv + 2 * 4 * ld  # slots, sparse gathers' indices


class UpdateKernels:
    """Kernels bound to one DeviceMatrix; scratch buffers sized for ``max_vectors`` at a time."""

    def __init__(self, matrix, max_vectors: int, *, cpu_kernels: bool | None = None) -> None:
        """``cpu_kernels`` overrides the device type's choice of kernels (for testing both)."""
        import pyopencl as cl

        if max_vectors < 1:
            raise InvalidInputError(f"max_vectors must be >= 1; got {max_vectors}")
        dev = matrix.device
        self.matrix, self.device, self.nv_max = matrix, dev, int(max_vectors)
        self.M, self.ld = matrix.M, matrix.ld
        self.real = matrix.real_dtype
        self.layout = UpdateLayout.make(dev, self.M, self.ld, matrix.dtype.itemsize, self.real.itemsize, cpu_kernels)
        prg = dev.program("update.cl", {**matrix.defines, **self.layout.defines(self.nv_max)})
        names = ("gather_rows", "gather_partial", "gather_reduce", "gather_sparse_cols", "gather_sparse_rows",
                 "rank_update_rows", "rank_update", "read_slots", "write_slots", "double_reflection")
        self._k = {n: cl.Kernel(prg, n) for n in names}
        mf, ctx, r = cl.mem_flags, dev.context, self.real.itemsize
        nv, M, ld = self.nv_max, self.M, self.ld
        self._rowpart = cl.Buffer(ctx, mf.READ_WRITE, self.layout.parts * nv * M * r)
        self._colpart = cl.Buffer(ctx, mf.READ_WRITE, self.layout.max_partial_blocks(nv) * ld * r)
        # Inputs and results per channel, so every channel's uploads are queued before the first
        # pass (an upload queued behind a kernel holds the host until the kernel is done, see
        # update_slots) and all its results come back in one read. X and Y hold the gathers'
        # vectors (dense: pitch ld and M; sparse: the values on the non-zero slots), later the
        # rank update's A and B; cols and rows the slots' read-back, later the values
        # write_slots puts there. The queue is in order, so each use comes after the last.
        self._res = [{**{name: cl.Buffer(ctx, mf.READ_WRITE, nv * M * r) for name in ("KX", "YK", "cols", "rows")},
                      "X": cl.Buffer(ctx, mf.READ_WRITE, max(2 * nv * M, nv * ld) * r),
                      "Y": cl.Buffer(ctx, mf.READ_WRITE, 2 * nv * ld * r)}
                     for _ in range(matrix.C)]
        self._slots = cl.Buffer(ctx, mf.READ_ONLY, nv * 4)
        # The sparse gathers' slots (columns, rows): at most M each, padded to whole steps.
        self._idx = [cl.Buffer(ctx, mf.READ_ONLY, ld * 4) for _ in range(2)]
        self._out = cl.Buffer(ctx, mf.READ_WRITE, 3 * M * r)
        self._zeros = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.zeros(M, dtype=self.real))
        if dev.queue.properties & cl.command_queue_properties.OUT_OF_ORDER_EXEC_MODE_ENABLE:
            raise InvalidInputError("UpdateKernels needs an in-order command queue")
        self._inflight: list[np.ndarray] = []  # host arrays of uploads not yet known complete
        self._slots_held: np.ndarray | None = None  # what the last upload put into _slots

    @property
    def nbytes(self) -> int:
        """Device bytes of the scratch buffers (vectors and partial sums)."""
        return scratch_nbytes(self.device, self.M, self.ld, self.matrix.dtype.itemsize, self.real.itemsize, self.nv_max,
                              self.matrix.C)

    # -- helpers ---------------------------------------------------------------------------------
    def _put(self, buf, a: np.ndarray, width: int, dtype=None) -> None:
        """Upload rows of a (n, M) array into buf with row pitch ``width`` (zero padded).

        The copy is not waited for: the queue is in order, so the kernels after it see the
        data, and the host array is kept alive until the next :meth:`_get` has waited."""
        import pyopencl as cl

        a = np.atleast_2d(a)
        if a.shape[1] == width:
            host = np.array(a, dtype=dtype or self.real, order="C")  # always a copy the caller cannot touch
        else:
            host = np.zeros((a.shape[0], width), dtype=dtype or self.real)
            host[:, : a.shape[1]] = a
        cl.enqueue_copy(self.device.queue, buf, host, is_blocking=False)
        self._inflight.append(host)
        if len(self._inflight) > 64:  # callers that never read back: bound what is kept
            self.device.queue.finish()
            self._inflight.clear()

    def _put_slots(self, slots) -> int:
        """Check and upload slot indices; returns their count. The copy is skipped when the
        buffer already holds the same ones (a frame's read and write passes, and every
        channel, use one set of slots)."""
        slots = np.ascontiguousarray(slots, dtype=np.int32)
        self._check(len(slots))
        if self._slots_held is None or not np.array_equal(self._slots_held, slots):
            self._put(self._slots, slots, len(slots), np.int32)
            self._slots_held = slots.copy()
        return len(slots)

    def _get(self, *bufs: tuple) -> list[np.ndarray]:
        """Read (buffer, n) or (buffer, n, width) items, n rows of ``width`` (default M) each,
        with one wait; float64 copies."""
        import pyopencl as cl

        hosts = [np.empty((b[1], b[2] if len(b) > 2 else self.M), dtype=self.real) for b in bufs]
        events = [cl.enqueue_copy(self.device.queue, h, b[0], is_blocking=False) for h, b in zip(hosts, bufs)]
        events[-1].wait()  # in-order queue: every earlier command is done too
        self._inflight.clear()
        return [h.astype(np.float64) for h in hosts]

    def _check(self, n: int) -> None:
        if not 1 <= n <= self.nv_max:
            raise InvalidInputError(f"between 1 and {self.nv_max} vectors per call; got {n}")

    def warm_up(self) -> None:
        """Launch every kernel once on channel 0, leaving K as it was.

        PoCL compiles a kernel's work-group function at its first launch (~100 ms each on a
        2-core CPU), which would otherwise land inside the first frame that swaps. Costs one
        read pass and one read-write pass over one channel of K; the write-back of slot 0's
        column and row restores the values read (a round trip through REAL is exact)."""
        zero = np.zeros((1, self.M))
        cols, rows = self.read_slots(0, [0])
        self.gather(0, zero, zero)
        self.gather_all(np.zeros((self.matrix.C, 1, self.M)), np.zeros((self.matrix.C, 1, self.M)), sparse=True)
        self.rank_update(0, zero, zero)
        self.write_slots(0, [0], cols, rows)
        self.double_reflection(zero[0], zero[0], zero[0])
        self.device.queue.finish()

    # -- operations -------------------------------------------------------------------------------
    def _put_gather(self, channel: int, X: np.ndarray, Y: np.ndarray) -> int:
        """Upload a dense gather's X and Y of one channel; returns the vector count."""
        X, Y = np.atleast_2d(X), np.atleast_2d(Y)
        n = X.shape[0]
        self._check(n)
        if Y.shape != X.shape:
            raise InvalidInputError(f"gather needs X, Y of equal shape; got {X.shape}, {Y.shape}")
        self._put(self._res[channel]["X"], X, self.ld)
        self._put(self._res[channel]["Y"], Y, self.M)
        return n

    def _launch_gather(self, channel: int, n: int) -> None:
        q, K, lay, res = self.device.queue, self.matrix.buffers[channel], self.layout, self._res[channel]
        rb, blocks = lay.gather_blocks(n)
        M, ld, nv = np.int32(self.M), np.int32(self.ld), np.int32(n)
        if lay.cpu:
            self._k["gather_rows"](q, *lay.gather_grid(blocks), K, M, ld, np.int32(rb), np.int32(lay.gather_cw), nv,
                                   res["X"], res["Y"], self._rowpart, self._colpart)
        else:
            self._k["gather_partial"](q, *lay.gather_grid(blocks), K, M, ld, np.int32(rb), nv, res["X"], res["Y"],
                                      self._rowpart, self._colpart)
        # In-order queue: the next channel's gather reuses the partial sums only after this reduce.
        self._k["gather_reduce"](q, *lay.element_grid(n), self._rowpart, self._colpart, M, ld, nv, np.int32(lay.parts),
                                 np.int32(blocks), res["KX"], res["YK"])

    def _sparse_steps(self) -> tuple[tuple[str, int, bool, int], ...]:
        """(kernel, step, values transposed, work-items) of the column and row sparse gathers:
        SW entries per step of the column kernel, RR rows per step of the row kernel."""
        sw = self.layout.sw
        return (("gather_sparse_cols", sw, False, self.M), ("gather_sparse_rows", CPU_ROWS, True, -(-self.M // sw)))

    def _put_sparse_slots(self, cols: np.ndarray, rows: np.ndarray) -> list[np.ndarray]:
        """Upload the sparse gathers' slots (the vectors' non-zeros), padded with slot 0 to
        whole steps; returns them padded."""
        padded = []
        for buf, nz, (_, step, _, _) in zip(self._idx, (cols, rows), self._sparse_steps()):
            idx = np.zeros(round_up(max(1, len(nz)), step), dtype=np.int32)
            idx[: len(nz)] = nz
            self._put(buf, idx[None], len(idx), np.int32)
            padded.append(idx)
        return padded

    def _put_sparse_gather(self, channel: int, X: np.ndarray, Y: np.ndarray, cols: np.ndarray,
                           rows: np.ndarray, padded: list[np.ndarray]) -> int:
        """Upload X's values on ``cols`` and Y's on ``rows`` (zero on the padding): (n, Rp) for
        the column kernel, (Rp, n) for the row kernel."""
        n = X.shape[0]
        for name, nz, vectors, idx, (_, _, transpose, _) in zip(("X", "Y"), (cols, rows), (X, Y), padded,
                                                                 self._sparse_steps()):
            vals = np.zeros((n, len(idx)))
            vals[:, : len(nz)] = vectors[:, nz]
            self._put(self._res[channel][name], (vals.T if transpose else vals).reshape(1, -1), vals.size)
        return n

    def _launch_sparse_gather(self, channel: int, n: int, padded: list[np.ndarray]) -> None:
        """K X and Y K from the uploaded slots alone."""
        q, K, res = self.device.queue, self.matrix.buffers[channel], self._res[channel]
        M, ld, nv = np.int32(self.M), np.int32(self.ld), np.int32(n)
        for (name, _, _, items), buf, idx, vals, out in zip(self._sparse_steps(), self._idx, padded, ("X", "Y"),
                                                            ("KX", "YK")):
            self._k[name](q, (global_size(items),), (WG,), K, M, ld, np.int32(len(idx)), buf, res[vals], nv, res[out])

    def _enqueue_read_slots(self, channel: int, slots: np.ndarray) -> int:
        k = self._put_slots(slots)
        self._launch_read_slots(channel, k)
        return k

    def _launch_read_slots(self, channel: int, k: int) -> None:
        res = self._res[channel]
        self._k["read_slots"](self.device.queue, *self.layout.element_grid(k), self.matrix.buffers[channel],
                              np.int32(self.M), np.int32(self.ld), self._slots, res["cols"], res["rows"])

    def gather(self, channel: int, X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K X^T)^T and Y K for X, Y of shape (n, M): returns two (n, M) float64 arrays."""
        n = self._put_gather(channel, X, Y)
        self._launch_gather(channel, n)
        KX, YK = self._get((self._res[channel]["KX"], n), (self._res[channel]["YK"], n))
        return KX, YK

    def gather_all(self, X: np.ndarray, Y: np.ndarray, slots: np.ndarray | None = None,
                   sparse: bool | None = None) -> tuple[np.ndarray, ...]:
        """:meth:`gather` for every channel c with X[c], Y[c] (C, n, M), and with ``slots`` also
        :meth:`read_slots` (taken before the gathers): all passes enqueued, one wait.

        ``sparse``: use the sparse gathers (``gather_sparse_cols``/``_rows``: K's part on the
        slots where some X[c] or Y[c] is non-zero) or the dense pass; None picks the sparse ones
        when those slots are at most :data:`SPARSE_DENSITY` of 2 M.

        Returns KX, YK (C, n, M) and, with ``slots``, cols, rows (C, k, M), float64."""
        C = self.matrix.C
        X, Y = np.asarray(X, dtype=np.float64), np.asarray(Y, dtype=np.float64)
        if len(X) != C or len(Y) != C:
            raise InvalidInputError(f"gather_all needs one X and Y per channel ({C}); got {len(X)}, {len(Y)}")
        if X.ndim != 3 or X.shape != Y.shape or X.shape[2] != self.M:
            raise InvalidInputError(f"gather_all needs X, Y of equal shape ({C}, n, {self.M}); got {X.shape}, {Y.shape}")
        self._check(X.shape[1])
        cols = np.flatnonzero(np.any(X != 0, axis=(0, 1))).astype(np.int32)
        rows = np.flatnonzero(np.any(Y != 0, axis=(0, 1))).astype(np.int32)
        if sparse is None:
            sparse = len(cols) + len(rows) <= SPARSE_DENSITY * 2 * self.M
        # Every upload first, then every pass, then one read-back: the host waits once.
        k = self._put_slots(slots) if slots is not None else 0
        padded = self._put_sparse_slots(cols, rows) if sparse else None
        n = [self._put_sparse_gather(c, X[c], Y[c], cols, rows, padded) if sparse else self._put_gather(c, X[c], Y[c])
             for c in range(C)]
        reads = []
        for c in range(C):
            if slots is not None:
                self._launch_read_slots(c, k)
                reads += [(self._res[c]["cols"], k), (self._res[c]["rows"], k)]
            if sparse:
                self._launch_sparse_gather(c, n[c], padded)
            else:
                self._launch_gather(c, n[c])
            reads += [(self._res[c]["KX"], n[c]), (self._res[c]["YK"], n[c])]
        out = self._get(*reads)
        step = 4 if slots is not None else 2
        per = [np.stack(out[i::step]) for i in range(step)]
        return (per[2], per[3], per[0], per[1]) if slots is not None else (per[0], per[1])

    def _put_rank(self, channel: int, A: np.ndarray, B: np.ndarray) -> int:
        A, B = np.atleast_2d(A), np.atleast_2d(B)
        n = A.shape[0]
        if not 1 <= n <= 2 * self.nv_max or B.shape != A.shape:
            raise InvalidInputError(f"rank update needs A, B of equal shape (n <= {2 * self.nv_max}, M); got {A.shape}, {B.shape}")
        self._put(self._res[channel]["X"], A, self.M)
        self._put(self._res[channel]["Y"], B, self.ld)
        return n

    def _launch_rank(self, channel: int, n: int, k: int = 0) -> None:
        """K += A B from the channel's X and Y; then, with ``k`` > 0, the k uploaded slots'
        columns and rows from its cols and rows buffers: in the same pass on a CPU
        (``rank_update_rows``), by ``write_slots`` after it on a GPU."""
        q, K, lay, res = self.device.queue, self.matrix.buffers[channel], self.layout, self._res[channel]
        M, ld, na = np.int32(self.M), np.int32(self.ld), np.int32(n)
        if lay.cpu:
            self._k["rank_update_rows"](q, *lay.rank_grid, K, M, ld, na, np.int32(lay.rank_rb), res["X"], res["Y"],
                                        np.int32(k), self._slots, res["cols"], res["rows"])
            return
        self._k["rank_update"](q, *lay.rank_grid, K, M, ld, na, res["X"], res["Y"])
        if k:
            self._launch_write(channel, k, res["cols"], res["rows"])

    def _put_write(self, channel: int, slots: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> int:
        """Slots and their values into the channel's cols and rows buffers (not the rank update's inputs)."""
        k = self._put_slots(slots)
        self._put(self._res[channel]["cols"], cols, self.M)
        self._put(self._res[channel]["rows"], rows, self.M)
        return k

    def _launch_write(self, channel: int, k: int, cols_buf, rows_buf) -> None:
        self._k["write_slots"](self.device.queue, *self.layout.element_grid(k), self.matrix.buffers[channel],
                               np.int32(self.M), np.int32(self.ld), self._slots, np.int32(k), cols_buf, rows_buf)

    def rank_update(self, channel: int, A: np.ndarray, B: np.ndarray) -> None:
        """K += sum_n outer(A[n], B[n]) for A, B of shape (n, M), n <= 2 * max_vectors."""
        self._launch_rank(channel, self._put_rank(channel, A, B))

    def read_slots(self, channel: int, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Columns K[:, slots] and rows K[slots, :], both as (k, M) float64."""
        k = self._enqueue_read_slots(channel, slots)
        cols, rows = self._get((self._res[channel]["cols"], k), (self._res[channel]["rows"], k))
        return cols, rows

    def write_slots(self, channel: int, slots: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> None:
        """K[:, slots[m]] = cols[m], K[slots[m], :] = rows[m]; cols/rows must agree where they cross."""
        self._launch_write(channel, self._put_write(channel, slots, cols, rows), self._res[channel]["cols"],
                           self._res[channel]["rows"])

    def update_slots(self, channel: int, A: np.ndarray, B: np.ndarray, slots: np.ndarray, cols: np.ndarray,
                     rows: np.ndarray) -> None:
        """:meth:`rank_update` then :meth:`write_slots`, every upload before the first launch.

        An upload waits for the commands queued before it on PoCL (its non-blocking writes
        return only when the queue has reached them: measured 2-9 ms behind an M = 4096 rank
        pass), so uploading the slots' values after launching the rank update held the host
        for the whole pass; this way the caller gets control back as soon as both are queued."""
        self.update_channels([channel], [A], [B], slots, [cols], [rows])

    def update_channels(self, channels, A, B, slots: np.ndarray, cols, rows) -> None:
        """:meth:`update_slots` for several channels with one set of slots: every channel's
        uploads, then every channel's passes (an upload between two channels' passes would hold
        the host until the first channel's are done). A, B, cols, rows: one array per channel."""
        ns = [self._put_rank(c, a, b) for c, a, b in zip(channels, A, B)]
        ks = [self._put_write(c, slots, co, ro) for c, co, ro in zip(channels, cols, rows)]
        for c, n, k in zip(channels, ns, ks):
            self._launch_rank(c, n, k)

    def clear_slot(self, channel: int, slot: int) -> None:
        """K[:, slot] = 0 and K[slot, :] = 0, from a device buffer of M zeros (no upload)."""
        self._launch_write(channel, self._put_slots([slot]), self._zeros, self._zeros)

    def double_reflection(self, f_c: np.ndarray, f_r: np.ndarray, rho: np.ndarray) -> float | np.ndarray:
        """Eq. 1: sum_a f_c[a] f_r[a] rho[a] over the M slots, reduced on the device.

        ``rho`` (M,) gives a float; (C, M), one albedo row per channel, gives (C,) with one wait."""
        rho = np.asarray(rho)
        rows = np.atleast_2d(rho)
        if rows.shape[0] > self.matrix.C:
            raise InvalidInputError(f"at most {self.matrix.C} albedo rows; got {rows.shape[0]}")
        for c, r in enumerate(rows):
            # The input buffer is reused: in order, each upload lands after the previous kernel.
            self._put(self._out, np.concatenate([f_c, f_r, r])[None], 3 * self.M)
            self._k["double_reflection"](self.device.queue, *self.layout.reduction_grid(), self._out, np.int32(self.M),
                                         self._res[c]["KX"])
        dr = np.array([h[0, 0] for h in self._get(*[(self._res[c]["KX"], 1, 1) for c in range(len(rows))])])
        return float(dr[0]) if rho.ndim == 1 else dr
