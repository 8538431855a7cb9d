"""Host threads for native passes that release the GIL: the cores this process may run on, one
shared pool, and rows cut into parts of equal work."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["cores", "pool", "row_parts", "map_parts"]

_pool: ThreadPoolExecutor | None = None
_lock = threading.Lock()
_THREADS = "pydynrad-pool"  # the pool's thread names begin so


def _after_fork_in_child() -> None:
    # A forked child has the pool object but none of its threads: map() would wait forever.
    global _pool, _lock
    _pool, _lock = None, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def cores() -> int:
    """CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def pool() -> ThreadPoolExecutor:
    """The process's pool of :func:`cores` threads (made on first use)."""
    global _pool
    with _lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=cores(), thread_name_prefix=_THREADS)
        return _pool


def row_parts(indptr: np.ndarray, parts: int) -> list[tuple[int, int]]:
    """Rows [k0, k1) of a CSR structure (``indptr`` (r + 1,)) in at most ``parts`` runs of about
    equal entries, none empty unless there are no rows."""
    rows = len(indptr) - 1
    if parts <= 1:
        return [(0, rows)]
    cuts = np.searchsorted(indptr, np.linspace(0, indptr[-1], int(parts) + 1)[1:-1], side="right") - 1
    edges = np.unique(np.concatenate([[0], np.clip(cuts, 0, rows), [rows]]))
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])] or [(0, 0)]


def map_parts(fn, parts) -> list:
    """``[fn(p) for p in parts]``: the first part in the calling thread, the others on the pool
    at the same time (a pass through the pool costs its threads' wake-ups, which a move's many
    passes of one part each would pay for nothing; and a pool thread may be waiting on the device
    meanwhile).
    Called from a pool thread, every part runs in it, one after another: a pool task waiting on
    tasks queued behind it would wait forever once every worker did (one core: at once)."""
    parts = list(parts)
    if len(parts) <= 1 or threading.current_thread().name.startswith(_THREADS):
        return [fn(p) for p in parts]
    others = [pool().submit(fn, p) for p in parts[1:]]
    return [fn(parts[0])] + [f.result() for f in others]
