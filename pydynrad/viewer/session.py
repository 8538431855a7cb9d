"""The viewer's solver loop and the handle scripts drive it by (:class:`Viewer`).

One thread owns the solution: it waits for a change (the browser's camera, the lights, the
path's frame, an overlay), then runs one frame as :func:`pydynrad.walk` does (move the objects,
``update`` at the camera, ``radiosity`` with the lights), averages B onto the renderer's smooth
vertices (:mod:`pydynrad.smoothing`, so the picture is the renderer's smooth shading), and hands
one message to every browser's sender, which keeps only the newest. While the local set is
still moving towards the camera (a frame used all its swaps) it runs again without waiting.
"""

from __future__ import annotations

import base64
import collections
import math
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from ..comparison import radiosity_error
from ..dynamic import DynamicRadiosity
from ..dynamic.moves import MovingObjects
from ..errors import InvalidInputError, PydynradError
from ..geometry.camera import Camera
from ..image_io import read_image, write_image
from ..lights.sky import SkyLight, north_east, sun_direction
from ..lights.sources import DirectionalLight, PointLight
from ..paths import CameraPath, WalkFile, lights_at, load_walk
from ..renderer import Renderer
from ..rows.files import whole_matrix
from ..smoothing import smooth_vertices
from ..solution import solve
from .protocol import pack
from .server import Server

__all__ = ["Viewer", "OVERLAYS", "SKY_KINDS"]

OVERLAYS = ("none", "local", "clusters", "error")
SKY_KINDS = ("none", "uniform", "cie_overcast", "overcast", "clear")
#: Hemicube resolution of a sky set from the page: its light pass is one hemicube per patch.
SKY_RESOLUTION = 16
#: Texture width of the page's radiosity and overlay textures (texels per row).
TEXTURE_WIDTH = 2048
#: Half floats end here: radiosity beyond it is clipped (a display, not a measurement).
HALF_MAX = 65000.0
#: Seconds between K residual probes (:meth:`pydynrad.DynamicRadiosity.residual`) in the panel.
RESIDUAL_INTERVAL = 2.0


