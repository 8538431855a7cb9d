"""The viewer's web server: the page at ``/`` and a WebSocket at ``/ws`` on one port.

Built on ``websockets`` (the ``view`` extra), its threaded server: one thread per browser
reading its controls, and one sender thread per browser holding only the newest radiosity
frame, so a slow browser or link skips frames instead of delaying the solver or the others.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable

from ..errors import MissingExtraError
from .page import page_bytes

__all__ = ["Client", "Server", "require_websockets"]


def require_websockets():
    """The ``websockets`` module (13 or later), or MissingExtraError naming the extra."""
    try:
        import websockets
        from websockets.sync.server import serve  # noqa: F401
    except ImportError:
        raise MissingExtraError("the viewer", "websockets 13 or later", "view", name="websockets") from None
    return websockets


class _QuietProbes(logging.Filter):
    """Drop the tracebacks of connections closed before sending a request: browsers open spare
    sockets ahead of need (preconnect) and close them unused."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        return not (
            record.getMessage() == "opening handshake failed"
            and exc is not None
            and isinstance(exc.__cause__, EOFError)
        )


_LOG = logging.getLogger("pydynrad.viewer")
_LOG.addFilter(_QuietProbes())


class Client:
    """One connected browser: messages to it go through a sender thread; radiosity frames
    replace each other while waiting (only the newest is sent)."""

    def __init__(self, connection) -> None:
        self.connection = connection
        self._cond = threading.Condition()
        self._queue: list = []  # messages sent in order (scene, state, camera)
        self._frame: bytes | None = None  # the newest frame, sent after the queued messages
        self._closed = False
        self.frames_sent = 0
        self.stats: dict = {}
        self._thread = threading.Thread(target=self._send_loop, name="pydynrad-viewer-send", daemon=True)
        self._thread.start()

    def send(self, message) -> None:
        with self._cond:
            self._queue.append(message)
            self._cond.notify()

    def send_frame(self, message: bytes) -> None:
        with self._cond:
            self._frame = message
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()

    def _send_loop(self) -> None:
        while True:
            with self._cond:
                while not self._closed and not self._queue and self._frame is None:
                    self._cond.wait()
                if self._closed:
                    return
                if self._queue:
                    message, is_frame = self._queue.pop(0), False
                else:
                    message, self._frame, is_frame = self._frame, None, True
            try:
                self.connection.send(message)
            except Exception:  # the browser went away: its reader thread ends the client
                self.close()
                return
            if is_frame:
                self.frames_sent += 1


class Server:
    """Serves :func:`~pydynrad.viewer.page.page_bytes` and the WebSocket on ``host:port`` (0: any free
    port) in a background thread. ``on_connect(client)`` runs when a browser connects,
    ``on_message(client, message)`` for each message it sends (parsed JSON)."""

    def __init__(self, host: str, port: int, on_connect: Callable, on_message: Callable) -> None:
        require_websockets()
        from websockets.datastructures import Headers
        from websockets.http11 import Response
        from websockets.sync.server import serve

        page = page_bytes()

        def process_request(connection, request):
            path = request.path.split("?")[0]
            if path == "/ws":
                return None  # the WebSocket handshake
            if path in ("/", "/index.html"):
                headers = Headers(
                    [
                        ("Content-Type", "text/html; charset=utf-8"),
                        ("Content-Length", str(len(page))),
                        ("Cache-Control", "no-store"),
                    ]
                )
                return Response(200, "OK", headers, page)
            return connection.respond(404, "not found\n")

        self.clients: list[Client] = []
        self._lock = threading.Lock()
        self._on_connect, self._on_message = on_connect, on_message

        # compression=None: deflating half-float radiosity costs more CPU than it saves on a local link.
        self._server = serve(
            self._handle,
            host,
            port,
            process_request=process_request,
            compression=None,
            max_size=64 * 2**20,
            server_header=None,
            logger=_LOG,
        )
        self.host, self.port = self._server.socket.getsockname()[:2]
        self._thread = threading.Thread(target=self._server.serve_forever, name="pydynrad-viewer-http", daemon=True)
        self._thread.start()

    def _handle(self, connection) -> None:
        client = Client(connection)
        with self._lock:
            self.clients.append(client)
        try:
            self._on_connect(client)
            for raw in connection:
                if isinstance(raw, str):
                    self._on_message(client, json.loads(raw))
        except Exception:  # a closed connection ends the loop; anything else ends this browser only
            pass
        finally:
            client.close()
            with self._lock:
                if client in self.clients:
                    self.clients.remove(client)

    def broadcast(self, message, frame: bool = False) -> None:
        with self._lock:
            clients = list(self.clients)
        for c in clients:
            (c.send_frame if frame else c.send)(message)

    def close(self) -> None:
        self._server.shutdown()
        with self._lock:
            clients = list(self.clients)
        for c in clients:
            c.close()
            try:
                c.connection.close()
            except Exception:
                pass
        self._thread.join(timeout=5)
