"""How many threads numpy's BLAS may use for host algebra that runs beside a CPU device.

A threaded BLAS (OpenBLAS) spins its threads while they wait for work. Where the OpenCL
device is the host's own CPU (PoCL), the kernels queued on it hold those cores, so every
BLAS thread beyond the first competes with them and with the other BLAS threads: the exact
swap's k x M products ran two to three times slower with OpenBLAS's two threads than with one,
and a moving-object frame about twice as slow
(docs/decisions/0009-host-lapack-and-one-blas-thread.md).
Big solves with the device idle (the K build) keep their threads, except where the channels
already run side by side (:mod:`pydynrad.bounces`).
"""

from __future__ import annotations

import threading
from contextlib import AbstractContextManager, contextmanager, nullcontext
from functools import lru_cache

__all__ = ["one_blas_thread", "blas_beside"]


@lru_cache(maxsize=1)
def _controller():
    # Inspecting the loaded libraries is slow; a limit through a kept controller is cheap.
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


# threadpoolctl's limit is process-wide and puts back what it found on entry, and numpy's
# OpenBLAS (as numpy 2.4 ships it) does not honour a count set or restored from another thread
# as it does one from the main thread: a limit taken in one worker thread and restored in a
# second left the whole process on one thread. So only the main thread lowers the limit
# (counted, for nesting: the outermost holder restores it); the threads it starts inherit it,
# and work called from other threads runs with the count as it finds it.
_lock = threading.Lock()
_holders = 0
_limiter = None


@contextmanager
def one_blas_thread():
    """A context in which numpy's BLAS runs on one thread, where entered from the main thread
    (and in the threads it starts meanwhile); the process's count is back on exit."""
    global _holders, _limiter
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with _lock:
        if _holders == 0:
            _limiter = _controller().limit(limits=1, user_api="blas")
        _holders += 1
    try:
        yield
    finally:
        with _lock:
            _holders -= 1
            if _holders == 0:
                _limiter.restore_original_limits()
                _limiter = None


def blas_beside(device) -> AbstractContextManager:
    """:func:`one_blas_thread` where ``device`` is a CPU (its kernels share the host's cores), else nothing."""
    return one_blas_thread() if device.traits.cpu else nullcontext()
