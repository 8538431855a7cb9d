"""Host products beside a CPU device (pydynrad.host.product) against float64 products of the same
stored values, and the rule that puts a matrix there."""

import numpy as np
import pytest
import scipy.sparse as sp

from pydynrad import InvalidInputError
from pydynrad.device.csr import DeviceCSR
from pydynrad.device.matrix import DeviceMatrix
from pydynrad.host.product import HOST_PRODUCT_BYTES, HostBounce, HostMatrix, on_host


@pytest.mark.parametrize("density, dense", [(0.6, True), (0.25, True), (0.05, False)])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_bounce_is_l_plus_p_a_x(device, density, dense, dtype):
    rng = np.random.default_rng(3)
    A = sp.random(300, 70, density=density, format="csr", random_state=rng)
    L, rho, x = rng.random((300, 3)), rng.random((300, 3)), rng.random((70, 3))
    prod = HostBounce(A, dtype)
    assert prod.dense == dense and prod.nbytes == HostBounce.nbytes_of(A, dtype)
    stored = A.astype(dtype).astype(np.float64)
    want = L + rho * (stored @ x)
    got = prod.bounce(L, rho, x)
    # Dense float32 multiplies float32 x (as the device does); CSR sums in float64 (rows_product).
    # Observed (Zen 4): 1.4e-7 dense float32, 7e-16 dense float64, 0 by CSR.
    tol = 2e-7 if dtype == np.float32 and dense else 1e-15
    np.testing.assert_allclose(got, want, rtol=tol, atol=0)
    # The device's CSR kernel gives the same to its rounding.
    np.testing.assert_allclose(
        got, DeviceCSR(device, A, dtype).bounce(L, rho, x), rtol=5e-7 if dtype == np.float32 else 1e-15
    )
    grey = prod.bounce(L[:, :1], rho[:, :1], x[:, :1])
    np.testing.assert_allclose(grey, want[:, :1], rtol=tol)
    with pytest.raises(InvalidInputError, match="needs L, rho"):
        prod.bounce(L, rho, x[:-1])


@pytest.mark.parametrize("storage, rtol", [("fp16", 2e-7), ("fp32", 2e-7), ("fp64", 1e-15)])
def test_matrix_products_of_the_stored_entries(device, storage, rtol):
    rng = np.random.default_rng(4)
    K = rng.random((3, 40, 40)) / 40
    host, dev = HostMatrix(K, storage), DeviceMatrix(device, K, storage)
    stored = K.astype({"fp16": np.float16, "fp32": np.float32, "fp64": np.float64}[storage]).astype(np.float64)
    x = rng.random((3, 40))
    want = np.einsum("cij,cj->ci", stored, x)
    # Observed (Zen 4): 1.1e-7 in float32 (fp16 and fp32 storage), 4e-16 in float64.
    np.testing.assert_allclose(host.matvec(x), want, rtol=rtol)
    np.testing.assert_allclose(host.matvec(x), dev.matvec(x), rtol=2 * rtol)
    X = rng.random((5, 40))
    np.testing.assert_allclose(host.matmat(X), np.einsum("cij,rj->cri", stored, X), rtol=rtol)
    assert host.nbytes == HostMatrix.nbytes_of(3, 40, storage) and host.C == 3 and host.M == 40
    with pytest.raises(InvalidInputError, match="shape"):
        host.matvec(np.ones(39))
    with pytest.raises(InvalidInputError, match="range"):
        HostMatrix(np.full((1, 2, 2), 1e6), "fp16")
    with pytest.raises(InvalidInputError, match="finite"):
        HostMatrix(np.full((1, 2, 2), np.nan), "fp32")
    with pytest.raises(InvalidInputError, match="floating"):
        HostMatrix(np.ones((1, 2, 2), int), "fp32")
    with pytest.raises(InvalidInputError, match="NaN or infinite"):
        host.matvec(np.full((3, 40), np.inf))


def test_small_matrices_go_to_the_host_beside_a_cpu_device_only(device):
    assert device.traits.cpu  # the tests' PoCL device
    assert on_host(device, HOST_PRODUCT_BYTES) and not on_host(device, HOST_PRODUCT_BYTES + 1)
    assert not on_host(device.with_traits(cpu=False), 1)
