"""Baked files written whole and checked: the bytes on disk are read back and compared before
the file replaces its target, so a short write or a full disk never leaves a file that looks
complete (see :func:`pydynrad.atomic.write_atomic` for the temporary-file-and-rename part)."""

from __future__ import annotations

import hashlib
from pathlib import Path

from ..atomic import write_atomic

__all__ = ["write_checked"]


def write_checked(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole; OSError when the file read back differs."""
    digest = hashlib.sha256(data).digest()

    def write(tmp: Path) -> None:
        tmp.write_bytes(data)
        if hashlib.sha256(tmp.read_bytes()).digest() != digest:
            raise OSError(f"cannot write {str(path)!r}: the file read back differs from what was written")

    return write_atomic(path, write)
