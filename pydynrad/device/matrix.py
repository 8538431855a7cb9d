"""Device-resident dense matrices (the multibounce matrix K) and their matrix-vector products.

A :class:`DeviceMatrix` holds C channels of an M x M matrix on an OpenCL device, one buffer
per channel, row-major with a padded leading dimension :attr:`DeviceMatrix.ld`. Elements are
stored as fp16, fp32 or fp64 (``storage``); fp16 and fp32 compute in fp32, fp64 in fp64.
Lighting a frame is one product per channel, ``y = K x``, which streams K once: the kernels in
``kernels/matvec.cl`` are written to run at memory bandwidth (see ``bench/radiosity.py``).
:meth:`DeviceMatrix.matmat` multiplies several vectors per pass over K (a grey K lit by an
RGB light vector: three products for the traffic of one).

Other kernels that work on K in place (``kernels/update.cl``) include ``kernels/storage.h``
and build with :attr:`DeviceMatrix.defines` so they read and write the same element type.

See docs/design.md, 'Cost model'.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..checks import finite
from ..errors import DeviceError, InvalidInputError, OutOfMemoryError
from ..precision import compute_dtype, storage_dtype
from .launch import MAX_RHS, enqueue_kernel, matvec_layout, round_up
from .transfers import ReadSlab

__all__ = ["DeviceMatrix", "MAX_RHS"]


#: Rows are padded to a multiple of this many elements (128 bytes of fp16, 256 of fp32), so
#: every vector load is aligned and rows start on cache-line boundaries.
LD_ALIGN = 64


def padded_ld(M: int) -> int:
    """The row pitch (elements) of an M x M matrix: M rounded up to a multiple of :data:`LD_ALIGN`."""
    return round_up(M, LD_ALIGN)


def _check_storage_on(device, storage: str) -> None:
    storage_dtype(storage)
    if storage == "fp64" and not device.supports_fp64:
        raise DeviceError(f"fp64 storage needs cl_khr_fp64, which {device.name} lacks; use storage='fp32' or 'fp16'")


class DeviceMatrix:
    """C channels of an M x M matrix in device memory.

    Parameters
    ----------
    device : pydynrad.device.Device
    K : (C, M, M) array
        The matrix per channel (any float dtype; converted to the storage type with
        round-to-nearest-even).
    storage : "fp16" | "fp32" | "fp64"
    layout : (VW, LX), optional
        Kernel layout override (vector width, work-items per row); by default the device's
        (:func:`pydynrad.device.launch.matvec_layout`: up to 4 rows side by side per item and two
        SIMD registers per load on a CPU, (4, 64) on a GPU). For tuning and for testing the GPU path on a CPU.

    Attributes
    ----------
    C, M, ld : int
        Channels, rows/columns, and the row pitch in elements (ld >= M, ld % 64 == 0; the
        padding columns hold zeros and must stay zero).
    buffers : list of pyopencl.Buffer
        One buffer per channel, M * ld elements of the storage type.
    storage : str
    real_dtype : numpy dtype
        The compute type of vectors passed to the kernels: float32, or float64 for fp64.
    """

    def __init__(self, device, K: np.ndarray, storage: str = "fp32", *, layout: tuple[int, int] | None = None) -> None:
        K = np.asarray(K)
        if K.ndim != 3 or K.shape[1] != K.shape[2] or K.shape[1] == 0:
            raise InvalidInputError(f"K must have shape (C, M, M) with M > 0; got {K.shape}")
        if not np.issubdtype(K.dtype, np.floating) or not np.all(np.isfinite(K)):
            raise InvalidInputError("K must hold finite floating-point values")
        self._allocate(device, K.shape[0], K.shape[1], storage, layout)
        self.upload(K)

    @classmethod
    def zeros(cls, device, C: int, M: int, storage: str = "fp32", *, layout=None) -> DeviceMatrix:
        """An all-zero matrix, for callers that fill K with their own kernels."""
        import pyopencl as cl

        if C < 1 or M < 1:
            raise InvalidInputError(f"need C >= 1 and M >= 1; got C={C}, M={M}")
        out = object.__new__(cls)
        out._allocate(device, int(C), int(M), storage, layout)
        zero = np.zeros(1, dtype=out.dtype)
        for buf in out.buffers:
            cl.enqueue_fill_buffer(device.queue, buf, zero, 0, out.channel_nbytes)
        device.queue.finish()
        return out

    # -- construction ------------------------------------------------------------------------
    def _allocate(self, device, C: int, M: int, storage: str, layout) -> None:
        import pyopencl as cl

        _check_storage_on(device, storage)
        self.device, self.storage, self.C, self.M = device, storage, C, M
        self.dtype = storage_dtype(storage)
        self.real_dtype = compute_dtype(storage)
        self.ld = padded_ld(M)
        per = self.channel_nbytes
        if per > device.max_alloc_bytes:
            raise OutOfMemoryError(
                f"one channel of a {M} x {M} {storage} matrix needs {per / 2**20:.1f} MiB, above the device's "
                f"largest allocation ({device.max_alloc_bytes / 2**20:.0f} MiB on {device.name}); use fewer patches "
                "or fp16 storage"
            )
        if C * per > device.global_mem_bytes:
            raise OutOfMemoryError(
                f"{C} channels of a {M} x {M} {storage} matrix need {C * per / 2**20:.1f} MiB, above the device's "
                f"global memory ({device.global_mem_bytes / 2**20:.0f} MiB)"
            )
        try:
            self.buffers = [cl.Buffer(device.context, cl.mem_flags.READ_WRITE, per) for _ in range(C)]
        except cl.Error as exc:
            raise OutOfMemoryError(f"allocating {C} x {per / 2**20:.1f} MiB on {device.name} failed: {exc}") from exc
        self._layout = matvec_layout(device, M, self.ld, layout, self.real_dtype.itemsize, self.dtype.itemsize)
        self._n_blocks = -(-M // self._layout.rb)
        self._y: ReadSlab | None = None
        self._partial: Any = None  # a pyopencl Buffer once the first transposed product needs it
        prg = self._program(1)
        # Kernel objects hold their arguments: one per matrix, reused by every call.
        self._k_matvec = {1: cl.Kernel(prg, "matvec")}
        self._k_partial = cl.Kernel(prg, "rmatvec_partial")
        self._k_reduce = cl.Kernel(prg, "rmatvec_reduce")

    def _program(self, nrhs: int):
        return self.device.program("matvec.cl", {**self.defines, **self._layout.defines(nrhs)})

    def upload(self, K: np.ndarray) -> None:
        """Overwrite every channel with K (C, M, M)."""
        import pyopencl as cl

        K = np.asarray(K)
        if K.shape != (self.C, self.M, self.M):
            raise InvalidInputError(f"K must have shape {(self.C, self.M, self.M)}; got {K.shape}")
        # Past the storage type's range an entry would be stored as inf (numpy only warns) and
        # every product with K would be inf or NaN: a multibounce matrix at albedos near 1.
        top = max(float(K.max(initial=0.0)), -float(K.min(initial=0.0)))  # no temporary of |K|
        if top > float(np.finfo(self.dtype).max):
            raise InvalidInputError(
                f"K's entries reach {top:.3g}, beyond {self.storage}'s range "
                f"({float(np.finfo(self.dtype).max):.4g}; albedos near 1 make K large): "
                "use a wider storage"
            )
        host = np.zeros((self.M, self.ld), dtype=self.dtype)
        for c in range(self.C):
            host[:, : self.M] = K[c]
            cl.enqueue_copy(self.device.queue, self.buffers[c], host, is_blocking=True)

    # -- properties ----------------------------------------------------------------------------
    @property
    def channel_nbytes(self) -> int:
        return self.M * self.ld * self.dtype.itemsize

    @property
    def nbytes(self) -> int:
        """Device bytes held by the matrix (all channels, padding included)."""
        return self.C * self.channel_nbytes

    @property
    def defines(self) -> dict[str, int]:
        """Build defines selecting this storage in ``kernels/storage.h``."""
        return {f"STORAGE_{self.storage.upper()}": 1}

    # -- device-side products (no host round trip) ---------------------------------------------
    def enqueue_matvec(self, channel: int, x_buf, y_buf, nrhs: int = 1) -> None:
        """Enqueue y = K[channel] x on device buffers: x holds ld REAL values (zeros past M), y M.

        ``nrhs`` (1 to :data:`MAX_RHS`) products in one pass over K: x then holds nrhs vectors of
        ld values each (stride ld), y nrhs vectors of M values (stride M).
        """
        import pyopencl as cl

        if not 1 <= nrhs <= MAX_RHS:
            raise InvalidInputError(f"nrhs must be 1 to {MAX_RHS}; got {nrhs}")
        k = self._k_matvec.get(nrhs)
        if k is None:
            k = self._k_matvec[nrhs] = cl.Kernel(self._program(nrhs), "matvec")
        enqueue_kernel(
            self.device,
            k,
            *self._layout.matvec_grid(self.M, nrhs),
            self.buffers[channel],
            np.int32(self.M),
            np.int32(self.ld),
            x_buf,
            y_buf,
            fixed=self._layout.lx > 1,  # LX > 1: a local-memory reduction over exactly LX items
        )

    def enqueue_rmatvec(self, channel: int, x_buf, y_buf) -> None:
        """Enqueue y = x^T K[channel] on device buffers: x holds M REAL values, y M."""
        import pyopencl as cl

        if self._partial is None:
            self._partial = cl.Buffer(
                self.device.context, cl.mem_flags.READ_WRITE, self._n_blocks * self.ld * self.real_dtype.itemsize
            )
        d, M, ld = self.device, np.int32(self.M), np.int32(self.ld)
        partial_grid, reduce_grid = self._layout.rmatvec_grids(self.M, self.ld)
        enqueue_kernel(
            d,
            self._k_partial,
            *partial_grid,
            self.buffers[channel],
            M,
            ld,
            np.int32(self._layout.rb),
            x_buf,
            self._partial,
        )
        enqueue_kernel(d, self._k_reduce, *reduce_grid, self._partial, M, ld, np.int32(self._n_blocks), y_buf)

    # -- host-facing products --------------------------------------------------------------------
    def _vectors(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if x.shape == (self.M,):
            x = np.broadcast_to(x, (self.C, self.M))
        if x.shape != (self.C, self.M):
            raise InvalidInputError(f"x must have shape ({self.C}, {self.M}) or ({self.M},); got {x.shape}")
        finite(x, "x")
        return x

    def _results(self) -> ReadSlab:
        """Every channel's product output, as parts of one slab: all channels' products are
        queued, then read back with one command."""
        if self._y is None:
            self._y = ReadSlab(self.device, [MAX_RHS * self.M] * self.C, self.real_dtype)
        return self._y

    def matmat(self, X: np.ndarray) -> np.ndarray:
        """Y[c, q] = K[c] X[c, q] for r right-hand sides per channel, each pass over K serving
        up to :data:`MAX_RHS` of them (the three colour channels of a light vector under one
        grey K cost one pass, not three).

        X: (C, r, M), or (r, M) for every channel. Returns (C, r, M) float64.
        """
        X = np.asarray(X, dtype=np.float64)
        if X.ndim == 2:
            X = np.broadcast_to(X, (self.C, *X.shape))
        if X.ndim != 3 or X.shape[0] != self.C or X.shape[2] != self.M or X.shape[1] < 1:
            raise InvalidInputError(
                f"X must have shape ({self.C}, r, {self.M}) or (r, {self.M}) with r >= 1; got {X.shape}"
            )
        finite(X, "X")
        r = X.shape[1]
        slab = self._results()
        xh = np.zeros((self.C, MAX_RHS, self.ld), dtype=self.real_dtype)
        out = np.empty((self.C, r, self.M))
        for q0 in range(0, r, MAX_RHS):
            n = min(MAX_RHS, r - q0)
            xh[:, :n, : self.M] = X[:, q0 : q0 + n]
            for c in range(self.C):
                self.enqueue_matvec(c, self.device.to_device(xh[c, :n]), slab.parts[c], n)
            ys = slab.read([(c, n * self.M) for c in range(self.C)])
            out[:, q0 : q0 + n] = np.stack(ys).reshape(self.C, n, self.M)
        return out

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """y = K x per channel. x: (C, M) or (M,) for every channel. Returns (C, M) float64."""
        return self.matmat(self._vectors(x)[:, None])[:, 0]

    def rmatvec(self, x: np.ndarray) -> np.ndarray:
        """y = x^T K per channel (light gathered by row vector x). Returns (C, M) float64."""
        x = self._vectors(x)
        slab = self._results()
        for c in range(self.C):
            self.enqueue_rmatvec(c, self.device.to_device(x[c].astype(self.real_dtype)), slab.parts[c])
        return np.stack(slab.read([(c, self.M) for c in range(self.C)])).astype(np.float64)

    def to_host(self) -> np.ndarray:
        """The stored matrix as (C, M, M) float64 (values as stored: fp16 rounding included)."""
        import pyopencl as cl

        host = np.empty((self.M, self.ld), dtype=self.dtype)
        out = np.empty((self.C, self.M, self.M))
        for c in range(self.C):
            cl.enqueue_copy(self.device.queue, host, self.buffers[c], is_blocking=True)
            out[c] = host[:, : self.M]
        return out

    def __repr__(self) -> str:
        return f"DeviceMatrix(C={self.C}, M={self.M}, ld={self.ld}, storage={self.storage!r}, {self.nbytes / 2**20:.1f} MiB)"
