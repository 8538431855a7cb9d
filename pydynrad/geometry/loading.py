"""Scenes from meshes and mesh files: materials read per geometry, then patched.

``load(path)`` reads OBJ (+MTL; also gzip-compressed, ``.obj.gz``), PLY, GLB/glTF, STL and OFF
through trimesh and hands the result to :func:`from_mesh`, which accepts a ``trimesh.Trimesh``
or a ``trimesh.Scene``.

Materials, per patch, as area means over the patch's footprint (:mod:`.materials`):

* OBJ/MTL: albedo ``Kd x map_Kd``, emission ``Ke x map_Ke`` (radiant exitance per m^2, the
  unit of every other emission). A multi-material OBJ loads as one geometry per material, so
  materials are read per geometry, never from a merged mesh (merging drops them).
* GLB/glTF: albedo ``baseColorFactor x COLOR_0 x baseColorTexture``, emission
  ``emissiveFactor x emissiveTexture x emissiveStrength`` (KHR_materials_emissive_strength);
  factors as float64 from the file (trimesh keeps them in 8 bits), textures sRGB-decoded,
  wrapped or clamped as their samplers say.
* Face colours (PLY) and vertex colours (PLY, glTF without a material): 8-bit values ``c``
  give albedo ``c / 255``, read as linear reflectance.
* Anything else (STL, a mesh without colours or materials): the ``default_albedo`` and no
  emission.

Patching (``max_patch_area``, ``max_edge``) splits triangles; every patch gets the mean of its
own part of the texture, not its source triangle's.

An albedo of 1 (``Kd 1 1 1``, colour 255, a white texel) would make a closed scene's radiosity
infinite, and such values are common in files that mean "white", so albedos in
``[MAX_ALBEDO, 1]`` are clamped to ``MAX_ALBEDO`` with one :class:`AlbedoClampedWarning` that
counts the patches and names the materials. Albedos above 1 are errors, not typos to repair.

Units and up axis: glTF is metres and +y up by its specification; OBJ, PLY, STL and OFF state
neither, and are read as metres and +y up unless ``load(..., unit=, up=)`` says otherwise. The
scene keeps the file's coordinates and declares them (:attr:`Scene.unit`, :attr:`Scene.up`).

``source_face[k]`` says which face of the file patch k comes from: for an OBJ, the index of its
``f`` line among the file's ``f`` lines (from 0; an n-gon's n - 2 triangles share it), and the
patches come in that order; for PLY, OFF and STL the file's triangles in order; for glTF, the
scene graph's instances in trimesh's node order, each primitive's triangles in index order.
Where an OBJ's triangles cannot all be matched to its lines (by material and corner
positions), trimesh's geometry order is kept and the summary says so. For a
mesh given in memory: the concatenation of its triangle geometries, taken in
``trimesh.Scene.graph.nodes_geometry`` order. Scene-graph transforms are applied; a
mirroring transform reverses the winding so normals keep pointing to the same (lit) side.

``load(..., report=True)`` prints :meth:`Scene.summary`: per material the patches, mean albedo
and emission, the textures used and what was clamped or ignored.
"""

from __future__ import annotations

import gzip
import io
import json
import math
import os
import re
import struct
import warnings
from pathlib import Path

import numpy as np
import trimesh

from ..errors import InvalidInputError, SceneFileError
from .materials import (
    Material,
    MaterialTable,
    Texture,
    barycentric_corners,
    clamp_albedo,
    gltf_sampler_wrap,
    sample_materials,
)
from .patching import subdivide, subdivide_scene
from .scene import Scene, unit_metres, up_vector

__all__ = [
    "load",
    "from_mesh",
    "patched_scene",
    "soup_scene",
    "AlbedoClampedWarning",
    "MissingMaterialWarning",
    "MalformedLineWarning",
    "MAX_ALBEDO",
    "SUPPORTED_FORMATS",
]

MAX_ALBEDO = 0.999
SUPPORTED_FORMATS = ("obj", "ply", "glb", "gltf", "stl", "off")
_TEXT_FORMATS = ("obj", "off", "gltf")


class AlbedoClampedWarning(UserWarning):
    """Albedos of 1 (or within ``1 - MAX_ALBEDO`` of it) were clamped to ``MAX_ALBEDO``."""


class MissingMaterialWarning(UserWarning):
    """An OBJ file names materials that could not be loaded; defaults were used."""


class MalformedLineWarning(UserWarning):
    """A line of an OBJ or MTL file cannot be used (a face of fewer than 3 corners, a non-numeric colour)."""


