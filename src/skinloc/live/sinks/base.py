"""The sink interface and ``make_sink``, which builds one from a short text spec."""

from __future__ import annotations

import abc
import json
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs, urlsplit

import numpy as np

from skinloc._lazy import resolve

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = [
    "SINK_SPECS",
    "CallbackSink",
    "ListSink",
    "Sink",
    "SkinInfo",
    "gesture_json",
    "make_sink",
]

#: The spec forms ``make_sink`` understands, for help texts and error messages.
SINK_SPECS = (
    "jsonl (stdout) | jsonl:FILE",
    "ws://HOST:PORT (WebSocket server; port 0: any free port)",
    "udp://HOST:PORT (one JSON datagram per contact)",
    "foxglove://HOST:PORT[?mcap=FILE] (Foxglove live 3D scene, port 0: any free port; MCAP)",
    "mcap:FILE (Foxglove MCAP recording only)",
    "lsl[:NAME] (Lab Streaming Layer outlet)",
    "ros2[:NODE] (ROS 2 topics over DDS, or through rclpy when present)",
    "mcap-ros2:FILE (the ROS 2 topics and raw frames as a ROS 2 bag, MCAP)",
)


@dataclass(frozen=True)
class SkinInfo:
    """What a sink may want to know of a skin: its name, mesh, grid and pose on the robot.

    Attributes
    ----------
    name : str
        Skin name (``Contact.skin``).
    vertices : (V, 3) float or None
        Mesh vertices, m.
    faces : (F, 3) int or None
        Mesh triangles.
    n_tx, n_rx : int or None
        Grid of the raw frames.
    parent_frame : str or None
        A robot frame (link) the skin is mounted on; None: not configured.
    translation_m : (float, float, float)
        Origin of the skin's mesh frame in ``parent_frame``, m.
    rotation_xyzw : (float, float, float, float)
        Orientation of the mesh frame in ``parent_frame``, unit quaternion.
    max_contacts : int
        K: contacts (tracks, slots) per frame at most.
    """

    name: str
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    n_tx: int | None = None
    n_rx: int | None = None
    parent_frame: str | None = None
    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    max_contacts: int = 1


def _json_ready(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_ready(v) for v in value]
    return value


def gesture_json(skin: str, event: dict[str, Any], **extra: Any) -> str:
    """A gesture event as one line of JSON.

    ``"event": "gesture"`` and ``"skin"`` are always set, nan and infinities become null, and
    ``extra`` keys come first (the WebSocket sink's ``"type"``).
    """
    d = {**extra, **event, "event": "gesture", "skin": event.get("skin", skin)}
    return json.dumps(_json_ready(d), separators=(",", ":"))


class Sink(abc.ABC):
    """A consumer of contacts.

    ``open`` is called once with the skins it will see, ``emit`` for every contact from the
    pipeline's thread (it must not block for long: network sinks queue and send on their own
    thread), ``close`` once at the end. Usable as a context manager.
    """

    name: str = "sink"

    def open(self, skins: list[SkinInfo]) -> None:  # noqa: B027 - optional hook
        """Prepare for the given skins (start servers, advertise channels)."""

    @abc.abstractmethod
    def emit(self, contact: Contact) -> None:
        """Deliver one contact."""

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Deliver every contact of one frame of ``skin`` (one per track, ``end`` included).

        Sinks that send a frame's contacts together (Foxglove, ROS 2) override this; the
        default delivers them one by one through ``emit``.
        """
        for contact in contacts:
            self.emit(contact)

    def emit_gesture(  # noqa: B027 - optional hook
        self, skin: str, timestamp_s: float, event: dict[str, Any]
    ) -> None:
        """Deliver a gesture event of ``skin`` (a JSON-ready dict); ignored unless overridden.

        The ROS 2 sinks publish it on ``/skinloc/<skin>/gestures``.
        """

    def close(self) -> None:  # noqa: B027 - optional hook
        """Flush and release everything; no thread may be left behind."""

    def __enter__(self) -> Sink:
        self.open([])
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class CallbackSink(Sink):
    """Call ``fn(contact)`` for every contact."""

    name = "callback"

    def __init__(self, fn: Callable[[Contact], Any]) -> None:
        self.fn = fn

    def emit(self, contact: Contact) -> None:
        """Call the function."""
        self.fn(contact)


class ListSink(Sink):
    """Keep every contact in ``contacts``, every frame's in ``frames``, gestures in ``gestures``."""

    name = "list"

    def __init__(self) -> None:
        self.contacts: list[Contact] = []
        self.frames: list[list[Contact]] = []
        self.gestures: list[dict[str, Any]] = []

    def emit(self, contact: Contact) -> None:
        """Append."""
        self.contacts.append(contact)

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Append the frame's contacts (to ``frames`` and one by one to ``contacts``)."""
        self.frames.append(list(contacts))
        self.contacts.extend(contacts)

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """Append."""
        self.gestures.append(event)


