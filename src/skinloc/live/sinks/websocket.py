"""A WebSocket server that broadcasts every contact as JSON to every connected client.

On connecting, a client first receives ``{"type": "hello", "skins": [...]}`` (names and meshes,
m); then one message per contact, the same JSON object as the JSON-lines sink (with
``"type": "contact"``), and one per gesture event (``"type": "gesture"``). The server runs
on its own thread with its own asyncio loop, so a slow client never stalls the pipeline
(``websockets`` drops it when its buffer fills).
"""

from __future__ import annotations

import asyncio
import json
import logging
import socket
import threading
from typing import TYPE_CHECKING, Any

from skinloc.live.sinks.base import Sink, SinkSpec, SkinInfo, gesture_json

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_PORT", "WebSocketSink"]

#: The sink's default TCP port: not 8765, which ``skinloc app`` serves on, nor Foxglove's 8766.
DEFAULT_PORT = 8767


def _listen(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host:port`` (``port=0``: a free port the kernel picks).

    Bound here, not by ``websockets``, so that a host with several addresses (``localhost``)
    gets one socket and one port, and a port in use fails in ``open`` itself.
    """
    infos = socket.getaddrinfo(host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    family, _, _, _, address = infos[0]
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(address)
        sock.listen(64)
    except OSError:
        sock.close()
        raise
    return sock


class WebSocketSink(Sink):
    """Serve contacts on ``ws://host:port`` (``port=0`` picks a free port: see ``port``).

    Parameters
    ----------
    host : str, default="127.0.0.1"
        Address to bind; the loopback by default (use 0.0.0.0 deliberately).
    port : int, default=DEFAULT_PORT (8767)
        TCP port; 0 asks the system for a free one. After ``open``, ``port`` and ``url`` hold
        the port actually bound (logged, and sent in the hello message).
    """

    name = "websocket"

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> WebSocketSink:
        """``ws[://HOST][:PORT]``: a server on HOST (127.0.0.1) and PORT (8767; 0: any free)."""
        return cls(*spec.address(DEFAULT_PORT))

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> None:
        port = int(port)
        if not 0 <= port < 65536:
            raise ValueError(f"WebSocket port must be 0 (any free port) or 1-65535, got {port}")
        self.host = host
        self.port = port
        self._want_port = port  # what to bind on every open (0: a fresh free port)
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Future | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._hello = json.dumps({"type": "hello", "skins": []})
        self._server: Any = None
        self.n_sent = 0

    @property
    def url(self) -> str:
        """``ws://host:port`` of the server (after ``open``: the port actually bound)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def open(self, skins: list[SkinInfo]) -> None:
        """Start the server thread; raises ``OSError`` when the port cannot be bound."""
        try:
            import websockets  # noqa: F401
        except ImportError:  # pragma: no cover - a dependency
            raise ImportError(
                "the WebSocket sink needs 'websockets': pip install websockets"
            ) from None
        if self._thread is None:
            try:
                self._sock = _listen(self.host, self._want_port)
            except OSError as exc:
                raise OSError(
                    f"WebSocket sink cannot listen on {self.host}:{self._want_port}: "
                    f"{exc.strerror or exc}"
                ) from None
            self.port = self._sock.getsockname()[1]
        self._hello = json.dumps(
            {
                "type": "hello",
                "url": self.url,
                "skins": [
                    {
                        "name": s.name,
                        "vertices": None if s.vertices is None else s.vertices.tolist(),
                        "faces": None if s.faces is None else s.faces.tolist(),
                    }
                    for s in skins
                ],
            }
        )
        if self._thread is not None:
            return
        self._ready.clear()
        self._thread = threading.Thread(target=self._run, name="skinloc-ws-sink", daemon=True)
        self._thread.start()
        self._ready.wait(10.0)
        if self._error is not None:
            err, self._error = self._error, None
            self._thread.join(2.0)
            self._thread = None
            self._close_socket()
            raise OSError(f"WebSocket sink cannot listen on {self.host}:{self.port}: {err}")
        log.info("WebSocket sink on %s", self.url)

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # noqa: BLE001 - reported to open()
            self._error = exc
            self._ready.set()

    async def _main(self) -> None:
        from websockets.asyncio.server import serve

        self._loop = asyncio.get_running_loop()
        self._stop = self._loop.create_future()

        async def handler(ws: Any) -> None:
            await ws.send(self._hello)
            try:
                async for _ in ws:  # clients may talk; nothing to answer
                    pass
            except Exception:  # noqa: BLE001 - a client going away is normal
                pass

        async with serve(handler, sock=self._sock, max_queue=16, write_limit=2**16) as srv:
            self._server = srv
            self._ready.set()
            await self._stop

    def _broadcast(self, text: str) -> None:
        from websockets.asyncio.server import broadcast

        if self._server is not None:
            broadcast(self._server.connections, text)
            self.n_sent += 1

    def emit(self, contact: Contact) -> None:
        """Queue one message for every client (never blocks)."""
        loop = self._loop
        if loop is None or self._server is None:
            return
        d = contact.to_dict()
        d["type"] = "contact"
        self._queue(json.dumps(d, separators=(",", ":")))

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """Queue the gesture event for every client (``"type": "gesture"``)."""
        self._queue(gesture_json(skin, event, type="gesture"))

    def _queue(self, text: str) -> None:
        loop = self._loop
        if loop is None or self._server is None:
            return
        try:
            loop.call_soon_threadsafe(self._broadcast, text)
        except RuntimeError:  # the loop is closing
            pass

    @property
    def n_clients(self) -> int:
        """Clients connected now."""
        return 0 if self._server is None else len(self._server.connections)

    def close(self) -> None:
        """Stop the server and join its thread."""
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None:
            try:
                loop.call_soon_threadsafe(lambda: stop.done() or stop.set_result(None))
            except RuntimeError:
                pass
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        self._close_socket()
        self._loop = self._stop = self._server = None

    def _close_socket(self) -> None:
        # The server closes the socket it serves; this covers a server that never started.
        if self._sock is not None:
            self._sock.close()
            self._sock = None
