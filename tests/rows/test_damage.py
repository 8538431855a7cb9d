"""Damaged stores: every reader turns a broken file into a
StoreCorruptError naming the block, ``--verify`` repairs it (F, G, the prolongation, pose files),
a block rewritten in the legacy format is refused in a store of bound blocks, and a resume over
an edited header refuses before it deletes anything.

Before: a bit flip that broke a block's deflate stream escaped as ``zlib.error`` from ``rows()``,
``DynamicRadiosity``, ``verify()`` and ``pydynrad formfactors --verify`` (a traceback).
"""

import hashlib
import io
import json
import zipfile

import numpy as np
import pytest

import pydynrad as pd
from pydynrad.cli.main import main
from pydynrad.rows.store import StoreCorruptError, StoreMismatchError

R = 8


def _formfactors(tmp_path, capsys, *extra, name="s"):
    args = [
        "formfactors",
        "closed_box",
        "-o",
        str(tmp_path / name),
        "--resolution",
        str(R),
        "--block-rows",
        "32",
        "--workers",
        "0",
        "--quiet",
        *extra,
    ]
    code = main(args)
    out = capsys.readouterr()
    assert code == 0, out
    return out.out


def _flip(path, fraction: float, bit: int = 3) -> bytes:
    """Flip one bit ``fraction`` of the way into ``path``; returns the bytes before."""
    good = path.read_bytes()
    bad = bytearray(good)
    bad[int(len(bad) * fraction)] ^= 1 << bit
    path.write_bytes(bytes(bad))
    return good


@pytest.fixture
def store(tmp_path, capsys):
    _formfactors(tmp_path, capsys)
    return pd.open_form_factors(pd.scenes.closed_box(), tmp_path / "s")


def test_the_issues_bit_flip_is_a_named_error_and_verify_repairs_it(store, tmp_path, capsys, device):
    scene = pd.scenes.closed_box()
    assert store.n_blocks >= 4
    good = store.to_csr()
    _flip(store.block_path(3), 1 / 3)
    with pytest.raises(StoreCorruptError, match=r"block 3 \(rows 96\.\.127\) of store"):
        store.rows(np.arange(len(scene)))
    with pytest.raises(StoreCorruptError, match="block 3"):
        pd.DynamicRadiosity(scene, store, local_size=len(scene), observer=[0.5] * 3, far_field=False, device=device)
    assert store.verify()["corrupt"] == [3]
    out = _formfactors(tmp_path, capsys, "--verify")
    assert "1 fail their checksum and are recomputed (block 3)" in out
    assert abs(store.to_csr() - good).max() == 0


@pytest.mark.parametrize("bit", [0, 5])
def test_a_bit_flip_anywhere_is_refused_never_served_or_escaped(store, bit):
    """One bit flipped at each of 40 places of a block: a StoreCorruptError (or, where the flip
    hits only zip padding that nothing reads, the block as it was), never another exception."""
    path = store.block_path(1)
    truth = store.read_block(1)
    outcomes = {"refused": 0, "same": 0}
    for fraction in np.linspace(0.0, 0.999, 40):
        good = _flip(path, fraction, bit)
        try:
            block = store.read_block(1)
        except StoreCorruptError as exc:
            assert "block 1" in str(exc)
            outcomes["refused"] += 1
        else:
            assert abs(block - truth).max() == 0, fraction  # never a different block served
            outcomes["same"] += 1
        path.write_bytes(good)
    assert outcomes["refused"] >= 30, outcomes


def test_damaged_g_and_prolongation_are_repaired_by_verify(tmp_path, capsys):
    _formfactors(tmp_path, capsys, "--clusters", "6")
    store = pd.open_form_factors(pd.scenes.closed_box(), tmp_path / "s")
    G, pr = store.cluster_form_factors(), store.prolongation()
    _flip(store.block_path(2, "G"), 1 / 3)
    _flip(store.path / "prolongation.npz", 1 / 3)
    with pytest.raises(StoreCorruptError, match="of G"):
        store.cluster_form_factors()
    with pytest.raises(StoreCorruptError, match="the prolongation"):
        store.prolongation()
    out = _formfactors(tmp_path, capsys, "--clusters", "6", "--verify")
    assert "G: 5 of 6 blocks already done; 1 fail their checksum and are recomputed (block 2)" in out, out
    store = pd.open_form_factors(pd.scenes.closed_box(), tmp_path / "s")
    assert abs(store.prolongation() - pr).max() == 0 and abs(store.cluster_form_factors() - G).max() == 0


