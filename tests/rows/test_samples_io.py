"""``samples`` (hemicubes per row) through every path that makes or keeps rows of F: the .npz
file, the store (F, and G beside it), rows on demand, DynamicRadiosity and the CLI. Each gives
the rows of ``form_factors(samples=K)``, refuses rows of other samples, and reads data from
before samples were recorded as samples=1."""

import io
import json
import shutil

import numpy as np
import pytest
from helpers import assert_one_line_error, box_mesh, run_main, same_csr

from pydynrad import DynamicRadiosity, InvalidInputError, Scene, form_factors
from pydynrad.farfield.gather import cluster_form_factors_for
from pydynrad.precompute.store import compute_store
from pydynrad.rows.files import FF_FORMAT, load_form_factors, open_form_factors, save_form_factors
from pydynrad.rows.prolongation import as_prolongation
from pydynrad.rows.sources import HemicubeRows
from pydynrad.rows.store import HEADER, FormFactorStore, StoreCorruptError, StoreMismatchError
from pydynrad.scenes import cornell_box

R, K = 16, 4


@pytest.fixture(scope="module")
def emitting_box():
    """A closed box of 48 patches, the light at one face."""
    emission = np.zeros((48, 3))
    emission[:8] = 1.0
    return Scene(*box_mesh(n=2), albedo=0.6, emission=emission, name="box")


@pytest.fixture(scope="module")
def sampled(emitting_box, device):
    return form_factors(emitting_box, resolution=R, samples=K, device=device)


def labels_of(scene):
    return np.arange(len(scene)) // 8  # the box's faces, 8 patches each


def test_file_records_samples_and_refuses_others(emitting_box, sampled, tmp_path):
    path = save_form_factors(emitting_box, tmp_path / "f.npz", sampled, R, samples=K)
    F, header = load_form_factors(emitting_box, path, samples=K)
    assert same_csr(F, sampled) and header["samples"] == K
    assert same_csr(open_form_factors(emitting_box, path, samples=K), sampled)
    with pytest.raises(InvalidInputError, match=r"other parameters \(samples 4, requested 1\)"):
        open_form_factors(emitting_box, path, samples=1)
    with pytest.raises(InvalidInputError, match="power of 4"):
        save_form_factors(emitting_box, tmp_path / "g.npz", sampled, R, samples=3)
    # A file written before samples was recorded: the same header, no "samples" in it.
    with np.load(path) as z:
        arrays = {k: z[k] for k in ("data", "indices", "indptr")}
        old = {k: v for k, v in json.loads(str(z["header"])).items() if k != "samples"}
    for name, hdr in (("old.npz", old), ("bad.npz", {**old, "samples": 5})):
        buf = io.BytesIO()
        np.savez(buf, header=np.array(json.dumps(hdr)), **arrays)
        (tmp_path / name).write_bytes(buf.getvalue())
    assert load_form_factors(emitting_box, tmp_path / "old.npz", samples=1)[1]["samples"] == 1
    with pytest.raises(InvalidInputError, match="samples 1, requested 4"):
        load_form_factors(emitting_box, tmp_path / "old.npz", samples=K)
    with pytest.raises(InvalidInputError, match="damaged: samples must be a power of 4"):
        load_form_factors(emitting_box, tmp_path / "bad.npz")
    assert FF_FORMAT == old["format"]


def test_store_of_samples_f_and_g(emitting_box, sampled, tmp_path, device):
    pr = as_prolongation(labels_of(emitting_box), len(emitting_box))
    store = compute_store(
        emitting_box,
        tmp_path / "ff",
        resolution=R,
        samples=K,
        block_rows=16,
        progress=False,
        device=device,
        clusters=labels_of(emitting_box),
        cluster_basis="indicator",
    )
    assert store.samples == K and same_csr(store.to_csr(), sampled)  # the same rows, bit for bit
    G = store.cluster_form_factors().toarray()
    np.testing.assert_allclose(G, (sampled.astype(np.float64) @ pr).toarray(), rtol=0, atol=1e-7)  # summed from F
    # G alone (no F): cluster-id hemicubes with F's samples, F Pr of the rows a walk would compute.
    g_only = compute_store(
        emitting_box,
        tmp_path / "g",
        resolution=R,
        samples=K,
        block_rows=16,
        progress=False,
        device=device,
        clusters=labels_of(emitting_box),
        cluster_basis="indicator",
        compute_f=False,
    )
    assert g_only.cluster_samples == K
    np.testing.assert_allclose(g_only.cluster_form_factors().toarray(), G, rtol=0, atol=3e-7)
    with pytest.raises(StoreMismatchError, match="samples: store has 4, requested 1"):
        compute_store(emitting_box, tmp_path / "ff", resolution=R, block_rows=16, progress=False, device=device)
    with pytest.raises(StoreMismatchError, match="samples: store has 4, requested 16"):
        open_form_factors(emitting_box, tmp_path / "ff", samples=16)
    assert same_csr(open_form_factors(emitting_box, tmp_path / "ff").to_csr(), sampled)  # opened with what it records
    # A block of a samples=1 store of the same scene, resolution and rows is refused, not served.
    single = compute_store(emitting_box, tmp_path / "one", resolution=R, block_rows=16, progress=False, device=device)
    shutil.copy(single.block_path(1), store.block_path(1))
    with pytest.raises(StoreCorruptError, match="belongs to another store"):
        store.read_block(1)


