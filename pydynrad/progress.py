"""Progress bars: one rule for every long call that takes ``progress=``.

``progress=True`` shows a tqdm bar, ``False`` never does, and ``None`` (the default
everywhere) shows one only when stderr is a terminal, and only for work the caller counts
as long, so scripts, tests and notebooks stay quiet unless asked.
"""

from __future__ import annotations

import sys

__all__ = ["progress_bar", "shows_progress"]


def shows_progress(progress: bool | None, long: bool = True) -> bool:
    """Whether a bar is shown: ``progress`` itself, or for None: long work on a terminal."""
    if progress is None:
        return bool(long) and sys.stderr.isatty()
    return bool(progress)


def progress_bar(progress: bool | None, *, long: bool = True, **tqdm_options):
    """A ``tqdm.auto.tqdm`` (``total=``, ``desc=``, ``unit=``, or an iterable) shown by :func:`shows_progress`."""
    from tqdm.auto import tqdm

    return tqdm(disable=not shows_progress(progress, long), **tqdm_options)
