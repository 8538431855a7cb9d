"""Scenes from meshes and mesh files: materials read per geometry, then patched.

``load(path)`` reads OBJ (+MTL), PLY, GLB/glTF, STL and OFF through trimesh and hands the
result to :func:`from_mesh`, which accepts a ``trimesh.Trimesh`` or a ``trimesh.Scene``.

Materials, per input face:

* OBJ/MTL: ``Kd`` is the albedo, ``Ke`` the emission (radiant exitance, same unit as every
  other emission in the scene). A multi-material OBJ loads as one geometry per material, so
  materials are read per geometry, never from a merged mesh (merging drops them).
* GLB/glTF: ``baseColorFactor`` is the albedo, ``emissiveFactor`` the emission.
* Face colours (PLY) and vertex colours (PLY, GLB; averaged over a face's three corners):
  8-bit values ``c`` give albedo ``c / 255``, read as linear reflectance.
* Anything else (STL, a mesh without colours or materials, a texture-only material): the
  ``default_albedo`` and no emission. Textures are not sampled.

An albedo of 1 (``Kd 1 1 1``, colour 255) would make a closed scene's radiosity infinite, and
such values are common in files that mean "white", so albedos in ``[MAX_ALBEDO, 1]`` are
clamped to ``MAX_ALBEDO`` with an :class:`AlbedoClampedWarning` that counts the faces.
Albedos above 1 are errors, not typos to repair.

``source_face[k]`` is the index of patch k's face in the concatenation of the input's
triangle geometries, taken in ``trimesh.Scene.graph.nodes_geometry`` order (for a single
``Trimesh``: its own face index). Scene-graph transforms are applied; a mirroring transform
reverses the winding so normals keep pointing to the same (lit) side.
"""

from __future__ import annotations

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
from .patching import subdivide_scene
from .scene import Scene

__all__ = ["load", "from_mesh", "patched_scene", "soup_scene", "AlbedoClampedWarning", "MissingMaterialWarning", "MalformedLineWarning", "MAX_ALBEDO", "SUPPORTED_FORMATS"]

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


def load(path, max_patch_area: float | None = None, max_edge: float | None = None, default_albedo=0.5) -> Scene:
    """Read a mesh file into a :class:`~pydynrad.Scene`.

    Parameters
    ----------
    path : str, Path, trimesh.Trimesh or trimesh.Scene
        An ``.obj`` (with its ``.mtl``), ``.ply``, ``.glb``, ``.gltf``, ``.stl`` or ``.off`` file,
        or a mesh already in memory (read as :func:`from_mesh` reads it).
    max_patch_area, max_edge : float, optional
        Split triangles (4-way, at edge midpoints) until no patch exceeds this area (file
        units squared) or edge length (file units). ``None``: keep the file's triangles.
    default_albedo : float or (3,)
        Albedo of faces whose file gives none.

    Raises
    ------
    SceneFileError
        The file is missing, unreadable, malformed, of an unsupported format, has no
        triangles, or holds invalid values (NaN vertices, albedo above 1, negative emission);
        the message names the file and the problem.
    """
    if isinstance(path, (trimesh.Trimesh, trimesh.Scene)):
        return from_mesh(path, max_patch_area=max_patch_area, max_edge=max_edge, default_albedo=default_albedo)
    if not isinstance(path, (str, os.PathLike)):
        raise SceneFileError("path must be a file name (str or os.PathLike) or a trimesh mesh; "
                             f"got {type(path).__name__}")
    path = Path(path)
    fmt = path.suffix.lower().lstrip(".")
    if not path.is_file():
        raise SceneFileError(f"{path}: no such file" if not path.exists() else f"{path}: not a regular file")
    if fmt not in SUPPORTED_FORMATS:
        raise SceneFileError(f"{path}: unsupported format {path.suffix!r}; supported: {', '.join(SUPPORTED_FORMATS)}")
    data = path.read_bytes() if fmt in _TEXT_FORMATS else b""  # read once for the checks below
    if b"\0" in data[:1 << 16]:
        raise SceneFileError(f"{path}: malformed {fmt.upper()} file: binary data (NUL bytes) in a text format")
    try:
        # process=False keeps face order (source_face) and lets bad vertices reach validation.
        loaded = trimesh.load(str(path), file_type=fmt, process=False, resolver=_MtlResolver(str(path)))
    except Exception as exc:  # trimesh raises anything from ValueError to UnicodeDecodeError
        raise SceneFileError(f"{path}: cannot read as {fmt.upper()}: {type(exc).__name__}: {exc}") from exc
    if fmt == "obj":
        _warn_malformed_lines(str(path), data.decode("utf-8", errors="replace"), "obj")
        if b"usemtl" in data:
            _warn_lost_materials(path, loaded)
    if fmt in ("gltf", "glb"):
        _apply_emissive_strength(path, data if fmt == "gltf" else path.read_bytes(), loaded)
    try:
        return from_mesh(loaded, max_patch_area=max_patch_area, max_edge=max_edge, default_albedo=default_albedo, name=path.stem)
    except InvalidInputError as exc:
        raise SceneFileError(f"{path}: {exc}") from exc


