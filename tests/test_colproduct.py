"""The product with chosen columns of a CSC matrix (pydynrad/colproduct.py, csrc/colproduct.c)
against scipy's dense product, in every index and value type, split over threads or not."""

import numpy as np
import pytest
import scipy.sparse as sp

import pydynrad as pd
import pydynrad.colproduct as colproduct
from pydynrad.colproduct import columns_product


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
