"""Baked files written whole and checked: the bytes on disk are read back and compared before
the file replaces its target, so a short write or a full disk never leaves a file that looks
complete (see :func:`pydynrad.atomic.write_atomic` for the temporary-file-and-rename part)."""

from __future__ import annotations

import hashlib
import os
import uuid
from pathlib import Path

from ..atomic import TMP_MARK, check_file_target, write_atomic

__all__ = ["remove_stale_temporaries", "write_checked", "write_pair"]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return pid > 0  # another user's process (alive), or a number no process has
    return True


def remove_stale_temporaries(path) -> int:
    """Delete the hidden temporary files that writers of ``path`` killed mid-write left beside it
    (:func:`pydynrad.atomic.write_atomic`'s ``.NAME.tmp-PID-...``, and those of the temporaries
    it wrote through), where their process is gone; returns how many. A writer still running,
    this process included, keeps its own. As stores remove theirs on a resume
    (:meth:`pydynrad.FormFactorStore.remove_stale_temporaries`)."""
    path = Path(path)
    mark, n = f"{path.name}{TMP_MARK}", 0
    try:
        names = os.listdir(path.parent)
    except OSError:
        return 0
    for name in names:
        if not (name.startswith("." + mark) or name.startswith(".." + mark)):  # its own, or one written through it
            continue
        at = name.find(mark)
        pid = name[at + len(mark) :].split("-", 1)[0]
        if not pid.isdigit() or int(pid) == os.getpid() or _alive(int(pid)):
            continue
        try:
            (path.parent / name).unlink()
            n += 1
        except FileNotFoundError:
            pass
    return n


def write_pair(first, first_writer, second, second_writer) -> tuple[Path, Path]:
    """Write two files that belong together (a lightmap and the mesh that names it) so that
    ``second`` never stands beside a ``first`` that is not its own, whatever moment the process
    is killed at. Each is written whole to a temporary name in its own folder first
    (``first_writer(tmp)``, ``second_writer(tmp)``: each writes the file it is given); then
    ``second`` is removed, ``first`` renamed into place and ``second`` last: ``second`` is the
    pair's mark. A kill leaves the old pair, the new pair, or ``first`` alone (old or new)
    without ``second``, never ``second`` without its ``first``; the temporaries a kill leaves
    are removed by the next write of these names (:func:`remove_stale_temporaries`)."""
    paths = [check_file_target(first), check_file_target(second)]
    for p in paths:
        remove_stale_temporaries(p)
    tmps = [
        p.with_name(
            f".{p.name.encode()[:150].decode(errors='ignore')}{TMP_MARK}{os.getpid()}-"
            f"{uuid.uuid4().hex[:8]}{p.suffix if len(p.suffix.encode()) <= 16 else ''}"
        )
        for p in paths
    ]
    try:
        for tmp, target, writer in zip(tmps, paths, (first_writer, second_writer)):
            try:
                writer(tmp)
                with open(tmp, "rb+") as f:
                    os.fsync(f.fileno())
            except OSError as exc:  # a full disk: named for the file asked for, not the temporary one
                why = f"cannot write {str(target)!r}: {exc.strerror or exc}"
                raise (OSError(exc.errno, why) if exc.errno else OSError(why)) from None
        paths[1].unlink(missing_ok=True)
        os.replace(tmps[0], paths[0])
        os.replace(tmps[1], paths[1])
        for folder in {p.parent for p in paths}:  # the renames themselves on disk
            try:
                fd = os.open(folder, os.O_RDONLY)
            except OSError:
                continue
            try:
                os.fsync(fd)
            except OSError:
                pass
            finally:
                os.close(fd)
    finally:
        for tmp in tmps:
            tmp.unlink(missing_ok=True)
    return paths[0], paths[1]


def write_checked(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole; OSError when the file read back differs. Temporaries of
    ``path`` that killed writers left are removed first (:func:`remove_stale_temporaries`)."""
    digest = hashlib.sha256(data).digest()
    remove_stale_temporaries(path)

    def write(tmp: Path) -> None:
        tmp.write_bytes(data)
        if hashlib.sha256(tmp.read_bytes()).digest() != digest:
            raise OSError(f"cannot write {str(path)!r}: the file read back differs from what was written")

    return write_atomic(path, write)
