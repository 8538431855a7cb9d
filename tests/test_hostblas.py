"""Host BLAS threads beside a CPU device (pydynrad.hostblas)."""

import numpy as np
from threadpoolctl import threadpool_info

from pydynrad.hostblas import blas_beside


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
    args = (rng.random((M, k)), rng.random((k, M)), rng.random((M, k)), rng.random((k, M)),
            1e-2 * rng.random((M, k)), 1e-2 * rng.random((k, M)), 1e-2 * rng.random((k, k)),
            0.5 * rng.random(M), 0.5 * rng.random(k), np.arange(k))
    free = batched_swap(*args)
    with blas_beside(device):
        one = batched_swap(*args)
    for a, b in zip((free.A, free.B, free.cols, free.rows), (one.A, one.B, one.cols, one.rows)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
