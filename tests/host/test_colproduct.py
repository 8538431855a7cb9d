"""The product with chosen columns of a CSC matrix and the product by row of a CSR matrix
(pydynrad/host/colproduct.py, csrc/colproduct.c) against scipy's products, in every index and value
type, split over threads or not."""

import numpy as np
import pytest
import scipy.sparse as sp

import pydynrad as pd
import pydynrad.host.colproduct as colproduct
from pydynrad.host.colproduct import columns_product, rows_product


@pytest.mark.parametrize("index_dtype", [np.int32, np.int64])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("k", [1, 3])
@pytest.mark.parametrize("parallel", [False, True])
def test_columns_product_matches_dense(index_dtype, dtype, k, parallel, monkeypatch):
    rng = np.random.default_rng(9)
    A = sp.random(300, 500, density=0.05, random_state=rng, format="csc", dtype=dtype)
    A.indices, A.indptr = A.indices.astype(index_dtype), A.indptr.astype(index_dtype)
    cols = rng.choice(500, 120, replace=False)
    cols[:3] = cols[0]  # a column chosen three times adds three times
    x = rng.standard_normal((len(cols), k))
    monkeypatch.setattr(colproduct, "PARALLEL_ENTRIES", 1 if parallel else 10**12)
    got = columns_product(A, cols, x)
    truth = A.astype(np.float64).toarray()[:, cols] @ x
    assert got.dtype == np.float64 and got.shape == (300, k)
    np.testing.assert_allclose(got, truth, rtol=1e-12, atol=1e-12 * np.abs(truth).max())  # observed 2e-16


def test_columns_product_refuses_bad_input():
    A = sp.random(30, 40, density=0.2, random_state=1, format="csc")
    with pytest.raises(pd.InvalidInputError, match="CSC"):
        columns_product(A.tocsr(), [0], np.ones((1, 1)))
    with pytest.raises(pd.InvalidInputError, match="column numbers"):
        columns_product(A, [40], np.ones((1, 1)))
    with pytest.raises(pd.InvalidInputError, match="shape"):
        columns_product(A, [0, 1], np.ones((1, 1)))
    assert not columns_product(A, [], np.ones((0, 3))).any()
    with pytest.raises(pd.InvalidInputError, match="float32/float64"):
        columns_product(sp.csc_matrix(np.eye(3, dtype=np.int64)), [0], np.ones((1, 1)))
    A.indices[0] = 30  # a row index past the rows: refused by the native pass, not written
    with pytest.raises(ValueError, match="out of range"):
        columns_product(A, [0], np.ones((1, 1)))


@pytest.mark.parametrize("index_dtype", [np.int32, np.int64])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("k", [1, 2, 3, 4])
@pytest.mark.parametrize("parallel", [False, True])
def test_rows_product_sums_as_scipy(index_dtype, dtype, k, parallel, monkeypatch):
    """Each row summed in float64 in its entries' order (unsorted rows among them): bit for bit
    a sequential sum, against scipy to rounding; empty rows give 0; a 1-D x gives a 1-D answer."""
    rng = np.random.default_rng(9)
    A = sp.random(300, 500, density=0.05, random_state=rng, format="csr", dtype=dtype)
    A.indices, A.indptr = A.indices.astype(index_dtype), A.indptr.astype(index_dtype)
    A = sp.csr_matrix(sp.diags(np.arange(300) % 7 != 0, dtype=dtype) @ A)  # every seventh row empty
    A.indices, A.indptr = A.indices.astype(index_dtype), A.indptr.astype(index_dtype)
    x = rng.standard_normal((500, k))
    monkeypatch.setattr(colproduct, "PARALLEL_ENTRIES", 1 if parallel else 10**12)
    got = rows_product(A, x)
    assert got.dtype == np.float64 and got.shape == (300, k)
    truth = A.astype(np.float64) @ x
    np.testing.assert_allclose(got, truth, rtol=0, atol=1e-14 * np.abs(truth).max())  # observed 2e-15 (unsorted rows)
    assert not got[::7].any()
    for i in (1, 150, 299):  # the row's sum in its entries' order, term by term
        a, b = A.indptr[i], A.indptr[i + 1]
        for q in range(k):
            s = 0.0
            for j in range(a, b):
                s += float(A.data[j]) * float(x[A.indices[j], q])
            assert got[i, q] == s
    np.testing.assert_array_equal(rows_product(A, x[:, 0]), got[:, 0])


def test_rows_product_refuses_bad_input():
    A = sp.random(30, 40, density=0.2, random_state=1, format="csr")
    with pytest.raises(pd.InvalidInputError, match="CSR"):
        rows_product(A.tocsc(), np.ones((40, 1)))
    with pytest.raises(pd.InvalidInputError, match="shape"):
        rows_product(A, np.ones((39, 1)))
    with pytest.raises(pd.InvalidInputError, match="shape"):
        rows_product(A, np.ones((40, 5)))
    with pytest.raises(pd.InvalidInputError, match="float32/float64"):
        rows_product(sp.csr_matrix(np.eye(3, dtype=np.int64)), np.ones((3, 1)))
    assert rows_product(sp.csr_matrix((0, 40)), np.ones((40, 3))).shape == (0, 3)
    A.indices[0] = 40  # a column index past x: refused by the native pass, never read
    with pytest.raises(ValueError, match="out of range"):
        rows_product(A, np.ones((40, 1)))


def test_columns_product_in_a_forked_child():
    """The shared pool is made anew after a fork (the child has the pool object but none of its
    threads, so its map would wait forever)."""
    import os
    import signal

    A = sp.random(300, 500, density=0.05, random_state=2, format="csc")
    cols, x = np.arange(0, 500, 3), np.ones((167, 1))
    old = colproduct.PARALLEL_ENTRIES
    colproduct.PARALLEL_ENTRIES = 1
    try:
        truth = columns_product(A, cols, x)  # the parent's pool, threads started
        pid = os.fork()
        if pid == 0:  # the child: exit 0 only if the product returns, and right
            signal.alarm(20)
            ok = np.allclose(columns_product(A, cols, x), truth)
            os._exit(0 if ok else 1)
        _, status = os.waitpid(pid, 0)
    finally:
        colproduct.PARALLEL_ENTRIES = old
    assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
