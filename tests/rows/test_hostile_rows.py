"""Hostile form-factor files and stores: broken arrays, other dtypes, blocks from other stores, overwrites."""

import numpy as np
import pytest

import pydynrad
from pydynrad.errors import InvalidInputError


class _Source:
    """A row source that serves F's rows with one block broken."""

    def __init__(self, F, kind, bad_patch):
        self.F, self.kind, self.bad_patch, self.n_patches = F, kind, bad_patch, F.shape[0]

    def rows(self, idx):
        block = self.F[idx]
        if self.bad_patch in set(np.asarray(idx).tolist()):
            k = int(np.flatnonzero(np.asarray(idx) == self.bad_patch)[0])
            if self.kind == "column":
                block.indices[block.indptr[k]] = self.n_patches + 7
            elif self.kind == "value":
                block.data[block.indptr[k]] = np.nan
            elif self.kind == "shape":
                block = block[:, :-1]
        return block


@pytest.mark.parametrize(
    "kind, message",
    [
        ("column", r"row 30 has column index 55 outside 0\.\.47"),
        ("value", "NaN or infinite"),
        ("shape", r"must have shape \(\d+, 48\); got \(\d+, 47\)"),
    ],
)
def test_row_source_blocks_are_checked_with_the_patch_named(closed_box_48, closed_box_48_F, device, kind, message):
    source = _Source(closed_box_48_F, kind, bad_patch=30)
    # The far field sums G from every row at construction: the bad block is refused there.
    with pytest.raises(InvalidInputError, match=message):
        pydynrad.DynamicRadiosity(closed_box_48, source, local_size=48, device=device)
    # Row 30's patch is near the observer below, so it enters the local set on the first update.
    dyn = pydynrad.DynamicRadiosity(closed_box_48, source, local_size=48, far_field=False, device=device)
    with pytest.raises(InvalidInputError, match=message):
        dyn.update(closed_box_48.centers[30])
    with pydynrad.rows.RowCache(source, 1 << 20) as cache, pytest.raises(InvalidInputError, match=message):
        cache.rows([29, 30])


def test_a_form_factor_file_with_broken_arrays_is_refused(closed_box_48, closed_box_48_F, tmp_path):
    path = pydynrad.save_form_factors(closed_box_48, tmp_path / "F.npz", closed_box_48_F, 16)
    with np.load(path) as z:
        arrays = dict(z)
    arrays["indices"] = arrays["indices"].copy()
    arrays["indices"][arrays["indptr"][9]] = 4096
    np.savez(path, **arrays)
    with pytest.raises(InvalidInputError, match=r"F\.npz'.*row 9 has column index 4096 outside 0\.\.47"):
        pydynrad.rows.load_form_factors(closed_box_48, path)
    arrays["indptr"] = arrays["indptr"][:-1]
    np.savez(path, **arrays)
    with pytest.raises(InvalidInputError, match="indptr has 48 entries; 48 rows need 49"):
        pydynrad.rows.load_form_factors(closed_box_48, path)


def test_a_form_factor_file_of_another_dtype_is_refused(closed_box_48, closed_box_48_F, tmp_path):
    """float16 or text values (a file not written by pydynrad) are named, not left to scipy (a raw
    ValueError inside it)."""
    path = pydynrad.save_form_factors(closed_box_48, tmp_path / "F.npz", closed_box_48_F, 16)
    with np.load(path) as z:
        arrays = dict(z)
    for data in (arrays["data"].astype(np.float16), arrays["data"].astype(str)):
        np.savez(path, **{**arrays, "data": data})
        with pytest.raises(InvalidInputError, match=f"holds {data.dtype} values"):
            pydynrad.rows.load_form_factors(closed_box_48, path)


