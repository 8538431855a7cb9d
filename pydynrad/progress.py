"""Progress bars: one rule for every call that can take seconds and takes ``progress=``.

tqdm's own rules (``tqdm.auto``: a text bar on stderr, a widget in Jupyter):

- ``progress=None`` (the default everywhere): a bar appears once the work has run for
  :data:`pydynrad.defaults.PROGRESS_DELAY` (2) seconds (tqdm's ``delay=``), on any stream,
  terminal or not; work that ends sooner prints nothing;
- ``progress=True``: a bar from the start;
- ``progress=False`` (``--quiet`` on the command line): never.

Used by form factors (and stores), far-field G, multibounce matrices, solves, pose
precompute, baking, walks and the path tracer.
"""

from __future__ import annotations

from .defaults import PROGRESS_DELAY

__all__ = ["progress_bar", "shows_progress"]


def shows_progress(progress: bool | None) -> bool:
    """Whether a bar may be shown: ``progress`` itself; for None, yes (after the delay)."""
    return True if progress is None else bool(progress)


def progress_bar(progress: bool | None, **tqdm_options):
    """A ``tqdm.auto.tqdm`` (``total=``, ``desc=``, ``unit=``, or an iterable) by the rule above."""
    from tqdm.auto import tqdm

    tqdm_options.setdefault("delay", PROGRESS_DELAY if progress is None else 0.0)
    return tqdm(disable=not shows_progress(progress), **tqdm_options)
