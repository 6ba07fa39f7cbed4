r"""Pure parsers of the two wire formats a skin speaks over serial (``hardware.protocol``).

* **text**: the paper's firmware prints one line of comma-separated decimal counts per frame,
  TX-major, ending in ``\r\n`` (``Serial.println``), at 115200 baud. Lines that are not data
  (start-up chatter such as ``RX active lines: 11111111``) are counted and skipped.
* **binary**: skinloc's framed format (``docs/protocol.md``): sync bytes ``A5 5A``, version,
  grid, a 16-bit frame counter, 16-bit little-endian counts and a CRC-32.

Every parser is a pure object with ``feed(data: bytes) -> list[RawFrame]``: no I/O, no clocks,
no threads. Whatever bytes come in, ``feed`` never raises and never returns a frame it cannot
vouch for; anything it rejects is counted in ``stats``. ``AutoParser`` tells the formats apart by
itself.
"""

from __future__ import annotations

import logging
import re
import struct
import zlib
from dataclasses import dataclass, fields

import numpy as np

from skinloc.hardware.protocol import (
    COUNT_MAX,
    CRC_SIZE,
    HEADER,
    HEADER_SIZE,
    MAX_LINE_BYTES,
    MAX_RX,
    MAX_TX,
    SYNC,
    WIRE_VERSION,
    RawFrame,
    WireFormat,
    check_grid,
)

_CRC = struct.Struct("<I")  # the frame's CRC-32, after its counts
log = logging.getLogger(__name__)

__all__ = ["AutoParser", "BinaryParser", "ParserStats", "TextParser", "make_parser"]

_DATA_LINE = re.compile(rb"\d{1,5}(?:,\d{1,5})*,?")
_LETTER = re.compile(rb"[A-Za-z]")
_PRINTABLE = re.compile(rb"[\x20-\x7e\t]*")


