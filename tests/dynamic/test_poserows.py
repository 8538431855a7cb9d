"""Sparse rows at a pose (pydynrad.dynamic.poserows) against dense numpy: rows at a pose, their differences from the kept rows and since the last pose."""

import numpy as np
import pytest
import scipy.sparse as sp

import pydynrad as pd
from pydynrad.dynamic.poserows import at_pose, reciprocal_columns


def test_rows_at_pose():
    """Reciprocal object columns, hidden entries dropped and the cap, against hand numbers."""
    rows = sp.csr_matrix(np.array([[0.0, 0.2, 0.3, 0.0, 0.0], [0.4, 0.0, 0.4, 0.0, 0.0], [0.1, 0.1, 0.0, 0.0, 0.0]]))
    objects = sp.csr_matrix(np.array([[0.2, 0.1, 0.0, 0.0, 0.0], [0.1, 0.3, 0.0, 0.0, 0.0]]))  # patches 3, 4
    areas = np.array([1.0, 2.0, 1.0, 2.0, 2.0])
    obj = np.array([3, 4])
    # F[s, o] = A_o F[o, s] / A_s: (0.4, 0.2), (0.1, 0.3), (0, 0).
    recip = reciprocal_columns(np.array([0, 1, 2]), objects, obj, areas, 5)
    np.testing.assert_allclose(recip.toarray(), [[0, 0, 0, 0.4, 0.2], [0, 0, 0, 0.1, 0.3], [0, 0, 0, 0, 0]], rtol=1e-12)
    # Rows 0 and 1 sum to 1.1 and 1.2: their static entries are scaled by 0.4 / 0.5 and 0.6 / 0.8.
    out = at_pose(rows, np.zeros(rows.nnz, bool), recip)
    expect = [[0.0, 0.16, 0.24, 0.4, 0.2], [0.3, 0.0, 0.3, 0.1, 0.3], [0.1, 0.1, 0.0, 0.0, 0.0]]
    np.testing.assert_allclose(out.toarray(), expect, rtol=1e-12)
    assert out.has_sorted_indices and not np.any(out.data == 0)
    # Patch 3's row doubled and F[1, 2] hidden: row 1 sums to 0.9, no cap; row 0's static
    # entries all go, its object columns alone filling it (0.8 + 0.2).
    hidden = np.zeros(rows.nnz, bool)
    hidden[3] = True  # entries in order: (0, 1), (0, 2), (1, 0), (1, 2), ...
    out = at_pose(rows, hidden, reciprocal_columns(np.array([0, 1, 2]), sp.diags([2.0, 1.0]) @ objects, obj, areas, 5))
    expect = [[0.0, 0.0, 0.0, 0.8, 0.2], [0.4, 0.0, 0.0, 0.2, 0.3], [0.1, 0.1, 0.0, 0.0, 0.0]]
    np.testing.assert_allclose(out.toarray(), expect, rtol=1e-12)
    assert out.nnz == 7
    with pytest.raises(pd.InvalidInputError, match="do not match"):
        at_pose(rows, hidden, recip[:2])
    with pytest.raises(pd.InvalidInputError, match="one flag per entry"):
        at_pose(rows, hidden[:-1], recip)
    with pytest.raises(pd.InvalidInputError, match="CSR"):
        at_pose(rows.tocoo(), hidden, recip)
    # Object columns alone above 1 (patch 4's row x 4: 0.4 + 0.8 for row 0): scaled to 1, the
    # static entries gone; no row at the pose sums above 1.
    out = at_pose(
        rows,
        np.zeros(rows.nnz, bool),
        reciprocal_columns(np.array([0, 1, 2]), sp.diags([1.0, 4.0]) @ objects, obj, areas, 5),
    )
    np.testing.assert_allclose(
        out.toarray(),
        [[0, 0, 0, 0.4 / 1.2, 0.8 / 1.2], [0, 0, 0, 0.1 / 1.3, 1.2 / 1.3], [0.1, 0.1, 0, 0, 0]],
        rtol=1e-12,
    )


