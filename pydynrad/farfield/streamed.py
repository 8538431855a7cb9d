"""G left in its form-factor store: read in bounded chunks of row blocks, once per pass over it.

A million-patch store's G (linear basis, about 200 non-zeros per row, twice F's) takes 1.7-2 GB
held whole, more than the rest of a store-fed walk; docs/design.md, 'Far field', 'As built'.
G is needed only when the lights change (B_far, then fixed until the next change), so a
:class:`StoredG` keeps none of it: each pass reads the store's blocks of G in chunks of about
:data:`CHUNK_NNZ` non-zeros, the next chunk read (unzipped and checksummed, which releases the
GIL) by a thread while the device multiplies the current one.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp

from ..checks import check_form_factor_rows
from ..errors import InvalidInputError

__all__ = ["StoredG", "CHUNK_NNZ"]

#: Non-zeros of G per chunk a pass holds (two at once, with the one being read): 4 M is 32 MB
#: of float32 values and int32 indices, a few of the store's blocks.
CHUNK_NNZ = 4_000_000


class StoredG:
    """The (N, K) patch-to-cluster form factors G of a form-factor store, never held whole.

    Parameters
    ----------
    store : pydynrad.rows.store.FormFactorStore
        Holding all of G's blocks.
    prolongation : (N, K) sparse, optional
        The prolongation the caller's far field uses; checked to be the one G was made with
        (:class:`~pydynrad.StoreMismatchError` otherwise).
    chunk_nnz : int
        About how many non-zeros of G one chunk holds.
    """

    def __init__(self, store, prolongation=None, chunk_nnz: int = CHUNK_NNZ) -> None:
        from ..rows.store import StoreIncompleteError

        if prolongation is not None:
            store.check_clusters(prolongation)
        missing = store.missing_blocks(part="G")
        if missing:
            raise StoreIncompleteError(f"{len(missing)} of {store.n_blocks} blocks of G in store {store.path} have not "
                                       "been computed; run compute_store with the same clusters to finish them")
        self.store, self.shape = store, (store.n_patches, store.n_clusters)
        self.chunk_nnz = int(chunk_nnz)
        self.nnz = None  # known after the first pass

    def _chunks_in_order(self):
        chunk, held = [], 0
        for k in range(self.store.n_blocks):
            block = self.store.read_block(k, "G")
            chunk.append(block)
            held += block.nnz
            if held >= self.chunk_nnz:
                yield chunk
                chunk, held = [], 0
        if chunk:
            yield chunk

    def chunks(self):
        """(first row, (rows, K) float32 CSR) for consecutive chunks covering all N rows; the next
        chunk is read ahead by a thread."""
        first = 0
        parts = self._chunks_in_order()
        with ThreadPoolExecutor(max_workers=1) as pool:
            ahead = pool.submit(next, parts, None)
            while True:
                chunk = ahead.result()
                if chunk is None:
                    return
                ahead = pool.submit(next, parts, None)
                block = chunk[0] if len(chunk) == 1 else sp.vstack(chunk, format="csr")
                del chunk
                yield first, block
                first += block.shape[0]

    def coarse_form_factors(self, restriction: sp.csr_matrix, clusters: int) -> sp.csr_matrix:
        """F_c = R G_1 (C, C) float64, G_1 G summed over each cluster's K / C functions, in one pass
        that checks every chunk as rows of F are checked (and counts :attr:`nnz`)."""
        R = restriction.tocsc()  # column slices per chunk
        funcs = self.shape[1] // clusters
        rows, cols, vals, nnz = [], [], [], 0
        for first, block in self.chunks():
            names = np.arange(first, first + block.shape[0])
            G = check_form_factor_rows(block, "G", names, (block.shape[0], self.shape[1]))
            nnz += G.nnz
            G1 = G[:, :clusters]
            for f in range(1, funcs):
                G1 = G1 + G[:, f * clusters:(f + 1) * clusters]
            part = (R[:, first:first + block.shape[0]] @ G1).tocoo()
            rows.append(part.row.astype(np.int32))
            cols.append(part.col.astype(np.int32))
            vals.append(part.data)
        self.nnz = nnz
        if not rows:
            raise InvalidInputError("the store's G has no rows")
        # Duplicates (clusters whose patches straddle two chunks) are summed by the conversion.
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(clusters, clusters))

    def bounce(self, device, dtype, L: np.ndarray, rho: np.ndarray, x: np.ndarray) -> np.ndarray:
        """y = L + rho * (G x) as :meth:`pydynrad.devicecsr.DeviceCSR.bounce` (the same kernel and
        precision, per chunk): L, rho (N, k), x (K, k); returns (N, k) float64."""
        import pyopencl as cl

        from ..devicecsr import DeviceCSR

        k = x.shape[1]
        width = 1 if k == 1 else 4
        out = np.empty((self.shape[0], k))
        x_buf = None
        for first, block in self.chunks():
            part = DeviceCSR(device, block, dtype)
            if x_buf is None:  # x once for every chunk
                x_buf = device.to_device(part.packed(x, width))
            stop = first + block.shape[0]
            L_buf, rho_buf = (device.to_device(part.packed(a[first:stop], width)) for a in (L, rho))
            y = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, max(block.shape[0], 1) * width * part.dtype.itemsize)
            part.bounce_buffers(L_buf, rho_buf, x_buf, y, width)
            got = np.empty((block.shape[0], width), dtype=part.dtype)
            if block.shape[0]:
                cl.enqueue_copy(device.queue, got, y, is_blocking=True)
            out[first:stop] = got[:, :k]
        return out
