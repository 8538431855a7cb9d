"""multibounce_block: K from the local block of F directly (what DynamicRadiosity's builds and
refreshes use), against numpy float64 and against multibounce over the same patches."""

import numpy as np
import pytest
import scipy.sparse as sp
from helpers import box_scene, dense_K, reciprocal_F, rel

import pydynrad
from pydynrad.bounces import multibounce, multibounce_block
from pydynrad.rows.sources import CSRRows


def test_block_matches_dense_inverse_and_multibounce(device):
    rng = np.random.default_rng(5)
    s = box_scene(4)
    s = s.with_materials(albedo=rng.uniform(0, 0.9, (len(s), 3)))
    F = reciprocal_F(s.areas, row_sum=0.95, density=0.2, seed=6)
    idx = rng.permutation(len(s))[:150]
    F_SS = sp.csr_matrix(F)[idx][:, idx]
    rho = s.albedo[idx].astype(np.float64)
    K = multibounce_block(F_SS, rho, dtype=np.float64, device=device)
    assert K.shape == (3, 150, 150)
    assert rel(K, dense_K(s, F, idx)) < 1e-13  # observed ~7e-16
    # The same numbers as the build that validates and slices all of F.
    assert np.array_equal(K, multibounce(s, F, patches=idx, dtype=np.float64, device=device))
    # A dense block gives the same K.
    assert np.array_equal(K, multibounce_block(F_SS.toarray(), rho, dtype=np.float64, device=device))


@pytest.mark.parametrize(
    "block,albedo,match",
    [
        (np.full((4, 4), 0.3), np.full((4, 1), 0.5), "sums to"),
        (-np.eye(4)[::-1] * 0.1, np.full((4, 1), 0.5), ">= 0"),
        (np.where(np.eye(4) > 0, 0.0, np.nan), np.full((4, 1), 0.5), "NaN or infinite"),
        (np.zeros((4, 3)), np.full((4, 1), 0.5), "square"),
        (np.zeros((4, 4)), np.full((4, 2), 0.5), "albedo must have shape"),
        (np.zeros((4, 4)), np.full((4, 1), 1.0), r"\[0, 1\)"),
    ],
)
def test_block_refuses_bad_input(device, block, albedo, match):
    with pytest.raises(pydynrad.InvalidInputError, match=match):
        multibounce_block(block, albedo, device=device)


def test_dynamic_refuses_source_rows_summing_above_one(device):
    s = box_scene(3, albedo=0.5)
    F = sp.csr_matrix(reciprocal_F(s.areas, seed=7)).astype(np.float32)
    F = F.tolil()
    F[0, 1] = F[0, 1] + 2.0  # row 0 now sums above 1
    with pytest.raises(pydynrad.InvalidInputError, match="row 0 of form-factor matrix sums to"):
        CSRRows(F.tocsr())  # CSRRows checks on construction; a source of its own is checked per block

    class Source:
        n_patches = len(s)

        def rows(self, idx):
            return F.tocsr()[idx]

    source = Source()
    with pytest.raises(pydynrad.InvalidInputError, match="row 0 of form-factor rows sums to"):
        pydynrad.DynamicRadiosity(s, source, local_size=len(s), observer=s.centers[0], device=device)


def test_checked_block_takes_rows_summing_above_one(device):
    """The far field's coarse F_c with a weighted prolongation may have rows summing above 1
    while P F_c's stay below 1: ``checked=True`` builds K = (I - F P)^{-1} F for it (against
    numpy's dense inverse in float64), the default refuses it by name."""
    rng = np.random.default_rng(11)
    M = 40
    F = rng.uniform(0, 1, (M, M))
    F *= (1.3 / F.sum(axis=1))[:, None]  # every row sums to 1.3
    rho = np.full((M, 1), 0.5)  # P F's rows sum to 0.65
    K = multibounce_block(sp.csr_matrix(F), rho, dtype=np.float64, device=device, checked=True)
    truth = np.linalg.solve(np.eye(M) - F * rho[:, 0][None, :], F)
    assert rel(K[0], truth) < 1e-12  # observed 3e-16
    with pytest.raises(pydynrad.InvalidInputError, match="sums to"):
        multibounce_block(sp.csr_matrix(F), rho, dtype=np.float64, device=device)