def test_rows_at_pose_match_numpy():
    """The native pass against the same rule in dense numpy, on random rows with every case."""
    rng = np.random.default_rng(5)
    n_static, n_obj, r = 40, 6, 300
    dense = rng.random((r, n_static)) * (rng.random((r, n_static)) < 0.3) * rng.choice([0.02, 0.05], (r, 1))
    rows = sp.csr_matrix(np.hstack([dense, np.zeros((r, n_obj))]))
    hidden = rng.random(rows.nnz) < 0.2
    objects = sp.csr_matrix(rng.random((n_obj, n_static + n_obj)) * (rng.random((n_obj, n_static + n_obj)) < 0.5) * 0.3)
    areas = rng.uniform(0.5, 2.0, n_static + n_obj)
    patches = rng.permutation(n_static)[rng.integers(0, n_static, r)]
    recip = reciprocal_columns(patches, objects, np.arange(n_static, n_static + n_obj), areas, n_static + n_obj)
    kept = rows.copy()
    kept.data[hidden] = 0.0
    kept = kept.toarray()[:, :n_static]
    obj = areas[n_static:] * objects[:, patches].toarray().T / areas[patches][:, None]
    np.testing.assert_allclose(recip.toarray()[:, n_static:], obj, rtol=1e-14)
    s_kept, s_obj = kept.sum(axis=1), obj.sum(axis=1)
    over = (s_kept > 0) & (s_kept + s_obj > 1.0)
    assert 0 < over.sum() < r and (s_obj > 1.0).any()  # rows capped, and rows whose objects overfill them
    kept[over] *= (np.maximum(1.0 - s_obj[over], 0.0) / s_kept[over])[:, None]
    obj[s_obj > 1.0] /= s_obj[s_obj > 1.0][:, None]
    got = at_pose(rows, hidden, recip)
    np.testing.assert_allclose(got.toarray(), np.hstack([kept, obj]), rtol=1e-13, atol=1e-17)
    assert got.sum(axis=1).max() <= 1.0 + 1e-12
    assert got.nnz == np.count_nonzero(np.hstack([kept, obj]))
    assert (at_pose(rows, 256 * hidden.astype(np.int64), recip) != got).nnz == 0  # any non-zero flag hides
    # Rows picked out of a larger matrix (with only the static columns) and read in place give
    # the same rows as the copy of them, the mask over the larger matrix's entries.
    big = sp.vstack(
        [sp.random(7, n_static, density=0.3, random_state=rng, format="csr"), dense, dense[::-1]], format="csr"
    )
    select = 7 + np.arange(r)
    big_hidden = np.zeros(big.nnz, bool)
    big_hidden[big.indptr[7] : big.indptr[7 + r]] = hidden
    picked = at_pose(big, big_hidden, recip, select)
    assert picked.shape == got.shape and (picked != got).nnz == 0
    with pytest.raises(pd.InvalidInputError, match=rf"rows to select must be patch indices in 0\.\.{big.shape[0] - 1}"):
        at_pose(big, big_hidden, recip, select + big.shape[0])


def _static_rows_in_f(rng, n_static: int, n_obj: int, r: int, density: float):
    """(F, select): a CSR "static F" of 7 + r rows over n_static + n_obj columns (the object
    columns empty) whose rows ``select``, the last r, hold entries of 0.02 or 0.05 (one value
    per row) at ``density``: rows read in place out of a larger F, as a move reads them."""
    dense = rng.random((r, n_static)) * (rng.random((r, n_static)) < density) * rng.choice([0.02, 0.05], (r, 1))
    big = sp.vstack([sp.random(7, n_static, density=0.3, random_state=rng, format="csr"), dense], format="csr")
    return sp.csr_matrix(sp.hstack([big, sp.csr_matrix((big.shape[0], n_obj))])), 7 + np.arange(r)


