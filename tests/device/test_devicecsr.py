"""DeviceCSR's bounce y = L + P (A x) against numpy, square and not: a non-square A (the far
field's G, N x C) has an x of C rows, which the kernel must never index by A's row (it read
x[i] for the residual of every row i, past x's end: a segfault in bounce, seen twice)."""

import numpy as np
import pyopencl as cl
import pytest
import scipy.sparse as sp

from pydynrad.device.csr import DeviceCSR


def _bounce(device, A, L, rho, x):
    """(y, partial (blocks, 2)) of one bounce, through bounce_buffers."""
    dev = DeviceCSR(device, A, np.float64)
    width = 1 if x.shape[1] == 1 else 4
    bufs = [device.to_device(dev.packed(a, width)) for a in (L, rho, x)]
    y = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, A.shape[0] * width * 8)
    partial = cl.Buffer(device.context, cl.mem_flags.READ_WRITE, 2 * dev._n_blocks * 8)
    dev.bounce_buffers(*bufs, y, width, partial)
    out, part = np.empty((A.shape[0], width)), np.empty((dev._n_blocks, 2))
    cl.enqueue_copy(device.queue, out, y)
    cl.enqueue_copy(device.queue, part, partial, is_blocking=True)
    return out[:, : x.shape[1]], part


@pytest.mark.parametrize("channels", [1, 3])
def test_non_square_bounce_reads_x_by_column_only(device, channels):
    rng = np.random.default_rng(5)
    n, c = 20_000, 3  # x holds 3 rows: row i of A past 3 has no x[i]
    A = sp.random(n, c, density=0.5, format="csr", random_state=rng)
    L, rho, x = rng.random((n, channels)), rng.random((n, channels)), rng.random((c, channels))
    y, part = _bounce(device, A, L, rho, x)
    want = L + rho * (A @ x)
    np.testing.assert_allclose(y, want, rtol=1e-14, atol=0)  # float64 sums in another order
    assert np.all(part[:, 0] == 0.0)  # no residual without a square A
    assert part[:, 1].max() == pytest.approx(np.abs(want).max(), rel=1e-14)
    dev = DeviceCSR(device, A, np.float64)
    np.testing.assert_allclose(dev.bounce(L, rho, x), want, rtol=1e-14, atol=0)


def test_square_bounce_measures_its_residual(device):
    rng = np.random.default_rng(6)
    n = 500
    A = sp.random(n, n, density=0.02, format="csr", random_state=rng) * 0.1
    L, rho, x = rng.random((n, 3)), rng.random((n, 3)), rng.random((n, 3))
    y, part = _bounce(device, A, L, rho, x)
    want = L + rho * (A @ x)
    np.testing.assert_allclose(y, want, rtol=1e-14, atol=0)
    assert part[:, 0].max() == pytest.approx(np.abs(want - x).max(), rel=1e-14)
