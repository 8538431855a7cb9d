"""Small products on the host where the device is the host's own CPU.

A product with a matrix of a few MiB costs less on the host than one call on a CPU device
(PoCL): a call's upload, launch, wake-up of the device's threads and read-back cost the same
whatever the size, and a call queued behind other device work (a moved object's hemicubes) waits
for all of it. The far field's coarse K_c and its gather matrix G on a small scene are such
matrices: held dense and multiplied through one BLAS thread, each costs the host a fraction of
one device call (docs/decisions/0019-far-field-coarse-solve.md).
Above :data:`HOST_PRODUCT_BYTES`, and on every other device, matrices stay on the device.

:class:`HostBounce` is :class:`~pydynrad.device.csr.DeviceCSR`'s ``bounce`` on the host, dense
where that reads at most twice the CSR's bytes; :class:`HostMatrix` is
:class:`~pydynrad.device.matrix.DeviceMatrix`'s ``matvec``/``matmat`` for dense channels. Their dense
products multiply in the matrix's type as the device does (float32 values by float32 vectors,
or float64), on one BLAS thread beside a CPU device (:mod:`pydynrad.host.blas`); a CSR product
sums in float64, and ``L + P (A x)`` is formed in float64: at least the device's precision.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..checks import finite
from ..errors import InvalidInputError
from ..precision import compute_dtype, storage_dtype
from .blas import one_blas_thread
from .colproduct import rows_product
from .shortcuts import host_shortcuts

__all__ = ["HOST_PRODUCT_BYTES", "DENSE_FILL", "on_host", "HostBounce", "HostMatrix"]

#: The largest matrix (bytes as it would be held) whose products run on the host beside a CPU
#: device: at one core's memory bandwidth a product of it takes about one device call's fixed
#: cost (above; docs/decisions/0019-far-field-coarse-solve.md).
HOST_PRODUCT_BYTES = 4 << 20

#: The fraction of non-zero entries from which :class:`HostBounce` holds its matrix dense: dense
#: float32 reads 4 bytes an entry, CSR 8 a non-zero, so from 1/4 dense reads at most twice the
#: bytes, and BLAS streams them where CSR gathers x by index (faster for the far field's G,
#: about half filled; docs/decisions/0019-far-field-coarse-solve.md).
DENSE_FILL = 0.25


def on_host(device, nbytes: int) -> bool:
    """Whether a matrix of ``nbytes`` has its products on the host: a CPU device, and small
    (never with ``PYDYNRAD_FORCE_DEVICE=1``: :func:`pydynrad.host.shortcuts.host_shortcuts`)."""
    return host_shortcuts(device) and nbytes <= HOST_PRODUCT_BYTES


class HostBounce:
    """y = L + P (A x) on the host for a sparse (rows, cols) A, in ``dtype`` (float32 or
    float64): :class:`~pydynrad.device.csr.DeviceCSR`'s ``bounce``.

    Held dense where at least :data:`DENSE_FILL` of its entries are non-zero (a BLAS product in
    ``dtype``), else as CSR in ``dtype`` summed in float64 by row
    (:func:`~pydynrad.host.colproduct.rows_product`)."""

    def __init__(self, A: sp.csr_matrix, dtype) -> None:
        A = sp.csr_matrix(A)
        self.shape, self.nnz, self.dtype = A.shape, int(A.nnz), np.dtype(dtype)
        self.dense = self._full_enough(A)
        # A copy either way: a CSR of A's own dtype would share its arrays, counted twice where
        # the caller keeps A too.
        self._A = A.toarray().astype(self.dtype) if self.dense else sp.csr_matrix(A, dtype=self.dtype, copy=True)
        self.nbytes = self.nbytes_of(A, self.dtype)

    @staticmethod
    def _full_enough(A: sp.csr_matrix) -> bool:
        """Whether ``A`` is held dense: at least :data:`DENSE_FILL` of its entries non-zero."""
        size = A.shape[0] * A.shape[1]
        return size > 0 and A.nnz >= DENSE_FILL * size

    @staticmethod
    def nbytes_of(A: sp.csr_matrix, dtype) -> int:
        """The bytes a HostBounce of ``A`` in ``dtype`` holds."""
        item = np.dtype(dtype).itemsize
        if HostBounce._full_enough(A):
            return A.shape[0] * A.shape[1] * item
        return A.nnz * (item + A.indices.dtype.itemsize) + A.indptr.nbytes

    def bounce(self, L: np.ndarray, rho: np.ndarray, x: np.ndarray) -> np.ndarray:
        """y = L + rho * (A x): L, rho (rows, k), x (cols, k), k = 1 or 3; returns (rows, k) float64."""
        k = x.shape[1]
        if x.shape[0] != self.shape[1] or L.shape != (self.shape[0], k) or rho.shape != (self.shape[0], k):
            raise InvalidInputError(
                f"bounce of a {self.shape} matrix needs L, rho ({self.shape[0]}, {k}) and x "
                f"({self.shape[1]}, {k}); got {L.shape}, {rho.shape}, {x.shape}"
            )
        if self.dense:
            with one_blas_thread():
                Ax = self._A @ x.astype(self.dtype)
        else:
            Ax = rows_product(self._A, x)
        return L + rho * Ax


class HostMatrix:
    """C channels of a dense M x M matrix on the host: :class:`~pydynrad.device.matrix.DeviceMatrix`'s
    products, its entries rounded to ``storage`` as the device's are and multiplied in the type
    the device computes in (float32, or float64 for fp64 storage)."""

    def __init__(self, K: np.ndarray, storage: str = "fp32") -> None:
        K = np.asarray(K)
        if K.ndim != 3 or K.shape[1] != K.shape[2] or K.shape[1] == 0:
            raise InvalidInputError(f"K must have shape (C, M, M) with M > 0; got {K.shape}")
        if not np.issubdtype(K.dtype, np.floating):
            raise InvalidInputError(f"K must hold floating-point values; got {K.dtype}")
        stored = storage_dtype(storage)
        top = max(float(K.max(initial=0.0)), -float(K.min(initial=0.0)))
        if not np.all(np.isfinite(K)) or top > float(np.finfo(stored).max):
            raise InvalidInputError(f"K's entries must be finite and within {storage}'s range; they reach {top:.3g}")
        self.storage, self.C, self.M = storage, K.shape[0], K.shape[1]
        self.real_dtype = compute_dtype(storage)
        self._K = np.ascontiguousarray(K.astype(stored).astype(self.real_dtype))

    @staticmethod
    def nbytes_of(C: int, M: int, storage: str) -> int:
        return C * M * M * compute_dtype(storage).itemsize

    @property
    def nbytes(self) -> int:
        return self._K.nbytes

    def matmat(self, X: np.ndarray) -> np.ndarray:
        """Y[c, q] = K[c] X[c, q]: X (C, r, M), or (r, M) for every channel; returns (C, r, M) float64."""
        X = np.asarray(X, np.float64)
        if X.ndim == 2:
            X = np.broadcast_to(X, (self.C, *X.shape))
        if X.ndim != 3 or X.shape[0] != self.C or X.shape[2] != self.M or X.shape[1] < 1:
            raise InvalidInputError(
                f"X must have shape ({self.C}, r, {self.M}) or (r, {self.M}) with r >= 1; got {X.shape}"
            )
        finite(X, "X")
        with one_blas_thread():
            return np.matmul(X.astype(self.real_dtype), self._K.transpose(0, 2, 1)).astype(np.float64)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        """y = K x per channel. x: (C, M) or (M,) for every channel. Returns (C, M) float64."""
        x = np.asarray(x, np.float64)
        if x.shape == (self.M,):
            x = np.broadcast_to(x, (self.C, self.M))
        if x.shape != (self.C, self.M):
            raise InvalidInputError(f"x must have shape ({self.C}, {self.M}) or ({self.M},); got {x.shape}")
        return self.matmat(x[:, None])[:, 0]