def test_difference_at_pose_is_at_pose_minus_kept(monkeypatch):
    """The fused pass gives at_pose's rows minus the kept rows bit for bit (capped rows, rows
    whose object columns overfill them, hidden entries, rows read in place out of a larger F),
    in one part or in parts on the cores, kept rows out of column order sorted first; bad
    shapes refused."""
    from pydynrad.dynamic import poserows
    from pydynrad.dynamic.poserows import difference_at_pose
    from pydynrad.dynamic.stale import rows_minus

    rng = np.random.default_rng(13)
    n_static, n_obj, r, M = 40, 6, 200, 260
    big, select = _static_rows_in_f(rng, n_static, n_obj, r, 0.3)
    hidden = rng.random(big.nnz) < 0.2
    objects = sp.csr_matrix(rng.random((n_obj, n_static + n_obj)) * (rng.random((n_obj, n_static + n_obj)) < 0.5) * 0.3)
    areas = rng.uniform(0.5, 2.0, n_static + n_obj)
    patches = rng.integers(0, n_static, r)
    recip = reciprocal_columns(patches, objects, np.arange(n_static, n_static + n_obj), areas, n_static + n_obj)
    kept = sp.random(M, n_static + n_obj, density=0.25, random_state=rng, format="csr").toarray()
    slots = rng.permutation(M)[:r]
    kept[slots[:50]] = at_pose(big, hidden, recip, select)[:50].toarray()  # rows equal to their kept rows: empty in D
    kept = sp.csr_matrix(kept)
    truth = rows_minus(at_pose(big, hidden, recip, select), kept, slots)
    assert truth.nnz and not np.diff(truth.indptr)[:50].any()

    def same(a, b):
        return a.shape == b.shape and all(
            np.array_equal(getattr(a, k), getattr(b, k)) for k in ("indptr", "indices", "data")
        )

    got = difference_at_pose(big, hidden, recip, kept, slots, select)
    assert same(got.delta, truth)
    # Capped: where the row at the pose sums above 1 (its static entries left, plus its object columns).
    sums = (
        np.add.reduceat(np.where(hidden, 0.0, big.data), big.indptr[:-1])[select]
        + np.asarray(recip.sum(axis=1)).ravel()
    )
    objects = np.asarray(recip.sum(axis=1)).ravel()
    np.testing.assert_array_equal(got.capped, (objects > 1.0) | ((sums - objects > 0) & (sums > 1.0)))
    assert 0 < got.capped.sum() < r
    monkeypatch.setattr(poserows, "PARALLEL_ENTRIES", 1)
    monkeypatch.setattr(poserows, "cores", lambda: 3)
    assert same(difference_at_pose(big, hidden, recip, kept, slots, select).delta, truth)
    shuffled = kept.copy()
    for k in range(M):  # each kept row's entries reversed: columns out of order
        a, b = shuffled.indptr[k], shuffled.indptr[k + 1]
        shuffled.indices[a:b], shuffled.data[a:b] = shuffled.indices[a:b][::-1].copy(), shuffled.data[a:b][::-1].copy()
    shuffled.has_sorted_indices = False
    assert same(difference_at_pose(big, hidden, recip, shuffled, slots, select).delta, truth)
    rows = sp.csr_matrix(big[select])  # the same rows as a matrix of their own, read whole
    assert same(difference_at_pose(rows, hidden[big.indptr[7] :], recip, kept, slots).delta, truth)
    bad = rows.copy()
    bad.indices[bad.indptr[3] : bad.indptr[4]] = bad.indices[bad.indptr[3] : bad.indptr[4]][::-1].copy()
    with pytest.raises(pd.InvalidInputError, match="row 3's static columns are out of increasing order"):
        difference_at_pose(bad, hidden[big.indptr[7] :], recip, kept, slots)
    with pytest.raises(pd.InvalidInputError, match=r"\[0, 260\)"):
        difference_at_pose(big, hidden, recip, kept, slots + M, select)
    with pytest.raises(pd.InvalidInputError, match="one kept row per row"):
        difference_at_pose(big, hidden, recip, kept, slots[:-1], select)
    with pytest.raises(pd.InvalidInputError, match="one flag per entry"):
        difference_at_pose(big, hidden[:-1], recip, kept, slots, select)
    with pytest.raises(pd.InvalidInputError, match="do not match"):
        difference_at_pose(big, hidden, recip[:-1], kept, slots, select)


