"""Wire bytes into a skin's pipeline: ``SkinCore.feed`` (parsing, frame counters, link resets)."""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

__all__ = ["WireInput"]


class WireInput:
    """The byte-level input of ``SkinCore`` (a mixin: the core sets the attributes used here).

    The core provides ``process_frame``, ``n_frames``, ``wire_format``, ``n_tx``, ``n_rx`` and
    sets ``_parser = None``, ``_last_counter = None``, ``_counter_base = 0``.
    """

    _parser: Any
    _last_counter: int | None
    _counter_base: int
    n_frames: int
    wire_format: str
    n_tx: int
    n_rx: int

    def process_frame(
        self, values: np.ndarray, timestamp_s: float, index: int = -1, t_in: float | None = None
    ) -> Sequence[Contact]:
        """Process one decoded frame (``SkinCore.process_frame``)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ bytes
    def feed(self, data: bytes, t_in: float | None = None) -> list[Contact]:
        """Parse wire bytes (``skinloc.hardware.framing``) and process every complete frame in them.

        Returns every contact of those frames. Frame timestamps are ``t_in`` (arrival,
        ``time.monotonic()``); indices are the device's counter, unwrapped (binary) or a
        running count (text).
        """
        out: list[Contact] = []
        for contacts in self.feed_frames(data, t_in):
            out += contacts
        return out

    def feed_frames(self, data: bytes, t_in: float | None = None) -> list[Sequence[Contact]]:
        """As ``feed``, the contacts frame by frame (only frames that have some)."""
        if t_in is None:
            t_in = time.monotonic()
        if self._parser is None:
            from skinloc.hardware.framing import make_parser

            self._parser = make_parser(self.wire_format, self.n_tx, self.n_rx)
        out: list[Sequence[Contact]] = []
        for raw in self._parser.feed(data):
            counter = raw.counter
            if counter is None:
                index = self.n_frames
            else:
                if self._last_counter is not None and counter < self._last_counter:
                    self._counter_base += 1 << 16
                self._last_counter = counter
                index = self._counter_base + counter
            contacts = self.process_frame(raw.values, t_in, index, t_in)
            if contacts:
                out.append(contacts)
        return out

    def reset_link(self) -> None:
        """Forget partial wire input after a reconnect (the touch state is kept)."""
        if self._parser is not None:
            self._parser.reset()
        self._last_counter = None
        self._counter_base = (self._counter_base >> 16) + 1 << 16

    @property
    def parser_stats(self) -> dict[str, int]:
        """Counters of the wire parser (empty before ``feed``)."""
        return {} if self._parser is None else self._parser.stats.as_dict()