def _padded(a: np.ndarray) -> np.ndarray:
    """``a`` (n, k) padded with zero rows to a whole number of texture rows."""
    n = len(a)
    h = max(1, -(-n // TEXTURE_WIDTH))
    out = np.zeros((h * TEXTURE_WIDTH, a.shape[1]), dtype=a.dtype)
    out[:n] = a
    return out


def _texture_rows(n: int) -> int:
    return max(1, -(-n // TEXTURE_WIDTH))


def _hue_colours(labels: np.ndarray) -> np.ndarray:
    """(n, 3) uint8 colours, one per label, scattered over hues by the golden ratio."""
    h = (labels.astype(np.float64) * 0.618033988749895) % 1.0
    k = (np.array([5.0, 3.0, 1.0])[None, :] + 6.0 * h[:, None]) % 6.0
    rgb = 1.0 - 0.65 * np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
    return (255 * rgb).astype(np.uint8)


def _error_colours(err: np.ndarray, vmax: float = 0.2) -> np.ndarray:
    """(n, 3) uint8: relative error 0 (blue) to ``vmax`` and above (red), through green and yellow."""
    t = np.clip(err / vmax, 0.0, 1.0)[:, None]
    stops = np.array([[40, 60, 200], [40, 200, 90], [240, 220, 40], [230, 40, 30]], dtype=np.float64)
    x = t * 3.0
    i = np.minimum(x.astype(int), 2)[:, 0]
    f = x[:, 0] - i
    return ((1 - f)[:, None] * stops[i] + f[:, None] * stops[i + 1]).astype(np.uint8)


class _Lights:
    """What the page edits: a sun (elevation and azimuth about the scene's up axis), a sky, point
    lights; everything else given (spot lights, luminaires, a path's moving lights) stays fixed."""

    def __init__(self, scene, lights) -> None:
        self.up = np.asarray(scene.up, dtype=np.float64)
        self.unit = float(scene.unit)
        self.scale = float(scene.scale)
        self.sun = {"on": False, "elevation": 35.0, "azimuth": 135.0, "irradiance": 100.0}
        self.sky = {"kind": "none", "illuminance": 50.0}
        self.points: list[dict] = []
        self.fixed: list = []
        self.set(lights)

    def set(self, lights) -> None:
        lights = [lights] if not isinstance(lights, (list, tuple)) else list(lights)
        self.sun["on"], self.sky["kind"], self.points, self.fixed = False, "none", [], []
        for light in lights:
            if isinstance(light, DirectionalLight) and not self.sun["on"]:
                self.sun.update(
                    self._angles(-np.asarray(light.direction)), on=True, irradiance=float(max(light.irradiance))
                )
            elif (
                isinstance(light, SkyLight)
                and self.sky["kind"] == "none"
                and light.horizontal_illuminance is not None
                and light.kind in ("uniform", "cie_overcast", 1, 12)
            ):
                self.sky = {
                    "kind": {1: "overcast", 12: "clear"}.get(light.kind, light.kind),
                    "illuminance": float(light.horizontal_illuminance),
                }
            elif isinstance(light, PointLight):
                peak = float(max(light.intensity)) or 1.0
                self.points.append(
                    {"position": list(light.position), "intensity": peak, "colour": [c / peak for c in light.intensity]}
                )
            else:
                self.fixed.append(light)

    def _angles(self, towards: np.ndarray) -> dict:
        north, east = north_east(self.up)
        t = towards / np.linalg.norm(towards)
        el = math.degrees(math.asin(max(-1.0, min(1.0, float(t @ self.up)))))
        az = math.degrees(math.atan2(float(t @ east), float(t @ north))) % 360.0
        return {"elevation": round(el, 2), "azimuth": round(az, 2)}

    def update(self, message: dict) -> None:
        """The page's lights message, checked: a bad field raises InvalidInputError."""
        sun, sky = message.get("sun", {}), message.get("sky", {})
        new_sun = {
            "on": bool(sun.get("on", self.sun["on"])),
            "elevation": float(sun.get("elevation", self.sun["elevation"])),
            "azimuth": float(sun.get("azimuth", self.sun["azimuth"])) % 360.0,
            "irradiance": float(sun.get("irradiance", self.sun["irradiance"])),
        }
        if not -90.0 <= new_sun["elevation"] <= 90.0 or not new_sun["irradiance"] >= 0:
            raise InvalidInputError(f"sun elevation must lie in -90..90 degrees and irradiance be >= 0; got {sun}")
        kind = sky.get("kind", self.sky["kind"])
        if kind not in SKY_KINDS:
            raise InvalidInputError(f"sky model must be one of {', '.join(SKY_KINDS)}; got {kind!r}")
        new_sky = {"kind": kind, "illuminance": float(sky.get("illuminance", self.sky["illuminance"]))}
        points = []
        for i, p in enumerate(message.get("points", [dict(q) for q in self.points])):
            old = self.points[i] if i < len(self.points) else {"colour": [1.0, 1.0, 1.0]}
            points.append(
                {
                    "position": [float(v) for v in p["position"]],
                    "intensity": float(p["intensity"]),
                    "colour": old["colour"],
                }
            )
        self.sun, self.sky, self.points = new_sun, new_sky, points
        self.objects()  # raise here, not in the solver thread

    def objects(self) -> list:
        """The light objects of this state."""
        out = []
        if self.sun["on"] and self.sun["irradiance"] > 0:
            towards = sun_direction(self.sun["elevation"], self.sun["azimuth"], self.up)
            out.append(DirectionalLight(tuple(-v for v in towards), (self.sun["irradiance"],) * 3))
        if self.sky["kind"] != "none":
            kind = self.sky["kind"]
            sun = (
                sun_direction(max(0.0, self.sun["elevation"]), self.sun["azimuth"], self.up)
                if kind == "clear"
                else None
            )
            out.append(
                SkyLight(
                    kind, horizontal_illuminance=self.sky["illuminance"], sun_direction=sun, resolution=SKY_RESOLUTION
                )
            )
        for p in self.points:
            out.append(PointLight(p["position"], tuple(p["intensity"] * c for c in p["colour"])))
        return out + self.fixed

    def state(self) -> dict:
        return {
            "sun": dict(self.sun),
            "sky": dict(self.sky),
            "points": [{"position": p["position"], "intensity": p["intensity"]} for p in self.points],
            "fixed": len(self.fixed),
        }


class Viewer:
    """A running viewer: a web page at :attr:`url` where the browser's camera is the observer of
    a :class:`~pydynrad.DynamicRadiosity`. Made by :func:`pydynrad.viewer.view`; every method
    may be called from any thread. Close it with :meth:`close` (or use it in a ``with`` block).

    Attributes
    ----------
    dynamic : pydynrad.DynamicRadiosity
        The solution the viewer drives (its :attr:`~pydynrad.DynamicRadiosity.lock` lets other
        threads read it whole).
    url : str
        Where the page is served.
    """

    def __init__(
        self,
        dynamic: DynamicRadiosity,
        *,
        lights=(),
        path=None,
        form_factors=None,
        host: str = "127.0.0.1",
        port: int = 8080,
        frames_per_second: float = 10.0,
        camera: Camera | None = None,
    ) -> None:
        self.dynamic = dynamic
        self._form_factors = form_factors
        scene = dynamic.scene
        self._n = len(scene)
        self._static_n = self._n - sum(len(o) for o in dynamic.objects)
        self._reflecting = ~np.any(np.asarray(scene.emission) > 0, axis=1)  # what auto-exposure looks at
        self._smooth = smooth_vertices(scene)  # of the first poses; objects move rigidly, their groups stay
        self._lights = _Lights(scene, lights)
        self._path, self._tracks = None, []
        if path is not None:
            walk = (
                path
                if isinstance(path, WalkFile)
                else (WalkFile(path, [], []) if isinstance(path, CameraPath) else load_walk(path))
            )
            self._path, self._tracks = walk.path, list(walk.objects)
            self._lights.fixed += list(walk.lights)
        self._fps = float(frames_per_second)
        self._cond = threading.Condition()  # guards everything below, and wakes the solver
        self._closing = False
        self._camera = camera or (self._path.camera(0) if self._path is not None else _default_camera(scene))
        self._camera_seq = 0
        self._lights_version = 0
        self._path_state = {"frame": 0, "playing": False, "follow": True}
        self._next_path_frame = 0.0
        self._overlay = "none"
        self._reference = None  # (lights version, B of the full solve)
        self._stats: dict = {"frame": -1}
        self._history: collections.deque = collections.deque(maxlen=10000)
        self._frames = 0
        self._done = None  # (camera seq, lights version, path frame, overlay) of the last frame
        self._converging = False
        self._last_residual = (0.0, None)
        self._record_dir: Path | None = None
        self._recorded = 0
        self._screenshots: dict[int, object] = {}
        self._screenshot_id = 0
        self._notice = ""
        self._first_move = True
        self._path_camera_frame = 0 if self._path is not None else None  # the path frame whose camera was taken
        self._broadcast_path = False
        self._origin = scene.bbox.astype(np.float64).mean(axis=0)  # the page's coordinates: scene minus origin
        self._server = Server(host, port, self._on_connect, self._on_message)
        self.host, self.port = self._server.host, self._server.port
        shown = (
            "localhost"
            if host in ("127.0.0.1", "localhost", "::1")
            else (host if host not in ("", "0.0.0.0", "::") else "localhost")
        )
        self.url = f"http://{shown}:{self.port}/"
        self._solver = threading.Thread(target=self._run, name="pydynrad-viewer-solver", daemon=True)
        self._solver.start()

    # -- the handle ---------------------------------------------------------------------------------
    @property
    def camera(self) -> Camera:
        """The observer's camera: the browser's latest, or the one :meth:`set_camera` set."""
        with self._cond:
            return self._camera

    def set_camera(self, position, look_at, fov_y: float | None = None) -> None:
        """Move the observer (and every browser's camera) to ``position`` looking at ``look_at``."""
        cam = self.camera
        cam = Camera(
            position, look_at, self.dynamic.scene.up, cam.fov_y if fov_y is None else fov_y, cam.width, cam.height
        )
        self._set_camera(cam)
        self._server.broadcast(
            _json(
                {
                    "kind": "camera",
                    "position": cam.position.tolist(),
                    "look_at": cam.look_at.tolist(),
                    "fov_y": cam.fov_y,
                }
            )
        )

    @property
    def lights(self) -> list:
        """The light objects of the current frame's state (without a path's light tracks placed)."""
        with self._cond:
            return self._lights.objects()

    def set_lights(self, lights) -> None:
        """Replace the lights: the first directional light becomes the page's sun, the first uniform
        or CIE overcast/clear sky its sky, point lights its point lights; others stay fixed."""
        with self._cond:
            self._lights.set(lights)
            self._lights.objects()
            self._lights_changed()
        self._broadcast_state()

    def set_sun(self, elevation: float, azimuth: float, irradiance: float | None = None, on: bool = True) -> None:
        """The sun at ``elevation`` degrees above the horizon and ``azimuth`` degrees clockwise from
        north (:func:`pydynrad.lights.sky.sun_direction` about the scene's up axis)."""
        sun = {"on": on, "elevation": elevation, "azimuth": azimuth}
        if irradiance is not None:
            sun["irradiance"] = irradiance
        self._apply_lights({"sun": sun})

    def set_sky(self, kind: str, illuminance: float | None = None) -> None:
        """The sky model (``"none"``, ``"uniform"``, ``"cie_overcast"``, ``"overcast"``, ``"clear"``)
        and its unobstructed horizontal illuminance."""
        sky = {"kind": kind} if illuminance is None else {"kind": kind, "illuminance": illuminance}
        self._apply_lights({"sky": sky})

    def set_overlay(self, mode: str) -> None:
        """``"none"``, ``"local"`` (the local set green, the far field magenta), ``"clusters"``
        (the far field's clusters) or ``"error"`` (against a full solve: :meth:`full_solve`)."""
        if mode not in OVERLAYS:
            raise InvalidInputError(f"overlay must be one of {', '.join(OVERLAYS)}; got {mode!r}")
        with self._cond:
            self._overlay = mode
            self._cond.notify_all()
        self._broadcast_state()

    def play(self, playing: bool = True) -> None:
        """Play the path (its camera, moving lights and objects) at ``frames_per_second``."""
        self._set_path({"playing": playing})

    def pause(self) -> None:
        self._set_path({"playing": False})

    def seek(self, frame: int) -> None:
        """Go to ``frame`` of the path (paused)."""
        self._set_path({"frame": frame, "playing": False})

    @property
    def stats(self) -> dict:
        """The last frame's statistics: ``frame``, seconds by stage (``t_select``,
        ``t_form_factors``, ``t_update``, ``t_move``, ``t_lighting``, ``t_colours``, ``t_frame``
        = the solver's part, as :func:`pydynrad.walk` times update and lighting), ``swaps``,
        ``M``, ``N``, ``local`` (local patches), ``clusters``, ``residual`` (K's drift probe),
        ``error`` (relative RMS against the last full solve, while its lights hold), ``far_error``
        (the far field's own estimate of the all-patch error, where it makes one), ``seq`` (the
        camera pose it answered), ``clients`` (each browser's report: frames per second, radiosity
        updates per second received, median move-to-radiosity latency in ms)."""
        with self._cond:
            out = dict(self._stats)
        out["clients"] = [dict(c.stats) for c in self._server.clients]
        return out

    @property
    def history(self) -> list[dict]:
        """The stats of the last 10,000 frames, oldest first (as :attr:`stats`, without ``clients``)."""
        with self._cond:
            return list(self._history)

    def wait_frame(self, after: int | None = None, timeout: float = 30.0) -> dict:
        """Block until a frame newer than ``after`` (default: the current one) is done; its stats."""
        deadline = time.monotonic() + timeout
        with self._cond:
            after = self._stats["frame"] if after is None else after
            while self._stats["frame"] <= after:
                left = deadline - time.monotonic()
                if left <= 0 or self._closing:
                    raise TimeoutError(f"no viewer frame after {after} within {timeout:g} s")
                self._cond.wait(left)
        return self.stats

    def wait_idle(self, timeout: float = 60.0) -> dict:
        """Block until the solver has caught up with the camera, lights and path (the local set
        settled around the camera); the last frame's stats."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._needs_frame() or self._converging or self._done is None:
                left = deadline - time.monotonic()
                if left <= 0 or self._closing:
                    raise TimeoutError(f"the viewer did not settle within {timeout:g} s")
                self._cond.wait(min(left, 0.1))
        return self.stats

    def full_solve(self) -> float:
        """Solve the full radiosity for the current lights (all N patches, :func:`pydynrad.solve`),
        keep it for the ``"error"`` overlay, and return the current frame's relative RMS error."""

        if self._form_factors is None:
            raise InvalidInputError("a full solve needs the form factors: give view() form_factors=F")
        if self._tracks:
            raise InvalidInputError(
                "a full solve of a path with moving objects is not offered here: use walk's reference_frames"
            )
        with self._cond:
            version, lights = self._lights_version, self._frame_lights()
        reference = solve(
            self.dynamic.scene, whole_matrix(self._form_factors), lights, device=self.dynamic.device
        ).radiosity
        with self._cond:
            self._reference = (version, np.asarray(reference))
            self._done = None  # send the next frame with the error
            self._cond.notify_all()
        return self.wait_frame()["error"]

    def screenshot(self, path=None, timeout: float = 20.0) -> np.ndarray:
        """What the first connected browser shows, as an (H, W, 4) uint8 RGBA array (written to
        ``path`` too when given: .png)."""
        clients = list(self._server.clients)
        if not clients:
            raise InvalidInputError(f"no browser is connected: open {self.url}")
        with self._cond:
            self._screenshot_id += 1
            sid = self._screenshot_id
        clients[0].send(_json({"kind": "screenshot", "id": sid}))
        deadline = time.monotonic() + timeout
        with self._cond:
            while sid not in self._screenshots:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"the browser sent no screenshot within {timeout:g} s")
                self._cond.wait(left)
            png = self._screenshots.pop(sid)
        target = Path(path) if path is not None else None
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            file = target or Path(tmp) / "shot.png"
            file.write_bytes(png)
            image = read_image(file)
        return (
            np.asarray(np.clip(np.round(image * 255.0), 0, 255), dtype=np.uint8) if image.dtype != np.uint8 else image
        )

    def record(self, folder) -> None:
        """Write every radiosity update from now on to ``folder`` as ``frame_NNNNN.png``, rendered
        by :class:`pydynrad.renderer.Renderer` at the browser's camera and the page's automatic
        exposure (pictures of the solution, whatever the browser's speed)."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        with self._cond:
            self._record_dir, self._recorded = folder, 0
            self._done = None
            self._cond.notify_all()
        self._broadcast_state()

    def stop_recording(self) -> int:
        """Stop :meth:`record`; the number of frames written."""
        with self._cond:
            self._record_dir = None
            n = self._recorded
        self._broadcast_state()
        return n

    def close(self) -> None:
        """Stop the solver thread and the server; the page says it was closed."""
        with self._cond:
            if self._closing:
                return
            self._closing = True
            self._cond.notify_all()
        self._solver.join(timeout=30)
        self._server.close()

    def serve_forever(self) -> None:
        """Block until interrupted (Ctrl-C), then close."""
        try:
            while not self._closing:
                time.sleep(0.5)
        finally:
            self.close()

    def __enter__(self) -> Viewer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<pydynrad Viewer at {self.url}, {self._n} patches, M = {self.dynamic.M}>"

    def _repr_html_(self) -> str:  # Jupyter: the page in an iframe
        return f'<iframe src="{self.url}" width="100%" height="600" style="border:0"></iframe>'

    # -- state changes --------------------------------------------------------------------------------
    def _set_camera(self, cam: Camera, seq: int | None = None) -> None:
        with self._cond:
            self._camera = cam
            self._camera_seq = self._camera_seq + 1 if seq is None else max(seq, self._camera_seq)
            self._cond.notify_all()

    def _apply_lights(self, message: dict) -> None:
        with self._cond:
            self._lights.update(message)
            self._lights_changed()
        self._broadcast_state()

    def _lights_changed(self) -> None:
        self._lights_version += 1
        self._cond.notify_all()

    def _set_path(self, change: dict) -> None:
        if self._path is None:
            raise InvalidInputError("this viewer has no path: give view() path=PATH.json")
        with self._cond:
            if "frame" in change:
                k = int(change["frame"])
                if not 0 <= k < len(self._path):
                    raise InvalidInputError(f"path frame must lie in 0..{len(self._path) - 1}; got {k}")
                self._path_state["frame"] = k
            for key in ("playing", "follow"):
                if key in change:
                    self._path_state[key] = bool(change[key])
            self._next_path_frame = time.monotonic()
            self._cond.notify_all()
        self._broadcast_state()

    def _state(self) -> dict:
        with self._cond:
            path = None if self._path is None else {**self._path_state, "frames": len(self._path)}
            return {
                "kind": "state",
                "lights": self._lights.state(),
                "path": path,
                "overlay": self._overlay,
                "recording": self._record_dir is not None,
            }

    def _broadcast_state(self) -> None:
        self._server.broadcast(_json(self._state()))

    def _on_connect(self, client) -> None:
        scene = self.dynamic.scene
        origin = self._origin
        corners = (np.asarray(scene.triangles, dtype=np.float64) - origin).astype(np.float32)
        n_v = self._smooth.n_vertices
        cam = self.camera
        head = {
            "name": getattr(scene, "name", "scene"),
            "n_patches": self._n,
            "n_vertices": n_v,
            "origin": origin.tolist(),
            "up": [float(v) for v in scene.up],
            "scale": float(scene.scale),
            "rad_w": TEXTURE_WIDTH,
            "rad_h": _texture_rows(n_v),
            "ov_w": TEXTURE_WIDTH,
            "ov_h": _texture_rows(self._n),
            "camera": {"position": cam.position.tolist(), "look_at": cam.look_at.tolist(), "fov_y": cam.fov_y},
            "point_intensity": 20.0 * (0.25 * float(scene.scale) * float(scene.unit)) ** 2,
        }
        client.send(
            pack(
                "scene",
                {"positions": corners.reshape(-1), "vid": self._smooth.corner_vertex.reshape(-1).astype(np.uint32)},
                **head,
            )
        )
        client.send(_json(self._state()))
        if self._notice:
            client.send(_json({"kind": "notice", "text": self._notice}))
        with self._cond:
            self._done = None  # the new browser gets a frame
            self._cond.notify_all()

    def _on_message(self, client, msg: dict) -> None:
        kind = msg.get("type")
        try:
            if kind == "camera":
                cam = self.camera
                aspect = float(msg.get("aspect") or cam.width / cam.height)
                width = 640
                height = max(1, int(round(width / max(aspect, 1e-3))))
                new = Camera(
                    msg["position"],
                    msg["look_at"],
                    self.dynamic.scene.up,
                    float(msg.get("fov_y", cam.fov_y)),
                    width,
                    min(height, 4096),
                )
                self._set_camera(new, int(msg.get("seq", 0)))
            elif kind == "lights":
                self._apply_lights(msg)
            elif kind == "overlay":
                self.set_overlay(msg.get("mode", "none"))
                if msg.get("mode") == "error" and self._reference is None:
                    self._notify("overlay 'error': press 'full solve' to compute the reference")
            elif kind == "full_solve":
                threading.Thread(target=self._full_solve_from_page, daemon=True).start()
            elif kind == "path":
                self._set_path({k: msg[k] for k in ("frame", "playing", "follow") if k in msg})
            elif kind == "record":
                if msg.get("on"):
                    self.record(Path.cwd() / f"pydynrad-view-{time.strftime('%Y%m%d-%H%M%S')}")
                else:
                    self.stop_recording()
            elif kind == "client_stats":
                client.stats = {
                    k: msg.get(k)
                    for k in ("fps", "updates_per_second", "frames_received", "latency_ms_median", "bytes_received")
                }
            elif kind == "screenshot":
                png = base64.b64decode(str(msg["png"]).split(",", 1)[1])
                with self._cond:
                    self._screenshots[int(msg["id"])] = png
                    self._cond.notify_all()
        except (PydynradError, ValueError, KeyError, TypeError) as exc:
            self._notify(f"{kind}: {exc}")
            self._broadcast_state()  # the page shows the state that holds

    def _full_solve_from_page(self) -> None:
        try:
            self._notify("solving the full radiosity...")
            error = self.full_solve()
            self._notify(f"full solve done: {100 * error:.2f}% relative RMS error")
        except Exception as exc:  # reported on the page, not raised in a thread
            self._notify(f"full solve: {exc}")

    def _notify(self, text: str) -> None:
        self._notice = text
        self._server.broadcast(_json({"kind": "notice", "text": text}))

    # -- the solver thread ----------------------------------------------------------------------------
    def _frame_lights(self) -> list:
        lights = self._lights.objects()
        if self._path is not None:
            lights = lights_at(lights, self._path_state["frame"], len(self._path))
        return lights

    def _key(self) -> tuple:
        return (self._camera_seq, self._lights_version, self._path_state["frame"], self._overlay)

    def _needs_frame(self) -> bool:
        return self._done != self._key()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closing:
                    now = time.monotonic()
                    if self._path is not None and self._path_state["playing"] and now >= self._next_path_frame:
                        self._path_state["frame"] = (self._path_state["frame"] + 1) % len(self._path)
                        self._next_path_frame = now + 1.0 / self._fps
                        self._broadcast_path = True
                    if self._needs_frame() or self._converging:
                        break
                    wait = 0.5
                    if self._path is not None and self._path_state["playing"]:
                        wait = max(0.0, self._next_path_frame - now)
                    self._cond.wait(wait)
                if self._closing:
                    return
                key = self._key()
                lights = self._frame_lights()
                k = self._path_state["frame"]
                cam, from_path = self._camera, False
                if self._path is not None and self._path_state["follow"] and k != self._path_camera_frame:
                    cam, from_path = self._path.camera(k), True
                    self._path_camera_frame = k
                overlay, reference = self._overlay, self._reference
                record = self._record_dir
            if from_path:
                self._set_camera(cam)
                with self._cond:
                    key = self._key()
                self._server.broadcast(
                    _json(
                        {
                            "kind": "camera",
                            "position": cam.position.tolist(),
                            "look_at": cam.look_at.tolist(),
                            "fov_y": cam.fov_y,
                        }
                    )
                )
            if self._broadcast_path:
                self._broadcast_path = False
                self._broadcast_state()
            try:
                self._frame(key, cam, lights, k, overlay, reference, record)
            except Exception as exc:  # the page says what went wrong; the loop goes on with the next change
                with self._cond:
                    self._done, self._converging = key, False
                    self._cond.notify_all()
                self._notify(f"frame failed: {type(exc).__name__}: {exc}")

    def _frame(self, key, cam: Camera, lights, k: int, overlay: str, reference, record) -> None:
        dyn = self.dynamic
        t0 = time.perf_counter()
        moved = False
        if self._tracks and (self._first_move or key[2] != getattr(self, "_moved_frame", None)):
            for t in self._tracks:
                dyn.move(t.object, t.at(k, len(self._path)))
            self._moved_frame, self._first_move, moved = key[2], False, True
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a sky facing away and the like: the picture says it
            stats = dyn.update(cam.position)
            t1 = time.perf_counter()
            B = np.asarray(dyn.radiosity(lights))
        t2 = time.perf_counter()
        rad = self._smooth.radiosity(B)
        rad16 = _padded(np.clip(rad, 0.0, HALF_MAX).astype(np.float16))
        local = dyn.local_mask
        lit = local & self._reflecting if (local & self._reflecting).any() else self._reflecting
        auto = _auto_stops(B[lit] if lit.any() else B)
        arrays = {"rad": rad16.reshape(-1)}
        error = None
        if reference is not None and reference[0] == key[1]:
            error = radiosity_error(B, reference[1], dyn.scene.areas)
        if overlay != "none":
            arrays["overlay"] = self._overlay_rgba(overlay, local, B, reference, key[1]).reshape(-1)
        t3 = time.perf_counter()
        now = time.monotonic()
        if now - self._last_residual[0] >= RESIDUAL_INTERVAL:
            self._last_residual = (now, float(dyn.residual()))
        st = {
            "frame": self._frames,
            "seq": key[0],
            "swaps": int(stats.swaps),
            "M": int(dyn.M),
            "N": self._n,
            "local": int(local.sum()),
            "clusters": None if dyn.far is None else int(dyn.far.C),
            "t_select": stats.t_select,
            "t_form_factors": stats.t_form_factors,
            "t_update": stats.t_update,
            "t_move": stats.t_move,
            "t_lighting": t2 - t1,
            "t_colours": t3 - t2,
            "t_frame": t2 - t0,
            "residual": self._last_residual[1],
            "error": error,
            "auto_stops": auto,
            "far_error": _far_error(dyn),
            "recording": record is not None,
            "recorded": self._recorded,
        }
        if moved:
            first = self._static_n
            corners = (np.asarray(dyn.scene.triangles[first:], dtype=np.float64) - self._origin).astype(np.float32)
            self._server.broadcast(pack("positions", {"positions": corners.reshape(-1)}, offset=first * 9))
        self._server.broadcast(
            pack(
                "frame",
                arrays,
                frame=self._frames,
                seq=key[0],
                stats=st,
                auto_stops=auto,
                recording=record is not None,
                recorded=self._recorded,
            ),
            frame=True,
        )
        if record is not None:
            self._record(record, B, cam, auto)
        with self._cond:
            self._stats = st
            self._history.append(st)
            self._frames += 1
            self._done = key
            self._converging = stats.swaps >= dyn.max_swaps
            self._cond.notify_all()

    def _overlay_rgba(self, overlay: str, local: np.ndarray, B: np.ndarray, reference, version: int) -> np.ndarray:
        n = self._n
        rgba = np.zeros((n, 4), dtype=np.uint8)
        if overlay == "local":
            rgba[:, :3] = np.where(local[:, None], [[40, 220, 90]], [[220, 40, 200]])
            rgba[:, 3] = 90
        elif overlay == "clusters" and self.dynamic.far is not None:
            labels = (
                self.dynamic.far.clusters.labels[:n]
                if len(self.dynamic.far.clusters.labels) >= n
                else np.concatenate(
                    [self.dynamic.far.clusters.labels, np.arange(n - len(self.dynamic.far.clusters.labels)) + 10**6]
                )
            )
            rgba[:, :3] = _hue_colours(labels)
            rgba[:, 3] = 160
        elif overlay == "error" and reference is not None and reference[0] == version:
            ref = reference[1].sum(axis=1)
            err = np.abs(B.sum(axis=1) - ref) / np.maximum(ref, 1e-3 * max(float(ref.max()), 1e-30))
            rgba[:, :3] = _error_colours(err)
            rgba[:, 3] = 200
        return _padded(rgba)

    def _record(self, folder: Path, B: np.ndarray, cam: Camera, stops) -> None:
        renderer = getattr(self, "_renderer", None)
        if renderer is None or renderer.scene is not self.dynamic.scene:
            renderer = self._renderer = Renderer(self.dynamic.scene, self.dynamic.device)
        image = renderer.render(B, cam)
        write_image(folder / f"frame_{self._recorded:05d}.png", image, 0.0 if stops is None else stops)
        self._recorded += 1


def _far_error(dyn) -> float | None:
    """The far field's estimate of this answer's all-patch error (relative RMS), where the
    solution makes one (:mod:`pydynrad.farfield.estimate`)."""
    estimate = getattr(dyn, "error_estimate", None)
    value = getattr(estimate, "error", None)
    return None if value is None else float(value)


def _json(obj: dict) -> str:
    import json

    return json.dumps(obj, separators=(",", ":"))


def _auto_stops(B: np.ndarray) -> float | None:
    """Stops that bring the median luminance of ``B`` (the local set's reflecting patches: what
    the observer is among) to 0.18, a mid grey, or less where that would push the brightest
    twentieth past 0.9; None for no light."""
    y = B @ np.array([0.2126, 0.7152, 0.0722])
    y = y[y > 0]
    if not len(y):
        return None
    median, high = np.percentile(y, [50, 95])
    return float(np.clip(min(math.log2(0.18 / median), math.log2(0.9 / high)), -60.0, 60.0))


def _default_camera(scene) -> Camera:
    """Looking at the scene's centre from one diagonal away, along the horizontal axis nearest
    +z (the Cornell box's published side) and a third of a diagonal up."""
    lo, hi = scene.bbox.astype(np.float64)
    centre, size = 0.5 * (lo + hi), float(scene.scale)
    up = np.asarray(scene.up, dtype=np.float64)
    axes = np.eye(3)[[2, 0, 1]]
    h = min(axes, key=lambda a: abs(float(a @ up)))
    h = h - (h @ up) * up
    h /= np.linalg.norm(h)
    return Camera(centre - 0.9 * size * h + 0.35 * size * up, centre, up, 45.0, 640, 480)


def build_dynamic(scene, form_factors, path, local_size, solver_options, resolution: int, device) -> DynamicRadiosity:
    """A DynamicRadiosity for the viewer: M = ``local_size`` (default min(N, 1024), as walk), with
    the path's moving objects."""
    options = dict(solver_options or {})
    tracks = list(path.objects) if isinstance(path, WalkFile) else []
    if tracks:
        settings = options.get("objects")
        settings = settings if isinstance(settings, MovingObjects) else MovingObjects(())
        import dataclasses

        options["objects"] = dataclasses.replace(settings, objects=[t.object for t in tracks])
    if form_factors is None or tracks:  # rows by hemicube: entering patches', or the objects'
        options.setdefault("resolution", resolution)
    n = len(scene) + sum(len(t.object) for t in tracks)
    m = min(n, 1024) if local_size is None else min(int(local_size), n)
    return DynamicRadiosity(scene, form_factors, local_size=m, device=device, **options)
