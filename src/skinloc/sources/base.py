"""Frame sources: the interface, the options that name one, and the one factory that builds it.

Every caller that opens a skin (the command line, ``skinloc run``'s runner, the browser app)
describes it with one ``SourceOptions`` and builds it with ``make_source``; the backends are
named in ``_BACKENDS`` and imported only when used.
"""

from __future__ import annotations

import abc
import logging
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._lazy import require_extra, resolve
from skinloc.errors import SkinlocError, SourceAlreadyConnectedError, SourceNotConnectedError

log = logging.getLogger(__name__)

__all__ = [
    "Frame",
    "FrameSource",
    "SourceKind",
    "SourceOptions",
    "check_source_extras",
    "make_source",
    "source_kind",
]


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
    BAG = "bag"

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


@dataclass(frozen=True)
class SourceOptions:
    """Which skin to read, and how: everything ``make_source`` needs.

    Attributes
    ----------
    source : str
        ``sim`` (the simulated skin; ``sim:SEED`` picks its seed), a recording (``.h5``,
        ``.hdf5``, ``.mat``; a ROS 2 bag ``.mcap``), or else a serial port or pyserial URL.
    n_tx, n_rx : int
        Grid the device sends (the simulated skin's grid).
    baud : int
        Baud rate of a serial port.
    format : {"auto", "binary", "text"}
        Frame format of a serial port (``skinloc.hardware.protocol``).
    tx_mask, rx_mask : str or None
        Lines of a serial port to keep, e.g. ``"11111111000"`` (``SerialSourceConfig``).
    seed : int
        Seed of the simulated skin (``sim:SEED`` overrides it).
    rate_hz : float
        Frame rate of the simulated skin, Hz.
    realtime : bool
        Run the simulated skin on the wall clock (False: as fast as it is read).
    loop : bool
        Replay a recording over and over.
    skin : str or None
        Which skin's frames a ROS 2 bag replays (its ``/skinloc/<skin>/frames`` topic).

    Examples
    --------
    >>> SourceOptions("sim:3").kind, SourceOptions("run.mcap").kind, SourceOptions("COM3").kind
    (<SourceKind.SIM: 'sim'>, <SourceKind.BAG: 'bag'>, <SourceKind.SERIAL: 'serial'>)
    """

    source: str = "sim"
    n_tx: int = 8
    n_rx: int = 8
    baud: int = 115200
    format: str = "auto"
    tx_mask: str | None = None
    rx_mask: str | None = None
    seed: int = 0
    rate_hz: float = 100.0
    realtime: bool = False
    loop: bool = False
    skin: str | None = None

    @property
    def kind(self) -> SourceKind:
        """The backend the source names (``source_kind``)."""
        return source_kind(self.source)

    @property
    def sim_seed(self) -> int:
        """The simulated skin's seed: ``N`` of ``sim:N``, else ``seed``."""
        _, _, seed = self.source.partition(":")
        if not seed:
            return self.seed
        try:
            return int(seed)
        except ValueError:
            raise ValueError(f"sim:SEED needs a whole number, not {seed!r}") from None


#: Recordings by file suffix; any other source is a serial port (or URL).
_SUFFIXES: dict[str, SourceKind] = {
    ".h5": SourceKind.REPLAY,
    ".hdf5": SourceKind.REPLAY,
    ".mat": SourceKind.REPLAY,
    ".mcap": SourceKind.BAG,
}


def source_kind(source: str) -> SourceKind:
    """The kind of source a name gives: ``sim[:SEED]``, a recording by suffix, else serial."""
    text = str(source)
    if text == "sim" or text.startswith("sim:"):
        return SourceKind.SIM
    return _SUFFIXES.get(Path(text).suffix.lower(), SourceKind.SERIAL)


# Each kind's factory, by name: this module never imports a backend (they import it). A
# factory takes ``(options, mesh)``.
_BACKENDS: dict[SourceKind, str] = {
    SourceKind.SIM: "skinloc.sim.skin:SimulatedSkin.from_options",
    SourceKind.SERIAL: "skinloc.hardware.serial:SerialSource.from_options",
    SourceKind.REPLAY: "skinloc.sources.replay:ReplaySource.from_options",
    SourceKind.BAG: "skinloc.sources.mcap_ros2:McapReplaySource.from_options",
}

#: The optional modules each kind's backend imports (the bag: its reader and the CDR types).
_REQUIRES: dict[SourceKind, tuple[str, ...]] = {
    SourceKind.BAG: ("mcap.reader", "cyclonedds.idl"),
}


def check_source_extras(source: str) -> None:
    """A one-line ``MissingExtraError`` when ``source``'s backend needs a missing extra.

    Commands call it before they load a model (a fresh install compiles the engine's kernels
    there), so that a source that cannot be read is refused at once.
    """
    kind = source_kind(source)
    for module in _REQUIRES.get(kind, ()):
        require_extra(module, f"the {kind.value} source")


def make_source(options: SourceOptions, *, mesh: Any = None) -> FrameSource:
    """Build (not connect) the source ``options`` names, importing its backend only now.

    Parameters
    ----------
    options : SourceOptions
        The source and its settings.
    mesh : trimesh.Trimesh, optional
        The simulated skin's surface (default: the built-in cone); other kinds ignore it.

    Examples
    --------
    >>> make_source(SourceOptions("sim", seed=0)).n_sensors
    64
    >>> make_source(SourceOptions("loop://", n_tx=21, n_rx=12)).n_sensors
    252
    """
    kind = options.kind
    if kind in (SourceKind.REPLAY, SourceKind.BAG) and not Path(options.source).is_file():
        raise SkinlocError(f"recording not found: {options.source}")
    return resolve(_BACKENDS[kind])(options, mesh)
