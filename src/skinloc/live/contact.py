"""``Contact``: one output of the live pipeline, the type every sink consumes.

A leaf module so that the pipeline (which makes contacts) and the sinks (which send them) both
import it without importing each other.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["Contact"]


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
