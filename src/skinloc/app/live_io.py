"""The app's two ends of the live pipeline: frames in (``FrameQueue``), contacts out (``TabSink``).

The app reads the skin itself (``DeviceLink``) and uses its frames for the heat map, the sensor
statistics and the link state; in the live view it hands each frame to a
``skinloc.live.runner.Pipeline`` through a ``FrameQueue``, and the pipeline delivers what it
finds through the sink interface every other output uses (``skinloc.live.sinks.Sink``): every
contact of a frame together (``emit_contacts``: one per track, ``end`` included) and each
gesture event (``emit_gesture``). ``TabSink`` sends both to the tabs over the WebSocket.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Sequence
from typing import Any

from skinloc.app.hub import Hub
from skinloc.errors import FrameTimeoutError
from skinloc.live.contact import Contact, colour_index
from skinloc.live.sinks.base import Sink
from skinloc.sources.base import Frame, FrameSource

__all__ = ["FrameQueue", "TabSink"]

#: Frames kept for a pipeline that falls behind; past this the oldest go (the newest matter).
MAX_QUEUED = 256


class FrameQueue(FrameSource):
    """A frame source fed by another thread (the app's reader) with ``put``.

    Parameters
    ----------
    n_tx, n_rx : int
        Grid of the frames.
    name : str
        Shown in the pipeline's messages.
    """

    def __init__(self, n_tx: int, n_rx: int, name: str = "app") -> None:
        self.n_tx, self.n_rx = int(n_tx), int(n_rx)
        self._name = name
        self._frames: collections.deque[Frame] = collections.deque()
        self._ready = threading.Condition()
        self._open = False
        self.n_dropped = 0

    @property
    def name(self) -> str:
        """The name given."""
        return self._name

    @property
    def is_connected(self) -> bool:
        """Whether frames are being taken."""
        return self._open

    def _connect(self) -> None:
        self._open = True

    def _disconnect(self) -> None:
        with self._ready:
            self._open = False
            self._frames.clear()

    def put(self, frame: Frame) -> None:
        """Queue a frame (never blocks; drops the oldest past ``MAX_QUEUED``)."""
        with self._ready:
            self._frames.append(frame)
            if len(self._frames) > MAX_QUEUED:
                self._frames.popleft()
                self.n_dropped += 1
            self._ready.notify()

    def _read(self, timeout_s: float) -> Frame:
        with self._ready:
            if not self._frames and not self._ready.wait_for(lambda: self._frames, timeout_s):
                raise FrameTimeoutError(f"no frame from {self._name} within {timeout_s:g} s")
            return self._frames.popleft()


class TabSink(Sink):
    """Sends a skin's contacts and gestures to every tab.

    Messages: ``{"type": "live", "skin", "timestamp_s", "contacts": [...]}`` per frame with
    contacts (``Contact.to_dict()`` and ``colour``, the finger's index into the palette), and
    ``{"type": "gesture", **event}`` per gesture event (the shared gesture format: ``kind``,
    ``direction``, ``start_s``, ``end_s``, ``track_ids``, ...).
    A slow tab may lose ``live`` messages, never a gesture (``skinloc.app.hub``).
    """

    name = "app"

    def __init__(self, hub: Hub) -> None:
        self.hub = hub

    def emit(self, contact: Contact) -> None:
        """A contact delivered alone: a frame with one contact."""
        self.emit_contacts(contact.skin, contact.timestamp_s, [contact])

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Every contact of one frame, in one message."""
        self.hub.publish(
            {
                "type": "live",
                "skin": skin,
                "timestamp_s": timestamp_s,
                # each with its finger's colour, an index into the page's palette
                "contacts": [{**c.to_dict(), "colour": colour_index(c)} for c in contacts],
            }
        )

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """A gesture event, as it is (``skin`` and ``timestamp_s`` filled in when missing)."""
        self.hub.publish({"skin": skin, "timestamp_s": timestamp_s, **event, "type": "gesture"})
