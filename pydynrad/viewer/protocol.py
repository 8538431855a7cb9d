"""The viewer's messages: JSON text for state and controls, one binary layout for arrays.

A binary message is ``uint32 n`` (little-endian), ``n`` bytes of UTF-8 JSON (the header), zero
padding to a multiple of 8 bytes, then the arrays back to back, each at an offset that is a
multiple of 8 bytes from the start of the payload. The header names them:
``{"kind": ..., "arrays": {"name": [dtype, offset, count], ...}, ...}`` with ``dtype`` one of
``f4``, ``f2``, ``u4``, ``u1``, so the page reads each as a typed array view without a copy.
"""

from __future__ import annotations

import json
import struct

import numpy as np

__all__ = ["pack", "unpack"]

_DTYPES = {"f4": np.float32, "f2": np.float16, "u4": np.uint32, "u1": np.uint8}


def _pad(n: int) -> int:
    return (-n) % 8


def pack(kind: str, arrays: dict | None = None, **fields) -> bytes:
    """One binary message of ``kind`` carrying ``arrays`` (name -> numpy array of a supported dtype)."""
    arrays = arrays or {}
    table, chunks, offset = {}, [], 0
    for name, a in arrays.items():
        a = np.ascontiguousarray(a)
        code = next((c for c, t in _DTYPES.items() if a.dtype == t), None)
        if code is None:
            raise TypeError(f"array {name!r} of dtype {a.dtype} cannot be sent (f4, f2, u4 or u1)")
        raw = a.tobytes()
        table[name] = [code, offset, int(a.size)]
        chunks += [raw, b"\0" * _pad(len(raw))]
        offset += len(raw) + _pad(len(raw))
    head = json.dumps({"kind": kind, "arrays": table, **fields}, separators=(",", ":")).encode()
    return b"".join([struct.pack("<I", len(head)), head, b"\0" * _pad(4 + len(head)), *chunks])


def unpack(message: bytes) -> tuple[dict, dict]:
    """(header, arrays) of a message made by :func:`pack` (the page's decoder, in Python: tests)."""
    (n,) = struct.unpack_from("<I", message, 0)
    head = json.loads(message[4 : 4 + n])
    base = 4 + n + _pad(4 + n)
    arrays = {
        name: np.frombuffer(message, _DTYPES[code], count, base + off)
        for name, (code, off, count) in head["arrays"].items()
    }
    return head, arrays
