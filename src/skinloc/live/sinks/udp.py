"""UDP: one JSON datagram per contact and per gesture event to a host and port (fire and forget)."""

from __future__ import annotations

import logging
import socket
from typing import TYPE_CHECKING, Any

from skinloc.live.sinks.base import Sink, SinkSpec, gesture_json

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = ["DEFAULT_PORT", "UdpSink"]

#: Where datagrams go when the spec names no port.
DEFAULT_PORT = 9870


class UdpSink(Sink):
    """Send ``Contact.to_json()`` as one UTF-8 datagram to ``(host, port)``.

    Sending never blocks the pipeline; a datagram the network refuses is counted in
    ``n_errors`` and skipped.
    """

    name = "udp"

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> UdpSink:
        """``udp[://HOST][:PORT]``: datagrams to HOST (127.0.0.1) and PORT (9870).

        The host is resolved here, so that a name that does not resolve is refused before a
        command loads its model.
        """
        sink = cls(*spec.address(DEFAULT_PORT))
        sink.resolve()
        return sink

    def __init__(self, host: str = "127.0.0.1", port: int = 9870) -> None:
        if not 0 < int(port) < 65536:
            raise ValueError(f"UDP port must be 1-65535 (where datagrams go), got {port!r}")
        self.address = (host, int(port))
        self._sock: socket.socket | None = None
        self._target: Any = None  # the resolved address
        self._family = socket.AF_INET
        self.n_sent = 0
        self.n_errors = 0

    def resolve(self) -> None:
        """Resolve the host once (kept for every datagram).

        Raises
        ------
        OSError
            Naming the host, when it does not resolve.
        """
        if self._target is None:
            host, port = self.address
            try:
                family, _, _, _, target = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
            except socket.gaierror as exc:
                why = f"cannot resolve {host} ({exc.strerror})"
                raise OSError(f"UDP sink {host}:{port}: {why}") from None
            self._family, self._target = family, target

    def open(self, skins: list) -> None:
        """Resolve the host (``resolve``) and create the socket."""
        if self._sock is None:
            self.resolve()
            self._sock = socket.socket(self._family, socket.SOCK_DGRAM)
            self._sock.setblocking(False)

    def emit(self, contact: Contact) -> None:
        """Send one datagram."""
        self._send(contact.to_json())

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """Send the gesture event as one datagram (``"event": "gesture"``)."""
        self._send(gesture_json(skin, event))

    def _send(self, text: str) -> None:
        if self._sock is None:
            self.open([])
        try:
            self._sock.sendto(text.encode(), self._target)
            self.n_sent += 1
        except OSError as exc:
            self.n_errors += 1
            if self.n_errors <= 3:
                log.warning("UDP sink %s:%d: %s", *self.address, exc)

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None
