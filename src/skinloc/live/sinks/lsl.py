"""Lab Streaming Layer outlets: one sample per frame's contacts, one marker per gesture.

Through ``pylsl``. Per skin, two outlets:

* ``<name>-<skin>``, type ``Contact``, float32, irregular rate: one sample per frame that has
  contacts, laid out as ``K`` fixed slots (``K`` = the skin's ``max_contacts``; the slot is the
  track's protocol-B slot, so a finger keeps its columns while it is down). Channels: first
  ``touch_id``, ``signal_z``, ``latency_us`` (the frame's), then for each slot ``k`` in
  ``0..K-1``: ``s<k>_x_m``, ``s<k>_y_m``, ``s<k>_z_m`` (position on the skin, m),
  ``s<k>_state`` (1 start, 2 move, 3 end), ``s<k>_track_id``, ``s<k>_confidence``,
  ``s<k>_uncertainty_mm``, ``s<k>_strength`` (counts). An empty slot is nan in every column
  (state too). ``K`` = 1: 11 channels.
* ``<name>-<skin>-gestures``, type ``Markers``, one string channel, irregular rate: each gesture
  event as one JSON string (the JSON-lines sink's gesture line).

The sample's LSL timestamp is the local LSL clock when it was pushed.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from skinloc._lazy import require_extra
from skinloc.live.sinks.base import Sink, SinkSpec, SkinInfo, gesture_json

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = ["LSL_FRAME_CHANNELS", "LSL_SLOT_CHANNELS", "LslSink", "lsl_channels"]

#: Per-frame channels, first in every sample.
LSL_FRAME_CHANNELS = ("touch_id", "signal_z", "latency_us")
#: Channels of each slot, in order (``s<k>_`` prefixed).
LSL_SLOT_CHANNELS = (
    "x_m",
    "y_m",
    "z_m",
    "state",
    "track_id",
    "confidence",
    "uncertainty_mm",
    "strength",
)
_STATE_CODE = {"idle": 0.0, "start": 1.0, "move": 2.0, "end": 3.0}


def lsl_channels(max_contacts: int) -> list[str]:
    """Channel labels of a skin's contact outlet with ``max_contacts`` slots."""
    slots = [f"s{k}_{c}" for k in range(max_contacts) for c in LSL_SLOT_CHANNELS]
    return [*LSL_FRAME_CHANNELS, *slots]


def _require_pylsl() -> Any:
    return require_extra("pylsl", "the LSL sink")  # pylsl raises RuntimeError without liblsl


class LslSink(Sink):
    """Push contacts and gestures to LSL outlets (two per skin).

    Parameters
    ----------
    name : str, default="skinloc"
        Stream name prefix.
    """

    name = "lsl"

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> LslSink:
        """``lsl[:NAME]``: outlets named after NAME (default ``skinloc``)."""
        return cls(spec.label("skinloc"))

    def __init__(self, name: str = "skinloc") -> None:
        self.stream_name = name
        self._outlets: dict[str, Any] = {}
        self._markers: dict[str, Any] = {}
        self._slots: dict[str, int] = {}
        self._pylsl: Any = None

    def _outlet(self, skin: str) -> Any:
        out = self._outlets.get(skin)
        if out is None:
            pylsl = self._pylsl
            labels = lsl_channels(self._slots.setdefault(skin, 1))
            info = pylsl.StreamInfo(
                f"{self.stream_name}-{skin}",
                "Contact",
                len(labels),
                pylsl.IRREGULAR_RATE,
                "float32",
                f"skinloc-{self.stream_name}-{skin}",
            )
            chans = info.desc().append_child("channels")
            for label in labels:
                chans.append_child("channel").append_child_value("label", label)
            out = self._outlets[skin] = pylsl.StreamOutlet(info)
        return out

    def _marker_outlet(self, skin: str) -> Any:
        out = self._markers.get(skin)
        if out is None:
            pylsl = self._pylsl
            info = pylsl.StreamInfo(
                f"{self.stream_name}-{skin}-gestures",
                "Markers",
                1,
                pylsl.IRREGULAR_RATE,
                "string",
                f"skinloc-{self.stream_name}-{skin}-gestures",
            )
            out = self._markers[skin] = pylsl.StreamOutlet(info)
        return out

    def open(self, skins: list[SkinInfo]) -> None:
        """Create each skin's outlets (its ``max_contacts`` slots)."""
        self._pylsl = _require_pylsl()
        for s in skins:
            self._slots[s.name] = max(int(s.max_contacts), 1)
            self._outlet(s.name)
            self._marker_outlet(s.name)

    def emit(self, contact: Contact) -> None:
        """Push one sample holding this contact in its slot."""
        self.emit_contacts(contact.skin, contact.timestamp_s, [contact])

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Push one sample: the frame's contacts in their slots, nan in the empty ones."""
        if self._pylsl is None:
            self.open([])
        outlet = self._outlet(skin)
        k = self._slots[skin]
        n = len(LSL_SLOT_CHANNELS)
        first = contacts[0] if contacts else None
        sample = [
            float(first.touch_id) if first else math.nan,
            first.signal_z if first else math.nan,
            first.latency_us if first else math.nan,
        ] + [math.nan] * (k * n)
        for c in contacts:
            slot = c.slot if 0 <= c.slot < k else 0
            x, y, z = c.position_m
            at = len(LSL_FRAME_CHANNELS) + slot * n
            sample[at : at + n] = [
                x,
                y,
                z,
                _STATE_CODE.get(c.state, -1.0),
                float(c.track_id),
                c.confidence,
                c.uncertainty_mm,
                c.strength,
            ]
        outlet.push_sample(sample)

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """Push the gesture event as one JSON marker on the skin's ``Markers`` outlet."""
        if self._pylsl is None:
            self.open([])
        self._marker_outlet(skin).push_sample([gesture_json(skin, event)])

    def close(self) -> None:
        """Drop the outlets."""
        self._outlets.clear()
        self._markers.clear()
