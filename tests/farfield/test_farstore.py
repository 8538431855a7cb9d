"""The far field without F (stores, rows on demand): the piecewise-linear coarse basis."""

from pathlib import Path

import numpy as np
import pytest
from helpers import box_scene, dense_radiosity, reciprocal_F, store_of
from test_farfield import yard_and_room

import pydynrad
from pydynrad import DirectionalLight, DynamicRadiosity
from pydynrad.comparison import radiosity_error
from pydynrad.farfield import FarField, cluster_form_factors, cluster_patches
from pydynrad.farfield.clusters import light_components, linear_basis
from pydynrad.farfield.gather import basis_prolongation, clusters_without_f, light_components_by_hemicube
from pydynrad.rows.prolongation import LINEAR_FUNCTIONS, labels_of_linear


def test_linear_basis_reproduces_affine_fields_and_sums_to_one():
    scene = box_scene(6)  # six flat walls: every cluster lies in one plane
    cl = cluster_patches(scene, patches_per_cluster=6)
    Pr, R = linear_basis(cl, scene)
    n, C = len(scene), cl.count
    assert Pr.shape == (n, LINEAR_FUNCTIONS * C) and R.shape == (LINEAR_FUNCTIONS * C, n)
    assert Pr.data.min() >= 0 and Pr.data.max() <= 1
    np.testing.assert_allclose(np.asarray(Pr.sum(axis=1)).ravel(), 1.0, atol=1e-7)  # rows of G sum as F's
    # Any affine field over space is affine over each flat cluster: the basis holds it exactly.
    x = scene.centers.astype(np.float64)
    f = np.column_stack([x @ [0.3, -1.2, 0.7] + 2.0, x @ [-2.0, 0.5, 0.1] + 3.0])
    np.testing.assert_allclose(Pr @ (R @ f), f, rtol=2e-6)  # observed 3e-7 (the basis is rounded to float32)
    # A constant cluster value (the indicator's) is not enough for it.
    ind = cl.indicator() @ (cl.restriction(scene.areas) @ f)
    assert np.abs(ind - f).max() > 0.05
    np.testing.assert_array_equal(labels_of_linear(Pr), cl.labels)
    mixed = Pr.tolil()
    mixed[0, (cl.labels[0] + 1) % C] = 0.5  # a patch in two clusters: not this layout
    assert labels_of_linear(mixed.tocsr()) is None


def test_every_patch_its_own_cluster_is_the_full_solve_without_f(device):
    scene = box_scene(3).with_materials(albedo=np.random.default_rng(1).uniform(0.1, 0.9, (108, 3)))
    F = reciprocal_F(scene.areas, row_sum=1.0, density=0.2, seed=2)
    L = np.random.default_rng(3).random((len(scene), 3))
    cl = cluster_patches(scene, len(scene))
    G = F @ basis_prolongation(scene, cl, "linear")
    far = FarField(scene, None, cl, G=G, tol=1e-14, max_sweeps=5000, dtype=np.float64, device=device)
    assert far.prolongation == "linear" and G.shape == (len(scene), 3 * len(scene)) and far.G_nnz == G.nnz
    dyn = DynamicRadiosity(
        scene, F, local_size=7, storage="fp64", observer=[0.1, 0.9, 0.5], far_field=far, device=device
    )
    # Observed max relative error 8.7e-16 (PoCL CPU).
    np.testing.assert_allclose(dyn.radiosity(light=L), dense_radiosity(scene, F, L), rtol=5e-14)


