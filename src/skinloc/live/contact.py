"""``Contact``: one output of the live pipeline, the type every sink consumes, and its colour.

A leaf module so that the pipeline (which makes contacts) and the sinks (which send them) both
import it without importing each other.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["TRACK_COLOURS", "TRACK_RGB", "Contact", "colour_index", "track_colour"]

#: The fingers' colours (sRGB), shared by every view of the contacts: the app's page (the
#: server writes them into it), the ROS 2 markers (RViz) and the Foxglove scene. Fingers down
#: at once never share a slot, so never a colour (``colour_index``).
TRACK_COLOURS: tuple[str, ...] = ("#2f6fde", "#e8590c", "#2b8a3e", "#ae3ec9", "#c2255c", "#0c8599")


@dataclass(slots=True)
class Contact:
    """One output of the pipeline.

    Attributes
    ----------
    skin : str
        Name of the skin (pipeline) it comes from.
    timestamp_s : float
        The source frame's timestamp, s (serial ports: host ``time.monotonic()`` at arrival;
        the simulated skin: its clock; recordings: their recorded times).
    index : int
        The source frame's counter.
    state : str
        ``start``, ``move``, ``end`` (or ``idle`` with ``emit_idle``).
    position_m : tuple of 3 float
        Filtered contact point on the skin, m, mesh frame (nan while idle).
    raw_m : tuple of 3 float
        Network output for this frame before constraint and filtering, m.
    confidence : float
        In [0, 1]: signal strength above the release threshold times agreement of the ensemble.
    signal_z : float
        Peak baseline-subtracted signal in units of each sensor's noise.
    uncertainty_mm : float
        Spread of the ensemble members, mm (nan for a single network).
    latency_us : float
        Processing latency, bytes (or frame) in to contact out, microseconds.
    touch_id : int
        Number of the touch since start (0 before the first).
    track_id : int
        Tracking id of the finger this contact belongs to (the Linux multi-touch protocol B
        convention: a new id per finger landing, kept until it lifts; -1: none).
    slot : int
        Slot of the track (0..K-1, reused after a lift; -1: none).
    strength : float
        Fitted contact strength, counts (nan when the model does not estimate it).
    """

    skin: str
    timestamp_s: float
    index: int
    state: str
    position_m: tuple[float, float, float]
    raw_m: tuple[float, float, float]
    confidence: float
    signal_z: float
    uncertainty_mm: float
    latency_us: float
    touch_id: int
    track_id: int = -1
    slot: int = -1
    strength: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (nan becomes None)."""
        d = asdict(self)
        for k in ("position_m", "raw_m"):
            d[k] = [None if math.isnan(v) else v for v in d[k]]
        for k in ("confidence", "signal_z", "uncertainty_mm", "strength"):
            if math.isnan(d[k]):
                d[k] = None
        return d

    def to_json(self) -> str:
        """One line of JSON (the wire format of the JSON-lines, WebSocket and UDP sinks)."""
        return json.dumps(self.to_dict(), separators=(",", ":"))


def colour_index(contact: Contact) -> int:
    """The index into ``TRACK_COLOURS`` (modulo its length) of a contact's finger.

    Its slot; without one (a one-contact pipeline) its track id, else its touch number.
    """
    if contact.slot >= 0:
        return contact.slot
    if contact.track_id >= 0:
        return contact.track_id
    return max(contact.touch_id - 1, 0)


#: ``TRACK_COLOURS`` as ``(r, g, b)`` in [0, 1] (parsed once: the ROS 2 markers ask every frame)
TRACK_RGB: tuple[tuple[float, float, float], ...] = tuple(
    (int(h[1:3], 16) / 255, int(h[3:5], 16) / 255, int(h[5:7], 16) / 255) for h in TRACK_COLOURS
)


def track_colour(contact: Contact) -> tuple[float, float, float]:
    """The colour of a contact's finger, ``(r, g, b)`` in [0, 1]."""
    return TRACK_RGB[colour_index(contact) % len(TRACK_RGB)]
