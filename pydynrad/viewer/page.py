"""The page the viewer serves: ``page.html`` beside this module (package data), one HTML document
with its style and script, nothing fetched from elsewhere.

The script draws the scene with WebGL 2 in the browser's own render loop: the geometry (every
patch's three corners) arrives once, then each radiosity update is one half-float texture of
smooth-vertex radiosity (and, with an overlay on, one byte-per-patch texture), which the vertex
shader fetches by index. The camera is the browser's (orbit, pan, dolly, WASD fly) and moves at
the display's frame rate whatever the solver costs; its pose goes to the server at most 30 times
a second, tagged with a sequence number so the page can time a move to its first radiosity.
Exposure (automatic by default), the sRGB transfer and back faces in black (patches radiate
from their front only, as :mod:`pydynrad.renderer` shows them) are applied in the fragment shader.

``window.pydynrad`` exposes the page's state to scripts and tests: ``ready``, ``stats`` (frames
received, updates per second, browser frames per second, move-to-radiosity latencies), the
camera, and ``setCamera(position, look_at)``.
"""

from __future__ import annotations

from importlib.resources import files

__all__ = ["page_bytes"]


def page_bytes() -> bytes:
    """The whole page, served at ``/``, read when a server starts (not when pydynrad is imported)."""
    return files(__package__).joinpath("page.html").read_bytes()
