"""A Lab Streaming Layer outlet: one sample per contact (through ``pylsl``).

Stream type ``Contact``, 9 float32 channels: ``x_m, y_m, z_m`` (position on the skin, m),
``confidence``, ``state`` (1 start, 2 move, 3 end, 0 idle), ``signal_z``, ``uncertainty_mm``,
``latency_us``, ``touch_id``; irregular rate; the sample's LSL timestamp is the local LSL clock
when the contact was emitted. One outlet per skin, named ``<name>-<skin>``.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from skinloc.live.sinks.base import Sink, SkinInfo

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = ["LSL_CHANNELS", "LslSink"]

#: Channel labels of the outlet, in order.
LSL_CHANNELS = (
    "x_m",
    "y_m",
    "z_m",
    "confidence",
    "state",
    "signal_z",
    "uncertainty_mm",
    "latency_us",
    "touch_id",
)
_STATE_CODE = {"idle": 0.0, "start": 1.0, "move": 2.0, "end": 3.0}


def _require_pylsl() -> Any:
    try:
        import pylsl
    except (ImportError, RuntimeError, OSError) as exc:  # pylsl raises RuntimeError w/o liblsl
        raise ImportError(
            f"the LSL sink needs pylsl with liblsl: pip install 'skinloc[live]' ({exc})"
        ) from None
    return pylsl


class LslSink(Sink):
    """Push contacts to LSL outlets (one per skin).

    Parameters
    ----------
    name : str, default="skinloc"
        Stream name prefix.
    """

    name = "lsl"

    def __init__(self, name: str = "skinloc") -> None:
        self.stream_name = name
        self._outlets: dict[str, Any] = {}
        self._pylsl: Any = None

    def _outlet(self, skin: str) -> Any:
        out = self._outlets.get(skin)
        if out is None:
            pylsl = self._pylsl
            info = pylsl.StreamInfo(
                f"{self.stream_name}-{skin}",
                "Contact",
                len(LSL_CHANNELS),
                pylsl.IRREGULAR_RATE,
                "float32",
                f"skinloc-{self.stream_name}-{skin}",
            )
            chans = info.desc().append_child("channels")
            for label in LSL_CHANNELS:
                chans.append_child("channel").append_child_value("label", label)
            out = self._outlets[skin] = pylsl.StreamOutlet(info)
        return out

    def open(self, skins: list[SkinInfo]) -> None:
        """Create one outlet per skin."""
        self._pylsl = _require_pylsl()
        for s in skins:
            self._outlet(s.name)

    def emit(self, contact: Contact) -> None:
        """Push one sample."""
        if self._pylsl is None:
            self.open([])
        x, y, z = contact.position_m
        self._outlet(contact.skin).push_sample(
            [
                x,
                y,
                z,
                contact.confidence,
                _STATE_CODE.get(contact.state, -1.0),
                contact.signal_z,
                contact.uncertainty_mm,
                contact.latency_us,
                float(contact.touch_id),
            ]
        )

    def close(self) -> None:
        """Drop the outlets."""
        self._outlets.clear()