def _warn_malformed_lines(name: str, text: str, kind: str) -> None:
    """Warn, naming each line (up to 5), about what trimesh drops without a word: OBJ faces of
    fewer than three corners, MTL colours (Kd, Ka, Ks, Ke) that are not numbers."""
    bad = []
    for number, line in enumerate(text.splitlines(), 1):
        tokens = line.split()
        if not tokens:
            continue
        key = tokens[0].lower()
        if kind == "obj" and key == "f" and len(tokens) < 4:
            bad.append(f"line {number} {line.strip()!r} (a face needs 3 corners)")
        elif kind == "mtl" and key in ("kd", "ka", "ks", "ke"):
            try:
                [float(t) for t in tokens[1:4]]
            except ValueError:
                bad.append(f"line {number} {line.strip()!r} (not numbers)")
    if bad:
        more = f" and {len(bad) - 5} more" if len(bad) > 5 else ""
        warnings.warn(f"{name}: cannot use {'; '.join(bad[:5])}{more}", MalformedLineWarning, stacklevel=4)


def load(
    path,
    max_patch_area: float | None = None,
    max_edge: float | None = None,
    default_albedo=0.5,
    *,
    unit=None,
    up=None,
    report: bool = False,
) -> Scene:
    """Read a mesh file into a :class:`~pydynrad.Scene`.

    Parameters
    ----------
    path : str, Path, trimesh.Trimesh or trimesh.Scene
        An ``.obj`` (with its ``.mtl``; or ``.obj.gz``), ``.ply``, ``.glb``, ``.gltf``, ``.stl`` or
        ``.off`` file, or a mesh already in memory (read as :func:`from_mesh` reads it).
    max_patch_area, max_edge : float, optional
        Split triangles (4-way, at edge midpoints) until no patch exceeds this area (file
        units squared) or edge length (file units). ``None``: keep the file's triangles.
    default_albedo : float or (3,)
        Albedo of faces whose file gives none.
    unit : str or float, optional
        The file's length unit ("m", "cm", "mm", "in", "ft", or metres per unit): metres by
        default (glTF's by its specification; OBJ, PLY, STL and OFF do not say).
    up : str or (3,), optional
        The file's up axis ("+y", "+z", ... or a vector): +y by default (glTF's by its
        specification; the usual convention of OBJ and PLY files).
    report : bool
        Print :meth:`Scene.summary` (what was read, per material).

    Raises
    ------
    SceneFileError
        The file is missing, unreadable, malformed, of an unsupported format, has no
        triangles, or holds invalid values (NaN vertices, albedo above 1, negative emission);
        the message names the file and the problem.
    """
    unit = "m" if unit is None else unit
    up = "+y" if up is None else up
    if isinstance(path, (trimesh.Trimesh, trimesh.Scene)):
        scene = from_mesh(
            path, max_patch_area=max_patch_area, max_edge=max_edge, default_albedo=default_albedo, unit=unit, up=up
        )
        if report:
            print(scene.summary())
        return scene
    if not isinstance(path, (str, os.PathLike)):
        raise SceneFileError(
            f"path must be a file name (str or os.PathLike) or a trimesh mesh; got {type(path).__name__}"
        )
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    compressed = fmt == "gz"
    if compressed:
        fmt = Path(path.stem).suffix.lower().lstrip(".")
    if not path.is_file():
        raise SceneFileError(f"{path}: no such file" if not path.exists() else f"{path}: not a regular file")
    if fmt not in SUPPORTED_FORMATS:
        raise SceneFileError(
            f"{path}: unsupported format {''.join(path.suffixes[-2:]) if compressed else path.suffix!r}; "
            f"supported: {', '.join(SUPPORTED_FORMATS)} (and .gz of them)"
        )
    try:
        unit_checked, up_checked = _unit_up(unit, up)
    except InvalidInputError as exc:
        raise SceneFileError(f"{path}: {exc}") from None
    if compressed:
        try:
            raw = gzip.decompress(path.read_bytes())
        except (OSError, EOFError, gzip.BadGzipFile) as exc:
            raise SceneFileError(f"{path}: cannot decompress: {type(exc).__name__}: {exc}") from exc
    data = (raw if compressed else path.read_bytes()) if fmt in _TEXT_FORMATS else b""  # read once for the checks below
    if b"\0" in data[: 1 << 16]:
        raise SceneFileError(f"{path}: malformed {fmt.upper()} file: binary data (NUL bytes) in a text format")
    try:
        # process=False keeps face order (source_face) and lets bad vertices reach validation.
        source = io.BytesIO(raw) if compressed else str(path)
        if fmt == "obj" and (_RELATIVE_FACE.search(data) or _TABBED.search(data)):
            # trimesh 5.2 resolves relative (negative) OBJ indices wrongly and skips `v` lines
            # separated by tabs (McGuire's Cornell box had come out with half its triangles
            # zero-area, then failed): indices made absolute and lines single-spaced first.
            data = _absolute_obj_indices(data.decode("utf-8", errors="replace")).encode()
            source = io.BytesIO(data)
        loaded = trimesh.load(source, file_type=fmt, process=False, resolver=_MtlResolver(str(path)))
    except Exception as exc:  # trimesh raises anything from ValueError to UnicodeDecodeError
        raise SceneFileError(f"{path}: cannot read as {fmt.upper()}: {type(exc).__name__}: {exc}") from exc
    if fmt == "obj":
        _warn_malformed_lines(str(path), data.decode("utf-8", errors="replace"), "obj")
        if b"usemtl" in data:
            _warn_lost_materials(path, loaded)
    doc, order = None, None
    if fmt in ("gltf", "glb"):
        whole = data if fmt == "gltf" else (raw if compressed else path.read_bytes())
        _apply_emissive_strength(path, whole, loaded)
        doc = _gltf_json(path, whole)
    try:
        parts = _parts(loaded)
        if fmt == "obj":
            order = _obj_file_order(data.decode("utf-8", errors="replace"), parts)
        name = path.name[: -len("".join(path.suffixes[-2:]))] if compressed else path.stem
        scene = _scene_of_parts(
            parts,
            max_patch_area,
            max_edge,
            default_albedo,
            name,
            unit_checked,
            up_checked,
            doc=doc,
            order=order,
            base=path.parent,
            check_order=fmt == "obj",
        )
    except InvalidInputError as exc:
        raise SceneFileError(f"{path}: {exc}") from exc
    if report:
        print(scene.summary())
    return scene


