"""A skin on a serial port (a Muca board behind an Arduino), read on a background thread.

The port is anything pyserial opens: a device (``/dev/ttyACM0``, ``COM3``) or a URL such as
``loop://`` (tests) or ``socket://host:port``. Ports a person or a page names go through
``check_source`` first, which lets only ``sim`` and serial devices through (URLs on opt-in). A
reader thread feeds the bytes to the one serial reader of ``hardware.link`` (the parser, the
line masks, the counter unwrapped, frames stamped by the device counter), keeps the frames in a
bounded buffer and reopens the port by itself when the device goes away and comes back.
"""

from __future__ import annotations

import collections
import logging
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skinloc.errors import FrameTimeoutError, SourceNotConnectedError
from skinloc.hardware.link import PortLink, WireDecoder, parse_line_mask, why_not_open
from skinloc.hardware.ports import PortInfo, check_source, list_ports  # re-exported
from skinloc.hardware.protocol import MAX_RX, MAX_TX, WireFormat
from skinloc.sources.base import Frame, FrameSource, SourceOptions

log = logging.getLogger(__name__)

__all__ = [
    "check_source",
    "list_ports",
    "parse_line_mask",
    "PortInfo",
    "SerialSource",
    "SerialSourceConfig",
    "SourceStats",
    "why_not_open",
]


