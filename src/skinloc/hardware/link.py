"""The one serial reader: a port's link (opened, lost, reopened) and its bytes decoded to frames.

Both readers of a serial port are built from these pieces: ``SerialSource`` (a reader thread of
its own, ``hardware.serial``) and the live runner's loop (``skinloc.live.feeds``: a
non-blocking file descriptor in one ``selectors`` loop, no thread per port).

* ``PortLink`` opens the port, notices it lost, reopens it, counts both and says in one line
  why a port did not open (``why_not_open``).
* ``WireDecoder`` turns the bytes into ``Frame`` objects: the parser of ``hardware.framing``,
  the line masks (``parse_line_mask``), the device's 16-bit counter unwrapped into a frame
  index (a fresh epoch after a reconnect), and each frame stamped by the device counter and
  the frame period (``FrameStamper``), not all with the time of the read that brought it.
"""

from __future__ import annotations

import errno
import io
import logging
import os
import statistics
import threading
from collections.abc import Sequence
from typing import Any

import numpy as np

from skinloc.hardware.framing import ParserStats, make_parser
from skinloc.hardware.protocol import WireFormat
from skinloc.sources.base import Frame

log = logging.getLogger(__name__)

__all__ = [
    "FrameStamper",
    "NoFileDescriptor",
    "PortLink",
    "WireDecoder",
    "parse_line_mask",
    "why_not_open",
]


def parse_line_mask(mask: str | Sequence[bool] | Sequence[int] | None, n: int, what: str):
    """A line mask as a boolean array of length ``n``.

    Parameters
    ----------
    mask : str, sequence or None
        ``"11110000"`` (the firmware's notation), a sequence of bools or 0/1, or ``None`` for
        all lines.
    n : int
        Lines the device sends.
    what : str
        ``"tx_mask"`` or ``"rx_mask"`` for messages.

    Examples
    --------
    >>> parse_line_mask("1101", 4, "rx_mask").tolist()
    [True, True, False, True]
    """
    if mask is None:
        return np.ones(n, dtype=bool)
    if isinstance(mask, str):
        text = mask.strip()
        if not text or set(text) - {"0", "1"}:
            raise ValueError(f"{what} must be a string of 0 and 1 like '11110000', got {mask!r}")
        arr = np.array([c == "1" for c in text])
    else:
        arr = np.asarray(mask)
        if arr.ndim != 1 or not np.isin(arr, (0, 1)).all():
            raise ValueError(f"{what} must be a sequence of 0/1 or bools, got {mask!r}")
        arr = arr.astype(bool)
    if arr.size != n:
        raise ValueError(f"{what} must have {n} entries (one per line), got {arr.size}: {mask!r}")
    if not arr.any():
        raise ValueError(f"{what} selects no line: {mask!r}")
    return arr