def from_mesh(
    mesh,
    max_patch_area: float | None = None,
    max_edge: float | None = None,
    default_albedo=0.5,
    name: str | None = None,
    *,
    unit="m",
    up="+y",
) -> Scene:
    """A :class:`~pydynrad.Scene` from a ``trimesh.Trimesh`` or ``trimesh.Scene``.

    Materials come from each geometry's visual (see the module docstring; glTF factors in
    trimesh's 8 bits, as no file is at hand); vertices at identical positions are merged so
    the patches form one connected mesh. Patching, ``unit`` and ``up`` as in :func:`load`.
    Raises :class:`~pydynrad.errors.InvalidInputError` for an input with no triangles, and
    whatever :class:`~pydynrad.Scene` raises for invalid values.
    """
    parts = _parts(mesh)
    if name is None:
        name = str(mesh.metadata.get("file_name") or "mesh") if hasattr(mesh, "metadata") else "mesh"
    return _scene_of_parts(parts, max_patch_area, max_edge, default_albedo, name, *_unit_up(unit, up))


def checked_scene(value, what: str = "scene") -> Scene:
    """``value`` as a :class:`~pydynrad.Scene`: a Scene as it is, a ``trimesh.Trimesh`` or
    ``trimesh.Scene`` through :func:`from_mesh` (metres, +y up, as :func:`load` reads it), else
    InvalidInputError naming its type. Every function that takes a scene takes it through here.
    A mesh is converted on every call: pass the Scene to calls that repeat."""
    if isinstance(value, Scene):
        return value
    if isinstance(value, (trimesh.Trimesh, trimesh.Scene)):
        return from_mesh(value)
    # Functions that take a scene and a file take them in that order: f(scene, path, ...).
    hint = " (the scene comes first, then the path)" if isinstance(value, (str, os.PathLike)) else ""
    raise InvalidInputError(f"{what} must be a pydynrad.Scene or a trimesh mesh; got {type(value).__name__}{hint}")


def _unit_up(unit, up):
    return unit_metres(unit), up_vector(up)


def _parts(mesh) -> list:
    """[((vertices, faces), geometry)] of the triangle geometries of ``mesh``, in world space."""
    if isinstance(mesh, trimesh.Scene):
        parts = [
            (_transformed(mesh.geometry[g], t), mesh.geometry[g])
            for t, g in (mesh.graph[n] for n in mesh.graph.nodes_geometry)
        ]
    elif isinstance(mesh, trimesh.Trimesh):
        parts = [((np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)), mesh)]
    elif isinstance(mesh, trimesh.parent.Geometry):  # a point cloud or a path: no triangles
        raise InvalidInputError(f"the mesh is empty: it has no triangles (got a {type(mesh).__name__})")
    else:
        raise InvalidInputError(f"from_mesh needs a trimesh.Trimesh or trimesh.Scene; got {type(mesh).__name__}")
    parts = [(vf, g) for vf, g in parts if isinstance(g, trimesh.Trimesh) and len(vf[1]) > 0]
    if not parts:
        raise InvalidInputError("the mesh is empty: it has no triangles")
    return parts


