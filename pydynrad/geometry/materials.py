"""Materials as the file formats define them: each patch's albedo and emission as area means.

A patch's albedo is the mean, over the patch's own footprint on its source triangle, of

* glTF: ``baseColorFactor x COLOR_0 x baseColorTexture`` (the texture sRGB-decoded, sampled
  through ``TEXCOORD_0`` with its sampler's wrap modes);
* OBJ/MTL: ``Kd x map_Kd`` (the texture sRGB-decoded, repeating);

and its emission likewise: ``emissiveFactor x emissiveTexture x emissiveStrength``
(KHR_materials_emissive_strength) or ``Ke x map_Ke``. Everything is float64 from the files'
own numbers (glTF factors are read from the file's JSON: trimesh keeps them in 8 bits).

The mean is a quadrature: the footprint (a triangle in UV space) is cut into ``n^2`` equal
sub-triangles whose centroids read the texel containing them (the image as texels, each a box)
in a mip level of the texture (2x2 box averages, so every level keeps the image's area means),
``n`` growing with the footprint's size in texels up to :data:`MAX_GRID` and the level chosen
so that samples are about a texel apart: a large patch over a fine texture averages it instead
of aliasing, a small one reads the full-resolution texels. Where the texture's detail is finer
than the chosen level's texels, the texels cut by the footprint's edges count whole.

Images come decoded by trimesh (PIL), as it loads them; nothing here decodes a file format.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from functools import cache

import numpy as np

__all__ = ["Texture", "Material", "MaterialTable", "srgb_decode", "sample_materials", "scene_summary", "MAX_GRID"]

#: Most sub-triangles per side of a patch's footprint (MAX_GRID^2 samples).
MAX_GRID = 24
_WRAP = {10497: "repeat", 33071: "clamp", 33648: "mirror"}


def srgb_decode(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB-encoded values in [0, 1] -> linear."""
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


class Texture:
    """A texture image as linear RGB float32 with its mip levels and wrap modes.

    ``image``: a PIL image (as trimesh gives it) or an (H, W, C) array of values in [0, 1];
    ``srgb``: decode the values from sRGB (colour textures: glTF's base colour and emissive
    textures, MTL maps); ``wrap``: ("repeat" | "clamp" | "mirror") along u and v.
    """

    def __init__(self, image, name: str = "", srgb: bool = True, wrap=("repeat", "repeat")) -> None:
        self.name = str(name)
        self.wrap = tuple(wrap)
        px = _pixels(image)
        self.channels = px.shape[2]
        rgb = px[..., :3] if px.shape[2] >= 3 else np.repeat(px[..., :1], 3, axis=2)
        rgb = srgb_decode(rgb) if srgb else rgb
        self.levels = [np.ascontiguousarray(rgb, dtype=np.float32)]
        while max(self.levels[-1].shape[:2]) > 1:
            self.levels.append(_half(self.levels[-1], self.wrap))
        self.size = (px.shape[1], px.shape[0])  # (W, H)

    @property
    def mean(self) -> np.ndarray:
        """The linear RGB mean over the whole image."""
        return self.levels[0].reshape(-1, 3).mean(axis=0, dtype=np.float64)

    def sample(self, uv: np.ndarray, level: np.ndarray) -> np.ndarray:
        """RGB (M, 3) float64 of the texels containing ``uv`` (M, 2) (trimesh's convention: v up from
        the image's bottom row) in mip ``level`` (M,) int: the image as texels (a box each), whose
        area means the quadrature takes (a bilinear lookup would bleed the opposite edge of a
        repeating texture into a footprint at the image's border)."""
        out = np.empty((len(uv), 3))
        level = np.minimum(level, len(self.levels) - 1)
        # Beyond a clamped edge the texture is its edge texels of full resolution, not a coarse
        # level's averages of several rows.
        for axis in (0, 1):
            if self.wrap[axis] == "clamp":
                level = np.where((uv[:, axis] < 0.0) | (uv[:, axis] > 1.0), 0, level)
        for lv in np.unique(level):
            pick = np.flatnonzero(level == lv)
            img = self.levels[int(lv)]
            h, w = img.shape[:2]
            x = _wrapped(np.floor(uv[pick, 0] * w).astype(np.int64), w, self.wrap[0])
            y = _wrapped(np.floor((1.0 - uv[pick, 1]) * h).astype(np.int64), h, self.wrap[1])
            out[pick] = img[y, x]
        return out