def why_not_open(exc: BaseException) -> str:
    """What to tell a person whose port did not open."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOENT:
        return "no such device (is the board plugged in? `skinloc ports` lists the ports)"
    if code == errno.EACCES:
        return (
            "permission denied (on Linux, add yourself to the 'dialout' group: "
            "`sudo usermod -aG dialout $USER`, then log in again)"
        )
    if code == errno.EBUSY:
        return "the port is busy (close other programs using it, e.g. a serial monitor)"
    if code in (errno.ENOTTY, errno.EISDIR) or "Inappropriate ioctl" in str(exc):
        return "not a serial port (`skinloc ports` lists the ports)"
    return f"{exc} (is the board plugged in? `skinloc ports` lists the ports)"


# --------------------------------------------------------------------------------------------
# the link


class NoFileDescriptor(Exception):
    """The port (a pyserial URL such as ``loop://``) has no file descriptor to wait on."""


class PortLink:
    """One serial port's connection: opened, lost and reopened, with its counters.

    Parameters
    ----------
    port : str
        Device (``/dev/ttyACM0``) or pyserial URL (``loop://``, ``socket://host:port``).
    baud : int
        Baud rate.
    nonblocking : bool
        False: reads wait up to 0.05 s (a reader thread). True: the port's file descriptor
        ``fd`` is made non-blocking for a ``selectors`` loop; ``open`` raises
        ``NoFileDescriptor`` for a URL without one.

    Attributes
    ----------
    ser : serial.Serial or None
        The open port; None while the link is down.
    fd : int
        Its file descriptor (non-blocking links), -1 while down.
    n_disconnects, n_reconnects : int
        Times the link was lost and reopened.
    last_error : str
        Why the link was last lost.
    lock : threading.Lock
        Held while ``ser`` is swapped or closed (a writer on another thread takes it too).
    """

    def __init__(self, port: str, baud: int, *, nonblocking: bool = False) -> None:
        self.port = port
        self.baud = baud
        self.nonblocking = nonblocking
        self.ser: Any = None
        self.fd = -1
        self.n_disconnects = 0
        self.n_reconnects = 0
        self.last_error = ""
        self.open_error: BaseException | None = None  # why the last ``reopen`` failed
        self.lock = threading.Lock()

    @property
    def up(self) -> bool:
        """Whether the port is open."""
        return self.ser is not None

    def open(self) -> None:
        """Open the port; raises pyserial's error (an ``OSError``) or ``ValueError`` as is."""
        import serial

        if not self.nonblocking:
            ser = serial.serial_for_url(self.port, baudrate=self.baud, timeout=0.05,
                                        write_timeout=1.0)  # fmt: skip
            with self.lock:
                self.ser = ser
            return
        ser = serial.serial_for_url(self.port, baudrate=self.baud, timeout=0)
        try:
            fd = ser.fileno()
            if not isinstance(fd, int):
                raise AttributeError("fileno")
        except (AttributeError, io.UnsupportedOperation):
            ser.close()
            raise NoFileDescriptor(self.port) from None
        os.set_blocking(fd, False)
        with self.lock:
            self.ser, self.fd = ser, fd

    def close(self) -> None:
        """Close the port (a dead port's close may fail: ignored)."""
        with self.lock:
            ser, self.ser, self.fd = self.ser, None, -1
        if ser is not None:
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port may fail in many ways
                pass

    def lost(self, exc: BaseException | str) -> None:
        """The port failed: say so once, close it, count a disconnect."""
        self.last_error = str(exc) or type(exc).__name__
        log.warning("lost %s: %s", self.port, self.last_error)
        self.close()
        self.n_disconnects += 1

    def reopen(self, *, count: bool = True) -> bool:
        """Try once to open the port again; True if it opened (``open_error`` says why not).

        ``count``: count and log a reconnect (False for a port seen for the first time).
        """
        try:
            self.open()
        except (OSError, ValueError, NoFileDescriptor) as exc:  # SerialException is an OSError
            self.open_error = exc
            return False
        self.open_error = None
        if count:
            self.n_reconnects += 1
            log.warning("reconnected to %s", self.port)
        return True


# --------------------------------------------------------------------------------------------
# bytes -> frames


class FrameStamper:
    """The times of the frames of one read, from the device counter and the frame period.

    One read returns every frame the port buffered since the last one: after a stall of the
    host of 0.3 s, the 30 frames of a 100 Hz skin at once. Stamped all with the read's time,
    they would look simultaneous (a two-finger tap then leaves a ghost track). Frame ``k`` of a
    read whose last frame has index ``i_last`` is stamped ``t_read - (i_last - i_k) * period``:
    the last frame at the read time (it arrived no later), the earlier ones back by the device
    frames between. A stamp never comes before the previous frame's (times stay monotonic) and
    never after its read.

    The period is measured from the stream (the device's clock, not a configured rate): the
    time per device frame over windows of at least ``window`` frames, followed by an average
    of the windows within a factor two of it (a window across a device that paused is left
    out; three such windows in a row are a new rate). Until the first window is complete, and
    for text frames, which carry no counter (their index counts frames received), it stamps as
    well as it knows: the frames of a read at that read's time, until measured.

    Parameters
    ----------
    period_s : float, optional
        A known frame period, s (no measuring).
    window : int
        Device frames per measurement of the period.

    Examples
    --------
    >>> st = FrameStamper(period_s=0.01)
    >>> [round(t, 3) for t in st.stamp([4, 5, 6], 10.0)]
    [9.98, 9.99, 10.0]
    >>> stamps = st.stamp(list(range(7, 37)), 10.3)  # 30 frames after a 0.3 s stall
    >>> round(stamps[0], 3), round(stamps[1] - stamps[0], 3), stamps[-1]
    (10.01, 0.01, 10.3)
    """

    def __init__(self, period_s: float | None = None, window: int = 32) -> None:
        if period_s is not None and not (np.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s must be > 0, got {period_s!r}")
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window!r}")
        self.fixed = period_s is not None
        self.period_s: float | None = period_s
        self.window = int(window)
        self._anchor: tuple[int, float] | None = None  # (index, read time) the window began at
        self._misses: list[float] = []
        self._last = -np.inf  # the last stamp given

    def restart(self) -> None:
        """The counter starts afresh (a reconnect): measure from the next read on."""
        self._anchor = None

    def _measure(self, last: int, t_read: float) -> None:
        if self._anchor is None:
            self._anchor = (last, t_read)
            return
        i0, t0 = self._anchor
        frames, dt = last - i0, t_read - t0
        if frames < self.window:
            if frames < 0:  # the counter went back (a device restart): start again
                self._anchor = (last, t_read)
            return
        self._anchor = (last, t_read)
        if dt <= 0:
            return
        per = dt / frames
        p = self.period_s
        if p is None:
            self.period_s = per
        elif 0.5 * p <= per <= 2.0 * p:
            self.period_s = p + 0.25 * (per - p)
            self._misses.clear()
        else:
            self._misses.append(per)
            if len(self._misses) >= 3:  # a new rate, not a pause
                self.period_s = statistics.median(self._misses)
                self._misses.clear()

    def stamp(self, indices: Sequence[int], t_read: float) -> list[float]:
        """The stamps of the frames ``indices`` (increasing) of one read at ``t_read``, s."""
        if not indices:
            return []
        last = indices[-1]
        if not self.fixed:
            self._measure(last, t_read)
        period = self.period_s or 0.0
        floor = self._last
        out = []
        for i in indices:
            t = t_read - (last - i) * period
            if t < floor:
                t = floor
            out.append(t)
            floor = t
        self._last = floor
        return out


class WireDecoder:
    """The bytes of one serial port in, the frames they carry out: masked, counted, stamped.

    Parameters
    ----------
    fmt : {"auto", "text", "binary"}
        Wire format (``hardware.framing.make_parser``).
    n_tx, n_rx : int
        Grid the device sends.
    tx_mask, rx_mask : str, sequence or None
        Lines to keep (``parse_line_mask``); the frames' grid is ``n_tx x n_rx`` kept lines.
    period_s : float, optional
        A known frame period, s; measured from the stream by default (``FrameStamper``).

    Notes
    -----
    ``Frame.index`` is the device's 16-bit counter unwrapped (binary; a link that was lost
    starts a fresh epoch of 65536, so indices never repeat) or the count of frames received
    (text). ``Frame.values`` are float32 counts of the kept sensors, TX-major.

    Examples
    --------
    >>> from skinloc.hardware.protocol import encode_binary
    >>> dec = WireDecoder("binary", 1, 3, rx_mask="101", period_s=0.01)
    >>> data = encode_binary([1, 2, 3], 1, 3, 65535) + encode_binary([4, 5, 6], 1, 3, 0)
    >>> [(f.index, f.values.tolist(), round(f.timestamp_s, 2)) for f in dec.feed(data, 5.0)]
    [(65535, [1.0, 3.0], 4.99), (65536, [4.0, 6.0], 5.0)]
    """

    def __init__(
        self,
        fmt: WireFormat | str,
        n_tx: int,
        n_rx: int,
        tx_mask: Any = None,
        rx_mask: Any = None,
        *,
        period_s: float | None = None,
    ) -> None:
        self.parser = make_parser(fmt, n_tx, n_rx)
        tx_keep = parse_line_mask(tx_mask, n_tx, "tx_mask")
        rx_keep = parse_line_mask(rx_mask, n_rx, "rx_mask")
        self.n_tx, self.n_rx = int(tx_keep.sum()), int(rx_keep.sum())
        #: the kept sensors of a device frame; None: all of them
        self.keep = (
            None
            if tx_keep.all() and rx_keep.all()
            else np.flatnonzero(np.outer(tx_keep, rx_keep).ravel())
        )
        self.stamper = FrameStamper(period_s)
        self._base = 0  # the index of counter 0 in the current wrap
        self._next_epoch = 0
        self._last_counter: int | None = None
        self._n_text = 0

    @property
    def n_sensors(self) -> int:
        """Values per frame (kept sensors)."""
        return self.n_tx * self.n_rx

    @property
    def format(self) -> WireFormat:
        """The wire format (``auto`` while an auto parser is still undecided)."""
        return getattr(self.parser, "format", WireFormat.AUTO)

    @property
    def stats(self) -> ParserStats:
        """What the parser has seen (``hardware.framing.ParserStats``)."""
        return self.parser.stats

    def reset(self) -> None:
        """The link was lost: forget partial input; the device may restart its counter."""
        self.parser.reset()
        self._last_counter = None
        self.stamper.restart()

    def _index(self, counter: int | None) -> int:
        """A frame's index: its 16-bit counter unwrapped, or the text frames' count."""
        if counter is None:
            self._n_text += 1
            return self._n_text - 1
        # Unwrap the 16-bit counter; after a reconnect start a fresh epoch.
        if self._last_counter is None:
            self._base = self._next_epoch
        elif counter < self._last_counter:
            self._base += 1 << 16
        self._last_counter = counter
        index = self._base + counter
        self._next_epoch = ((index >> 16) + 1) << 16
        return index

    def feed(self, data: bytes, t_read: float) -> list[Frame]:
        """The frames completed by ``data``, bytes read at ``t_read`` (``time.monotonic()`` s)."""
        raws = self.parser.feed(data)
        if not raws:
            return []
        if len(raws) == 1:  # a live port's usual read: one frame, without the lists
            raw = raws[0]
            index = self._index(raw.counter)
            values = raw.values.astype(np.float32)
            t = self.stamper.stamp((index,), t_read)[0]
            return [Frame(values if self.keep is None else values[self.keep], t, index)]
        indices = [self._index(raw.counter) for raw in raws]
        stamps = self.stamper.stamp(indices, t_read)
        keep = self.keep
        out = []
        for raw, index, t in zip(raws, indices, stamps, strict=True):
            values = raw.values.astype(np.float32)
            out.append(Frame(values if keep is None else values[keep], t, index))
        return out