def _scene_of_parts(
    parts, max_patch_area, max_edge, default_albedo, name, unit, up, doc=None, order=None, base=None, check_order=False
) -> Scene:
    point_parts: list[np.ndarray] = []
    triangle_parts: list[np.ndarray] = []
    offset = 0
    for (v, f), _ in parts:
        f = np.asarray(f)
        if f.size and (f.min() < 0 or f.max() >= len(v)):  # PLY and GLB indices reach here unchecked
            bad = int(np.flatnonzero((f < 0).any(axis=1) | (f >= len(v)).any(axis=1))[0])
            raise InvalidInputError(
                f"face {bad} indexes vertex {f[bad].tolist()} of {len(v)} (indices run 0..{len(v) - 1})"
            )
        point_parts.append(v)
        triangle_parts.append(np.asarray(f, dtype=np.int64) + offset)
        offset += len(v)
    table: list[Material] = []
    cache: dict[object, int] = {}  # ("default",) or id(material) -> index into table
    read = [_face_materials(g, np.asarray(f), default_albedo, table, cache, doc, base) for (_, f), g in parts]
    face_mat = np.concatenate([r[0] for r in read])
    n_faces = len(face_mat)
    face_uv = None
    if any(r[1] is not None for r in read):
        face_uv = np.concatenate([r[1] if r[1] is not None else np.full((len(r[0]), 3, 2), np.nan) for r in read])
    face_col = None
    if any(r[2] is not None for r in read):
        face_col = np.concatenate([r[2] if r[2] is not None else np.ones((len(r[0]), 3, 3)) for r in read])
    points, triangles = np.concatenate(point_parts), np.concatenate(triangle_parts)
    file_face = np.arange(n_faces)
    if order is not None:  # the file's face order: patches sorted by the file's face (f line)
        file_face = np.concatenate(order)
        perm = np.argsort(file_face, kind="stable")
        file_face, triangles, face_mat = file_face[perm], triangles[perm], face_mat[perm]
        face_uv = None if face_uv is None else face_uv[perm]
        face_col = None if face_col is None else face_col[perm]
    elif check_order:
        for m in table:
            m.note("source_face follows trimesh's geometry order (the file's face order could not be matched)")
    corners = points[triangles]
    points, triangles = _merge_points(points, triangles)
    # Geometry first (zero-area faces dropped and counted once, as input faces), then patching,
    # then each patch's materials over its own footprint.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AlbedoClampedWarning)
        shape = Scene(points, triangles, albedo=0.0, emission=0.0, name=name, unit=unit, up=up)
    src = shape.source_face
    if max_patch_area is not None or max_edge is not None:
        pts, tri, parent = subdivide(shape.vertices, shape.faces, max_area=max_patch_area, max_edge=max_edge)
        src = src[parent]
    else:
        pts, tri = shape.vertices, shape.faces
    weights = barycentric_corners(corners[src], pts[tri])
    albedo, emission = sample_materials(
        table,
        face_mat[src],
        None if face_uv is None else face_uv[src],
        None if face_col is None else face_col[src],
        weights,
    )
    albedo = clamp_albedo(albedo, face_mat[src], table, MAX_ALBEDO, AlbedoClampedWarning, stacklevel=4)
    scene = Scene(pts, tri, albedo=albedo, emission=emission, source_face=file_face[src], name=name, unit=unit, up=up)
    if len(scene) == len(src):
        scene.materials = MaterialTable(table, face_mat[src])
    return scene


def patched_scene(
    points,
    triangles,
    albedo,
    emission,
    source_face=None,
    max_patch_area: float | None = None,
    max_edge: float | None = None,
    name: str = "scene",
    unit="m",
    up="+z",
) -> Scene:
    """Validate a triangle mesh as a Scene, then split it into patches within the limits.

    Validation comes first so zero-area input triangles are dropped (and counted) once, as
    input faces, rather than after being split into many zero-area children.
    """
    scene = Scene(
        points, triangles, albedo=albedo, emission=emission, source_face=source_face, name=name, unit=unit, up=up
    )
    if max_patch_area is None and max_edge is None:
        return scene
    return subdivide_scene(scene, max_area=max_patch_area, max_edge=max_edge)