def test_damaged_pose_files_are_named_and_removed_by_verify(tmp_path, device):
    box = pd.scenes.closed_box()
    block = pd.scenes.block(0.2, 0)
    T = [np.eye(4), np.eye(4)]
    T[0][:3, 3], T[1][:3, 3] = (0.3, 0.3, 0.3), (0.5, 0.4, 0.3)
    store = pd.FormFactorStore.create(box, tmp_path / "ff", resolution=R)
    pd.precompute.precompute_poses(box, [pd.RigidObject(block)], T, resolution=R, device=device, store=store)
    files = store.pose_files()
    assert len(files) == 2 and store.verify_poses()["corrupt"] == []
    _flip(files[0], 1 / 3)
    with pytest.raises(StoreCorruptError, match="per-pose rows p"):
        for t in T:
            store.read_pose([t])
    assert store.verify_poses(remove=True)["corrupt"] == [files[0]]
    assert not files[0].exists() and files[1].exists()
    # Computed again by the same call, and read back whole.
    pd.precompute.precompute_poses(box, [pd.RigidObject(block)], T, resolution=R, device=device, store=store)
    assert all(store.read_pose([t]) is not None for t in T) and store.verify_poses()["corrupt"] == []


def _as_legacy(path, k: int, rows: range):
    """Rewrite a block file in the format from before checksums were bound: the plain SHA-256
    and no 'bound' flag (what a block copied from another store and re-signed would look like)."""
    with zipfile.ZipFile(path) as zf:
        meta = json.loads(zf.read("meta.json"))
        arrays = {n: zf.read(f"{n}.npy") for n in ("indptr", "indices", "data")}
    loaded = {n: np.lib.format.read_array(io.BytesIO(b)) for n, b in arrays.items()}
    h = hashlib.sha256()
    for n in ("indptr", "indices", "data"):
        h.update(np.ascontiguousarray(loaded[n]).tobytes())
    meta = {"block": k, "row_start": rows.start, "row_stop": rows.stop, "nnz": meta["nnz"], "sha256": h.hexdigest()}
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for n, b in arrays.items():
            zf.writestr(f"{n}.npy", b)
        zf.writestr("meta.json", json.dumps(meta))
    path.write_bytes(buf.getvalue())


def test_legacy_blocks_are_decided_once_per_store(tmp_path, capsys):
    """Item 4: a block from another store (another resolution) rewritten in the legacy format
    is refused in a store of bound blocks; a store whose header and blocks are all legacy reads."""
    _formfactors(tmp_path, capsys)
    args = [
        "formfactors",
        "closed_box",
        "-o",
        str(tmp_path / "o"),
        "--resolution",
        "16",
        "--block-rows",
        "32",
        "--workers",
        "0",
        "--quiet",
    ]
    assert main(args) == 0
    scene = pd.scenes.closed_box()
    a, b = pd.open_form_factors(scene, tmp_path / "s"), pd.open_form_factors(scene, tmp_path / "o")
    assert not a.legacy and a.header["checksums"] == "bound"
    b.block_path(1).write_bytes(a.block_path(1).read_bytes())
    _as_legacy(b.block_path(1), 1, b.block_range(1))
    with pytest.raises(StoreCorruptError, match="unbound checksum"):
        b.read_block(1)  # main: verified with the plain digest and served (up to 0.018 off)
    # A header from before the field: still bound, decided from its blocks.
    header = json.loads((b.path / "header.json").read_text())
    del header["checksums"]
    (b.path / "header.json").write_text(json.dumps(header))
    b = pd.open_form_factors(scene, tmp_path / "o")
    assert not b.legacy
    with pytest.raises(StoreCorruptError, match="unbound checksum"):
        b.read_block(1)
    # A store that is legacy through and through keeps working.
    for k in range(a.n_blocks):
        _as_legacy(a.block_path(k), k, a.block_range(k))
    header = json.loads((a.path / "header.json").read_text())
    del header["checksums"]
    (a.path / "header.json").write_text(json.dumps(header))
    a = pd.open_form_factors(scene, tmp_path / "s")
    assert a.legacy and a.verify()["corrupt"] == []


