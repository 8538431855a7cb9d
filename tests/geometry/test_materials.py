"""Materials as the formats define them: textures, vertex colours and factors read as
area means over each patch's footprint, against references computed here independently.

The reference of a patch is the mean over its footprint of the texture as texels (a piecewise-
constant image, each 8-bit value sRGB-decoded by the formula written out below), times the
factor and the vertex colour interpolated linearly, integrated on a fine barycentric grid
(64^2 sub-triangles): nothing of pydynrad's sampler (mip levels, bilinear lookups) is used.
"""

import base64
import io
import json
import warnings

import numpy as np
import pytest
from PIL import Image

import pydynrad
from pydynrad.geometry.loading import MAX_ALBEDO, AlbedoClampedWarning

N_TEX = 64


def _decode(c8):
    c = np.asarray(c8, float) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def checkerboard(n=N_TEX, checks=4, a=(230, 40, 90), b=(30, 200, 120)):
    """(n, n, 3) uint8: a checks x checks board, row 0 at the image's top."""
    i = np.arange(n) * checks // n
    odd = (i[:, None] + i[None, :]) % 2 == 1
    return np.where(odd[..., None], np.array(b, np.uint8), np.array(a, np.uint8)).astype(np.uint8)


def gradient(n=N_TEX):
    """(n, n, 3) uint8: red ramps left to right, green bottom to top, blue constant."""
    ramp = np.round(np.linspace(10, 245, n)).astype(np.uint8)
    img = np.zeros((n, n, 3), np.uint8)
    img[..., 0] = ramp[None, :]
    img[..., 1] = ramp[::-1, None]
    img[..., 2] = 128
    return img


def png(img) -> bytes:
    out = io.BytesIO()
    Image.fromarray(img).save(out, format="PNG")
    return out.getvalue()


def reference_mean(img8, uv, colours=None, factor=(1.0, 1.0, 1.0), wrap="repeat", k=64):
    """Area mean over the UV triangle ``uv`` (3, 2) (v up) of factor x colour x texel value."""
    factor = np.asarray(factor, dtype=np.float64)
    lin = _decode(img8)
    h, w = lin.shape[:2]
    i, j = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    keep = i + j < k
    b1 = np.concatenate([(i[keep] + 1 / 3) / k, (i[keep & (i + j < k - 1)] + 2 / 3) / k])
    b2 = np.concatenate([(j[keep] + 1 / 3) / k, (j[keep & (i + j < k - 1)] + 2 / 3) / k])
    bary = np.stack([1 - b1 - b2, b1, b2], axis=1)
    p = bary @ uv
    x = np.floor(p[:, 0] * w).astype(int)
    y = np.floor((1 - p[:, 1]) * h).astype(int)
    x, y = (np.mod(x, w), np.mod(y, h)) if wrap == "repeat" else (np.clip(x, 0, w - 1), np.clip(y, 0, h - 1))
    values = lin[y, x]
    if colours is not None:
        values = values * (bary @ colours)
    return factor * values.mean(axis=0)


# -- a quad in the xz plane (y up), UV [0, 1]^2 -----------------------------------------------------
QUAD = np.array([[0, 0, 0], [1, 0, 0], [1, 0, -1], [0, 0, -1]], float)  # faces +y
QUAD_UV = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]])


def write_gltf(
    path,
    img8,
    factor=(1, 1, 1, 1),
    colours=None,
    emissive=None,
    emissive_img=None,
    strength=None,
    wrap=10497,
    uv=QUAD_UV,
):
    """A .gltf (one quad, embedded buffers and images) with the given material."""
    blob = bytearray()
    views, accessors = [], []

    def add(a, comp, typ):
        data = np.ascontiguousarray(a).tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        blob.extend(data + b"\0" * (-len(data) % 4))
        acc = {"bufferView": len(views) - 1, "componentType": comp, "count": len(a), "type": typ}
        if typ == "VEC3" and comp == 5126 and not accessors:
            acc.update(min=a.min(0).tolist(), max=a.max(0).tolist())
        accessors.append(acc)
        return len(accessors) - 1

    attrs = {"POSITION": add(QUAD.astype(np.float32), 5126, "VEC3")}
    gl_uv = uv.copy()
    gl_uv[:, 1] = 1.0 - gl_uv[:, 1]  # glTF's v runs down from the image's top
    attrs["TEXCOORD_0"] = add(gl_uv.astype(np.float32), 5126, "VEC2")
    if colours is not None:
        attrs["COLOR_0"] = add(np.asarray(colours, np.float32), 5126, "VEC3")
    indices = add(QUAD_FACES.astype(np.uint32).ravel(), 5125, "SCALAR")
    images = [{"uri": "data:image/png;base64," + base64.b64encode(png(img8)).decode()}]
    material = {
        "name": "painted",
        "pbrMetallicRoughness": {"baseColorFactor": list(factor), "baseColorTexture": {"index": 0}},
    }
    if emissive is not None:
        material["emissiveFactor"] = list(emissive)
    if emissive_img is not None:
        images.append({"uri": "data:image/png;base64," + base64.b64encode(png(emissive_img)).decode()})
        material["emissiveTexture"] = {"index": 1}
    if strength is not None:
        material["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
    doc = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": attrs, "indices": indices, "material": 0}]}],
        "materials": [material],
        "images": images,
        "samplers": [{"wrapS": wrap, "wrapT": wrap}],
        "textures": [{"source": k, "sampler": 0} for k in range(len(images))],
        "buffers": [
            {
                "byteLength": len(blob),
                "uri": "data:application/octet-stream;base64," + base64.b64encode(bytes(blob)).decode(),
            }
        ],
        "bufferViews": views,
        "accessors": accessors,
    }
    path.write_text(json.dumps(doc))
    return path


