"""The frame-source interface shared by the simulated skin, serial hardware and file replay."""

from __future__ import annotations

import abc
import logging
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

import numpy as np

from skinloc._lazy import resolve
from skinloc.errors import SourceAlreadyConnectedError, SourceNotConnectedError

log = logging.getLogger(__name__)

__all__ = ["Frame", "FrameSource", "SourceKind", "make_source"]


@dataclass(frozen=True)
class Frame:
    """One sensor image.

    Attributes
    ----------
    values : (n_tx * n_rx,) float32
        Raw counts, TX-major (sensor k is TX ``k // n_rx``, RX ``k % n_rx``).
    timestamp_s : float
        When the frame was taken, s, on the source's clock.
    index : int
        Frame counter of the source; a gap means frames were lost.
    """

    values: np.ndarray
    timestamp_s: float
    index: int


class SourceKind(StrEnum):
    """Kinds of frame source ``make_source`` can build."""

    SIM = "sim"
    SERIAL = "serial"
    REPLAY = "replay"

    @classmethod
    def _missing_(cls, value: object) -> SourceKind:
        valid = ", ".join(m.value for m in cls)
        raise ValueError(f"unknown source kind {value!r}; choose one of: {valid}")


class FrameSource(abc.ABC):
    """A stream of sensor images of a fixed grid.

    Use as a context manager, or call ``connect`` and ``disconnect``. ``read`` blocks for the
    next frame and raises ``FrameTimeoutError`` after ``timeout_s``.
    """

    n_tx: int
    n_rx: int

    @property
    def n_sensors(self) -> int:
        """Sensors per frame, ``n_tx * n_rx``."""
        return self.n_tx * self.n_rx

    @property
    def name(self) -> str:
        """Human-readable name used in messages (a port, a file, ``sim``)."""
        return type(self).__name__

    @property
    @abc.abstractmethod
    def is_connected(self) -> bool:
        """Whether ``read`` may be called."""

    @abc.abstractmethod
    def _connect(self) -> None: ...

    @abc.abstractmethod
    def _disconnect(self) -> None: ...

    @abc.abstractmethod
    def _read(self, timeout_s: float) -> Frame: ...

    def connect(self) -> None:
        """Open the source; raises ``SourceAlreadyConnectedError`` when already open."""
        if self.is_connected:
            raise SourceAlreadyConnectedError(f"{self.name} is already connected")
        self._connect()

    def disconnect(self) -> None:
        """Close the source; raises ``SourceNotConnectedError`` when not open."""
        if not self.is_connected:
            raise SourceNotConnectedError(f"{self.name} is not connected")
        self._disconnect()

    def read(self, timeout_s: float = 1.0) -> Frame:
        """The next frame; raises ``FrameTimeoutError`` when none comes in ``timeout_s``."""
        if not self.is_connected:
            raise SourceNotConnectedError(f"{self.name} is not connected: call connect() first")
        return self._read(timeout_s)

    def read_many(self, n: int, timeout_s: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """``n`` consecutive frames as ``(values (n, n_sensors) float32, times (n,) s)``."""
        frames = [self.read(timeout_s) for _ in range(n)]
        values = np.stack([f.values for f in frames]).astype(np.float32)
        return values, np.array([f.timestamp_s for f in frames])

    @staticmethod
    def find_ports() -> list[str]:
        """Devices this kind of source could open (empty for sources without ports)."""
        return []

    def __enter__(self) -> FrameSource:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.is_connected:
            self.disconnect()


# Each kind's factory, by name: this module never imports a backend (they import it).
_BACKENDS: dict[SourceKind, str] = {
    SourceKind.SIM: "skinloc.sim.skin:SimulatedSkin",
    SourceKind.SERIAL: "skinloc.hardware.serial:SerialSource.from_options",
    SourceKind.REPLAY: "skinloc.sources.replay:ReplaySource",
}


def make_source(kind: SourceKind | str, **config: Any) -> FrameSource:
    """Build a source by kind, importing its backend only now.

    Examples
    --------
    >>> src = make_source("sim", random_state=0)
    >>> src.n_sensors
    64
    >>> make_source("serial", port="loop://", n_tx=21, n_rx=12).n_sensors
    252
    """
    kind = SourceKind(kind)
    return resolve(_BACKENDS[kind])(**config)