def _host_port(spec: str, default_port: int) -> tuple[str, int]:
    """Host and port of ``scheme://host:port``; a missing port is ``default_port``.

    ``:0`` stays 0 (servers then bind any free port), so no truthiness test on the port.
    """
    parts = urlsplit(spec)
    host = parts.hostname or "127.0.0.1"
    try:
        port = parts.port
    except ValueError:
        raise ValueError(f"bad port in sink {spec!r} (ports are 0-65535)") from None
    return host, default_port if port is None else port


# Each backend by name, imported when a spec asks for it: this module never imports a backend
# (they import it), and optional dependencies load only when used.
_BACKENDS: dict[str, str] = {
    "jsonl": "skinloc.live.sinks.jsonl:JsonLinesSink",
    "ws": "skinloc.live.sinks.websocket:WebSocketSink",
    "udp": "skinloc.live.sinks.udp:UdpSink",
    "foxglove": "skinloc.live.sinks.foxglove:FoxgloveSink",
    "lsl": "skinloc.live.sinks.lsl:LslSink",
    "ros2": "skinloc.live.sinks.ros2.sink:Ros2Sink",
    "mcap-ros2": "skinloc.live.sinks.ros2.bag:Ros2BagSink",
}
_WS_DEFAULT_PORT = "skinloc.live.sinks.websocket:DEFAULT_PORT"


def _backend(name: str) -> Callable[..., Sink]:
    """The sink class registered as ``name``, imported now."""
    return resolve(_BACKENDS[name])


def make_sink(spec: str | Sink) -> Sink:
    """Build a sink from a spec string (a ``Sink`` is returned as is).

    Parameters
    ----------
    spec : str
        One of ``SINK_SPECS``: ``jsonl``, ``jsonl:out.jsonl``, ``ws://127.0.0.1:8767``,
        ``udp://127.0.0.1:9870``, ``foxglove://127.0.0.1:8766?mcap=run.mcap``,
        ``mcap:run.mcap``, ``lsl``, ``lsl:skin``, ``ros2``, ``mcap-ros2:run.mcap``.

    Examples
    --------
    >>> make_sink("udp://127.0.0.1:9870").address
    ('127.0.0.1', 9870)
    """
    if isinstance(spec, Sink):
        return spec
    text = str(spec).strip()
    scheme, _, rest = text.partition(":")
    scheme = scheme.lower()
    if scheme == "jsonl":
        return _backend("jsonl")(rest or None)
    if scheme in ("ws", "websocket"):
        return _backend("ws")(*_host_port(text, resolve(_WS_DEFAULT_PORT)))
    if scheme == "udp":
        return _backend("udp")(*_host_port(text, 9870))
    if scheme == "foxglove":
        host, port = _host_port(text, 8766)
        query = parse_qs(urlsplit(text).query)
        mcap = query.get("mcap", [None])[0]
        live = query.get("live", ["1"])[0] not in ("0", "false", "no")
        return _backend("foxglove")(host=host, port=port, mcap_path=mcap, live=live)
    if scheme == "mcap":
        if not rest:
            raise ValueError("sink 'mcap:FILE' needs a file name")
        return _backend("foxglove")(mcap_path=rest, live=False)
    if scheme == "lsl":
        return _backend("lsl")(rest or "skinloc")
    if scheme == "ros2":
        return _backend("ros2")(rest or "skinloc")
    if scheme == "mcap-ros2":
        if not rest:
            raise ValueError("sink 'mcap-ros2:FILE' needs a file name")
        return _backend("mcap-ros2")(rest)
    raise ValueError(f"unknown sink {text!r}; use one of: {'; '.join(SINK_SPECS)}")