def soup_scene(
    vertices,
    albedo,
    emission,
    max_patch_area: float | None = None,
    max_edge: float | None = None,
    name: str = "scene",
    unit="m",
    up="+z",
) -> Scene:
    """A patched Scene from a triangle soup: (T, 3, 3) corners, counter-clockwise seen from the front.

    Corners at bit-identical positions become one point, so a soup built from shared literal
    coordinates (like the Cornell box data) comes out as a connected mesh.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 3 or v.shape[1:] != (3, 3):
        raise InvalidInputError(f"a triangle soup must have shape (T, 3, 3); got {v.shape}")
    points, triangles = _merge_points(v.reshape(-1, 3), np.arange(3 * len(v)).reshape(-1, 3))
    return patched_scene(
        points,
        triangles,
        albedo,
        emission,
        max_patch_area=max_patch_area,
        max_edge=max_edge,
        name=name,
        unit=unit,
        up=up,
    )


class _MtlResolver(trimesh.resolvers.FilePathResolver):
    """Serves MTL files with one-value colours (``Kd 0.5``, valid MTL) spelled as RGB triples.

    trimesh 5.2 fails on the one-value form and then silently drops every material of the file.
    """

    def get(self, name):
        data = super().get(name)
        if str(name).lower().endswith(".mtl"):
            text = data.decode("utf-8", errors="replace") if isinstance(data, bytes) else str(data)
            _warn_malformed_lines(str(name), text, "mtl")
            data = re.sub(r"(?im)^(\s*k[ads]\s+)(\S+)\s*$", r"\1\2 \2 \2", text).encode()
        return data


def _warn_lost_materials(path: Path, loaded) -> None:
    """Warn when an OBJ names materials but some geometry came back without one (no MTL file,
    an unknown material name): those faces get the default albedo and no emission."""
    geometries = loaded.geometry.values() if isinstance(loaded, trimesh.Scene) else [loaded]
    bare = sum(
        len(g.faces)
        for g in geometries
        if isinstance(g, trimesh.Trimesh) and getattr(g.visual, "material", None) is None
    )
    if bare:
        warnings.warn(
            f"{path}: {bare} face(s) use materials that could not be loaded (missing or unreadable MTL); "
            "they get the default albedo and no emission",
            MissingMaterialWarning,
            stacklevel=3,
        )


def _transformed(geometry, transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (float64) and faces of a scene-graph instance in world space."""
    if not isinstance(geometry, trimesh.Trimesh):
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    t = np.asarray(transform, dtype=np.float64)
    v = np.asarray(geometry.vertices, dtype=np.float64) @ t[:3, :3].T + t[:3, 3]
    f = np.asarray(geometry.faces)
    return v, (f[:, ::-1] if np.linalg.det(t[:3, :3]) < 0 else f)


