"""glTF 2.0 binary files (GLB) of one triangle mesh: the container, written and read.

One buffer, one mesh, one primitive of triangles with uint32 indices; every vertex attribute
is float32 (glTF's ``POSITION``, ``COLOR_0``, ``TEXCOORD_n``, or an application attribute
whose name starts with ``_``). The material is unlit (``KHR_materials_unlit``) so viewers show
baked light as stored, not lit again; it may carry one embedded PNG texture. ``extras`` goes
into ``asset.extras``: the place for what the values mean (units, exposure, encoding).

See https://registry.khronos.org/glTF/specs/2.0/glTF-2.0.html, 'GLB File Format Specification'.
"""

from __future__ import annotations

import json
import struct

import numpy as np

from ..errors import InvalidInputError

__all__ = ["glb_bytes", "read_glb"]

_MAGIC, _JSON, _BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
_FLOAT, _UINT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_LINEAR, _CLAMP = 9729, 33071
_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
_WIDTH = {v: k for k, v in _TYPES.items()}


def _padded(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


def glb_bytes(
    faces: np.ndarray,
    attributes: dict,
    extras: dict,
    name: str = "mesh",
    generator: str = "pydynrad",
    texture: bytes | None = None,
    texcoord: int = 0,
) -> bytes:
    """The GLB file of one mesh.

    Parameters
    ----------
    faces : (N, 3) int
        Vertex indices of each triangle, counter-clockwise seen from the front.
    attributes : dict of name -> (V, k) float array, k in 1..4
        Must hold ``"POSITION"`` (V, 3); every array has the same V.
    extras : dict
        JSON-serialisable description stored as ``asset.extras``.
    texture : bytes, optional
        A PNG file, embedded as the material's base colour (an unlit material shows it as it
        is), looked up bilinearly, clamped to the edge, through ``TEXCOORD_<texcoord>``.
    """
    positions = attributes["POSITION"]
    n_vertices = len(positions)
    blob = bytearray()
    views, accessors, named = [], [], {}

    def add(array: np.ndarray, component: int, target: int, type_: str, bounds: bool = False) -> int:
        data = np.ascontiguousarray(array).tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data), "target": target})
        blob.extend(_padded(data, b"\0"))
        acc = {"bufferView": len(views) - 1, "componentType": component, "count": len(array), "type": type_}
        if bounds:
            acc["min"] = array.min(axis=0).tolist()
            acc["max"] = array.max(axis=0).tolist()
        accessors.append(acc)
        return len(accessors) - 1

    for key, value in attributes.items():
        a = np.asarray(value, dtype=np.float32)
        if a.ndim == 1:
            a = a[:, None]
        if a.shape[0] != n_vertices or a.shape[1] not in _TYPES:
            raise InvalidInputError(f"glTF attribute {key} must be ({n_vertices}, 1..4); got {a.shape}")
        named[key] = add(a, _FLOAT, _ARRAY_BUFFER, _TYPES[a.shape[1]], bounds=key == "POSITION")
    indices = add(np.asarray(faces, dtype=np.uint32).reshape(-1), _UINT, _ELEMENT_ARRAY_BUFFER, "SCALAR")
    pbr = {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0.0, "roughnessFactor": 1.0}
    images = {}
    if texture is not None:
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(texture)})
        blob.extend(_padded(texture, b"\0"))
        pbr["baseColorTexture"] = {"index": 0, "texCoord": texcoord}
        images = {
            "images": [{"bufferView": len(views) - 1, "mimeType": "image/png"}],
            "samplers": [{"magFilter": _LINEAR, "minFilter": _LINEAR, "wrapS": _CLAMP, "wrapT": _CLAMP}],
            "textures": [{"source": 0, "sampler": 0}],
        }
    doc = {
        "asset": {"version": "2.0", "generator": generator, "extras": extras},
        "extensionsUsed": ["KHR_materials_unlit"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{"attributes": named, "indices": indices, "material": 0, "mode": 4}]}],
        "materials": [{"name": "baked", "pbrMetallicRoughness": pbr, "extensions": {"KHR_materials_unlit": {}}}],
        **images,
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": views,
        "accessors": accessors,
    }
    text = _padded(json.dumps(doc, separators=(",", ":")).encode(), b" ")
    chunks = struct.pack("<II", len(text), _JSON) + text + struct.pack("<II", len(blob), _BIN) + bytes(blob)
    return struct.pack("<III", _MAGIC, 2, 12 + len(chunks)) + chunks


def read_glb(data: bytes) -> tuple[dict, dict, np.ndarray]:
    """``(document, attributes, faces)`` of a GLB written by :func:`glb_bytes` (float attributes,
    uint32 indices, one primitive); InvalidInputError for anything else or a damaged file."""
    try:
        magic, version, length = struct.unpack_from("<III", data, 0)
        if magic != _MAGIC or version != 2 or length != len(data):
            raise ValueError("not a complete glTF 2.0 binary file")
        n_json, kind = struct.unpack_from("<II", data, 12)
        if kind != _JSON:
            raise ValueError("the first chunk is not JSON")
        doc = json.loads(data[20 : 20 + n_json])
        n_bin, kind = struct.unpack_from("<II", data, 20 + n_json)
        if kind != _BIN:
            raise ValueError("the second chunk is not BIN")
        blob = data[28 + n_json : 28 + n_json + n_bin]

        def accessor(i: int, dtype) -> np.ndarray:
            acc = doc["accessors"][i]
            view = doc["bufferViews"][acc["bufferView"]]
            width, count = _WIDTH[acc["type"]], acc["count"]
            # -1 had read the whole buffer, 1e30 overflowed: a count is a whole number that fits it.
            if isinstance(count, bool) or not isinstance(count, int) or not 0 <= count <= len(blob):
                raise ValueError(f"accessor {i} has count {count!r}")
            a = np.frombuffer(blob, dtype=dtype, count=count * width, offset=view["byteOffset"])
            return a.reshape(acc["count"], width) if width > 1 else a

        prim = doc["meshes"][0]["primitives"][0]
        attributes = {k: accessor(i, "<f4") for k, i in prim["attributes"].items()}
        faces = accessor(prim["indices"], "<u4").reshape(-1, 3)
        lengths = {len(a) for a in attributes.values()}
        if len(lengths) > 1 or (faces.size and faces.max() >= min(lengths, default=0)):
            raise ValueError("its attributes differ in length or its faces index past them")
    except (ValueError, KeyError, IndexError, TypeError, struct.error) as exc:
        raise InvalidInputError(f"not a pydynrad GLB file: {exc}") from None
    return doc, attributes, faces