def from_mesh(mesh, max_patch_area: float | None = None, max_edge: float | None = None, default_albedo=0.5, name: str | None = None) -> Scene:
    """A :class:`~pydynrad.Scene` from a ``trimesh.Trimesh`` or ``trimesh.Scene``.

    Materials come from each geometry's visual (see the module docstring); vertices at
    identical positions are merged so the patches form one connected mesh. Patching as in
    :func:`load`. Raises :class:`~pydynrad.errors.InvalidInputError` for an input with no
    triangles, and whatever :class:`~pydynrad.Scene` raises for invalid values.
    """
    if isinstance(mesh, trimesh.Scene):
        parts = [(_transformed(mesh.geometry[g], t), mesh.geometry[g]) for t, g in (mesh.graph[n] for n in mesh.graph.nodes_geometry)]
    elif isinstance(mesh, trimesh.Trimesh):
        parts = [((np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)), mesh)]
    elif isinstance(mesh, trimesh.parent.Geometry):  # a point cloud or a path: no triangles
        raise InvalidInputError(f"the mesh is empty: it has no triangles (got a {type(mesh).__name__})")
    else:
        raise InvalidInputError(f"from_mesh needs a trimesh.Trimesh or trimesh.Scene; got {type(mesh).__name__}")
    parts = [(vf, g) for vf, g in parts if isinstance(g, trimesh.Trimesh) and len(vf[1]) > 0]
    if not parts:
        raise InvalidInputError("the mesh is empty: it has no triangles")

    points, triangles, offset = [], [], 0
    for (v, f), _ in parts:
        f = np.asarray(f)
        if f.size and (f.min() < 0 or f.max() >= len(v)):  # PLY and GLB indices reach here unchecked
            bad = int(np.flatnonzero((f < 0).any(axis=1) | (f >= len(v)).any(axis=1))[0])
            raise InvalidInputError(f"face {bad} indexes vertex {f[bad].tolist()} of {len(v)} (indices run 0..{len(v) - 1})")
        points.append(v)
        triangles.append(np.asarray(f, dtype=np.int64) + offset)
        offset += len(v)
    albedo, emission = zip(*(_face_materials(g, default_albedo) for _, g in parts))
    points, triangles = _merge_points(np.concatenate(points), np.concatenate(triangles))
    if name is None:
        name = str(mesh.metadata.get("file_name") or "mesh") if hasattr(mesh, "metadata") else "mesh"
    return patched_scene(points, triangles, _clamp_albedo(np.concatenate(albedo)), np.concatenate(emission),
                         max_patch_area=max_patch_area, max_edge=max_edge, name=name)


def patched_scene(points, triangles, albedo, emission, source_face=None, max_patch_area: float | None = None,
                  max_edge: float | None = None, name: str = "scene") -> Scene:
    """Validate a triangle mesh as a Scene, then split it into patches within the limits.

    Validation comes first so zero-area input triangles are dropped (and counted) once, as
    input faces, rather than after being split into many zero-area children.
    """
    scene = Scene(points, triangles, albedo=albedo, emission=emission, source_face=source_face, name=name)
    if max_patch_area is None and max_edge is None:
        return scene
    return subdivide_scene(scene, max_area=max_patch_area, max_edge=max_edge)