def test_store_from_before_samples_reads_as_one(emitting_box, tmp_path, device):
    FormFactorStore.create(emitting_box, tmp_path / "ff", resolution=R, block_rows=16)
    header = json.loads((tmp_path / "ff" / HEADER).read_text())
    del header["params"]["samples"]
    (tmp_path / "ff" / HEADER).write_text(json.dumps(header))
    store = compute_store(emitting_box, tmp_path / "ff", resolution=R, block_rows=16, progress=False, device=device)
    assert store.samples == 1 and same_csr(store.to_csr(), form_factors(emitting_box, resolution=R, device=device))
    with pytest.raises(StoreMismatchError, match="samples: store has 1, requested 4"):
        FormFactorStore.open(emitting_box, tmp_path / "ff", resolution=R, samples=K)


def test_rows_on_demand_and_dynamic_radiosity(emitting_box, sampled, device):
    idx = np.array([40, 3, 17])
    rows = HemicubeRows(emitting_box, R, device, samples=K)
    assert same_csr(rows.rows(idx), form_factors(emitting_box, resolution=R, rows=idx, samples=K, device=device))
    G = cluster_form_factors_for(emitting_box, rows, labels_of(emitting_box), device=device)
    np.testing.assert_allclose(
        G.toarray(),
        (sampled.astype(np.float64) @ as_prolongation(labels_of(emitting_box), len(emitting_box))).toarray(),
        rtol=0,
        atol=3e-7,
    )
    with pytest.raises(InvalidInputError, match="even integer"):
        HemicubeRows(emitting_box, 8, samples=64)
    # Rows on demand with samples=K light the box as F computed with samples=K does.
    opts = dict(local_size=24, far_field=False, resolution=R, observer=(0.5, 0.5, 0.5), device=device)
    on_demand = DynamicRadiosity(emitting_box, None, samples=K, **opts).radiosity()
    given = DynamicRadiosity(emitting_box, sampled, **opts).radiosity()
    single = DynamicRadiosity(emitting_box, None, **opts).radiosity()
    np.testing.assert_array_equal(on_demand, given)  # the same rows, the same solve
    assert np.abs(single - given).max() > 0.01 * np.abs(given).max()  # samples did reach the rows
    with pytest.raises(InvalidInputError, match="rows computed on demand"):
        DynamicRadiosity(emitting_box, sampled, samples=K, **opts)


def test_cli_samples_file_and_store(tmp_path, capsys):
    small = ["cornell_box", "--max-edge", "250", "--resolution", "8", "--quiet"]
    scene = cornell_box(max_edge=250)
    truth = form_factors(scene, resolution=8, samples=K)
    code, out, err = run_main(["formfactors", *small, "--samples", "4", "-o", str(tmp_path / "f.npz")], capsys)
    assert code == 0, err
    assert same_csr(load_form_factors(scene, tmp_path / "f.npz", samples=K)[0], truth)
    ff = str(tmp_path / "ff")
    assert run_main(["formfactors", *small, "--samples", "4", "-o", ff, "--workers", "0"], capsys)[0] == 0
    assert same_csr(open_form_factors(scene, ff, samples=K).to_csr(), truth)
    code, _, err = run_main(["formfactors", *small, "-o", ff, "--workers", "0"], capsys)
    assert_one_line_error(code, err, "does not match", "samples: store has 4, requested 1")
    for bad, needle in (("5", "power of 4"), ("64", "which must be an even integer")):
        code, _, err = run_main(["formfactors", *small, "--samples", bad, "-o", str(tmp_path / "x.npz")], capsys)
        assert_one_line_error(code, err, needle)
    code, _, err = run_main(
        ["render", *small, "--form-factors", str(tmp_path / "f.npz"), "--samples", "16", "-o", str(tmp_path / "x.png")],
        capsys,
    )
    assert_one_line_error(code, err, "samples 4, requested 16")


@pytest.mark.slow
def test_distributed_store_of_samples(emitting_box, sampled, tmp_path):
    """Workers open the store with its samples and compute its rows with them (2 spawned workers)."""
    from pydynrad.precompute.distributed import precompute_distributed

    store = precompute_distributed(
        emitting_box, tmp_path / "ff", resolution=R, samples=K, block_rows=16, workers=2, progress=False
    )
    assert store.samples == K and same_csr(store.to_csr(), sampled)
    with pytest.raises(StoreMismatchError, match="samples: store has 4, requested 1"):
        precompute_distributed(emitting_box, tmp_path / "ff", resolution=R, block_rows=16, workers=2, progress=False)
