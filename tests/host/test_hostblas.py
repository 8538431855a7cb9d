"""Host BLAS threads beside a CPU device (pydynrad.host.blas)."""

import numpy as np
from threadpoolctl import threadpool_info

from pydynrad.host.blas import blas_beside


def _blas_threads() -> list[int]:
    return [lib["num_threads"] for lib in threadpool_info() if lib["user_api"] == "blas"]


def test_one_blas_thread_beside_a_cpu_device_and_restored_after(device):
    before = _blas_threads()
    assert before  # numpy links a BLAS that threadpoolctl sees
    with blas_beside(device):
        assert _blas_threads() == [1] * len(before)
    assert _blas_threads() == before


def test_no_limit_beside_a_gpu(device):
    before = _blas_threads()
    with blas_beside(device.with_traits(cpu=False)):
        assert _blas_threads() == before


def test_exact_swap_is_the_same_with_one_thread(device):
    """The swap's algebra under the limit equals the unlimited one to rounding (observed 0)."""
    from pydynrad.dynamic.exact import batched_swap

    rng = np.random.default_rng(3)
    M, k = 96, 6
    args = (
        rng.random((M, k)),
        rng.random((k, M)),
        rng.random((M, k)),
        rng.random((k, M)),
        1e-2 * rng.random((M, k)),
        1e-2 * rng.random((k, M)),
        1e-2 * rng.random((k, k)),
        0.5 * rng.random(M),
        0.5 * rng.random(k),
        np.arange(k),
    )
    free = batched_swap(*args)
    with blas_beside(device):
        one = batched_swap(*args)
    for a, b in zip((free.A, free.B, free.cols, free.rows), (one.A, one.B, one.cols, one.rows)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)


def test_limits_from_other_threads_leave_the_count_alone():
    """Two threads overlapping (a in, b in, a out, b out) leave the process's count as it was:
    only the main thread lowers it (a limit taken in one worker thread and restored in another
    left numpy's OpenBLAS on one thread for good)."""
    import threading

    from pydynrad.host.blas import one_blas_thread

    before = _blas_threads()
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()

    def a():
        with one_blas_thread():
            a_in.set()
            b_in.wait(5)
        a_out.set()

    def b():
        a_in.wait(5)
        with one_blas_thread():
            b_in.set()
            a_out.wait(5)

    threads = [threading.Thread(target=f) for f in (a, b)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert _blas_threads() == before


def test_nested_limits_in_the_main_thread_restore_on_the_outermost_exit():
    from pydynrad.host.blas import one_blas_thread

    before = _blas_threads()
    with one_blas_thread():
        with one_blas_thread():
            assert _blas_threads() == [1] * len(before)
        assert _blas_threads() == [1] * len(before)
    assert _blas_threads() == before