def test_difference_since_the_last_pose_is_the_pass_made_whole(monkeypatch):
    """D started from the last pose's D (the entries whose presence changed since made again, the
    object columns afresh) equals the pass made whole, bit for bit: entries shown and hidden
    since, kept rows of a third pose (D entries at both), kept rows equal to the last pose's
    rows, rows capped at the pose (made whole), rows not named; in one part and in parts. It
    does start from the last D (a wrong one shows), and not where the kept rows are out of
    order (then sorted, the last D unread); bad inputs refused."""
    from pydynrad.dynamic import poserows
    from pydynrad.dynamic.poserows import PoseDifference, Since, difference_at_pose

    rng = np.random.default_rng(29)
    n_static, n_obj, r, M = 50, 6, 240, 300
    big, select = _static_rows_in_f(rng, n_static, n_obj, r, 0.4)
    areas = rng.uniform(0.5, 2.0, n_static + n_obj)
    patches = rng.integers(0, n_static, r)

    def pose_of(seed):
        g = np.random.default_rng(seed)
        objects = sp.csr_matrix(
            g.random((n_obj, n_static + n_obj)) * (g.random((n_obj, n_static + n_obj)) < 0.5) * 0.15
        )
        return g.random(big.nnz) < 0.2, reciprocal_columns(
            patches, objects, np.arange(n_static, n_static + n_obj), areas, n_static + n_obj
        )

    (h_kept, r_kept), (h_last, r_last) = pose_of(1), pose_of(2)
    h_now, r_now = h_last.copy(), pose_of(3)[1]
    flip = rng.random(big.nnz) < 0.1
    h_now[flip] = ~h_now[flip]  # shown and hidden since the last pose
    slots = rng.permutation(M)[:r]
    kept = sp.random(M, n_static + n_obj, density=0.25, random_state=rng, format="csr").toarray()
    kept[slots[:150]] = at_pose(big, h_kept, r_kept, select)[:150].toarray()  # rows of a third pose
    kept[slots[150:180]] = at_pose(big, h_last, r_last, select)[150:180].toarray()  # the last pose's own: no D then
    kept = sp.csr_matrix(kept)
    last, last_capped = difference_at_pose(big, h_last, r_last, kept, slots, select)
    truth = difference_at_pose(big, h_now, r_now, kept, slots, select)
    assert 10 < truth.capped.sum() < r - 100 and 10 < last_capped.sum() < r - 100
    # The last D held in another order, as StaleRows holds it: empty rows not held (-1).
    held = np.flatnonzero(np.diff(last.indptr) > 0)
    assert len(held) < r - 20
    order = rng.permutation(held)
    last_row = np.full(r, -1)
    last_row[order] = np.arange(len(order))
    named = ~last_capped & (rng.random(r) < 0.9)
    row_sums = np.asarray(big.sum(axis=1)).ravel()[select]
    since = Since(named, h_last, row_sums, last[order], last_row, n_static)

    def same(a, b):
        return (
            isinstance(a, PoseDifference)
            and np.array_equal(a.capped, b.capped)
            and a.delta.shape == b.delta.shape
            and all(np.array_equal(getattr(a.delta, k), getattr(b.delta, k)) for k in ("indptr", "indices", "data"))
        )

    assert same(difference_at_pose(big, h_now, r_now, kept, slots, select, since), truth)
    monkeypatch.setattr(poserows, "PARALLEL_ENTRIES", 1)
    monkeypatch.setattr(poserows, "cores", lambda: 3)
    assert same(difference_at_pose(big, h_now, r_now, kept, slots, select, since), truth)
    # A wrong last D, where a row named has one that nothing since changes, shows in the answer.
    k = next(
        k
        for k in np.flatnonzero(named & ~truth.capped & (last_row >= 0))
        if (np.diff(last[k].indices) > 0).all() and len(last[k].indices)
    )
    wrong = last[order].tolil()
    wrong[last_row[k], last[k].indices[0]] += 1.0
    bent = difference_at_pose(big, h_now, r_now, kept, slots, select, since._replace(last=sp.csr_matrix(wrong)))
    assert not same(bent, truth) and (bent.delta - truth.delta).nnz == 1
    shuffled = kept.copy()
    for j in range(M):  # each kept row's entries reversed: sorted first, then the last D read against them
        a, b = shuffled.indptr[j], shuffled.indptr[j + 1]
        shuffled.indices[a:b], shuffled.data[a:b] = shuffled.indices[a:b][::-1].copy(), shuffled.data[a:b][::-1].copy()
    shuffled.has_sorted_indices = False
    assert same(difference_at_pose(big, h_now, r_now, shuffled, slots, select, since), truth)
    # Masks whose flags are any non-zero byte (a bool array viewed from bytes of 2 and 5) read as 0 and 1.
    twos = lambda h, v: (h.astype(np.uint8) * v).view(bool)  # noqa: E731
    assert same(
        difference_at_pose(big, twos(h_now, 2), r_now, kept, slots, select, since._replace(hidden=twos(h_last, 5))),
        truth,
    )
    for bad in (
        since._replace(rows=named[:-1]),
        since._replace(hidden=h_last[:-1]),
        since._replace(last_row=last_row + r),
        since._replace(row_sums=row_sums[:-1]),
    ):
        with pytest.raises(pd.InvalidInputError, match="since must give"):
            difference_at_pose(big, h_now, r_now, kept, slots, select, bad)