def _merge_points(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices at bit-identical positions (STL and per-material OBJ geometries repeat them)."""
    if not np.all(np.isfinite(points)):
        return points, triangles  # leave NaNs for Scene to report; np.unique would scramble them
    unique, inverse = np.unique(points, axis=0, return_inverse=True)
    return unique, inverse.reshape(-1)[triangles]


def _face_materials(mesh: trimesh.Trimesh, faces: np.ndarray, default_albedo, table: list, cache: dict, doc, base):
    """(F,) material index (appended to ``table``), (F, 3, 2) corner UVs or None, (F, 3, 3) linear
    corner colours or None, of one geometry's faces."""
    n = len(faces)
    visual = mesh.visual
    kind = getattr(visual, "kind", None)

    def add(material: Material) -> np.ndarray:
        table.append(material)
        return np.full(n, len(table) - 1, np.int64)

    if isinstance(visual, trimesh.visual.ColorVisuals) and kind == "face":
        col = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0
        return add(Material("(face colours)", "face colours", np.ones(3))), None, np.repeat(col[:, None], 3, axis=1)
    if isinstance(visual, trimesh.visual.ColorVisuals) and kind == "vertex":
        col = np.asarray(visual.vertex_colors, dtype=np.float64)[faces][:, :, :3] / 255.0
        return add(Material("(vertex colours)", "vertex colours", np.ones(3))), None, col
    material = getattr(visual, "material", None) if isinstance(visual, trimesh.visual.TextureVisuals) else None
    if material is None:
        key = ("default",)
        if key not in cache:
            table.append(
                Material("(default)", "default", np.broadcast_to(np.asarray(default_albedo, np.float64), (3,)).copy())
            )
            cache[key] = len(table) - 1
        return np.full(n, cache[key], np.int64), None, None
    if id(material) not in cache:
        table.append(_material(material, doc, base, np.broadcast_to(np.asarray(default_albedo, np.float64), (3,))))
        cache[id(material)] = len(table) - 1
    index = np.full(n, cache[id(material)], np.int64)
    mat = table[cache[id(material)]]
    uv = getattr(visual, "uv", None)
    face_uv = None
    if uv is not None and len(uv) == len(mesh.vertices):
        face_uv = np.asarray(uv, np.float64)[:, :2][faces]
    colours = None
    color = (getattr(visual, "vertex_attributes", None) or {}).get("color")
    if color is not None and len(color) == len(mesh.vertices):
        c = np.asarray(color)
        scale = float(np.iinfo(c.dtype).max) if np.issubdtype(c.dtype, np.integer) else 1.0
        c = c.astype(np.float64) / scale
        c = np.repeat(c[:, :1], 3, axis=1) if c.shape[1] < 3 else c[:, :3]
        colours = c[faces]
        if mat.kind == "gltf":
            mat.note("COLOR_0 applied")
    return index, face_uv, colours


def _material(material, doc, base, default_albedo) -> Material:
    """The :class:`Material` of a trimesh material: glTF (PBRMaterial, factors from the file's JSON
    where it can be matched) or MTL (SimpleMaterial, Kd / Ke / map_Kd / map_Ke)."""
    name = str(getattr(material, "name", None) or "(unnamed)")
    kwargs = getattr(material, "kwargs", None) or {}
    if isinstance(material, trimesh.visual.material.PBRMaterial):
        entry = _gltf_entry(doc, material)
        pbr = (entry or {}).get("pbrMetallicRoughness") or {}
        if entry is not None and "baseColorFactor" in pbr:
            albedo = np.asarray(pbr["baseColorFactor"], np.float64)[:3]
        else:
            base_factor = material.baseColorFactor
            albedo = np.ones(3) if base_factor is None else _rgb8_or_float(base_factor)
            if entry is None and doc is not None:
                albedo = albedo if base_factor is not None else np.ones(3)
        if doc is None and material.baseColorFactor is None and material.baseColorTexture is None:
            albedo = np.asarray(default_albedo, np.float64)
        emissive = material.emissiveFactor  # trimesh's, times the file's emissive strength (see load)
        emission = np.zeros(3) if emissive is None else np.asarray(emissive, dtype=np.float64)[:3]
        out = Material(name, "gltf", albedo, emission)
        if material.baseColorTexture is not None:
            info = pbr.get("baseColorTexture") if entry is not None else None
            out.albedo_texture = Texture(
                material.baseColorTexture,
                _image_name(material.baseColorTexture, "baseColor"),
                wrap=gltf_sampler_wrap(doc, info) if info else ("repeat", "repeat"),
            )
            if out.albedo_texture.channels == 4:
                out.note("alpha ignored (opaque)")
            if info and info.get("texCoord", 0) != 0:
                out.note(f"baseColorTexture uses TEXCOORD_{info['texCoord']}: read through TEXCOORD_0")
            if info and "KHR_texture_transform" in (info.get("extensions") or {}):
                out.note("KHR_texture_transform ignored")
        if material.emissiveTexture is not None:
            info = (entry or {}).get("emissiveTexture")
            out.emission_texture = Texture(
                material.emissiveTexture,
                _image_name(material.emissiveTexture, "emissive"),
                wrap=gltf_sampler_wrap(doc, info) if info else ("repeat", "repeat"),
            )
        if entry is None and doc is not None:
            out.note("not matched to the file's materials: factors in trimesh's 8 bits")
        if entry is not None and entry.get("alphaMode") in ("BLEND", "MASK"):
            out.note(f"alphaMode {entry['alphaMode']} ignored (opaque)")
        for ext in (entry or {}).get("extensions") or {}:
            if ext not in ("KHR_materials_emissive_strength",):
                out.note(f"{ext} ignored")
        return out
    # The MTL parser keeps Kd as floats in kwargs; material.diffuse is quantised to 8 bits.
    kd = kwargs.get("kd")
    albedo = _parse_rgb(kd, "Kd") if kd is not None else np.asarray(default_albedo, np.float64)
    ke = kwargs.get("ke")
    emission = _parse_rgb(ke, "Ke") if ke is not None else np.zeros(3)
    out = Material(name, "mtl", albedo, emission)
    image = getattr(material, "image", None)
    if image is not None:
        out.albedo_texture = Texture(image, _image_name(image, "map_Kd"))
        if kd is None:
            out.albedo = np.ones(3)  # map_Kd alone: the texture is the albedo
        if out.albedo_texture.channels == 4:
            out.note("alpha ignored (opaque)")
    map_ke = kwargs.get("map_ke")
    if map_ke:
        file_name = str(map_ke[-1] if isinstance(map_ke, (list, tuple)) else map_ke)
        try:
            from PIL import Image

            with Image.open(Path(base or ".") / file_name) as img:
                img.load()
                out.emission_texture = Texture(img, file_name)
            if ke is None:
                out.emission = np.ones(3)
        except (OSError, ValueError) as exc:
            out.note(f"map_Ke {file_name!r} ignored: {type(exc).__name__}: {exc}")
    for key in ("map_bump", "bump", "map_d", "d", "ks", "map_ks", "ns"):
        if key in kwargs and key in ("ks", "map_ks") and np.any(np.asarray(_try_rgb(kwargs[key])) > 0):
            out.note(f"{key.replace('map_ks', 'map_Ks').replace('ks', 'Ks')} ignored (diffuse only)")
    return out


def _try_rgb(value):
    try:
        return _parse_rgb(value, "Ks")
    except InvalidInputError:
        return np.zeros(3)


def _image_name(image, fallback: str) -> str:
    info = getattr(image, "info", None) or {}
    return str(info.get("file_path") or getattr(image, "filename", "") or fallback)


def _gltf_entry(doc, material):
    """The file's JSON material that trimesh's ``material`` came from, or None where it cannot be
    told: matched by name, then by trimesh's 8-bit base colour and emissive factor."""
    if not doc:
        return None
    entries = [m for m in (doc.get("materials") or []) if isinstance(m, dict)]
    named = [m for m in entries if (m.get("name") or None) == (getattr(material, "name", None) or None)]
    if len(named) > 1 and material.baseColorFactor is not None:
        base = _rgb8_or_float(material.baseColorFactor)
        named = [
            m
            for m in named
            if np.allclose(
                np.asarray((m.get("pbrMetallicRoughness") or {}).get("baseColorFactor", [1, 1, 1, 1]), float)[:3],
                base,
                atol=1.0 / 255.0,
            )
        ]
    if len(named) > 1 and all(json.dumps(m, sort_keys=True) == json.dumps(named[0], sort_keys=True) for m in named):
        named = named[:1]
    return named[0] if len(named) == 1 else None


_RELATIVE_FACE = re.compile(rb"(?m)^[ \t]*f[ \t][^\n]*(?<![\w.])-\d")
_TABBED = re.compile(rb"(?m)^[ \t]*(v|vt|vn|f)\t")


def _absolute_obj_indices(text: str) -> str:
    """``text`` with the relative (negative) indices of its ``f`` lines made absolute, and its
    vertex and face lines' fields separated by single spaces."""
    counts = {"v": 0, "vt": 0, "vn": 0}
    keys = ("v", "vt", "vn")
    out = []
    for line in text.splitlines():
        t = line.split()
        if t and t[0] in counts:
            counts[t[0]] += 1
            line = " ".join(t)
        elif t and t[0] == "f":
            corners = []
            for corner in t[1:]:
                fields = corner.split("/")
                for k, value in enumerate(fields[:3]):
                    if value.startswith("-"):
                        try:
                            fields[k] = str(counts[keys[k]] + 1 + int(value))
                        except ValueError:
                            pass
                corners.append("/".join(fields))
            line = "f " + " ".join(corners)
        out.append(line)
    return "\n".join(out) + "\n"


def _obj_file_order(text: str, parts) -> list | None:
    """Per part, the index (in file order, from 0) of the ``f`` line each of its triangles comes
    from, matched by material and corner positions; None where some triangle of trimesh's cannot
    be matched so, or some line's triangles are missing."""
    verts, faces, current = [], [], None
    try:
        for line in text.splitlines():
            t = line.split()
            if not t:
                continue
            if t[0] == "v":
                verts.append(tuple(float(x) for x in t[1:4]))
            elif t[0] == "usemtl":
                current = t[1] if len(t) > 1 else None
            elif t[0] == "f" and len(t) >= 4:
                idx = [int(x.split("/")[0]) for x in t[1:]]
                faces.append((current, [i - 1 if i > 0 else len(verts) + i for i in idx]))
        containing: dict[tuple[float, ...], list[int]] = {}
        for k, (_, idx) in enumerate(faces):
            for i in idx:
                containing.setdefault(verts[i], []).append(k)
    except (ValueError, IndexError):
        return None
    left = [len(idx) - 2 for _, idx in faces]
    single = len({m for m, _ in faces}) == 1
    out = []
    for (v, f), g in parts:
        material = getattr(getattr(g, "visual", None), "material", None)
        name = getattr(material, "name", None) if material is not None else None
        ids = np.empty(len(f), np.int64)
        for k, tri in enumerate(np.asarray(v, np.float64)[np.asarray(f)].tolist()):
            s0, s1, s2 = (containing.get(tuple(p)) for p in tri)  # the faces holding each corner
            if s0 is None or s1 is None or s2 is None:
                return None
            found = sorted(set(s0).intersection(s1, s2))
            found = [c for c in found if left[c] > 0 and (single or faces[c][0] == name)]
            if not found:
                return None
            left[found[0]] -= 1
            ids[k] = found[0]
        out.append(ids)
    return out if not any(left) else None


def _gltf_json(path: Path, data: bytes) -> dict:
    """The JSON of a .gltf file's text or a .glb file's first chunk ({} where there is none)."""
    if data[:4] == b"glTF":
        length, kind = struct.unpack_from("<I4s", data, 12) if len(data) >= 20 else (0, b"")
        data = data[20 : 20 + length] if kind == b"JSON" else b"{}"
    try:
        out = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise SceneFileError(f"{path}: malformed glTF JSON: {exc}") from None
    return out if isinstance(out, dict) else {}


def _apply_emissive_strength(path: Path, data: bytes, loaded) -> None:
    """Multiply each material's emission by its KHR_materials_emissive_strength, which trimesh
    drops (Blender writes it for any emission above 1: a lamp at strength 100 had come out 100
    times too dim). A loaded material is matched to the file's by name, base colour and
    emissive factor; where those cannot tell materials of different strengths apart, refused."""
    materials = _gltf_json(path, data).get("materials")
    materials = [m for m in materials if isinstance(m, dict)] if isinstance(materials, list) else []

    def strength(m) -> float:
        ext = (
            (m.get("extensions") or {}).get("KHR_materials_emissive_strength")
            if isinstance(m.get("extensions"), dict)
            else None
        )
        value = ext.get("emissiveStrength", 1.0) if isinstance(ext, dict) else 1.0
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value >= 0):
            raise SceneFileError(
                f"{path}: material {m.get('name')!r}: emissiveStrength must be a number >= 0; got {value!r}"
            )
        return float(value)

    strengths = [strength(m) for m in materials]
    if all(v == 1.0 for v in strengths):
        return

    def colour(value, n, default):
        v = np.asarray(value if value is not None else default, np.float64).ravel()
        return v[:n] if v.size >= n else np.asarray(default, np.float64)

    # The file's (name, base RGB, emissive RGB) per material; trimesh keeps base colours in 8 bits.
    described = [
        (
            m.get("name") or None,
            colour((m.get("pbrMetallicRoughness") or {}).get("baseColorFactor"), 3, (1.0, 1.0, 1.0)),
            colour(m.get("emissiveFactor"), 3, (0.0, 0.0, 0.0)),
        )
        for m in materials
    ]
    geometries = loaded.geometry.values() if isinstance(loaded, trimesh.Scene) else [loaded]
    done = set()
    for g in geometries:
        mat = getattr(getattr(g, "visual", None), "material", None)
        if not isinstance(mat, trimesh.visual.material.PBRMaterial) or id(mat) in done:
            continue
        emissive = colour(mat.emissiveFactor, 3, (0.0, 0.0, 0.0))
        base = None if mat.baseColorFactor is None else _rgb8_or_float(mat.baseColorFactor)
        found = {
            v
            for (name, b, e), v in zip(described, strengths)
            if name == (mat.name or None)
            and np.allclose(e, emissive, rtol=1e-6, atol=1e-7)
            and (base is None or np.allclose(b, base, rtol=0.0, atol=1.0 / 255.0))
        }
        if len(found) != 1:
            raise SceneFileError(
                f"{path}: cannot tell which of its materials' KHR_materials_emissive_strength belongs to "
                f"material {mat.name!r} (give the materials distinct names)"
            )
        if mat.emissiveFactor is not None:
            mat.emissiveFactor = np.asarray(mat.emissiveFactor, np.float64) * found.pop()
        done.add(id(mat))


