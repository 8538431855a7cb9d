"""Watch a dynamic radiosity solution live in a web browser: ``pydynrad view`` and :func:`view`.

:func:`view` serves a page (:mod:`pydynrad.viewer.page`) where the browser's camera is the
observer of a :class:`~pydynrad.DynamicRadiosity`: the local set follows it every frame, the
lights are edited live, a path file plays, and overlays show the local set, the far field's
clusters and the error against a full solve. It returns a :class:`Viewer`, the handle scripts
and notebooks drive it by. Needs the ``view`` extra (``pip install 'pydynrad[view]'``: the
``websockets`` package); the page is served from this package, nothing is fetched from the
internet. See docs/guide/viewer.md.
"""

from __future__ import annotations

from ..dynamic import DynamicRadiosity
from ..paths import CameraPath, WalkFile, load_walk
from .server import require_websockets
from .session import OVERLAYS, SKY_KINDS, Viewer, build_dynamic

__all__ = ["view", "Viewer", "OVERLAYS", "SKY_KINDS"]


def view(
    scene_or_dynamic,
    form_factors=None,
    *,
    lights=(),
    path=None,
    local_size: int | None = None,
    solver_options: dict | None = None,
    resolution: int = 32,
    host: str = "127.0.0.1",
    port: int = 8080,
    frames_per_second: float = 10.0,
    open_browser: bool = False,
    device=None,
) -> Viewer:
    """Serve a live view of a dynamic radiosity solution at ``http://host:port/``; the handle.

    Parameters
    ----------
    scene_or_dynamic : Scene or DynamicRadiosity
        A scene (a solution is built for it: M = ``local_size``, default min(N, 1024) as
        :func:`pydynrad.walk` takes, with ``solver_options``), or a ready solution to drive.
    form_factors : (N, N) sparse, RowSource or None
        F for the solution built here (None: one hemicube per entering patch at
        ``resolution``) and for the full solve of the error overlay.
    lights : sequence of lights
        The starting lights. The page edits a sun (the first DirectionalLight), a sky (the
        first uniform or CIE overcast or clear SkyLight given by horizontal illuminance) and
        point lights; other lights stay as given.
    path : str, Path, WalkFile or CameraPath, optional
        A path file (:func:`pydynrad.walks.load_walk`): the page plays, pauses and scrubs its
        camera, moving lights and moving objects.
    host, port : str, int
        Where to listen: 127.0.0.1 (this machine; over SSH forward the port, ``ssh -L
        8080:localhost:8080 host``) or 0.0.0.0 (every interface); port 0 picks a free one.
    frames_per_second : float
        Path frames per second while playing.
    open_browser : bool
        Open the page in this machine's browser.

    Returns
    -------
    Viewer
        Running until :meth:`Viewer.close`; in Jupyter it shows the page inline.
    """

    require_websockets()  # before any solver work
    if path is not None and not isinstance(path, WalkFile):
        path = path if isinstance(path, CameraPath) else load_walk(path)
    if isinstance(scene_or_dynamic, DynamicRadiosity):
        dynamic = scene_or_dynamic
    else:
        dynamic = build_dynamic(scene_or_dynamic, form_factors, path, local_size, solver_options, resolution, device)
    viewer = Viewer(
        dynamic,
        lights=lights,
        path=path,
        form_factors=form_factors,
        host=host,
        port=port,
        frames_per_second=frames_per_second,
    )
    if open_browser:
        import webbrowser

        webbrowser.open(viewer.url)
    return viewer