def write_obj(tmp_path, img8, kd="0.8 0.6 0.9", ke=None, ke_img=None, uv=QUAD_UV, name="room"):
    Image.fromarray(img8).save(tmp_path / "albedo.png")
    mtl = f"newmtl painted\nKd {kd}\nmap_Kd albedo.png\n"
    if ke is not None:
        mtl += f"Ke {ke}\n"
    if ke_img is not None:
        Image.fromarray(ke_img).save(tmp_path / "glow.png")
        mtl += "map_Ke glow.png\n"
    (tmp_path / f"{name}.mtl").write_text(mtl)
    lines = [f"mtllib {name}.mtl"] + [f"v {x} {y} {z}" for x, y, z in QUAD] + [f"vt {u} {v}" for u, v in uv]
    lines += ["usemtl painted", "f 1/1 2/2 3/3", "f 1/1 3/3 4/4"]
    path = tmp_path / f"{name}.obj"
    path.write_text("\n".join(lines) + "\n")
    return path


def patch_uv(scene):
    """(N, 3, 2) each patch's corner UVs, from its corners' positions on the quad (u = x, v = -z)."""
    v = scene.triangles
    return np.stack([v[..., 0], -v[..., 2]], axis=-1)


def patch_colours(scene, corner_colours):
    """(N, 3, 3) the vertex colours at each patch corner, bilinear on the quad (exact on its triangles)."""
    uv = patch_uv(scene)
    c = np.asarray(corner_colours, float)
    u, w = uv[..., :1], uv[..., 1:]
    # the quad's two triangles: (0,1,2) where u >= v, (0,2,3) where v >= u; linear on each
    lower = c[0] + u * (c[1] - c[0]) + w * (c[2] - c[1])
    upper = c[0] + w * (c[3] - c[0]) + u * (c[2] - c[3])
    centre = uv.mean(axis=1, keepdims=True)
    return np.where(centre[..., :1] >= centre[..., 1:], lower, upper)


@pytest.mark.parametrize("image", ["checkerboard", "gradient"])
@pytest.mark.parametrize("fmt", ["gltf", "obj"])
def test_every_patch_gets_its_footprints_mean(tmp_path, fmt, image):
    img = checkerboard() if image == "checkerboard" else gradient()
    colours = np.array([[0.1, 0.2, 0.8], [0.9, 0.9, 0.9], [0.5, 1.0, 0.3], [1.0, 0.4, 0.6]]) if fmt == "gltf" else None
    factor = np.array([0.7, 0.5, 0.9]) if fmt == "gltf" else np.array([0.8, 0.6, 0.9])
    path = (
        write_gltf(tmp_path / "quad.gltf", img, factor=(*factor, 1.0), colours=colours)
        if fmt == "gltf"
        else write_obj(tmp_path, img)
    )
    for max_edge in (None, 0.75, 0.3):
        scene = pydynrad.load(path, max_edge=max_edge)
        uv = patch_uv(scene)
        cols = None if colours is None else patch_colours(scene, colours)
        expected = np.array(
            [reference_mean(img, uv[k], None if cols is None else cols[k], factor) for k in range(len(scene))]
        )
        np.testing.assert_allclose(scene.albedo, expected, rtol=0.01, atol=1e-4)
        assert scene.albedo.dtype == np.float32 and scene.albedo.max() < MAX_ALBEDO


