"""G left in its form-factor store: read in bounded chunks of row blocks, once per pass over it.

A million-patch store's G (linear basis, about 250 non-zeros per row, twice F's) takes 2.2 GB
held whole, more than the rest of a store-fed walk; docs/design.md, 'Far field', 'As built'.
G is needed only when the lights change (B_far, then fixed until the next change), so a
:class:`StoredG` keeps none of it in memory: each pass goes through G in chunks of about
:data:`CHUNK_NNZ` non-zeros. The store's blocks are zipped and checksummed, and unzipping them
is most of a pass, far more than the products (docs/decisions/0021-far-field-without-f.md),
so the first pass, which checks every block as rows of F and sums F_c, also
writes the chunks unzipped to a temporary file (8 bytes a non-zero; removed when the StoredG
goes) that every later pass reads instead. Reads run ahead of the products on threads (unzipping
and file reads release the GIL).
"""

from __future__ import annotations

import os
import tempfile
from collections import deque
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp

from ..checks import check_form_factor_rows
from ..device.csr import DeviceCSR
from ..errors import InvalidInputError

__all__ = ["StoredG", "CHUNK_NNZ", "READERS"]

#: Non-zeros of G per chunk a pass holds (a few at once, with those being read): 4 M is 32 MB of
#: float32 values and int32 indices, about 60 of a million-patch store's blocks.
CHUNK_NNZ = 4_000_000

#: Threads unzipping the store's blocks ahead of the products.
READERS = 2


def _read_ahead(tasks, workers: int, depth: int):
    """The results of the zero-argument callables ``tasks``, in order, at most ``depth`` running ahead."""
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending = deque()
        for task in tasks:
            pending.append(pool.submit(task))
            if len(pending) > depth:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


class StoredG:
    """The (N, K) patch-to-cluster form factors G of a form-factor store, never held whole.

    Parameters
    ----------
    store : pydynrad.rows.store.FormFactorStore
        Holding all of G's blocks.
    prolongation : (N, K) sparse, optional
        The prolongation the caller's far field uses; checked to be the one G was made with
        (:class:`~pydynrad.rows.StoreMismatchError` otherwise).
    chunk_nnz : int
        About how many non-zeros of G one chunk holds.
    spill : bool
        Write the chunks unzipped to a temporary file on the first whole pass and read later
        passes from it (module docstring); False: unzip the store's blocks on every pass.

    Attributes
    ----------
    nnz : int or None
        G's non-zeros, known after the first whole pass.
    spilled_bytes : int
        Bytes of the temporary file (0 until the first whole pass).
    """

    def __init__(self, store, prolongation=None, chunk_nnz: int = CHUNK_NNZ, spill: bool = True) -> None:
        store.check_whole_g(prolongation)
        self.store, self.shape = store, (store.n_patches, store.n_clusters)
        self.chunk_nnz, self.spill = int(chunk_nnz), bool(spill)
        self.nnz = None
        self._file = None  # the unzipped chunks, once a whole pass wrote them
        self._index = []  # (first row, rows, nnz, byte offset) per chunk in it
        self.spilled_bytes = 0

    def _store_chunks(self):
        """(first row, chunk) from the store's blocks, unzipped ahead by :data:`READERS` threads."""
        tasks = (lambda k=k: self.store.read_block(k, "G") for k in range(self.store.n_blocks))
        chunk, held, first = [], 0, 0
        for block in _read_ahead(tasks, READERS, 4 * READERS):
            chunk.append(block)
            held += block.nnz
            if held >= self.chunk_nnz or first + sum(b.shape[0] for b in chunk) == self.shape[0]:
                out = chunk[0] if len(chunk) == 1 else sp.vstack(chunk, format="csr")
                yield first, out
                first += out.shape[0]
                chunk, held = [], 0

    @staticmethod
    def _spilled_whole(spill, size: int) -> bool:
        """Whether all ``size`` bytes reached the file (writes are buffered: a full disk may only
        show as a short file); if not, it is closed and later passes unzip the store again."""
        try:
            spill.flush()
            if os.fstat(spill.fileno()).st_size == size:
                return True
        except OSError:
            pass
        spill.close()
        return False

    def _read_spilled(self, rows: int, nnz: int, offset: int) -> sp.csr_matrix:
        f = self._file
        f.seek(offset)
        indptr = np.fromfile(f, np.int64, rows + 1)
        indices = np.fromfile(f, np.int32, nnz)
        data = np.fromfile(f, np.float32, nnz)
        return sp.csr_matrix((data, indices, indptr), shape=(rows, self.shape[1]))

    def chunks(self):
        """(first row, (rows, K) float32 CSR) for consecutive chunks covering all N rows, in order."""
        if self._file is not None:
            tasks = (lambda e=e: (e[0], self._read_spilled(*e[1:])) for e in self._index)
            yield from _read_ahead(tasks, 1, 1)
            return
        spill = tempfile.TemporaryFile(prefix="pydynrad-G-") if self.spill else None
        index, offset = [], 0
        try:
            for first, block in self._store_chunks():
                if spill is not None:
                    index.append((first, block.shape[0], block.nnz, offset))
                    try:
                        for a in (
                            block.indptr.astype(np.int64),
                            block.indices.astype(np.int32, copy=False),
                            block.data.astype(np.float32, copy=False),
                        ):
                            a.tofile(spill)
                            offset += a.nbytes
                    except OSError:  # a full disk costs the speed-up, not the pass
                        spill.close()
                        spill = None
                yield first, block
        except BaseException:
            if spill is not None:
                spill.close()
            raise
        if spill is not None and self._spilled_whole(spill, offset):  # a whole pass: later ones read the file
            self._file, self._index, self.spilled_bytes = spill, index, offset

    def close(self) -> None:
        """Remove the temporary file (later passes unzip the store's blocks again)."""
        if self._file is not None:
            self._file.close()
        self._file, self._index, self.spilled_bytes = None, [], 0

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
            if funcs > 1:  # column c + f C is function f of cluster c: fold the functions onto c
                G = sp.csr_matrix((G.data, G.indices % clusters, G.indptr), shape=(G.shape[0], clusters))
                G.sum_duplicates()
            part = (R[:, first : first + block.shape[0]] @ G).tocoo()
            rows.append(part.row.astype(np.int32))
            cols.append(part.col.astype(np.int32))
            vals.append(part.data)
        self.nnz = nnz
        if not rows:
            raise InvalidInputError("the store's G has no rows")
        # Duplicates (clusters whose patches straddle two chunks) are summed by the conversion.
        return sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(clusters, clusters)
        )

    def bounce(self, device, dtype, L: np.ndarray, rho: np.ndarray, x: np.ndarray) -> np.ndarray:
        """y = L + rho * (G x) as :meth:`pydynrad.device.csr.DeviceCSR.bounce` (the same kernel and
        precision, per chunk): L, rho (N, k), x (K, k); returns (N, k) float64."""
        import pyopencl as cl

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
