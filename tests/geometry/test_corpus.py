"""The real third-party scenes of bench/data/corpus, loaded and checked against the
values read off the files independently (corpus.json, made by its own stats.py), and the
Stanford bunny read straight from its .obj.gz."""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import pydynrad
from pydynrad.geometry.scene import DegenerateTriangleWarning

CORPUS = Path(__file__).resolve().parents[2] / "bench" / "data" / "corpus"
FACTS = {s["name"]: s for s in json.loads((CORPUS / "corpus.json").read_text())["scenes"]}
FAST = ["cornell_box", "veach_ajar", "kenney_retro_urban"]


def _srgb_decode(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _load(name):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = pydynrad.load(CORPUS / FACTS[name]["file"])
    dropped = sum(int(str(w.message).split()[1]) for w in caught if issubclass(w.category, DegenerateTriangleWarning))
    return scene, dropped


def _check(name):
    facts = FACTS[name]
    scene, dropped = _load(name)
    # Counts: every triangle of the file is a patch, or a zero-area one dropped and counted.
    assert len(scene) + dropped == facts["triangles"]
    assert dropped < 0.03 * facts["triangles"]  # zero-area triangles the kits and files do hold
    assert scene.unit == 1.0 and scene.up.tolist() == [0.0, 1.0, 0.0]  # the defaults (glTF's by its spec)
    table = scene.materials
    names = [m.name for m in table.materials]
    assert sorted(names) == sorted(facts["per_material"])
    areas = scene.areas.astype(np.float64)
    for k, m in enumerate(table.materials):
        rows = table.index == k
        per = facts["per_material"][m.name]
        mean = areas[rows] @ scene.albedo[rows].astype(np.float64) / areas[rows].sum()
        factor = np.asarray(per.get("Kd", per.get("baseColorFactor", [1, 1, 1]))[:3], float)
        if "texture" not in per:  # a plain colour: exactly the file's (clamped below 1)
            np.testing.assert_allclose(
                scene.albedo[rows], np.tile(np.minimum(factor, 0.999), (rows.sum(), 1)), rtol=1e-6
            )
        else:  # textured: the texture is read (not the factor's white), near the image's own mean
            assert m.albedo_texture is not None and m.albedo_texture.size == tuple(per["texture"]["size"])
            np.testing.assert_allclose(m.albedo_texture.mean, per["texture"]["mean_linear"], atol=2e-5)
            assert np.all(mean < 0.9) and np.all(mean > 0)
        emitting = np.asarray(per.get("Ke", [0, 0, 0]), float)
        np.testing.assert_allclose(scene.emission[rows], np.tile(emitting, (rows.sum(), 1)), rtol=1e-6)
    emitters = {names[i] for i in np.unique(table.index[scene.emitters])}
    assert emitters == set(facts["emissive_materials"])
    return scene


@pytest.mark.parametrize("name", FAST)
def test_corpus_scene_as_read(name):
    _check(name)


@pytest.mark.slow
def test_the_largest_corpus_scene_as_read():
    _check("kenney_suburb")


def test_textured_means_against_a_texel_reference():
    """Veach, Ajar's textured materials: each patch's albedo against the texels under its UV
    triangle, decoded here by the IEC 61966-2-1 formula, nearest texel on a fine grid."""
    scene, _ = _load("veach_ajar")
    import trimesh

    loaded = trimesh.load(CORPUS / FACTS["veach_ajar"]["file"], process=False)
    for k, m in enumerate(scene.materials.materials):
        if m.albedo_texture is None:
            continue
        geometry = next(g for g in loaded.geometry.values() if g.visual.material.name == m.name)
        img = np.asarray(geometry.visual.material.image.convert("RGB"), float) / 255.0
        lin = _srgb_decode(img)
        h, w = lin.shape[:2]
        g = 48
        i, j = np.meshgrid(np.arange(g), np.arange(g), indexing="ij")
        keep = i + j < g
        b = np.stack([(i[keep] + 1 / 3) / g, (j[keep] + 1 / 3) / g], axis=1)
        bary = np.stack([1 - b.sum(1), b[:, 0], b[:, 1]], axis=1)
        uv = geometry.visual.uv[geometry.faces]  # (F, 3, 2), file order within the material
        rows = np.flatnonzero(scene.materials.index == k)
        assert len(rows) == len(uv)
        for row, tri in zip(rows, uv):
            p = bary @ tri
            x = np.mod(np.floor(p[:, 0] * w).astype(int), w)
            y = np.mod(np.floor((1 - p[:, 1]) * h).astype(int), h)
            expected = m.albedo * lin[y, x].mean(axis=0)
            np.testing.assert_allclose(scene.albedo[row], np.minimum(expected, 0.999), rtol=0.02, atol=2e-3)


def test_a_gzipped_obj_loads_in_file_order():
    path = CORPUS.parent / "stanford-bunny.obj.gz"
    import gzip

    text = gzip.decompress(path.read_bytes()).decode()
    faces = sum(1 for line in text.splitlines() if line.startswith("f "))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DegenerateTriangleWarning)
        scene = pydynrad.load(path)
    assert scene.name == "stanford-bunny" and len(scene) <= faces
    assert np.all(np.diff(scene.source_face) >= 0) and scene.source_face.max() < faces  # the file's order


@pytest.mark.slow
def test_corpus_bench_section_tiny(tmp_path, device):
    from bench import suite

    results, _ = suite.run_suite("tiny", ["corpus"], tmp_path, device=device, progress=False, strict=True)
    rows = results["sections"]["corpus"]["tables"][0]["rows"]
    assert [r[0] for r in rows] == ["cornell_box", "kenney_retro_urban"] and all(r[1] > 0 for r in rows)
