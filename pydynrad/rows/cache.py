"""A bounded, prefetching cache in front of any :class:`~pydynrad.rows.sources.RowSource`.

The cache keeps whole rows in an LRU bounded in bytes and prefetches, on a background thread,
rows that will be needed soon (the patches just outside the local set).

So a walk through a scene whose F does not fit in RAM holds at most ``max_bytes`` of rows
(plus the rows of the request being served) on top of K.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
import scipy.sparse as sp

from ..checks import patch_indices
from ..errors import InvalidInputError
from .sources import RowSource, read_rows

__all__ = ["RowCache"]

# Host bytes a cached row costs beyond its nnz * 8 bytes of payload: two small ndarray
# headers, a tuple and an OrderedDict slot (measured with sys.getsizeof on CPython 3.11,
# rounded up), so max_bytes bounds the real footprint and not only the payload.
ROW_OVERHEAD = 384


def _split_rows(csr: sp.csr_matrix, idx: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    # Copies, so a cached row never keeps its whole source block alive.
    ip = csr.indptr
    return {
        int(r): (csr.indices[ip[k] : ip[k + 1]].astype(np.int32), csr.data[ip[k] : ip[k + 1]].astype(np.float32))
        for k, r in enumerate(idx)
    }


def _row_cost(row: tuple[np.ndarray, np.ndarray]) -> int:
    return row[0].nbytes + row[1].nbytes + ROW_OVERHEAD


class RowCache:
    """A :class:`RowSource` that serves rows of ``source`` through an LRU cache of ``max_bytes``.

    ``rows(idx)`` returns cached rows and reads the others from the source (rows a prefetch
    is already reading are waited for, not read twice). ``prefetch(idx)`` returns at once and
    reads the rows in a background thread, so the next frame's entering patches are usually
    hits. Errors from the source (e.g. a corrupt store block) are raised by ``rows``; a row
    that failed is never cached. Thread-safe; close it (or use ``with``) to stop the thread.

    Counters in :attr:`stats` (distinct rows per request): ``requested`` = ``hits`` (no
    foreground read: cached, or being prefetched) + ``misses`` (read in the foreground);
    ``prefetch_hits`` (the hits a prefetch brought in), ``prefetched`` (rows read in the
    background), ``evictions``.
    """

    rows_checked = True

    def __init__(self, source: RowSource, max_bytes: int) -> None:
        if not isinstance(source, RowSource):
            raise InvalidInputError(
                f"source must be a RowSource (n_patches and rows(idx)); got {type(source).__name__}"
            )
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, (int, np.integer)) or max_bytes < 0:
            raise InvalidInputError(f"max_bytes must be a non-negative integer; got {max_bytes!r}")
        self.source = source
        self.n_patches = int(source.n_patches)
        self.max_bytes = int(max_bytes)
        self.nbytes = 0
        self.peak_nbytes = 0
        self.stats = dict.fromkeys(("requested", "hits", "prefetch_hits", "misses", "prefetched", "evictions"), 0)
        self._rows: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._from_prefetch: set[int] = set()
        self._pending: dict[int, Future] = {}
        self._lock = threading.Lock()
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="pydynrad-prefetch")

    # -- cache bookkeeping (callers hold the lock) -------------------------------------------
    def _insert(self, r: int, row: tuple[np.ndarray, np.ndarray], prefetched: bool) -> None:
        if r in self._rows:
            self._rows.move_to_end(r)
            return
        cost = _row_cost(row)
        if cost > self.max_bytes:
            return
        self._rows[r] = row
        self.nbytes += cost
        if prefetched:
            self._from_prefetch.add(r)
        while self.nbytes > self.max_bytes:
            old, old_row = self._rows.popitem(last=False)
            self.nbytes -= _row_cost(old_row)
            self._from_prefetch.discard(old)
            self.stats["evictions"] += 1
        self.peak_nbytes = max(self.peak_nbytes, self.nbytes)

    def _read(self, idx: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        # Checked before caching (so this cache keeps the checked-rows contract): a broken
        # block is refused with its row named, never served later.
        return _split_rows(read_rows(self.source, idx), idx)

    # -- RowSource ---------------------------------------------------------------------------
    def rows(self, idx) -> sp.csr_matrix:
        idx = patch_indices(idx, self.n_patches, "row indices")
        wanted = np.unique(idx)
        found: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        waits: dict[int, Future] = {}
        with self._lock:
            self.stats["requested"] += int(wanted.size)
            for r in wanted.tolist():
                row = self._rows.get(r)
                if row is not None:
                    self._rows.move_to_end(r)
                    found[r] = row
                    self.stats["hits"] += 1
                    if r in self._from_prefetch:
                        self._from_prefetch.discard(r)
                        self.stats["prefetch_hits"] += 1
                elif r in self._pending:
                    waits[r] = self._pending[r]
        for r, fut in waits.items():
            found[r] = fut.result()[r]
        rest = np.array([r for r in wanted.tolist() if r not in found], dtype=np.int64)
        fetched = self._read(rest) if rest.size else {}
        found.update(fetched)
        with self._lock:
            self.stats["misses"] += len(fetched)
            self.stats["hits"] += len(waits)
            self.stats["prefetch_hits"] += len(waits)
            for r in waits:
                self._from_prefetch.discard(r)
            for r, row in fetched.items():
                self._insert(r, row, prefetched=False)
        ordered = [found[int(r)] for r in idx]
        lengths = np.fromiter((len(c) for c, _ in ordered), dtype=np.int64, count=len(ordered))
        indptr = np.concatenate([[0], np.cumsum(lengths)])
        indices = np.concatenate([c for c, _ in ordered]) if ordered else np.zeros(0, np.int32)
        data = np.concatenate([d for _, d in ordered]) if ordered else np.zeros(0, np.float32)
        return sp.csr_matrix((data, indices, indptr), shape=(len(idx), self.n_patches))

    # -- prefetch ----------------------------------------------------------------------------
    def prefetch(self, idx) -> Future | None:
        """Start reading rows ``idx`` in the background; returns the job's future, or None if nothing to read."""
        idx = np.unique(patch_indices(idx, self.n_patches, "row indices"))
        with self._lock:
            todo = np.array([r for r in idx.tolist() if r not in self._rows and r not in self._pending], dtype=np.int64)
            if not todo.size:
                return None
            fut = self._pool.submit(self._prefetch_job, todo)
            for r in todo.tolist():
                self._pending[r] = fut
        return fut

    def _prefetch_job(self, idx: np.ndarray) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        try:
            fetched = self._read(idx)
        except BaseException:
            with self._lock:
                for r in idx.tolist():
                    self._pending.pop(r, None)
            raise
        with self._lock:
            self.stats["prefetched"] += len(fetched)
            for r, row in fetched.items():
                self._pending.pop(r, None)
                self._insert(r, row, prefetched=True)
        return fetched

    # -- lifetime ----------------------------------------------------------------------------
    def clear(self) -> None:
        """Drop every cached row (pending prefetches still complete)."""
        with self._lock:
            self._rows.clear()
            self._from_prefetch.clear()
            self.nbytes = 0

    def close(self) -> None:
        """Wait for running prefetches and stop the background thread."""
        self._pool.shutdown(wait=True)

    def __enter__(self) -> RowCache:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __len__(self) -> int:
        return len(self._rows)

    def __repr__(self) -> str:
        return (
            f"RowCache({len(self._rows)} rows, {self.nbytes / 2**20:.1f} of {self.max_bytes / 2**20:.1f} MiB, "
            f"source={type(self.source).__name__})"
        )
