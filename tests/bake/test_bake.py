"""Baked meshes and lightmaps, read back by other tools' readers (trimesh, OpenImageIO)."""

import json
import struct

import numpy as np
import pytest
import trimesh

import pydynrad
from pydynrad import InvalidInputError, bake_lightmap, export_mesh
from pydynrad.bake.gltf import read_glb
from pydynrad.bake.ply import read_ply
from pydynrad.errors import OutOfMemoryError
from pydynrad.renderer import Renderer


@pytest.fixture(scope="module")
def solved(device):
    """The Cornell box at 384 patches with its full float64 radiosity."""
    scene = pydynrad.scenes.cornell_box(max_edge=200.0)
    F = pydynrad.form_factors(scene, resolution=16, device=device)
    return scene, pydynrad.solve(scene, F, method="dense").radiosity


def _srgb(x):
    """IEC 61966-2-1 encoding, written out independently of pydynrad.image_io."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def _load_one(path):
    """The single mesh of a file, as trimesh loads it (no merging of vertices)."""
    loaded = trimesh.load(path, process=False)
    return next(iter(loaded.geometry.values())) if isinstance(loaded, trimesh.Scene) else loaded


def test_glb_round_trip_holds_the_smooth_vertex_radiosity(solved, tmp_path):
    scene, B = solved
    path = export_mesh(scene, B, tmp_path / "box.glb", exposure=-6.0)
    mesh = _load_one(path)
    # Triangle i is patch i, in metres +y up (glTF's convention; the box is in millimetres,
    # y up, so scaled only; glTF holds float32).
    np.testing.assert_allclose(mesh.vertices[mesh.faces], scene.triangles * scene.unit, rtol=1e-6, atol=1e-9)
    radiosity = np.asarray(mesh.vertex_attributes["_RADIOSITY"])
    # Every corner carries what smooth shading interpolates there, to float32 rounding.
    corners = Renderer(scene).corner_radiosity(B)
    np.testing.assert_allclose(radiosity[mesh.faces], corners, rtol=2e-7, atol=0)
    colour = np.asarray(mesh.visual.vertex_attributes["color"], dtype=np.float64)
    np.testing.assert_allclose(colour[:, :3], np.clip(radiosity * 2.0**-6, 0, 1), rtol=1e-6, atol=1e-7)
    doc, _, _ = read_glb(path.read_bytes())
    meta = doc["asset"]["extras"]["pydynrad"]
    assert meta["exposure"] == -6.0 and meta["patches"] == len(scene)


def test_vertices_split_at_creases_and_material_borders_only(solved, tmp_path):
    scene, B = solved
    mesh = _load_one(export_mesh(scene, B, tmp_path / "box.glb"))
    faces = np.asarray(mesh.faces)
    vertex_face = np.repeat(np.arange(len(scene)), 3)
    order = np.argsort(faces.reshape(-1), kind="stable")
    v = faces.reshape(-1)[order]
    first = vertex_face[order][np.searchsorted(v, v)]  # one face of each vertex
    other = vertex_face[order]
    # Faces sharing a vertex have one material and normals within the crease angle.
    assert np.all(np.abs(scene.albedo[first] - scene.albedo[other]) <= 1e-6)
    assert np.all(np.einsum("ij,ij->i", scene.normals[first], scene.normals[other]) >= np.cos(np.radians(30)) - 1e-6)
    # ...and no more splits than that: the white floor's corners share vertices.
    floor = np.flatnonzero((scene.normals[:, 1] > 0.99) & (scene.centers[:, 1] < 1) & (scene.albedo[:, 1] > 0.6))
    assert len(np.unique(faces[floor])) < 3 * len(floor) / 2


def test_ply_carries_linear_floats_and_exposed_srgb_8bit(solved, tmp_path):
    scene, B = solved
    path = export_mesh(scene, B, tmp_path / "box.ply", exposure=-5.0)
    mesh = _load_one(path)
    comments, props, faces = read_ply(path.read_bytes())
    linear = np.stack([props[f"radiosity_{c}"] for c in "rgb"], axis=1).astype(np.float64)
    corners = Renderer(scene).corner_radiosity(B)
    np.testing.assert_allclose(linear[np.asarray(mesh.faces)], corners, rtol=2e-7)
    expected = np.round(_srgb(linear * 2.0**-5) * 255)
    np.testing.assert_array_equal(np.asarray(mesh.visual.vertex_colors)[:, :3], expected)
    assert "pydynrad exposure: -5.0" in comments
    assert any("sRGB" in c for c in comments)


def test_export_refuses_bad_input(solved, tmp_path):
    scene, B = solved
    with pytest.raises(InvalidInputError, match=r"shape \(384,\)"):
        export_mesh(scene, B[:-1], tmp_path / "a.glb")
    bad = B.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InvalidInputError, match="NaN|finite"):
        export_mesh(scene, bad, tmp_path / "a.glb")
    with pytest.raises(InvalidInputError, match=r"\.glb, \.ply"):
        export_mesh(scene, B, tmp_path / "a.obj")
    with pytest.raises(InvalidInputError, match="does not exist"):
        export_mesh(scene, B, tmp_path / "missing" / "a.glb")
    assert list(tmp_path.iterdir()) == []


def test_damaged_glb_and_ply_are_named_as_such(solved, tmp_path):
    scene, B = solved
    data = export_mesh(scene, B, tmp_path / "a.glb").read_bytes()
    with pytest.raises(InvalidInputError, match="not a pydynrad GLB"):
        read_glb(data[:-8])
    # A count of -1 (it had read the whole buffer) or past the buffer, in a file of the right length.
    n_json = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + n_json])
    for count in (-1, 10**30):
        doc["accessors"][0]["count"] = count
        text = json.dumps(doc).encode()
        text += b" " * (-len(text) % 4)
        rest = data[20 + n_json :]
        forged = struct.pack("<III", 0x46546C67, 2, 20 + len(text) + len(rest)) + struct.pack(
            "<II", len(text), 0x4E4F534A
        )
        with pytest.raises(InvalidInputError, match="count"):
            read_glb(forged + text + rest)
    data = export_mesh(scene, B, tmp_path / "a.ply").read_bytes()
    with pytest.raises(InvalidInputError, match="not a pydynrad PLY"):
        read_ply(data[:-8])
    with pytest.raises(InvalidInputError, match="negative element counts"):
        read_ply(data.replace(f"element face {len(scene)}".encode(), b"element face -1", 1))


@pytest.fixture(scope="module")
def lightmap(solved):
    scene, B = solved
    return bake_lightmap(scene, B, texels_per_unit=0.1)  # one texel per cm: 177 x 166 texels


def _texel_centres_inside(lm):
    """(triangle, texel, barycentrics) of every texel centre strictly inside a lightmap
    triangle, triangle by triangle over its bounding box."""
    h, w = lm.shape
    out = []
    for tri, (a, b, c) in enumerate((lm.uv.astype(np.float64) * [w, h])[lm.faces]):
        lo = np.floor(np.minimum(np.minimum(a, b), c)).astype(int)
        hi = np.ceil(np.maximum(np.maximum(a, b), c)).astype(int)
        y, x = np.mgrid[lo[1] : hi[1], lo[0] : hi[0]]
        p = np.stack([x.ravel() + 0.5, y.ravel() + 0.5], axis=1)
        st = np.linalg.solve(np.stack([b - a, c - a], axis=1), (p - a).T).T
        bary = np.concatenate([1 - st.sum(axis=1, keepdims=True), st], axis=1)
        inside = bary.min(axis=1) > 1e-6
        out.append((np.full(inside.sum(), tri), (y.ravel() * w + x.ravel())[inside], bary[inside]))
    return [np.concatenate(parts) for parts in zip(*out)]


def test_every_texel_centre_inside_a_chart_holds_its_triangles_interpolation(lightmap):
    lm = lightmap
    tri, texel, bary = _texel_centres_inside(lm)
    assert len(np.unique(texel)) == len(texel)  # charts never overlap
    assert len(texel) > 0.8 * lm.covered.sum()  # the rest: texels a chart's outline only crosses
    expected = np.einsum("pk,pkc->pc", bary, lm.vertex_radiosity[lm.faces[tri]])
    image = lm.image.reshape(-1, 3)
    np.testing.assert_allclose(image[texel], expected, rtol=2e-6)
    assert lm.covered.reshape(-1)[texel].all() and lm.filled.reshape(-1)[texel].all()


def _touched_texels(lm, k: int = 24):
    """(x, y, points per triangle) of the texels under points spread over each lightmap
    triangle, edges included, triangle by triangle."""
    h, w = lm.shape
    t = (lm.uv.astype(np.float64) * [w, h])[lm.faces]
    i, j = np.mgrid[0 : k + 1, 0 : k + 1]
    keep = i + j <= k
    bary = np.stack([i[keep], j[keep], k - i[keep] - j[keep]], axis=1) / k
    pts = np.einsum("sk,tkd->tsd", bary, t).reshape(-1, 2)
    x = np.clip(np.floor(pts[:, 0]).astype(int), 0, w - 1)
    y = np.clip(np.floor(pts[:, 1]).astype(int), 0, h - 1)
    return x, y, len(bary)


def test_every_texel_a_triangle_touches_is_covered(lightmap):
    lm = lightmap
    h, w = lm.shape
    t = (lm.uv.astype(np.float64) * [w, h])[lm.faces]
    x, y, _ = _touched_texels(lm)
    assert lm.covered[y, x].all()
    # ...and not many more: the charts' area in texels plus a band along their borders.
    uv_area = (
        0.5
        * np.abs(
            np.cross(np.pad(t[:, 1] - t[:, 0], ((0, 0), (0, 1))), np.pad(t[:, 2] - t[:, 0], ((0, 0), (0, 1))))[:, 2]
        ).sum()
    )
    assert uv_area < lm.covered.sum() < 1.1 * uv_area


def test_charts_end_at_material_borders(device):
    """The village's roads meet its grass in one plane: xatlas alone joins them into one chart,
    and bilinear lookups there mixed road and grass (a 14% seam in bench/bake.py)."""
    scene = pydynrad.scenes.village(houses=1, detail=0.25)
    lm = bake_lightmap(scene, np.ones(len(scene)), texels_per_unit=2.0)
    h, w = lm.shape
    x, y, per_triangle = _touched_texels(lm, k=8)
    # No texel a bilinear lookup reads (within one texel) is shared by two surfaces: charts
    # end at creases and material borders, where the smooth vertices split.
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    corner = lm.vertex[lm.faces]  # smooth vertex of each corner
    graph = coo_matrix(
        (np.ones(corner.size), (corner.reshape(-1), np.roll(corner, 1, axis=1).reshape(-1))),
        shape=(lm.vertex.max() + 1,) * 2,
    )
    surface = connected_components(graph, directed=False)[1][corner[:, 0]]
    owner = np.full((h + 2, w + 2), -1)
    point_surface = np.repeat(surface, per_triangle)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            seen = owner[y + dy, x + dx]
            assert np.all((seen == -1) | (seen == point_surface))
            owner[y + dy, x + dx] = point_surface


def test_dilation_fills_the_padding(lightmap):
    from scipy.ndimage import binary_dilation

    lm = lightmap
    reach = binary_dilation(lm.covered, np.ones((3, 3), bool), iterations=lm.padding)
    assert lm.filled[reach].all()
    # Dilated values are means of neighbours: within the range of the charts' values.
    lo, hi = lm.image[lm.covered].min(axis=0), lm.image[lm.covered].max(axis=0)
    grown = lm.image[lm.filled & ~lm.covered]
    assert np.all(grown >= lo - 1e-6 * hi) and np.all(grown <= hi * (1 + 1e-6))
    assert np.all(lm.image[~lm.filled] == 0)


def test_lightmap_at_patch_centres_is_the_smooth_radiosity(solved, lightmap):
    scene, B = solved
    n = len(scene)
    got = lightmap.sample(lightmap.patch_uv(np.arange(n), np.full((n, 3), 1 / 3)))
    smooth = Renderer(scene).corner_radiosity(B).astype(np.float64).mean(axis=1)
    np.testing.assert_allclose(got, smooth, rtol=0, atol=1e-5 * smooth.max())
    # A constant radiosity comes back constant everywhere a filter can read.
    flat = bake_lightmap(scene, np.full(n, 2.5), texels_per_unit=0.05)
    np.testing.assert_allclose(flat.image[flat.filled], 2.5, rtol=1e-7)


def test_lightmap_files_rendered_through_their_uvs_match_render(solved, lightmap, tmp_path, device):
    """A viewer's view: the GLB's second UV set and the EXR, read back by trimesh and
    OpenImageIO, looked up bilinearly (scipy, clamp to edge) at every pixel's surface point."""
    from scipy.ndimage import map_coordinates

    scene, B = solved
    exr = lightmap.write(tmp_path / "box.exr")
    glb = lightmap.write_mesh(tmp_path / "box.glb", image_name=exr.name)
    _, attributes, faces = read_glb(glb.read_bytes())
    np.testing.assert_array_equal(attributes["TEXCOORD_1"], attributes["TEXCOORD_0"])
    mesh = _load_one(glb)
    uv = np.asarray(mesh.visual.uv, dtype=np.float64).copy()
    uv[:, 1] = 1.0 - uv[:, 1]  # trimesh moves glTF's top-left origin to the bottom left
    np.testing.assert_allclose(uv, attributes["TEXCOORD_1"], atol=1e-7)
    image = pydynrad.image_io.read_image(exr)
    np.testing.assert_array_equal(image, lightmap.image)
    h, w = image.shape[:2]

    camera = pydynrad.Camera((278, 273, -800), (278, 273, 0), (0, 1, 0), 39.3, 96, 72)
    renderer = Renderer(scene, device)
    vis = renderer.visibility(camera)
    reference = renderer.shade(vis, B)
    front = vis.front
    p = np.einsum("pk,pkd->pd", vis.barycentric[front].astype(np.float64), uv[faces[vis.patch[front]]])
    coords = [p[:, 1] * h - 0.5, p[:, 0] * w - 0.5]
    looked_up = np.stack([map_coordinates(image[:, :, c], coords, order=1, mode="nearest") for c in range(3)], axis=1)
    rel = np.abs(looked_up - reference[front]).max(axis=1) / reference[front].max(axis=1)
    # Exact inside triangles; a few percent where a lookup straddles a kink between triangles.
    assert np.median(rel) < 1e-6
    assert np.mean(rel) < 2e-3 and rel.max() < 0.1