def test_sun_without_f_lights_every_lit_patch_and_leaks_nothing(device):
    scene = yard_and_room()
    F = pydynrad.form_factors(scene, resolution=32, device=device, progress=False)
    L = pydynrad.light_vector(scene, [DirectionalLight((-0.5, -1.0, -0.2), (3.0,) * 3)], device=device)
    ref = dense_radiosity(scene, F, L)
    dark = ref.max(axis=1) < 1e-3 * ref.mean()
    cl = clusters_without_f(scene, len(scene) // 8, device=device)
    errors = {}
    for basis in ("indicator", "linear"):
        G = cluster_form_factors(scene, basis_prolongation(scene, cl, basis), resolution=32, device=device)
        far = FarField(scene, None, cl, G=G, prolongation=basis, device=device)
        dyn = DynamicRadiosity(
            scene, F, local_size=len(scene) // 8, observer=[0.5, 0.5, 1.0], far_field=far, device=device, tolerance=None
        )  # the coarse level's own error, unrefined
        B = dyn.radiosity(light=L)
        assert np.all(B[~dark].max(axis=1) > 0)
        assert B[dark].max() < 1e-2 * ref.mean()
        errors[basis] = radiosity_error(B, ref, scene.areas)
    # Observed (PoCL): no leak (0.0); all-patch error indicator 2.6%, linear 0.77% (its
    # two default sweeps; 0.46% converged).
    assert errors["linear"] < 0.012 and errors["linear"] < 0.5 * errors["indicator"]


def test_bad_basis(device):
    scene = box_scene(2)
    cl = cluster_patches(scene)
    with pytest.raises(pydynrad.InvalidInputError, match="coarse basis"):
        basis_prolongation(scene, cl, "quadratic")


def test_light_components_without_f_are_those_of_f(device, tmp_path):
    from pydynrad.precompute.store import compute_store

    scene = yard_and_room()  # the closed room's inside exchanges no light with the yard
    F = pydynrad.form_factors(scene, resolution=32, device=device, progress=False)
    want, got = light_components(F), light_components_by_hemicube(scene, device=device)
    pairs = np.unique(np.column_stack([want, got]), axis=0)
    assert len(pairs) == len(np.unique(want)) == len(np.unique(got)) == 3  # the same partition (observed at R = 8)
    store = compute_store(
        scene,
        tmp_path / "ff",
        resolution=32,
        block_rows=100,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    streamed = light_components_by_hemicube(scene, store=store)  # F's own blocks, no rays
    assert len(np.unique(np.column_stack([want, streamed]), axis=0)) == len(np.unique(streamed)) == 3


def test_light_components_refuse_a_store_of_another_scene(device, tmp_path):
    from pydynrad.precompute.store import compute_store
    from pydynrad.rows.store import StoreIncompleteError

    scene = box_scene(2)
    F = pydynrad.form_factors(scene, resolution=8, device=device, progress=False)
    store = compute_store(
        scene,
        tmp_path / "ff",
        resolution=8,
        block_rows=8,
        progress=False,
        row_function=lambda scene, rows, resolution, device=None: F[rows],
    )
    # The same patch count, another geometry: its F would give this scene wrong components.
    moved = pydynrad.Scene(box_scene(2).vertices * [1.0, 2.0, 1.0], scene.faces, name="stretched box")
    with pytest.raises(pydynrad.InvalidInputError, match="another scene geometry"):
        light_components_by_hemicube(moved, store=store)
    with pytest.raises(pydynrad.InvalidInputError, match="rows; the scene has"):
        light_components_by_hemicube(box_scene(3), store=store)
    store.block_path(1).unlink()
    with pytest.raises(StoreIncompleteError, match="1 of 6 blocks missing"):
        light_components_by_hemicube(scene, store=store)


def test_store_records_only_the_basis_its_prolongation_has(tmp_path):
    from pydynrad.rows.store import FormFactorStore

    scene = box_scene(2)
    cl = cluster_patches(scene, 12)
    store = FormFactorStore.create(scene, tmp_path / "ff", resolution=8, block_rows=8)
    for pr, basis in ((cl.labels, "quadratic"), (cl.labels, "linear"), (basis_prolongation(scene, cl), "indicator")):
        # The indicator of 12 clusters read as linear would give 4 clusters of merged labels.
        with pytest.raises(pydynrad.InvalidInputError, match="basis"):
            store.set_clusters(pr, resolution=8, basis=basis)
    assert not store.has_clusters
    store.set_clusters(basis_prolongation(scene, cl), resolution=8, basis="linear")
    assert store.cluster_count == cl.count and np.array_equal(store.cluster_labels(), cl.labels)


def test_linear_basis_refuses_clusters_of_another_patch_count():
    scene = box_scene(2)
    with pytest.raises(pydynrad.InvalidInputError, match="cluster labels must be 48 integers"):
        basis_prolongation(scene, cluster_patches(box_scene(3)), "linear")


def test_linear_basis_drops_a_direction_that_is_only_rounding():
    """A cluster whose centres lie on a line across one of its tangents, far from the origin:
    their projections on that tangent agree to rounding (1e-10 at 1e6), which normalised to
    [0, 1] became a coordinate of noise (0, 0.25, 0.5 on main); it is dropped: that hat is 0."""
    from pydynrad.farfield.clusters import NORMAL_BINS, Clusters, _tangents

    bin_normal = NORMAL_BINS[np.argmax(NORMAL_BINS @ np.ones(3))]  # a diagonal bin: tangents off the axes
    t1, t2 = (t[0] for t in _tangents(bin_normal[None]))
    offset = np.array([1e6, -2e6, 3e6]) + 0.1
    points, triangles = [], []
    for i in range(8):
        c = offset + 0.7 * i * t2
        points += [c + 0.1 * t1, c - 0.05 * t1 + 0.0866 * t2, c - 0.05 * t1 - 0.0866 * t2]
        triangles.append([3 * i, 3 * i + 1, 3 * i + 2])
    scene = pydynrad.Scene(np.array(points), np.array(triangles))
    Pr, _ = linear_basis(Clusters.from_labels(scene, np.zeros(8, dtype=int)), scene)
    P = Pr.toarray()
    assert np.all(P[:, 1] == 0.0)  # across the line: nothing
    np.testing.assert_allclose(P[:, 2], np.arange(8) / 7 / 2, atol=1e-6)  # along it: the hat, to float32


def test_without_f_the_far_field_answers_no_negative_light(device, tmp_path):
    """veach_ajar (a real scene: a lamp behind an ajar door) from a store: the linear basis of the
    far field without F undershot below 0 on a patch where its cluster's light falls off steeply
    (-0.22 of 1000 at R = 24); light is not negative, so the answer is clamped, and the renderer,
    which refuses negative radiosity, draws it. Refined to the tolerance, it needs no clamp."""
    import warnings

    from pydynrad.rows.files import open_form_factors

    corpus = Path(__file__).resolve().parents[2] / "bench" / "data" / "corpus"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the file's own clamped albedos and missing textures
        scene = pydynrad.load(corpus / "veach_ajar" / "veach_ajar.obj")
    store_of(scene, pydynrad.form_factors(scene, resolution=24, device=device, progress=False), tmp_path / "ff", 24)
    L = pydynrad.light_vector(scene, device=device)
    obs = [4.05, 1.62, -2.31]
    dyn = DynamicRadiosity(
        scene, open_form_factors(scene, tmp_path / "ff"), local_size=1024, observer=obs, device=device, tolerance=None
    )
    B = dyn.radiosity(light=L)
    assert B.min() >= 0.0
    camera = pydynrad.Camera(obs, [0.0, 1.6, -2.8], (0, 1, 0), 60.0, 32, 24)
    assert np.isfinite(pydynrad.render(scene, B, camera, device=device)).all()