def _material_rgb(material, default_albedo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Albedo and emission RGB of an MTL (SimpleMaterial) or glTF (PBRMaterial) material."""
    kwargs = getattr(material, "kwargs", None) or {}
    if isinstance(material, trimesh.visual.material.PBRMaterial):
        base = material.baseColorFactor
        albedo = default_albedo if base is None else _rgb8_or_float(base)
        emissive = material.emissiveFactor
        emission = np.zeros(3) if emissive is None else np.asarray(emissive, dtype=np.float64)[:3]
        return albedo, emission
    # The MTL parser keeps Kd as floats in kwargs; material.diffuse is quantised to 8 bits.
    kd = kwargs.get("kd")
    albedo = _parse_rgb(kd, "Kd") if kd is not None else default_albedo
    ke = kwargs.get("ke")
    emission = _parse_rgb(ke, "Ke") if ke is not None else np.zeros(3)
    return albedo, emission


def _rgb8_or_float(value) -> np.ndarray:
    a = np.asarray(value)
    rgb = a[:3].astype(np.float64)
    return rgb / 255.0 if np.issubdtype(a.dtype, np.integer) else rgb


def _parse_rgb(value, key: str) -> np.ndarray:
    """An MTL colour: one value (grey) or three (RGB), given as numbers or strings."""
    tokens = value.split() if isinstance(value, str) else list(np.atleast_1d(value))
    try:
        rgb = np.array([float(t) for t in tokens], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(f"material {key} is not numeric: {value!r}") from exc
    if rgb.shape == (1,):
        rgb = np.repeat(rgb, 3)
    if rgb.shape != (3,):
        raise InvalidInputError(f"material {key} needs 1 or 3 values; got {value!r}")
    return rgb
