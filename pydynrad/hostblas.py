"""How many threads numpy's BLAS may use for host algebra that runs beside a CPU device.

A threaded BLAS (OpenBLAS) spins its threads while they wait for work. Where the OpenCL
device is the host's own CPU (PoCL), the kernels queued on it hold those cores, so every
BLAS thread beyond the first competes with them and with the other BLAS threads: the exact
swap's k x M products (M = 1024, k = 48) took a median of 7.8-11.7 ms with OpenBLAS's two
threads and 3.4 ms with one on a loaded 2-core Xeon (PoCL, 2026-12-02), and a moving-object
frame 324-399 ms against 145-195 ms (bench/results/objects-openblas-1-thread/).
Big solves with the device idle (the K build) keep their threads, except where the channels
already run side by side (:mod:`pydynrad.multibounce`).
"""

from __future__ import annotations

from contextlib import AbstractContextManager, nullcontext
from functools import lru_cache

__all__ = ["one_blas_thread", "blas_beside"]


@lru_cache(maxsize=1)
def _controller():
    # Inspecting the loaded libraries costs ~ms; a limit through a kept controller ~10 us.
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()


def one_blas_thread() -> AbstractContextManager:
    """A context in which numpy's BLAS runs on one thread (restored on exit)."""
    return _controller().limit(limits=1, user_api="blas")


def blas_beside(device) -> AbstractContextManager:
    """:func:`one_blas_thread` where ``device`` is a CPU (its kernels share the host's cores), else nothing."""
    return one_blas_thread() if device.traits.cpu else nullcontext()