def _pixels(image) -> np.ndarray:
    """(H, W, C) float64 values in [0, 1] of a PIL image or an array."""
    if hasattr(image, "mode") and hasattr(image, "convert"):  # PIL
        mode = image.mode
        if mode.startswith("I;16"):
            a = np.asarray(image, dtype=np.float64) / 65535.0
        elif mode in ("I", "F"):
            a = np.asarray(image, dtype=np.float64)
            a = a / (65535.0 if mode == "I" and a.max(initial=0) > 255 else (255.0 if mode == "I" else 1.0))
        else:
            keep = (
                mode
                if mode in ("RGB", "RGBA", "L", "LA")
                else ("RGBA" if "A" in mode or "transparency" in image.info else "RGB")
            )
            a = np.asarray(image.convert(keep), dtype=np.float64) / 255.0
    else:
        a = np.asarray(image, dtype=np.float64)
        if np.issubdtype(np.asarray(image).dtype, np.integer):
            a = a / float(np.iinfo(np.asarray(image).dtype).max)
    if a.ndim == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"a texture must be an image; got shape {a.shape}")
    if a.shape[2] == 2:  # grey + alpha
        a = a[:, :, :1]
    return np.clip(a, 0.0, 1.0)


def _half(img: np.ndarray, wrap) -> np.ndarray:
    """The next mip level: 2x2 box means (an odd row or column count padded by wrapping or clamping)."""
    h, w = img.shape[:2]
    if h > 1 and h % 2:
        img = np.concatenate([img, img[:1] if wrap[1] == "repeat" else img[-1:]], axis=0)
    if w > 1 and w % 2:
        img = np.concatenate([img, img[:, :1] if wrap[0] == "repeat" else img[:, -1:]], axis=1)
    h, w = img.shape[:2]
    if h > 1:
        img = 0.5 * (img[0::2] + img[1::2])
    if w > 1:
        img = 0.5 * (img[:, 0::2] + img[:, 1::2])
    return np.ascontiguousarray(img, dtype=np.float32)


def _wrapped(i: np.ndarray, n: int, mode: str) -> np.ndarray:
    if mode == "clamp":
        return np.clip(i, 0, n - 1)
    if mode == "mirror":
        period = np.mod(i, 2 * n)
        return np.where(period < n, period, 2 * n - 1 - period)
    return np.mod(i, n)


@dataclass
class Material:
    """One material as read: factors (linear RGB float64), textures, and notes on what was
    clamped or ignored. ``kind``: "gltf", "mtl", "face colours", "vertex colours" or "default"."""

    name: str
    kind: str
    albedo: np.ndarray
    emission: np.ndarray = field(default_factory=lambda: np.zeros(3))
    albedo_texture: Texture | None = None
    emission_texture: Texture | None = None
    notes: list = field(default_factory=list)

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)


@dataclass
class MaterialTable:
    """The materials of a loaded scene and each patch's material (``index`` (N,) into ``materials``)."""

    materials: list
    index: np.ndarray

    def take(self, rows) -> MaterialTable:
        return MaterialTable(self.materials, np.asarray(self.index)[rows])


@cache
def _grid(n: int) -> np.ndarray:
    """(n^2, 2) barycentric (b1, b2) of the centroids of a triangle's n x n equal sub-triangles."""
    out = []
    for i in range(n):
        for j in range(n - i):
            out.append(((i + 1 / 3) / n, (j + 1 / 3) / n))
            if i + j < n - 1:
                out.append(((i + 2 / 3) / n, (j + 2 / 3) / n))
    return np.array(out)


