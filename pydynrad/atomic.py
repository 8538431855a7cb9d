"""Writing files whole: every file pydynrad writes (form-factor files and store blocks, images,
bench reports) goes through :func:`~pydynrad.atomic.write_atomic`, so a reader sees the old file or the new
one, never half of one, and a failed write leaves no debris.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path

from .errors import InvalidInputError

__all__ = ["check_parent_folder", "check_file_target", "write_atomic", "TMP_MARK"]

#: Marks temporary files in their names, so a store can find and remove ones a crash left.
TMP_MARK = ".tmp-"


def check_parent_folder(path) -> Path:
    """``path`` as a Path, or :class:`InvalidInputError` when the folder it goes into is missing."""
    path = Path(path)
    if not path.parent.is_dir():
        raise InvalidInputError(f"cannot write {str(path)!r}: the folder {str(path.parent)!r} does not exist")
    return path


def check_file_target(path) -> Path:
    """:func:`check_parent_folder`, and :class:`InvalidInputError` when a folder stands where the
    file would go (else found only at the rename, after the work, naming the temporary file)."""
    path = check_parent_folder(path)
    if path.is_dir():
        raise InvalidInputError(f"cannot write the file {str(path)!r}: a folder of that name is in the way")
    if not os.access(
        path.parent,
        os.W_OK | os.X_OK,  # else found only after the work
        effective_ids=os.access in os.supports_effective_ids,
    ):
        raise InvalidInputError(f"cannot write {str(path)!r}: the folder {str(path.parent)!r} is not writable")
    return path


def write_atomic(path, payload: bytes | Callable[[Path], object]) -> Path:
    """Write ``path`` whole: into a temporary file in the same folder, fsync, then ``os.replace``.

    ``payload`` is the file's bytes, or a function that writes the file at the path it is
    given (for writers that want a file name: OpenImageIO, matplotlib). The folder must exist.
    Returns ``path`` as a Path.
    """
    path = check_file_target(path)
    # A leading dot hides the temporary file; the same folder makes the rename atomic.
    # The name cut to 150 bytes: a valid name near the 255-byte limit must leave room for the mark.
    # The suffix kept last: readers that go by it (OpenImageIO's PFM rows) read the temporary
    # file as they will read the file, so a check of it checks what they get.
    stem = path.name.encode()[:150].decode(errors="ignore")
    suffix = path.suffix if len(path.suffix.encode()) <= 16 else ""
    tmp = path.with_name(f".{stem}{TMP_MARK}{os.getpid()}-{uuid.uuid4().hex[:8]}{suffix}")
    try:
        if callable(payload):
            payload(tmp)
        else:
            tmp.write_bytes(payload)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        if exc.filename is None or Path(exc.filename) != tmp:
            raise  # about another file, or already worded by the writer
        # Named for the file asked for, not the temporary one (of the same class where it can be).
        why = f"cannot write {str(path)!r}: {exc.strerror}"
        try:
            named = type(exc)(exc.errno, why)
        except TypeError:
            named = OSError(exc.errno, why)
        raise named from None
    finally:
        tmp.unlink(missing_ok=True)
    return path