@dataclass
class ParserStats:
    """What a parser has seen; every rejected unit is counted exactly once.

    Attributes
    ----------
    n_frames : int
        Frames delivered.
    n_dropped : int
        Lines or frames rejected as malformed: partial, merged, garbled, wrong length, a value
        over 65535, a line longer than any frame, a bad binary header.
    n_corrupted : int
        Binary frames with a well-formed header whose CRC did not match.
    n_wrong_grid : int
        Intact frames of a grid other than the one expected (binary: CRC good, dims differ).
    n_lost : int
        Frames the device counter says were sent but never arrived (binary only).
    n_chatter : int
        Text lines that are messages rather than data (``RX active lines: 11111111``).
    n_bytes : int
        Bytes fed.
    n_bytes_skipped : int
        Bytes outside any delivered frame or chatter line (noise, rejected frames).
    """

    n_frames: int = 0
    n_dropped: int = 0
    n_corrupted: int = 0
    n_wrong_grid: int = 0
    n_lost: int = 0
    n_chatter: int = 0
    n_bytes: int = 0
    n_bytes_skipped: int = 0

    def __iadd__(self, other: ParserStats) -> ParserStats:
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name) + getattr(other, f.name))
        return self

    def as_dict(self) -> dict[str, int]:
        """The counters as a plain dict."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


# --------------------------------------------------------------------------------------------
# parsers


class TextParser:
    r"""Parse the paper's text format: one line of ``n_tx * n_rx`` decimal counts per frame.

    A line is delivered only when it is exactly ``n`` fields of 1-5 digits, each at most 65535,
    separated by commas (one trailing comma and a ``\r`` are allowed). Anything else is dropped
    and counted; printable lines with letters are counted as chatter. The bytes before the first
    newline are dropped (the line may have started before we listened).

    The text format has no checksum: a fault that removes or inserts digits inside one line
    without changing its number of fields, or a line end inserted inside the first number of a
    line, cannot be detected by any parser (see
    ``docs/reliability.md``); use the binary format where that matters.

    Examples
    --------
    >>> p = TextParser(1, 3)
    >>> [f.values.tolist() for f in p.feed(b"RX active lines: 111\r\n1,2,3\r\n4,5")]
    [[1, 2, 3]]
    >>> [f.values.tolist() for f in p.feed(b",6\r\n7,8\r\n")], p.stats.n_dropped
    ([[4, 5, 6]], 1)
    """

    format = WireFormat.TEXT

    def __init__(self, n_tx: int = 8, n_rx: int = 8, *, synced: bool = False) -> None:
        check_grid(n_tx, n_rx)
        self.n_tx, self.n_rx = int(n_tx), int(n_rx)
        self.n_values = self.n_tx * self.n_rx
        self.stats = ParserStats()
        self._buf = bytearray()
        self._synced = synced  # whether a newline has been seen since (re)start
        self._overlong = False  # the current line already exceeded MAX_LINE_BYTES

    def reset(self) -> None:
        """Forget any partial line (after a reconnect): the next line counts from a newline."""
        if self._buf:
            self.stats.n_bytes_skipped += len(self._buf)
        self._buf.clear()
        self._synced = False
        self._overlong = False

    def feed(self, data: bytes) -> list[RawFrame]:
        """Parse ``data``, the next bytes of the stream; returns the complete frames in it."""
        self.stats.n_bytes += len(data)
        buf = self._buf
        buf += data
        end = buf.rfind(b"\n")
        if end < 0:
            self._check_overlong()
            return []
        lines = bytes(buf[:end]).split(b"\n")
        del buf[: end + 1]
        if not self._synced:
            # The first piece began before we listened: it may be the tail of a line.
            self._synced = True
            first = lines.pop(0)
            self.stats.n_bytes_skipped += len(first) + 1
            first = first.rstrip(b"\r")
            if first:
                if _DATA_LINE.fullmatch(first) or not self._classify_chatter(first):
                    self.stats.n_dropped += 1
        frames: list[RawFrame] = []
        good: list[bytes] = []
        n = self.n_values
        for raw in lines:
            line = raw[:-1] if raw.endswith(b"\r") else raw
            if self._overlong:  # the tail of a line we already gave up on
                self._overlong = False
                self.stats.n_bytes_skipped += len(raw) + 1
                continue
            if not line:
                self.stats.n_bytes_skipped += len(raw) + 1
                continue
            if line.endswith(b","):
                line = line[:-1]
            if line.count(b",") == n - 1 and _DATA_LINE.fullmatch(line):
                good.append(line)
                continue
            self.stats.n_bytes_skipped += len(raw) + 1
            if not self._classify_chatter(line):
                self.stats.n_dropped += 1
        if good:
            # Every line is validated above, so numpy's text reader sees digits and commas only.
            values = np.fromstring(b",".join(good), dtype=np.int64, sep=",")
            values = values.reshape(len(good), n)
            ok = (values <= COUNT_MAX).all(axis=1)
            for row, fine, line in zip(values, ok, good, strict=True):
                if fine:
                    frames.append(RawFrame(row.astype(np.uint16), self.n_tx, self.n_rx, None))
                else:
                    self.stats.n_dropped += 1
                    self.stats.n_bytes_skipped += len(line)
        self.stats.n_frames += len(frames)
        self._check_overlong()
        return frames

    def _classify_chatter(self, line: bytes) -> bool:
        """Count ``line`` as chatter when it is printable text with a letter in it."""
        if _LETTER.search(line) and _PRINTABLE.fullmatch(line):
            self.stats.n_chatter += 1
            if self.stats.n_chatter <= 20:
                log.info("device says: %s", line.decode("ascii", "replace").strip())
            return True
        return False

    def _check_overlong(self) -> None:
        if len(self._buf) > MAX_LINE_BYTES:
            # No frame is this long: drop it and skip to the next newline.
            self.stats.n_dropped += 0 if self._overlong else 1
            self.stats.n_bytes_skipped += len(self._buf)
            self._buf.clear()
            self._overlong = True


class BinaryParser:
    """Parse skinloc's binary format, resynchronising on the sync bytes after any damage.

    A frame is delivered only when its header is valid and its CRC-32 matches. After a bad
    header or CRC the search restarts one byte after the false sync, so a real frame hidden
    behind garbage is still found. Gaps in the 16-bit frame counter are counted as lost frames.

    Parameters
    ----------
    n_tx, n_rx : int or None
        Grid to accept; frames of another grid are counted in ``n_wrong_grid`` and skipped.
        ``None`` accepts any grid up to 21 x 12.

    Examples
    --------
    >>> from skinloc.hardware.protocol import encode_binary
    >>> p = BinaryParser(1, 2)
    >>> data = b"noise" + encode_binary([7, 8], 1, 2, 0) + encode_binary([9, 10], 1, 2, 2)
    >>> [(f.counter, f.values.tolist()) for f in p.feed(data)], p.stats.n_lost
    ([(0, [7, 8]), (2, [9, 10])], 1)
    """

    format = WireFormat.BINARY

    def __init__(self, n_tx: int | None = None, n_rx: int | None = None) -> None:
        if (n_tx is None) != (n_rx is None):
            raise ValueError("give both n_tx and n_rx, or neither")
        if n_tx is not None:
            check_grid(n_tx, n_rx)
        self.n_tx, self.n_rx = n_tx, n_rx
        self.stats = ParserStats()
        self._buf = bytearray()
        self._last_counter: int | None = None
        self._warned_grid = False

    def reset(self) -> None:
        """Forget buffered bytes and the last counter (after a reconnect)."""
        if self._buf:
            self.stats.n_bytes_skipped += len(self._buf)
        self._buf.clear()
        self._last_counter = None

    def feed(self, data: bytes) -> list[RawFrame]:
        """Parse ``data``, the next bytes of the stream; returns the complete frames in it."""
        if not self._buf and self.n_tx is not None and type(data) is bytes:
            one = self._whole_frame(data)
            if one is not None:
                return one
        self.stats.n_bytes += len(data)
        buf = self._buf
        buf += data
        frames: list[RawFrame] = []
        pos = 0
        size = len(buf)
        stats = self.stats
        while True:
            start = buf.find(SYNC, pos)
            if start < 0:
                # Keep a trailing A5: it may be the first half of a sync.
                keep = 1 if size and buf[-1] == SYNC[0] else 0
                stats.n_bytes_skipped += size - keep - pos
                pos = size - keep
                break
            stats.n_bytes_skipped += start - pos
            pos = start
            if size - start < HEADER_SIZE:
                break
            _, version, n_tx, n_rx, counter = HEADER.unpack_from(buf, start)
            if version != WIRE_VERSION or not (1 <= n_tx <= MAX_TX and 1 <= n_rx <= MAX_RX):
                stats.n_dropped += 1
                stats.n_bytes_skipped += 1
                pos = start + 1
                continue
            n = n_tx * n_rx
            end = start + HEADER_SIZE + 2 * n + CRC_SIZE
            if end > size:
                break  # wait for the rest
            body = memoryview(buf)[start + 2 : end - CRC_SIZE]
            (crc,) = _CRC.unpack_from(buf, end - CRC_SIZE)
            ok = zlib.crc32(body) == crc
            body.release()
            if not ok:
                stats.n_corrupted += 1
                stats.n_bytes_skipped += 1
                pos = start + 1
                continue
            pos = end
            if self.n_tx is not None and (n_tx, n_rx) != (self.n_tx, self.n_rx):
                stats.n_wrong_grid += 1
                stats.n_bytes_skipped += end - start
                if not self._warned_grid:
                    self._warned_grid = True
                    log.warning(
                        "device sends %d x %d frames but %d x %d were expected: skipping them",
                        n_tx,
                        n_rx,
                        self.n_tx,
                        self.n_rx,
                    )
                continue
            if self._last_counter is not None:
                stats.n_lost += (counter - self._last_counter - 1) & 0xFFFF
            self._last_counter = counter
            values = np.frombuffer(buf, "<u2", n, start + HEADER_SIZE).astype(np.uint16)
            frames.append(RawFrame(values, n_tx, n_rx, counter))
        if pos:
            del buf[:pos]
        stats.n_frames += len(frames)
        return frames

    def _whole_frame(self, data: bytes) -> list[RawFrame] | None:
        """``data`` as one whole valid frame of the expected grid, else None.

        A live port read at the frame rate brings one frame a read (about 1 us less than the
        general path, which buffers, searches and cuts; anything else goes there).
        """
        n = self.n_tx * self.n_rx  # type: ignore[operator]
        end = len(data) - CRC_SIZE
        if end != HEADER_SIZE + 2 * n or not data.startswith(SYNC):
            return None
        _, version, n_tx, n_rx, counter = HEADER.unpack_from(data)
        if version != WIRE_VERSION or n_tx != self.n_tx or n_rx != self.n_rx:
            return None
        if zlib.crc32(memoryview(data)[2:end]) != _CRC.unpack_from(data, end)[0]:
            return None
        stats = self.stats
        stats.n_bytes += end + CRC_SIZE
        if self._last_counter is not None:
            stats.n_lost += (counter - self._last_counter - 1) & 0xFFFF
        self._last_counter = counter
        stats.n_frames += 1
        values = np.frombuffer(data, "<u2", n, HEADER_SIZE).astype(np.uint16)
        return [RawFrame(values, n_tx, n_rx, counter)]


class AutoParser:
    r"""Detect the wire format from the bytes, then parse with the matching parser.

    Until a first frame is found both parsers read the stream; the first to deliver a frame
    wins and the other is discarded. If the chosen parser then goes ``relock_bytes`` without a
    frame (the device was switched to the other format), detection starts again.

    Examples
    --------
    >>> from skinloc.hardware.protocol import encode_binary
    >>> p = AutoParser(1, 2)
    >>> [f.values.tolist() for f in p.feed(b"hello\n" + encode_binary([1, 2], 1, 2, 0))]
    [[1, 2]]
    >>> p.format.value
    'binary'
    """

    def __init__(self, n_tx: int = 8, n_rx: int = 8, *, relock_bytes: int = 16384) -> None:
        check_grid(n_tx, n_rx)
        self.n_tx, self.n_rx = int(n_tx), int(n_rx)
        self.relock_bytes = int(relock_bytes)
        self._past = ParserStats()
        self._start_detection()

    def _start_detection(self) -> None:
        self._text = TextParser(self.n_tx, self.n_rx)
        self._binary = BinaryParser(self.n_tx, self.n_rx)
        self._locked: TextParser | BinaryParser | None = None
        self._since_frame = 0

    @property
    def format(self) -> WireFormat:
        """The detected format, ``auto`` while still undecided."""
        return WireFormat.AUTO if self._locked is None else self._locked.format

    @property
    def stats(self) -> ParserStats:
        """Counters of the chosen parser plus those of earlier locks."""
        total = ParserStats(**self._past.as_dict())
        if self._locked is not None:
            total += self._locked.stats
        else:
            # Undecided: report the text side (chatter, bytes) without double-counting bytes.
            total.n_bytes += self._text.stats.n_bytes
            total.n_bytes_skipped += self._text.stats.n_bytes_skipped
            total.n_chatter += self._text.stats.n_chatter
        return total

    def reset(self) -> None:
        """Forget partial input (after a reconnect); the detected format is kept."""
        if self._locked is None:
            self._text.reset()
            self._binary.reset()
        else:
            self._locked.reset()

    def feed(self, data: bytes) -> list[RawFrame]:
        """Parse ``data``, the next bytes of the stream; returns the complete frames in it."""
        if self._locked is not None:
            frames = self._locked.feed(data)
            self._since_frame = 0 if frames else self._since_frame + len(data)
            if self._since_frame > self.relock_bytes:
                log.info(
                    "no %s frame in %d bytes: detecting the format again",
                    self.format,
                    self._since_frame,
                )
                self._past += self._locked.stats
                self._past.n_bytes -= len(data)  # counted again below
                self._start_detection()
                return self._detect(data)
            return frames
        return self._detect(data)

    def _detect(self, data: bytes) -> list[RawFrame]:
        from_text = self._text.feed(data)
        from_binary = self._binary.feed(data)
        if from_binary:
            self._locked = self._binary
            self._past.n_chatter += self._text.stats.n_chatter
            log.info("detected the binary wire format")
            return from_binary
        if from_text:
            self._locked = self._text
            log.info("detected the text wire format")
            return from_text
        return []


def make_parser(fmt: WireFormat | str, n_tx: int = 8, n_rx: int = 8):
    """A parser for ``fmt`` (``auto``, ``text`` or ``binary``) and grid ``n_tx x n_rx``."""
    fmt = WireFormat(fmt)
    if fmt is WireFormat.TEXT:
        return TextParser(n_tx, n_rx)
    if fmt is WireFormat.BINARY:
        return BinaryParser(n_tx, n_rx)
    return AutoParser(n_tx, n_rx)