@dataclass
class SerialSourceConfig:
    """Settings of a ``SerialSource``.

    Attributes
    ----------
    port : str
        Device (``/dev/ttyACM0``, ``COM3``) or pyserial URL (``loop://``).
    baud : int
        Baud rate: 115200 for the paper's text firmware; skinloc's firmware streams binary at
        1000000.
    n_tx, n_rx : int
        Grid the device sends, at most 21 x 12.
    tx_mask, rx_mask : str or None
        Lines to keep, e.g. ``"11111111000"``: one 0/1 per line the device sends; ``None`` keeps
        all. The source's grid is the number of ones.
    format : str
        ``auto`` (detect), ``text`` or ``binary``.
    timeout_s : float
        Default wait of ``read``, s.
    buffer_frames : int
        Frames kept for ``read`` and ``frames``; the oldest are dropped (and counted) beyond.
    max_age_ms : float
        Default age limit of ``latest``, ms.
    reconnect : bool
        Reopen the port by itself after the device goes away.
    reconnect_interval_s : float
        Pause between attempts to reopen, s.
    """

    port: str
    baud: int = 115200
    n_tx: int = 8
    n_rx: int = 8
    tx_mask: str | None = None
    rx_mask: str | None = None
    format: str = "auto"
    timeout_s: float = 1.0
    buffer_frames: int = 1024
    max_age_ms: float = 100.0
    reconnect: bool = True
    reconnect_interval_s: float = 0.1
    _tx_keep: np.ndarray = field(init=False, repr=False)
    _rx_keep: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not isinstance(self.port, str) or not self.port.strip():
            raise ValueError(f"SerialSourceConfig.port must name a port or URL, got {self.port!r}")
        if not (isinstance(self.baud, int) and 50 <= self.baud <= 12_000_000):
            raise ValueError(f"SerialSourceConfig.baud must be 50-12000000, got {self.baud!r}")
        if not (isinstance(self.n_tx, int) and 1 <= self.n_tx <= MAX_TX):
            raise ValueError(f"SerialSourceConfig.n_tx must be 1-{MAX_TX}, got {self.n_tx!r}")
        if not (isinstance(self.n_rx, int) and 1 <= self.n_rx <= MAX_RX):
            raise ValueError(f"SerialSourceConfig.n_rx must be 1-{MAX_RX}, got {self.n_rx!r}")
        self.format = WireFormat(self.format).value
        for name in ("timeout_s", "max_age_ms", "reconnect_interval_s"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise ValueError(f"SerialSourceConfig.{name} must be > 0, got {value!r}")
        if not (isinstance(self.buffer_frames, int) and self.buffer_frames >= 1):
            raise ValueError(
                f"SerialSourceConfig.buffer_frames must be >= 1, got {self.buffer_frames!r}"
            )
        self._tx_keep = parse_line_mask(self.tx_mask, self.n_tx, "tx_mask")
        self._rx_keep = parse_line_mask(self.rx_mask, self.n_rx, "rx_mask")


@dataclass(frozen=True)
class SourceStats:
    """Counters of a ``SerialSource`` since ``connect``.

    ``n_received`` frames were parsed; ``n_dropped`` lines or frames were malformed
    (partial, merged, garbled, wrong length); ``n_corrupted`` failed the CRC; ``n_lost`` never
    arrived (gaps in the device's counter); ``n_overflow`` were received but pushed out of the
    full buffer before anyone read them. ``rate_hz`` is measured over the last 100 frames.
    """

    port: str
    format: str
    n_received: int
    n_dropped: int
    n_corrupted: int
    n_lost: int
    n_wrong_grid: int
    n_overflow: int
    n_chatter: int
    n_bytes: int
    n_disconnects: int
    n_reconnects: int
    link_up: bool
    rate_hz: float

    def as_dict(self) -> dict:
        """The counters as a plain dict."""
        return dict(self.__dict__)


class SerialSource(FrameSource):
    """Frames from a Muca board (or anything speaking its formats) on a serial port.

    Parameters
    ----------
    config : SerialSourceConfig
        Port, baud, grid, masks and buffer settings.

    Notes
    -----
    ``read`` returns frames in order from the buffer (the frame stream); ``latest`` returns the
    newest frame if it is recent enough, for online use. Frame timestamps are host
    ``time.monotonic()`` seconds: the last frame of a read at the read's time, the earlier ones
    back by the device counter times the measured frame period (``hardware.link.FrameStamper``);
    ``Frame.index`` is the device's frame counter unwrapped (binary) or the count of frames
    parsed (text).

    Examples
    --------
    >>> from skinloc.hardware.protocol import encode_binary
    >>> with SerialSource(SerialSourceConfig("loop://", n_tx=1, n_rx=2)) as src:
    ...     src.write(encode_binary([5, 6], 1, 2, counter=0))
    ...     src.read(timeout_s=2.0).values.tolist()
    [5.0, 6.0]
    """

    def __init__(self, config: SerialSourceConfig) -> None:
        self.config = config
        self.n_tx = int(config._tx_keep.sum())
        self.n_rx = int(config._rx_keep.sum())
        self._connected = False
        self._link = PortLink(config.port, config.baud)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._cond = threading.Condition()
        self._buffer: collections.deque[Frame] = collections.deque()
        self._latest: Frame | None = None
        self._arrivals: collections.deque[float] = collections.deque(maxlen=100)
        self._decoder = WireDecoder(
            config.format, config.n_tx, config.n_rx, config.tx_mask, config.rx_mask
        )
        self._n_overflow = 0

    @classmethod
    def from_options(cls, options: SourceOptions, mesh: Any = None) -> SerialSource:
        """The port ``options`` name (``skinloc.sources.base.make_source``); no ``mesh``."""
        return cls(
            SerialSourceConfig(
                port=options.source,
                baud=options.baud,
                n_tx=options.n_tx,
                n_rx=options.n_rx,
                tx_mask=options.tx_mask,
                rx_mask=options.rx_mask,
                format=options.format,
            )
        )

    # -- FrameSource -------------------------------------------------------------------------
    @property
    def name(self) -> str:
        """The port."""
        return self.config.port

    @property
    def is_connected(self) -> bool:
        """Whether ``connect`` was called (the link itself may be down and reconnecting)."""
        return self._connected

    @staticmethod
    def find_ports() -> list[str]:
        """Serial devices present, likely Arduinos first (see ``list_ports`` for details)."""
        return [p.device for p in list_ports()]

    def _connect(self) -> None:
        try:
            self._link.open()
        except (OSError, ValueError) as exc:  # serial.SerialException is an OSError
            raise SourceNotConnectedError(
                f"cannot open serial port {self.config.port}: {why_not_open(exc)}"
            ) from None
        self._stop.clear()
        self._connected = True
        self._thread = threading.Thread(
            target=self._run, name=f"skinloc-serial-{self.config.port}", daemon=True
        )
        self._thread.start()
        log.info("reading %s at %d baud", self.config.port, self.config.baud)

    def _disconnect(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self._thread = None
        self._link.close()
        self._connected = False
        with self._cond:
            self._cond.notify_all()

    def _read(self, timeout_s: float) -> Frame:
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while not self._buffer:
                left = deadline - time.monotonic()
                if left <= 0 or not self._connected:
                    raise FrameTimeoutError(self._timeout_message(timeout_s))
                self._cond.wait(left)
            return self._buffer.popleft()

    def _timeout_message(self, timeout_s: float) -> str:
        link = self._link
        state = "" if link.up else f"; the link is down ({link.last_error}), reconnecting"
        stats = self.stats()
        hint = ""
        if stats.n_received == 0 and stats.n_bytes == 0:
            hint = "; no bytes at all: check the port, the baud rate and that the sketch runs"
        elif stats.n_received == 0:
            hint = (
                f"; {stats.n_bytes} bytes but no valid frame: check the baud rate "
                f"({self.config.baud}) and the grid ({self.config.n_tx} x {self.config.n_rx})"
            )
        return f"no frame from {self.config.port} within {timeout_s:g} s{state}{hint}"

    # -- beyond FrameSource --------------------------------------------------------------------
    def read(self, timeout_s: float | None = None) -> Frame:
        """The next frame of the stream; ``FrameTimeoutError`` naming the port after ``timeout_s``.

        ``timeout_s`` defaults to the config's.
        """
        return super().read(self.config.timeout_s if timeout_s is None else timeout_s)

    def latest(self, max_age_ms: float | None = None) -> Frame:
        """The newest frame, if younger than ``max_age_ms`` (default: the config's).

        Does not consume the stream. Raises ``FrameTimeoutError`` when the newest frame is older
        (the device stalled or was unplugged) and ``SourceNotConnectedError`` before ``connect``.
        """
        if not self._connected:
            raise SourceNotConnectedError(f"{self.name} is not connected: call connect() first")
        limit = (self.config.max_age_ms if max_age_ms is None else max_age_ms) / 1000.0
        with self._cond:
            frame = self._latest
        if frame is None:
            raise FrameTimeoutError(f"no frame from {self.config.port} yet")
        age = time.monotonic() - frame.timestamp_s
        if age > limit:
            raise FrameTimeoutError(
                f"newest frame from {self.config.port} is {age * 1e3:.0f} ms old "
                f"(limit {limit * 1e3:.0f} ms)"
            )
        return frame

    def frames(self, timeout_s: float | None = None) -> Iterator[Frame]:
        """Yield frames in order until disconnected; a stall longer than ``timeout_s`` raises."""
        while self._connected:
            yield self.read(timeout_s)

    def clear(self) -> int:
        """Discard buffered frames (e.g. before a fresh capture); returns how many."""
        with self._cond:
            n = len(self._buffer)
            self._buffer.clear()
        return n

    def write(self, data: bytes) -> None:
        r"""Send ``data`` to the device (a firmware command such as ``b"v\n"``)."""
        if not self._connected:
            raise SourceNotConnectedError(f"{self.name} is not connected: call connect() first")
        import serial

        with self._link.lock:
            ser = self._link.ser
            if ser is None:
                raise SourceNotConnectedError(f"{self.name}: the link is down, reconnecting")
            try:
                ser.write(data)
                ser.flush()
            except (serial.SerialException, OSError) as exc:
                raise SourceNotConnectedError(f"cannot write to {self.name}: {exc}") from None

    def stats(self) -> SourceStats:
        """Counters since ``connect`` and the measured frame rate."""
        with self._cond:
            p = self._decoder.stats
            arrivals = list(self._arrivals)
        rate = 0.0
        if len(arrivals) >= 2 and arrivals[-1] > arrivals[0]:
            rate = (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])
        link = self._link
        return SourceStats(
            port=self.config.port,
            format=str(self._decoder.format),
            n_received=p.n_frames,
            n_dropped=p.n_dropped,
            n_corrupted=p.n_corrupted,
            n_lost=p.n_lost,
            n_wrong_grid=p.n_wrong_grid,
            n_overflow=self._n_overflow,
            n_chatter=p.n_chatter,
            n_bytes=p.n_bytes,
            n_disconnects=link.n_disconnects,
            n_reconnects=link.n_reconnects,
            link_up=link.up,
            rate_hz=rate,
        )

    # -- the reader thread ---------------------------------------------------------------------
    def _run(self) -> None:
        import serial

        link = self._link
        while not self._stop.is_set():
            ser = link.ser
            if ser is None:
                if not self._reopen():
                    return
                continue
            try:
                data = ser.read(max(1, min(ser.in_waiting, 65536)))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                # pyserial raises TypeError/AttributeError when the port is closed under it.
                if self._stop.is_set():
                    return
                link.lost(exc)
                with self._cond:
                    self._decoder.reset()
                continue
            if data:
                self._deliver(self._decoder.feed(data, time.monotonic()))

    def _reopen(self) -> bool:
        """Try to reopen the port until it works; False when asked to stop."""
        if not self.config.reconnect:
            self._stop.wait()
            return False
        while not self._stop.wait(self.config.reconnect_interval_s):
            if self._link.reopen():
                return True
        return False

    def _deliver(self, frames: list[Frame]) -> None:
        if not frames:
            return
        now = time.monotonic()
        with self._cond:
            for frame in frames:
                if len(self._buffer) >= self.config.buffer_frames:
                    self._buffer.popleft()
                    self._n_overflow += 1
                self._buffer.append(frame)
                self._latest = frame
                self._arrivals.append(now)
            self._cond.notify_all()