def test_a_split_patch_gets_its_own_halfs_mean(tmp_path):
    # Left half of the texture dark, right half light: the quad's triangles each see both halves,
    # and after one split every child lies in one half (or straddles it by a known share).
    img = np.zeros((N_TEX, N_TEX, 3), np.uint8)
    img[:, : N_TEX // 2] = (40, 40, 40)
    img[:, N_TEX // 2 :] = (200, 150, 100)
    path = write_obj(tmp_path, img, kd="1 1 1")
    whole = pydynrad.load(path)
    split = pydynrad.load(path, max_edge=0.75)
    dark, light = _decode([40, 40, 40]), _decode([200, 150, 100])
    # Triangle (0,0)-(1,0)-(1,1) covers u < 1/2 on a quarter of its area: 1/4 dark, 3/4 light.
    np.testing.assert_allclose(whole.albedo[0], 0.25 * dark + 0.75 * light, rtol=0.01)
    assert len(split) == 8
    left = patch_uv(split)[..., 0].max(axis=1) <= 0.5 + 1e-9
    right = patch_uv(split)[..., 0].min(axis=1) >= 0.5 - 1e-9
    np.testing.assert_allclose(split.albedo[left], np.tile(dark, (left.sum(), 1)), rtol=0.01)
    np.testing.assert_allclose(split.albedo[right], np.tile(light, (right.sum(), 1)), rtol=0.01)
    # Area means are kept: the children's area-weighted albedo is their parent's.
    for face in range(2):
        rows = split.source_face == whole.source_face[face]
        w = split.areas[rows] / split.areas[rows].sum()
        np.testing.assert_allclose(w @ split.albedo[rows].astype(float), whole.albedo[face], rtol=0.01)


def test_factors_are_float_and_vertex_colours_count_under_a_material(tmp_path):
    white = np.full((4, 4, 3), 255, np.uint8)
    colours = np.tile([0.1, 0.2, 0.8], (4, 1))
    scene = pydynrad.load(write_gltf(tmp_path / "c.gltf", white, factor=(0.7, 0.7, 0.7, 1.0), colours=colours))
    # 0.7 x COLOR_0 (0.1, 0.2, 0.8) x white: not 8-bit 0.698, not the clamped white 0.999.
    np.testing.assert_allclose(scene.albedo, np.tile([0.07, 0.14, 0.56], (2, 1)), rtol=1e-6)


def test_clamp_wrap_and_emission(tmp_path):
    img = gradient()
    uv = QUAD_UV * 2.0 - 0.5  # UVs outside [0, 1]: the sampler decides
    for wrap, mode in ((10497, "repeat"), (33071, "clamp")):
        scene = pydynrad.load(write_gltf(tmp_path / f"w{wrap}.gltf", img, uv=uv, wrap=wrap))
        expected = [reference_mean(img, patch_uv(scene)[k] * 2.0 - 0.5, wrap=mode) for k in range(2)]
        np.testing.assert_allclose(scene.albedo, expected, rtol=0.01)
    glow = checkerboard(checks=2, a=(255, 255, 255), b=(0, 0, 0))
    scene = pydynrad.load(
        write_gltf(tmp_path / "e.gltf", img, emissive=(1.0, 0.5, 0.25), emissive_img=glow, strength=40.0)
    )
    expected = [reference_mean(glow, patch_uv(scene)[k], factor=40.0 * np.array([1.0, 0.5, 0.25])) for k in range(2)]
    np.testing.assert_allclose(scene.emission, expected, rtol=0.01)
    scene = pydynrad.load(write_obj(tmp_path, img, ke="3 2 1", ke_img=glow, name="lamp"))
    expected = [reference_mean(glow, patch_uv(scene)[k], factor=np.array([3.0, 2.0, 1.0])) for k in range(2)]
    np.testing.assert_allclose(scene.emission, expected, rtol=0.01)


def test_white_is_clamped_with_one_warning_naming_the_material(tmp_path):
    white = np.full((8, 8, 3), 255, np.uint8)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        scene = pydynrad.load(write_obj(tmp_path, white, kd="1 1 1"), max_edge=0.3)
    clamped = [w for w in caught if issubclass(w.category, AlbedoClampedWarning)]
    assert len(clamped) == 1 and "'painted'" in str(clamped[0].message)
    assert scene.albedo.max() == pytest.approx(MAX_ALBEDO)
    summary = scene.summary()
    assert "painted" in summary and "clamped" in summary and "albedo.png" in summary


def test_summary_lists_materials(tmp_path):
    scene = pydynrad.load(write_gltf(tmp_path / "s.gltf", gradient(), colours=np.ones((4, 3))), report=False)
    text = scene.summary()
    assert "painted" in text and "albedo texture" in text and "unit m" in text and "COLOR_0" in text
    assert scene.materials.index.shape == (len(scene),)