# Stores that know their own blocks.
def test_a_block_from_another_store_is_refused_and_recomputed_on_resume(tmp_path, capsys, device):
    import json
    import shutil

    from pydynrad.cli.main import main
    from pydynrad.rows.store import StoreCorruptError

    def formfactors(name, R):
        code = main(
            [
                "formfactors",
                "closed_box",
                "-o",
                str(tmp_path / name),
                "--resolution",
                str(R),
                "--block-rows",
                "64",
                "--workers",
                "0",
                "--quiet",
            ]
        )
        out = capsys.readouterr().out
        assert code == 0, out
        return out

    formfactors("a", 8)
    formfactors("b", 16)
    scene = pydynrad.scenes.closed_box()
    a, b = (pydynrad.open_form_factors(scene, tmp_path / n) for n in "ab")
    shutil.copy(a.block_path(1), b.block_path(1))  # same scene, other resolution: its own checksum is intact
    with pytest.raises(StoreCorruptError, match="belongs to another store or block"):
        b.read_block(1)  # main: served silently
    shutil.copy(b.block_path(0), b.block_path(2))  # moved within the store
    with pytest.raises(StoreCorruptError, match="belongs to another store or block"):
        b.read_block(2)
    # Re-running the command reads every finished block: the two are recomputed, not reported as done.
    out = formfactors("b", 16)
    assert "1 of 3 blocks already done; 2 fail their checksum and are recomputed (block 1, 2)" in out
    fresh = pydynrad.form_factors(scene, resolution=16, device=device)
    assert abs(pydynrad.open_form_factors(scene, tmp_path / "b").to_csr() - fresh).max() == 0
    # Headers every reader relies on: one-line errors.
    header = json.loads((tmp_path / "a" / "header.json").read_text())
    for field, value, needle in (
        ("block_rows", 0, "block_rows must be a positive integer; got 0"),
        ("block_rows", "64", "block_rows must be a positive integer; got '64'"),
        ("params", None, "params must be an object"),
    ):
        broken = dict(header, **{field: value})
        (tmp_path / "a" / "header.json").write_text(json.dumps(broken))
        with pytest.raises(StoreCorruptError, match=needle):
            pydynrad.FormFactorStore.read_header(tmp_path / "a")


def test_formfactors_verify_checks_every_block_and_recomputes_what_fails(tmp_path, capsys, device):
    from pydynrad.cli.main import main

    out = tmp_path / "s"
    args = [
        "formfactors",
        "closed_box",
        "-o",
        str(out),
        "--resolution",
        "8",
        "--block-rows",
        "64",
        "--workers",
        "0",
        "--clusters",
        "6",
        "--quiet",
    ]
    assert main(args) == 0
    capsys.readouterr()
    scene = pydynrad.scenes.closed_box()
    store = pydynrad.open_form_factors(scene, out)
    assert {k: len(v) for k, v in store.verify("G").items()} == {"verified": 3, "missing": 0, "corrupt": 0}
    good_f, good_g = store.read_block(1), store.read_block(2, "G")
    store.block_path(1).write_bytes(store.block_path(1).read_bytes()[:-40])  # truncated
    store.block_path(0, "G").write_bytes(store.block_path(1, "G").read_bytes())  # another block's
    store.block_path(2, "G").unlink()
    assert store.verify("F") == {"verified": [0, 2], "missing": [], "corrupt": [1]}
    assert store.verify("G") == {"verified": [1], "missing": [2], "corrupt": [0]}
    assert main(args + ["--verify"]) == 0
    printed = capsys.readouterr().out
    assert f"verified {out}: 2 of 3 blocks already done; 1 fail their checksum and are recomputed (block 1)" in printed
    assert (
        f"verified {out}, G: 1 of 3 blocks already done; 1 fail their checksum and are recomputed (block 0); 1 missing"
        in printed
    )
    assert all(not v for k, v in store.verify("F").items() if k != "verified")
    assert all(not v for k, v in store.verify("G").items() if k != "verified")
    assert abs(store.read_block(1) - good_f).max() == 0 and abs(store.read_block(2, "G") - good_g).max() == 0
    # Only for a store that exists, and not for a single file.
    for target, needle in (
        (tmp_path / "none", "--verify checks an existing store"),
        (tmp_path / "f.npz", "--verify apply to a store folder"),
    ):
        assert main(["formfactors", "closed_box", "-o", str(target), "--resolution", "8", "--verify", "--quiet"]) == 2
        assert needle in capsys.readouterr().err


def test_formfactors_will_not_overwrite_an_unrelated_npz(tmp_path, capsys):
    from pydynrad.cli.main import main

    other = tmp_path / "weights.npz"
    np.savez(other, w=np.arange(3))
    args = ["formfactors", "closed_box", "--resolution", "8", "--quiet", "-o", str(other)]
    assert main(args) == 2  # main: overwrote it without a word
    err = capsys.readouterr().err
    assert "is not a pydynrad form-factor file: not overwriting it (pass --force" in err and len(err.splitlines()) == 1
    assert np.load(other)["w"].tolist() == [0, 1, 2]
    assert main(args + ["--force"]) == 0
    assert main(args) == 0  # now a form-factor file: recomputing it in place is fine