def test_lightmap_refuses_bad_input(solved, lightmap, tmp_path):
    scene, B = solved
    with pytest.raises(InvalidInputError, match="shape"):
        bake_lightmap(scene, B[:10], texels_per_unit=0.1)
    with pytest.raises(InvalidInputError, match="texels_per_unit"):
        bake_lightmap(scene, B, texels_per_unit=0.0)
    with pytest.raises(InvalidInputError, match="padding"):
        bake_lightmap(scene, B, texels_per_unit=0.1, padding=0)
    # 1.9 m^2 at 1000 texels per mm would be 1.9e12 texels: refused before the atlas is built.
    with pytest.raises(OutOfMemoryError, match="texels_per_unit"):
        bake_lightmap(scene, B, texels_per_unit=1000.0)
    with pytest.raises(InvalidInputError, match="linear radiosity"):
        lightmap.write(tmp_path / "lm.png")
    with pytest.raises(InvalidInputError, match=r"\.glb"):
        lightmap.write_mesh(tmp_path / "lm.ply")
    assert list(tmp_path.iterdir()) == []


def test_lightmap_mesh_embeds_the_exposed_srgb_lightmap_for_viewers(lightmap, tmp_path):
    mesh = _load_one(lightmap.write_mesh(tmp_path / "box.glb", exposure=-6.0))
    texture = np.asarray(mesh.visual.material.baseColorTexture.convert("RGB"))
    np.testing.assert_array_equal(texture, np.round(_srgb(lightmap.image.astype(np.float64) * 2.0**-6) * 255))
    doc, attributes, _ = read_glb((tmp_path / "box.glb").read_bytes())
    assert doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["texCoord"] == 1
    assert "COLOR_0" not in attributes and "sRGB" in doc["asset"]["extras"]["pydynrad"]["lightmap"]["embedded"]
    # Without the texture, the vertex colours take its place.
    _, attributes, _ = read_glb(lightmap.write_mesh(tmp_path / "plain.glb", embed=False).read_bytes())
    assert "COLOR_0" in attributes and "images" not in read_glb((tmp_path / "plain.glb").read_bytes())[0]
