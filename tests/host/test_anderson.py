"""Anderson mixing (pydynrad/host/anderson.py) and the mixed Jacobi sweeps of DeviceCSR, against
dense solves."""

import numpy as np
import pytest
import scipy.sparse as sp

from pydynrad.device.csr import DeviceCSR
from pydynrad.host.anderson import Anderson


def test_anderson_mixing_solves_a_low_rank_fixed_point():
    """Anderson mixing on u = b + A u with A of rank 3 (per channel, other A each):
    the residuals span at most 3 directions, so depth-3 mixing reaches the fixed point (to
    rounding) in a few steps, where plain iteration still carries rho(A)^n."""
    rng = np.random.default_rng(7)
    M = 60
    A = []
    for _ in range(3):
        Q = np.linalg.qr(rng.standard_normal((M, 3)))[0]
        A.append(Q @ np.diag([0.7, -0.5, 0.3]) @ Q.T)  # spectral radius 0.7
    b = rng.standard_normal((M, 3))
    truth = np.stack([np.linalg.solve(np.eye(M) - A[c], b[:, c]) for c in range(3)], axis=1)

    def f(u):
        return b + np.stack([A[c] @ u[:, c] for c in range(3)], axis=1)

    mixed, plain, mixing = np.zeros((M, 3)), np.zeros((M, 3)), Anderson(3)
    for _ in range(6):
        fu = f(mixed)
        mixed = mixing.next(fu, fu - mixed)
        plain = f(plain)
    assert np.abs(mixed - truth).max() < 1e-12 * np.abs(truth).max()  # observed 6e-16 (exact from step 5)
    assert np.abs(plain - truth).max() > 1e-2 * np.abs(truth).max()  # observed 0.044


@pytest.mark.parametrize("channels", [1, 3])
def test_mixed_jacobi_reaches_the_dense_solution_in_fewer_sweeps(device, channels):
    """x = L + rho (A x) for a sparse A with rows summing to 0.9 (spectral radius of rho A up
    to 0.85): mixed and plain sweeps stop at the same tolerance on the same change measure,
    both at the float64 dense solution to within what that tolerance leaves, the mixed ones
    in fewer sweeps; the answer is the last sweep's image (its change is the one reported)."""
    rng = np.random.default_rng(4)
    n = 400
    A = sp.random(n, n, density=0.05, random_state=rng, format="csr")
    A = sp.diags(0.9 / np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1e-12)) @ A
    L, rho = rng.uniform(0, 1, (n, channels)), rng.uniform(0.5, 0.95, (n, channels))
    Ad = A.toarray()
    truth = np.stack([np.linalg.solve(np.eye(n) - rho[:, [c]] * Ad, L[:, c]) for c in range(channels)], axis=1)
    dev = DeviceCSR(device, A, np.float64)
    plain = dev.jacobi(L, rho, L, 1e-8, 500)
    mixed = dev.jacobi(L, rho, L, 1e-8, 500, mixing=3)
    for x, sweeps, change, history in (plain, mixed):
        assert change <= 1e-8 and history[-1] == change and len(history) == sweeps
        assert np.abs(x - truth).max() < 5e-8 * np.abs(truth).max()  # observed 1.4e-8 and 1.5e-8 plain, 6e-9 mixed
    assert mixed[1] < plain[1] / 2  # observed 13 against 40 (grey) and 42 (RGB)


def test_mixing_refuses_bad_input(device):
    import pydynrad as pd

    with pytest.raises(pd.InvalidInputError, match="depth"):
        Anderson(0)
    mixing = Anderson(2)
    mixing.next(np.ones((5, 3)), np.ones((5, 3)))
    with pytest.raises(pd.InvalidInputError, match="one shape"):
        mixing.next(np.ones((6, 3)), np.ones((6, 3)))
    # No sweep asked: x0 back, as the plain sweeps give it.
    A = sp.csr_matrix(np.full((4, 4), 0.2))
    x0 = np.arange(4.0)[:, None]
    x, sweeps, change, history = DeviceCSR(device, A, np.float64).jacobi(
        np.ones((4, 1)), np.full((4, 1), 0.5), x0, 1e-6, 0, mixing=3
    )
    np.testing.assert_array_equal(x, x0)
    assert sweeps == 0 and history == [] and change == np.inf
