"""Device operations on a :class:`~pydynrad.device.matrix.DeviceMatrix` K for the local update.

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

import os
import time

import numpy as np

from ..device.launch import CPU_ROWS, WG, UpdateLayout, enqueue_kernel, global_size, round_up
from ..device.transfers import ReadSlab
from ..errors import InvalidInputError

__all__ = ["UpdateKernels", "scratch_nbytes", "SPARSE_DENSITY", "PROBE_DENSITIES", "crossover"]

#: The sparse gathers run when the vectors' non-zero slots, on both sides together, are at
#: most this share of 2 M. Below some density the sparse gathers beat the dense pass and above
#: it they lose, and where they meet moves with the CPU (a dense pass bound by 8-float FMAs on
#: AVX2 leaves the gathers ahead to a higher density than a 16-wide one), while a walk's swap
#: batches are mostly sparse (docs/decisions/0008-measured-sparse-gather-threshold.md). So this
#: is only the threshold before
#: :meth:`UpdateKernels.warm_up` measures the device's own (:data:`PROBE_DENSITIES`).
SPARSE_DENSITY = 0.10

#: The densities at which :meth:`UpdateKernels.warm_up` times the sparse gathers against the
#: dense pass (best of 3 each, on channel 0 and the device's own K): the sparse gathers' time
#: grows linearly with the density, the dense pass's does not, so two points give where they
#: cross on this device for this M and storage. Kept per process (:data:`_CROSSOVERS`);
#: ``PYDYNRAD_SPARSE_DENSITY`` fixes the threshold instead.
PROBE_DENSITIES = (0.04, 0.24)
_CROSSOVERS: dict[tuple, float] = {}

#: What each channel's part of the result slab holds, in slab order (n rows of M each).
RESULTS = ("cols", "rows", "KX", "YK")


def crossover(dense_s: float, sparse_s: tuple[float, float], densities=PROBE_DENSITIES) -> float:
    """The density (share of 2 M slots) at which the sparse gathers, timed ``sparse_s`` at
    ``densities``, take as long as the dense pass (``dense_s``), on the line through the two
    points; clipped to [0.02, 0.5] (a probe cannot tell more on a noisy machine)."""
    (d0, d1), (t0, t1) = densities, sparse_s
    slope = (t1 - t0) / (d1 - d0)
    d = d0 + (dense_s - t0) / slope if slope > 0 else (d1 if t1 <= dense_s else d0)
    return float(np.clip(d, 0.02, 0.5))


def _density_from_env() -> float | None:
    text = os.environ.get("PYDYNRAD_SPARSE_DENSITY")
    if not text:
        return None
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value <= 1.0:
        raise InvalidInputError(f"PYDYNRAD_SPARSE_DENSITY must be a share of the slots in [0, 1]; got {text!r}")
    return value


def scratch_nbytes(
    device, M: int, ld: int, k_itemsize: int, real_itemsize: int, max_vectors: int, channels: int = 1
) -> int:
    """Device bytes of :class:`UpdateKernels`' buffers for these sizes at their peak: the
    partial sums and the result slab, which stay, and the uploads, which live until the kernels
    reading them are done. The rank passes are not waited for, so one frame's rank factors and
    slot values (every channel's) may still be queued when the next frame's gather inputs (or
    paper mode's Eq. 1 input) go up: both sets are counted."""
    lay = UpdateLayout.make(device, M, ld, k_itemsize, real_itemsize)
    nv = max_vectors
    shared = lay.parts * nv * M + lay.max_partial_blocks(nv) * ld + M  # row and column partials, zeros
    # The gather inputs (X and Y, at least the sparse values), Eq. 1's input, the rank factors
    # A, B and the slot values; then the result slab (slot columns and rows, K X, Y K) as laid out.
    per_channel = (nv * ld + nv * M) + 3 * M + (2 * nv * M + 2 * nv * ld) + 2 * nv * M
    real = np.float32 if real_itemsize == 4 else np.float64
    slab = ReadSlab.layout(device, [nv * M] * (len(RESULTS) * channels), real)[1]
    return real_itemsize * (shared + channels * per_channel) + slab + 4 * nv + 8 * ld  # slots, sparse gathers' indices


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
        names = (
            "gather_rows",
            "gather_partial",
            "gather_reduce",
            "gather_sparse_cols",
            "gather_sparse_rows",
            "rank_update_rows",
            "rank_update",
            "read_slots",
            "write_slots",
            "double_reflection",
        )
        self._k = {n: cl.Kernel(prg, n) for n in names}
        mf, ctx, r = cl.mem_flags, dev.context, self.real.itemsize
        nv, M, ld = self.nv_max, self.M, self.ld
        self._rowpart = cl.Buffer(ctx, mf.READ_WRITE, self.layout.parts * nv * M * r)
        self._colpart = cl.Buffer(ctx, mf.READ_WRITE, self.layout.max_partial_blocks(nv) * ld * r)
        # Results of every channel in one slab, so all channels' passes come back with one read:
        # per channel the slots' columns and rows, then K X and Y K (gather_all's order).
        self._slab = ReadSlab(dev, [nv * M] * (len(RESULTS) * matrix.C), self.real)
        self._zeros = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.zeros(M, dtype=self.real))
        #: gather_all's sparse gathers run at or below this share of 2 M non-zero slots:
        #: PYDYNRAD_SPARSE_DENSITY where set, else SPARSE_DENSITY until warm_up measures this
        #: device's crossover.
        self.sparse_density = self._threshold(measure=False)
        self._slots_held: tuple | None = None  # (slot indices, their buffer) of the last upload

    @property
    def nbytes(self) -> int:
        """Device bytes of the partial sums, the result slab and the uploads at their peak
        (:func:`scratch_nbytes`)."""
        return scratch_nbytes(
            self.device, self.M, self.ld, self.matrix.dtype.itemsize, self.real.itemsize, self.nv_max, self.matrix.C
        )

    # -- helpers ---------------------------------------------------------------------------------
    def _put(self, a: np.ndarray, width: int, dtype=None):
        """A new device buffer of the rows of a (n, M) array with row pitch ``width`` (zero padded)."""
        a = np.atleast_2d(a)
        host = np.zeros((a.shape[0], width), dtype=dtype or self.real)
        host[:, : a.shape[1]] = a
        return self.device.to_device(host)

    def _put_slots(self, slots):
        """Check slot indices; returns (their count, their buffer). The buffer is reused while
        the slots stay the same (a frame's read and write passes, and every channel)."""
        slots = np.ascontiguousarray(slots, dtype=np.int32)
        self._check(len(slots))
        if self._slots_held is None or not np.array_equal(self._slots_held[0], slots):
            # The kernels index K by them: out of range they would write outside it, twice the
            # same cell of a column would have two writers. (The held ones were checked.)
            if slots.min() < 0 or slots.max() >= self.M or len(np.unique(slots)) < len(slots):
                raise InvalidInputError(f"slots must be distinct indices in [0, {self.M}); got {slots.tolist()}")
            self._slots_held = (slots.copy(), self.device.to_device(slots))
        return len(slots), self._slots_held[1]

    def _res(self, channel: int, name: str):
        """The slab part a kernel writes ``name`` (one of :data:`RESULTS`) of ``channel`` into."""
        return self._slab.parts[self._part(channel, name)]

    @staticmethod
    def _part(channel: int, name: str) -> int:
        return len(RESULTS) * channel + RESULTS.index(name)

    def _get(self, *items: tuple) -> list[np.ndarray]:
        """(channel, name, n) or (channel, name, n, width) items: n rows of ``width`` (default
        M) each, with one read and wait; float64 copies."""
        parts = [(self._part(c, name), n * (w[0] if w else self.M)) for c, name, n, *w in items]
        return [h.reshape(item[2], -1).astype(np.float64) for h, item in zip(self._slab.read(parts), items)]

    def _check(self, n: int) -> None:
        if not 1 <= n <= self.nv_max:
            raise InvalidInputError(f"between 1 and {self.nv_max} vectors per call; got {n}")

    def warm_up(self) -> None:
        """Launch every kernel once on channel 0, leaving K as it was.

        PoCL compiles a kernel's work-group function at its first launch (far longer than a
        frame), which would otherwise land inside the first frame that swaps. Costs one
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
        self.sparse_density = self._threshold(measure=True)

    def _threshold(self, measure: bool) -> float:
        """PYDYNRAD_SPARSE_DENSITY where set; else, with ``measure``, this device's crossover of
        the sparse gathers and the dense pass (:func:`crossover`), measured once per process for
        each (device, kernel kind, M, storage, vectors), K only read; else SPARSE_DENSITY."""
        fixed = _density_from_env()
        if fixed is not None:
            return fixed
        if not measure:
            return SPARSE_DENSITY
        key = (
            self.device.cl_device.int_ptr,
            self.layout.cpu,
            self.M,
            self.matrix.dtype.itemsize,
            self.real.itemsize,
            self.nv_max,
        )
        if key not in _CROSSOVERS:
            rng = np.random.default_rng(0)
            X, Y = rng.standard_normal((2, self.nv_max, self.M))

            def best_of_3(run) -> float:
                times = []
                for _ in range(3):
                    t0 = time.perf_counter()
                    run()
                    self.device.queue.finish()
                    times.append(time.perf_counter() - t0)
                return min(times)

            sparse = []
            for d in PROBE_DENSITIES:
                k = max(1, round(d * self.M))  # k slots on each side: k / M of 2 M
                cols, rows = (np.sort(rng.choice(self.M, k, replace=False)).astype(np.int32) for _ in range(2))
                Xs, Ys = np.zeros_like(X), np.zeros_like(Y)
                Xs[:, cols], Ys[:, rows] = X[:, cols], Y[:, rows]
                sparse.append(best_of_3(lambda: self._enqueue_sparse_gather(0, Xs, Ys, cols, rows)))
            dense = best_of_3(lambda: self._enqueue_gather(0, X, Y))
            _CROSSOVERS[key] = crossover(dense, tuple(sparse))
        return _CROSSOVERS[key]

    # -- operations -------------------------------------------------------------------------------
    def _enqueue_gather(self, channel: int, X: np.ndarray, Y: np.ndarray) -> int:
        X, Y = np.atleast_2d(X), np.atleast_2d(Y)
        n = X.shape[0]
        self._check(n)
        if Y.shape != X.shape:
            raise InvalidInputError(f"gather needs X, Y of equal shape; got {X.shape}, {Y.shape}")
        X_buf, Y_buf = self._put(X, self.ld), self._put(Y, self.M)
        K, lay = self.matrix.buffers[channel], self.layout
        rb, blocks = lay.gather_blocks(n)
        M, ld, nv = np.int32(self.M), np.int32(self.ld), np.int32(n)
        if lay.cpu:
            enqueue_kernel(
                self.device,
                self._k["gather_rows"],
                *lay.gather_grid(blocks),
                K,
                M,
                ld,
                np.int32(rb),
                np.int32(lay.gather_cw),
                nv,
                X_buf,
                Y_buf,
                self._rowpart,
                self._colpart,
            )
        else:
            enqueue_kernel(
                self.device,
                self._k["gather_partial"],
                *lay.gather_grid(blocks),
                K,
                M,
                ld,
                np.int32(rb),
                nv,
                X_buf,
                Y_buf,
                self._rowpart,
                self._colpart,
            )
        # In-order queue: the next channel's gather reuses the partial sums only after this reduce.
        enqueue_kernel(
            self.device,
            self._k["gather_reduce"],
            *lay.element_grid(n),
            self._rowpart,
            self._colpart,
            M,
            ld,
            nv,
            np.int32(lay.parts),
            np.int32(blocks),
            self._res(channel, "KX"),
            self._res(channel, "YK"),
        )
        return n

    def _sparse_indices(self, cols: np.ndarray, rows: np.ndarray) -> tuple:
        """The sparse gathers' padded index lists and their buffers: (Rp, buffer) for the column
        kernel (SW entries per step) and for the row kernel (RR rows per step), each padded with
        slot 0 (and zero values) to whole steps."""
        out = []
        for nz, step in ((cols, self.layout.sw), (rows, CPU_ROWS)):
            idx = np.zeros(round_up(max(1, len(nz)), step), dtype=np.int32)
            idx[: len(nz)] = nz
            out.append((len(idx), self.device.to_device(idx)))
        return tuple(out)

    def _enqueue_sparse_gather(
        self,
        channel: int,
        X: np.ndarray,
        Y: np.ndarray,
        cols: np.ndarray,
        rows: np.ndarray,
        indices: tuple | None = None,
    ) -> int:
        """K X and Y K from the slots ``cols`` (X's non-zeros) and ``rows`` (Y's) alone;
        ``indices``: :meth:`_sparse_indices` of them, shared by every channel."""
        n = X.shape[0]
        K = self.matrix.buffers[channel]
        M, ld, nv = np.int32(self.M), np.int32(self.ld), np.int32(n)
        (cols_rp, cols_idx), (rows_rp, rows_idx) = indices or self._sparse_indices(cols, rows)
        # vals: (n, Rp) for columns, (Rp, n) for rows.
        for name, rp, idx, nz, vectors, transpose, out, items in (
            ("gather_sparse_cols", cols_rp, cols_idx, cols, X, False, "KX", self.M),
            ("gather_sparse_rows", rows_rp, rows_idx, rows, Y, True, "YK", -(-self.M // self.layout.sw)),
        ):
            vals = np.zeros((n, rp))
            vals[:, : len(nz)] = vectors[:, nz]
            vals_buf = self.device.to_device((vals.T if transpose else vals).astype(self.real))
            enqueue_kernel(
                self.device,
                self._k[name],
                (global_size(items),),
                (WG,),
                K,
                M,
                ld,
                np.int32(rp),
                idx,
                vals_buf,
                nv,
                self._res(channel, out),
            )
        return n

    def _enqueue_read_slots(self, channel: int, slots: np.ndarray) -> int:
        k, slots_buf = self._put_slots(slots)
        enqueue_kernel(
            self.device,
            self._k["read_slots"],
            *self.layout.element_grid(k),
            self.matrix.buffers[channel],
            np.int32(self.M),
            np.int32(self.ld),
            slots_buf,
            self._res(channel, "cols"),
            self._res(channel, "rows"),
        )
        return k

    def gather(self, channel: int, X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K X^T)^T and Y K for X, Y of shape (n, M): returns two (n, M) float64 arrays."""
        n = self._enqueue_gather(channel, X, Y)
        KX, YK = self._get((channel, "KX", n), (channel, "YK", n))
        return KX, YK

    def gather_all(
        self, X: np.ndarray, Y: np.ndarray, slots: np.ndarray | None = None, sparse: bool | None = None
    ) -> tuple[np.ndarray, ...]:
        """:meth:`gather` for every channel c with X[c], Y[c] (C, n, M), and with ``slots`` also
        :meth:`read_slots` (taken before the gathers): all passes enqueued, one read back.

        ``sparse``: use the sparse gathers (``gather_sparse_cols``/``_rows``: K's part on the
        slots where some X[c] or Y[c] is non-zero) or the dense pass; None picks the sparse ones
        when those slots are at most :attr:`sparse_density` of 2 M.

        Returns KX, YK (C, n, M) and, with ``slots``, cols, rows (C, k, M), float64."""
        C = self.matrix.C
        X, Y = np.asarray(X, dtype=np.float64), np.asarray(Y, dtype=np.float64)
        if len(X) != C or len(Y) != C:
            raise InvalidInputError(f"gather_all needs one X and Y per channel ({C}); got {len(X)}, {len(Y)}")
        if X.ndim != 3 or X.shape != Y.shape or X.shape[2] != self.M:
            raise InvalidInputError(
                f"gather_all needs X, Y of equal shape ({C}, n, {self.M}); got {X.shape}, {Y.shape}"
            )
        self._check(X.shape[1])
        cols = np.flatnonzero(np.any(X != 0, axis=(0, 1))).astype(np.int32)
        rows = np.flatnonzero(np.any(Y != 0, axis=(0, 1))).astype(np.int32)
        if sparse is None:
            sparse = len(cols) + len(rows) <= self.sparse_density * 2 * self.M
        indices = self._sparse_indices(cols, rows) if sparse else None
        reads = []
        for c in range(C):
            if slots is not None:
                k = self._enqueue_read_slots(c, slots)
                reads += [(c, "cols", k), (c, "rows", k)]
            if sparse:
                n = self._enqueue_sparse_gather(c, X[c], Y[c], cols, rows, indices)
            else:
                n = self._enqueue_gather(c, X[c], Y[c])
            reads += [(c, "KX", n), (c, "YK", n)]
        out = self._get(*reads)
        step = 4 if slots is not None else 2
        per = [np.stack(out[i::step]) for i in range(step)]
        return (per[2], per[3], per[0], per[1]) if slots is not None else (per[0], per[1])

    def _put_rank(self, A: np.ndarray, B: np.ndarray) -> tuple:
        A, B = np.atleast_2d(A), np.atleast_2d(B)
        n = A.shape[0]
        if not 1 <= n <= 2 * self.nv_max or B.shape != A.shape:
            raise InvalidInputError(
                f"rank update needs A, B of equal shape (n <= {2 * self.nv_max}, M); got {A.shape}, {B.shape}"
            )
        return n, self._put(A, self.M), self._put(B, self.ld)

    def _launch_rank(self, channel: int, rank: tuple, write: tuple | None = None) -> None:
        """K += A B (``rank``: :meth:`_put_rank`'s count and buffers); then, with ``write``
        (:meth:`_put_write`'s), the slots' columns and rows: in the same pass on a CPU
        (``rank_update_rows``), by ``write_slots`` after it on a GPU."""
        K, lay = self.matrix.buffers[channel], self.layout
        (n, A_buf, B_buf), M, ld = rank, np.int32(self.M), np.int32(self.ld)
        if lay.cpu:
            k, slots_buf, cols_buf, rows_buf = write or (0, self._zeros, self._zeros, self._zeros)
            enqueue_kernel(
                self.device,
                self._k["rank_update_rows"],
                *lay.rank_grid,
                K,
                M,
                ld,
                np.int32(n),
                np.int32(lay.rank_rb),
                A_buf,
                B_buf,
                np.int32(k),
                slots_buf,
                cols_buf,
                rows_buf,
            )
            return
        enqueue_kernel(self.device, self._k["rank_update"], *lay.rank_grid, K, M, ld, np.int32(n), A_buf, B_buf)
        if write:
            self._launch_write(channel, *write)

    def _put_write(self, slots: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> tuple:
        """(count, slots' buffer, columns' buffer, rows' buffer) of a slot write."""
        k, slots_buf = self._put_slots(slots)
        return k, slots_buf, self._put(cols, self.M), self._put(rows, self.M)

    def _launch_write(self, channel: int, k: int, slots_buf, cols_buf, rows_buf) -> None:
        enqueue_kernel(
            self.device,
            self._k["write_slots"],
            *self.layout.element_grid(k),
            self.matrix.buffers[channel],
            np.int32(self.M),
            np.int32(self.ld),
            slots_buf,
            np.int32(k),
            cols_buf,
            rows_buf,
        )

    def rank_update(self, channel: int, A: np.ndarray, B: np.ndarray) -> None:
        """K += sum_n outer(A[n], B[n]) for A, B of shape (n, M), n <= 2 * max_vectors."""
        self._launch_rank(channel, self._put_rank(A, B))

    def read_slots(self, channel: int, slots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Columns K[:, slots] and rows K[slots, :], both as (k, M) float64."""
        k = self._enqueue_read_slots(channel, slots)
        cols, rows = self._get((channel, "cols", k), (channel, "rows", k))
        return cols, rows

    def write_slots(self, channel: int, slots: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> None:
        """K[:, slots[m]] = cols[m], K[slots[m], :] = rows[m]; cols/rows must agree where they cross."""
        self._launch_write(channel, *self._put_write(slots, cols, rows))

    def update_slots(
        self, channel: int, A: np.ndarray, B: np.ndarray, slots: np.ndarray, cols: np.ndarray, rows: np.ndarray
    ) -> None:
        """:meth:`rank_update` then :meth:`write_slots`, queued together and not waited for.

        On a CPU the slot writes happen inside the rank pass (``rank_update_rows`` with NS > 0),
        on each row while it is in cache: less time than two kernels that each read the row
        (docs/decisions/0006-fewer-waits-and-transfers.md)."""
        self._launch_rank(channel, self._put_rank(A, B), self._put_write(slots, cols, rows))

    def clear_slot(self, channel: int, slot: int) -> None:
        """K[:, slot] = 0 and K[slot, :] = 0, from a device buffer of M zeros (no upload)."""
        self._launch_write(channel, *self._put_slots([slot]), self._zeros, self._zeros)

    def double_reflection(self, f_c: np.ndarray, f_r: np.ndarray, rho: np.ndarray) -> float | np.ndarray:
        """Eq. 1: sum_a f_c[a] f_r[a] rho[a] over the M slots, reduced on the device.

        ``rho`` (M,) gives a float; (C, M), one albedo row per channel, gives (C,) with one wait."""
        rho = np.asarray(rho)
        rows = np.atleast_2d(rho)
        if np.shape(f_c) != (self.M,) or np.shape(f_r) != (self.M,) or rows.shape[1:] != (self.M,):
            raise InvalidInputError(
                f"double_reflection needs f_c, f_r ({self.M},) and rho ({self.M},) or (C, {self.M}); "
                f"got {np.shape(f_c)}, {np.shape(f_r)}, {rho.shape}"
            )
        if rows.shape[0] > self.matrix.C:
            raise InvalidInputError(f"at most {self.matrix.C} albedo rows; got {rows.shape[0]}")
        for c, r in enumerate(rows):
            v = self.device.to_device(np.concatenate([f_c, f_r, r]).astype(self.real))
            enqueue_kernel(
                self.device,
                self._k["double_reflection"],
                *self.layout.reduction_grid(),
                v,
                np.int32(self.M),
                self._res(c, "KX"),
                fixed=True,  # a local-memory tree over RED_WG items
            )
        dr = np.array([h[0, 0] for h in self._get(*[(c, "KX", 1, 1) for c in range(len(rows))])])
        return float(dr[0]) if rho.ndim == 1 else dr
