"""JSON lines: one JSON object per contact and per gesture event, on stdout or in a file."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from skinloc.live.sinks.base import Sink, SinkSpec, gesture_json

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

__all__ = ["JsonLinesSink"]


class JsonLinesSink(Sink):
    """Write ``Contact.to_json()`` lines to stdout (``path=None``) or to a file.

    Each line is flushed, so a consumer reading a pipe sees every contact at once. Gesture
    events are lines of their own, ``{"event": "gesture", "kind": ..., ...}``
    (``skinloc.live.gestures``); contact lines have no ``"event"`` key.
    """

    name = "jsonl"

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> JsonLinesSink:
        """``jsonl`` (or ``jsonl:-``): stdout; ``jsonl:FILE``: appended to FILE."""
        return cls(spec.optional_file())

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = None if path in (None, "", "-") else Path(path)
        self._fh: IO[str] | None = None

    def open(self, skins: list) -> None:
        """Open the file (stdout needs nothing)."""
        if self.path is not None and self._fh is None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = self.path.open("a", encoding="utf-8")

    def _write(self, line: str) -> None:
        fh = self._fh if self._fh is not None else sys.stdout
        fh.write(line + "\n")
        fh.flush()

    def emit(self, contact: Contact) -> None:
        """Write one line."""
        self._write(contact.to_json())

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """Write the gesture event as one line."""
        self._write(gesture_json(skin, event))

    def close(self) -> None:
        """Close the file."""
        if self._fh is not None:
            self._fh.close()
            self._fh = None