def test_a_resume_over_an_edited_header_deletes_nothing(tmp_path, capsys):
    """Item 8: the header's block_rows edited after the blocks were written: the resume (and
    --verify, and compute_store(verify=True)) refuses, naming the header, with every block kept."""
    _formfactors(tmp_path, capsys)
    path = tmp_path / "s"
    files = {p.name: p.read_bytes() for p in (path / "blocks").iterdir()}
    header = json.loads((path / "header.json").read_text())
    (path / "header.json").write_text(json.dumps(dict(header, block_rows=16)))
    for extra in ((), ("--verify",)):
        code = main(
            ["formfactors", "closed_box", "-o", str(path), "--resolution", str(R), "--workers", "0", "--quiet", *extra]
        )
        err = capsys.readouterr().err
        assert code == 2 and "header.json was edited" in err and "Traceback" not in err
        assert {p.name: p.read_bytes() for p in (path / "blocks").iterdir()} == files
    scene = pd.scenes.closed_box()
    with pytest.raises(StoreMismatchError, match="Nothing was deleted"):
        pd.precompute.compute_store(
            scene, path, resolution=R, block_rows=16, verify=True, patching=header["params"]["patching"]
        )
    assert {p.name: p.read_bytes() for p in (path / "blocks").iterdir()} == files


def test_store_constructor_takes_a_str_and_refuses_a_bad_header(store):
    """Item 11: FormFactorStore(str, header) had raised a bare TypeError at the first block."""
    again = pd.FormFactorStore(str(store.path), store.header)
    assert abs(again.read_block(0) - store.read_block(0)).max() == 0
    with pytest.raises(pd.errors.InvalidInputError, match="header must be"):
        pd.FormFactorStore(str(store.path), "header.json")


def test_a_g_that_contradicts_f_is_refused(device):
    """Item 7: an all-zero G beside F (23% error against 1.4%) is refused; F Pr itself passes."""
    import scipy.sparse as sp

    from pydynrad.farfield import FarField
    from pydynrad.farfield.clusters import cluster_patches

    scene = pd.scenes.closed_box(subdivisions=3)
    F = pd.form_factors(scene, resolution=16, device=device)
    clusters = cluster_patches(scene, 12)
    G = sp.csr_matrix(F @ clusters.indicator())
    FarField(scene, F, clusters, G=G, device=device)  # consistent: accepted
    for bad in (sp.csr_matrix(G.shape), G * 0.5):
        with pytest.raises(pd.errors.InvalidInputError, match="contradicts the form factors"):
            FarField(scene, F, clusters, G=bad, device=device)


@pytest.mark.parametrize("mesh", ["../outside.obj", "/etc/outside.obj", "sub/../../outside.obj", "link.obj"])
def test_path_file_meshes_are_confined_to_its_folder(tmp_path, mesh):
    """Item 9: a path file names meshes in its own folder or below, never elsewhere."""
    from pydynrad.paths import load_walk

    cube = pd.scenes.block(2.0, 0)
    lines = [f"v {x} {y} {z}" for x, y, z in cube.vertices] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in cube.faces]
    (tmp_path / "outside.obj").write_text("\n".join(lines) + "\n")
    folder = tmp_path / "walk"
    (folder / "sub").mkdir(parents=True)
    (folder / "link.obj").symlink_to(tmp_path / "outside.obj")
    doc = {
        "frames": 2,
        "keyframes": [{"position": [0, 0, -5], "look_at": [0, 0, 0]}],
        "objects": [{"mesh": mesh, "keyframes": [{"position": [0, 0, 0]}]}],
    }
    (folder / "path.json").write_text(json.dumps(doc))
    with pytest.raises(pd.errors.InvalidInputError, match="outside the path file's folder"):
        load_walk(folder / "path.json")