def _textured_mean(texture: Texture, uv: np.ndarray, colours: np.ndarray | None) -> np.ndarray:
    """(P, 3) area mean of texture x colour over each patch's UV triangle ``uv`` (P, 3, 2), the
    colour linear over the patch from its corners ``colours`` (P, 3, 3) (None: 1)."""
    w, h = texture.size
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    texels = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * (w * h)
    n = np.clip(np.ceil(2.0 * np.sqrt(texels)), 1, MAX_GRID).astype(np.int64)  # ~4 samples a texel
    spacing = np.sqrt(2.0 * texels) / n  # sample spacing, texels of level 0
    with np.errstate(divide="ignore"):
        # texels about twice the sample spacing: ~4 samples a texel, so that the regular sample
        # grid does not beat against the texel grid
        level = np.clip(np.round(np.log2(np.maximum(spacing, 1e-30))) - 1, 0, len(texture.levels) - 1).astype(np.int64)
    out = np.empty((len(uv), 3))
    for k in np.unique(n):
        pick = np.flatnonzero(n == k)
        b = _grid(int(k))  # (S, 2)
        weights = np.stack([1.0 - b.sum(axis=1), b[:, 0], b[:, 1]], axis=1)  # (S, 3)
        for start in range(0, len(pick), max(1, 200_000 // len(b))):  # bounded memory
            part = pick[start : start + max(1, 200_000 // len(b))]
            pts = np.matmul(weights, uv[part])  # (P, S, 2)
            lv = np.repeat(level[part], len(b))
            values = texture.sample(pts.reshape(-1, 2), lv).reshape(len(part), len(b), 3)
            if colours is not None:
                values = values * np.matmul(weights, colours[part])
            out[part] = values.mean(axis=1)
    return out


def barycentric_corners(parent_corners: np.ndarray, child_corners: np.ndarray) -> np.ndarray:
    """(P, 3, 3) weights of each child corner on its parent triangle's corners (both (P, 3, 3)
    positions; the child lies in the parent's plane)."""
    p0 = parent_corners[:, 0]
    e1, e2 = parent_corners[:, 1] - p0, parent_corners[:, 2] - p0
    d = child_corners - p0[:, None]
    g11, g12, g22 = (e1 * e1).sum(-1), (e1 * e2).sum(-1), (e2 * e2).sum(-1)
    det = g11 * g22 - g12 * g12
    r1, r2 = (d * e1[:, None]).sum(-1), (d * e2[:, None]).sum(-1)
    b1 = (g22[:, None] * r1 - g12[:, None] * r2) / det[:, None]
    b2 = (g11[:, None] * r2 - g12[:, None] * r1) / det[:, None]
    return np.stack([1.0 - b1 - b2, b1, b2], axis=-1)


def sample_materials(
    table: list,
    face_material: np.ndarray,
    face_uv: np.ndarray | None,
    face_colour: np.ndarray | None,
    weights: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Albedo and emission (P, 3) float64 of P patches.

    ``face_material`` (P,): each patch's material (into ``table``); ``face_uv`` (P, 3, 2) its source
    face's corner UVs (NaN where it has none); ``face_colour`` (P, 3, 3) its source face's corner
    colours (linear; None: white); ``weights`` (P, 3, 3): each patch corner's barycentric weights on
    its source face's corners.
    """
    n = len(face_material)
    albedo, emission = np.empty((n, 3)), np.empty((n, 3))
    colours = None if face_colour is None else np.einsum("pkc,pcd->pkd", weights, face_colour)
    uv = None if face_uv is None else np.einsum("pkc,pcd->pkd", weights, face_uv)
    for m, mat in enumerate(table):
        pick = np.flatnonzero(face_material == m)
        if not len(pick):
            continue
        col = None if colours is None else colours[pick]
        has_uv = uv is not None and np.all(np.isfinite(uv[pick]))
        for tex, factor, out, with_colour in (
            (mat.albedo_texture, mat.albedo, albedo, True),
            (mat.emission_texture, mat.emission, emission, False),
        ):
            c = col if with_colour else None
            if tex is not None and uv is not None and has_uv and np.any(factor > 0):  # has_uv implies uv
                out[pick] = factor * _textured_mean(tex, uv[pick], c)
            else:
                if tex is not None and not has_uv:
                    mat.note(f"texture {tex.name!r} ignored: the faces have no texture coordinates")
                out[pick] = factor * (1.0 if c is None else c.mean(axis=1))
    return albedo, emission


def clamp_albedo(albedo: np.ndarray, index: np.ndarray, table: list, limit: float, warning, stacklevel: int = 3):
    """Albedos in [limit, 1] set to ``limit``, with one ``warning`` naming the materials and noting
    it in each; returns the albedo (values above 1 are left for the Scene to refuse)."""
    near_one = (albedo >= limit) & (albedo <= 1.0 + 1e-9)
    if not np.any(near_one):
        return albedo
    rows = near_one.any(axis=1)
    names = []
    for m in np.unique(index[rows]):
        count = int(np.count_nonzero(rows & (index == m)))
        table[m].note(f"albedo of {count} patch(es) clamped from up to 1 to {limit}")
        names.append(repr(table[m].name))
    warnings.warn(
        f"clamped albedo of {int(np.count_nonzero(rows))} face(s) from up to 1 to {limit} (albedo must be "
        f"< 1) in material(s) {', '.join(names)}",
        warning,
        stacklevel=stacklevel,
    )
    return np.where(near_one, limit, albedo)


def scene_summary(scene) -> str:
    """A text table of ``scene``: size, unit, up, and per material what was read."""
    lo, hi = scene.bbox
    size = (hi - lo) * scene.unit
    lines = [
        f"{scene.name}: {len(scene)} patches, {len(scene.emitters)} emitting; unit {scene.unit_name} "
        f"({scene.unit:g} m), up {tuple(round(float(x), 6) for x in scene.up)}; "
        f"extent {size[0]:.4g} x {size[1]:.4g} x {size[2]:.4g} m"
    ]
    table = scene.materials
    if table is None:
        groups = [("(all patches)", np.arange(len(scene)), None)]
    else:
        groups = [(m.name, np.flatnonzero(table.index == k), m) for k, m in enumerate(table.materials)]
    lines.append(f"{'material':<24} {'patches':>8}  {'mean albedo (area)':<24} {'mean emission':<24} texture / notes")
    areas = scene.areas.astype(np.float64)
    for name, rows, mat in groups:
        if not len(rows):
            continue
        w = areas[rows] / areas[rows].sum()
        a = w @ scene.albedo[rows].astype(np.float64)
        e = w @ scene.emission[rows].astype(np.float64)
        extra: list[str] = []
        if mat is not None:
            if mat.albedo_texture is not None:
                extra.append(
                    f"albedo texture {mat.albedo_texture.name} {mat.albedo_texture.size[0]}x"
                    f"{mat.albedo_texture.size[1]} ({'/'.join(mat.albedo_texture.wrap)})"
                )
            if mat.emission_texture is not None:
                extra.append(f"emission texture {mat.emission_texture.name}")
            if mat.kind in ("default", "face colours", "vertex colours"):
                extra.append(mat.kind)
            extra.extend(mat.notes)
        fmt = lambda v: "(" + ", ".join(f"{x:.4g}" for x in v) + ")"  # noqa: E731
        lines.append(f"{name[:24]:<24} {len(rows):>8}  {fmt(a):<24} {fmt(e):<24} {'; '.join(extra)}")
    return "\n".join(lines)


def gltf_sampler_wrap(doc: dict, texture_info) -> tuple:
    """("repeat" | "clamp" | "mirror") x 2 of a glTF textureInfo's sampler (REPEAT by default)."""
    try:
        tex = doc["textures"][texture_info["index"]]
        sampler = doc["samplers"][tex["sampler"]] if "sampler" in tex else {}
    except (KeyError, IndexError, TypeError):
        return ("repeat", "repeat")
    return (_WRAP.get(sampler.get("wrapS", 10497), "repeat"), _WRAP.get(sampler.get("wrapT", 10497), "repeat"))


def level_count(size) -> int:
    return int(math.ceil(math.log2(max(size)))) + 1 if max(size) > 1 else 1
