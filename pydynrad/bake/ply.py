"""Binary PLY files of one triangle mesh with per-vertex properties, written and read.

PLY holds any number of named vertex properties: baked radiosity goes in as float32 (linear,
exact) and as the 8-bit ``red green blue`` that viewers show (MeshLab, CloudCompare, Blender),
whose encoding the header's comments state.
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError

__all__ = ["ply_bytes", "read_ply"]

_PLY_TYPES = {"f4": "float", "u1": "uchar"}
_NP_TYPES = {v: k for k, v in _PLY_TYPES.items()}


def ply_bytes(faces: np.ndarray, properties: dict, comments: list[str]) -> bytes:
    """The PLY file (binary little-endian) of one mesh.

    ``properties``: name -> (V,) float32 or uint8 array, in file order, starting with x, y, z.
    ``comments``: header lines (no newlines) saying what the properties mean.
    """
    names = list(properties)
    n_vertices = len(properties[names[0]])
    dtype = np.dtype([(k, "<" + np.asarray(properties[k]).dtype.str[1:]) for k in names])
    for k in names:
        if dtype[k].str[1:] not in _PLY_TYPES or len(properties[k]) != n_vertices:
            raise InvalidInputError(f"PLY property {k} must be ({n_vertices},) float32 or uint8")
    vertices = np.empty(n_vertices, dtype=dtype)
    for k in names:
        vertices[k] = properties[k]
    faces = np.asarray(faces)
    face_rows = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face_rows["n"] = 3
    face_rows["v"] = faces
    header = [
        "ply",
        "format binary_little_endian 1.0",
        *(f"comment {c}" for c in comments),
        f"element vertex {n_vertices}",
        *(f"property {_PLY_TYPES[dtype[k].str[1:]]} {k}" for k in names),
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    if any("\n" in line or "\r" in line for line in header):
        raise InvalidInputError("PLY header lines must not contain line breaks")
    return ("\n".join(header) + "\n").encode("ascii") + vertices.tobytes() + face_rows.tobytes()


def read_ply(data: bytes) -> tuple[list[str], dict, np.ndarray]:
    """``(comments, properties, faces)`` of a PLY written by :func:`ply_bytes`; InvalidInputError otherwise."""
    try:
        end = data.index(b"end_header\n") + len(b"end_header\n")
        lines = data[:end].decode("ascii").splitlines()
        if lines[:2] != ["ply", "format binary_little_endian 1.0"]:
            raise ValueError("not a binary little-endian PLY file")
        comments = [line[len("comment ") :] for line in lines if line.startswith("comment ")]
        counts, fields, element = {}, [], None
        for line in lines:
            words = line.split()
            if words[0] == "element":
                element = words[1]
                counts[element] = int(words[2])
            elif words[0] == "property" and element == "vertex":
                fields.append((words[2], "<" + _NP_TYPES[words[1]]))
        vdtype = np.dtype(fields)
        n_v, n_f = counts["vertex"], counts["face"]
        if n_v < 0 or n_f < 0:
            raise ValueError(f"negative element counts ({n_v} vertices, {n_f} faces)")
        vertices = np.frombuffer(data, dtype=vdtype, count=n_v, offset=end)
        rows = np.frombuffer(
            data, dtype=[("n", "u1"), ("v", "<i4", (3,))], count=n_f, offset=end + n_v * vdtype.itemsize
        )
        if np.any(rows["n"] != 3) or end + n_v * vdtype.itemsize + rows.nbytes != len(data):
            raise ValueError("faces are not triangles or the file's length is wrong")
        if rows.size and (rows["v"].min() < 0 or rows["v"].max() >= n_v):
            raise ValueError("its faces index outside its vertices")
    except (ValueError, KeyError, IndexError, UnicodeDecodeError) as exc:
        raise InvalidInputError(f"not a pydynrad PLY file: {exc}") from None
    return comments, {k: vertices[k] for k in vdtype.names}, rows["v"]