def soup_scene(vertices, albedo, emission, max_patch_area: float | None = None, max_edge: float | None = None,
               name: str = "scene") -> Scene:
    """A patched Scene from a triangle soup: (T, 3, 3) corners, counter-clockwise seen from the front.

    Corners at bit-identical positions become one point, so a soup built from shared literal
    coordinates (like the Cornell box data) comes out as a connected mesh.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 3 or v.shape[1:] != (3, 3):
        raise InvalidInputError(f"a triangle soup must have shape (T, 3, 3); got {v.shape}")
    points, triangles = _merge_points(v.reshape(-1, 3), np.arange(3 * len(v)).reshape(-1, 3))
    return patched_scene(points, triangles, albedo, emission, max_patch_area=max_patch_area, max_edge=max_edge, name=name)


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
    bare = sum(len(g.faces) for g in geometries
               if isinstance(g, trimesh.Trimesh) and getattr(g.visual, "material", None) is None)
    if bare:
        warnings.warn(f"{path}: {bare} face(s) use materials that could not be loaded (missing or unreadable MTL); "
                      "they get the default albedo and no emission", MissingMaterialWarning, stacklevel=3)


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


def _face_materials(mesh: trimesh.Trimesh, default_albedo) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) albedo and (F, 3) emission of one geometry's faces, as float64."""
    n = len(mesh.faces)
    albedo = np.broadcast_to(np.asarray(default_albedo, dtype=np.float64), (3,))
    emission = np.zeros(3)
    visual = mesh.visual
    kind = getattr(visual, "kind", None)
    if isinstance(visual, trimesh.visual.ColorVisuals) and kind == "face":
        albedo = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0
    elif isinstance(visual, trimesh.visual.ColorVisuals) and kind == "vertex":
        albedo = np.asarray(visual.vertex_colors, dtype=np.float64)[mesh.faces][:, :, :3].mean(axis=1) / 255.0
    elif isinstance(visual, trimesh.visual.TextureVisuals) and visual.material is not None:
        albedo, emission = _material_rgb(visual.material, albedo)
    return (np.broadcast_to(albedo, (n, 3)).astype(np.float64), np.broadcast_to(emission, (n, 3)).astype(np.float64))


def _gltf_json(path: Path, data: bytes) -> dict:
    """The JSON of a .gltf file's text or a .glb file's first chunk ({} where there is none)."""
    if data[:4] == b"glTF":
        length, kind = struct.unpack_from("<I4s", data, 12) if len(data) >= 20 else (0, b"")
        data = data[20:20 + length] if kind == b"JSON" else b"{}"
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
        ext = (m.get("extensions") or {}).get("KHR_materials_emissive_strength") if isinstance(m.get("extensions"), dict) else None
        value = ext.get("emissiveStrength", 1.0) if isinstance(ext, dict) else 1.0
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value >= 0):
            raise SceneFileError(f"{path}: material {m.get('name')!r}: emissiveStrength must be a number >= 0; got {value!r}")
        return float(value)

    strengths = [strength(m) for m in materials]
    if all(v == 1.0 for v in strengths):
        return

    def colour(value, n, default):
        v = np.asarray(value if value is not None else default, np.float64).ravel()
        return v[:n] if v.size >= n else np.asarray(default, np.float64)

    # The file's (name, base RGB, emissive RGB) per material; trimesh keeps base colours in 8 bits.
    described = [(m.get("name") or None, colour((m.get("pbrMetallicRoughness") or {}).get("baseColorFactor"), 3,
                                                (1.0, 1.0, 1.0)), colour(m.get("emissiveFactor"), 3, (0.0, 0.0, 0.0)))
                 for m in materials]
    geometries = loaded.geometry.values() if isinstance(loaded, trimesh.Scene) else [loaded]
    done = set()
    for g in geometries:
        mat = getattr(getattr(g, "visual", None), "material", None)
        if not isinstance(mat, trimesh.visual.material.PBRMaterial) or id(mat) in done:
            continue
        emissive = colour(mat.emissiveFactor, 3, (0.0, 0.0, 0.0))
        base = None if mat.baseColorFactor is None else _rgb8_or_float(mat.baseColorFactor)
        found = {v for (name, b, e), v in zip(described, strengths)
                 if name == (mat.name or None) and np.allclose(e, emissive, rtol=1e-6, atol=1e-7)
                 and (base is None or np.allclose(b, base, rtol=0.0, atol=1.0 / 255.0))}
        if len(found) != 1:
            raise SceneFileError(f"{path}: cannot tell which of its materials' KHR_materials_emissive_strength belongs to "
                                 f"material {mat.name!r} (give the materials distinct names)")
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


def _clamp_albedo(albedo: np.ndarray) -> np.ndarray:
    near_one = (albedo >= MAX_ALBEDO) & (albedo <= 1.0)
    if np.any(near_one):
        n_faces = int(np.count_nonzero(near_one.any(axis=1)))
        warnings.warn(f"clamped albedo of {n_faces} face(s) from up to 1 to {MAX_ALBEDO} (albedo must be < 1)",
                      AlbedoClampedWarning, stacklevel=3)
        albedo = np.where(near_one, MAX_ALBEDO, albedo)
    return albedo
