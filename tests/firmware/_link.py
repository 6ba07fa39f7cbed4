"""A strict reader of the firmware's output for the tests: every byte must belong to a frame
with a good CRC or to a printable text line; anything else fails the test.

Unlike skinloc's parsers, which skip what they cannot use, this one accounts for every byte,
so a corrupted or truncated frame cannot hide.
"""

from __future__ import annotations

import re
import struct
import zlib
from dataclasses import dataclass, field

import numpy as np

from tests._helpers import wait_until

SYNC = b"\xa5\x5a"
_TEXT_FRAME = re.compile(rb"\d{1,5}(,\d{1,5})*")
_PRINTABLE = re.compile(rb"[\x20-\x7e]*")


@dataclass
class Item:
    """One unit of the stream: a frame (binary or text) or a text line."""

    kind: str  # "binary", "text" or "line"
    values: np.ndarray | None = None
    n_tx: int = 0
    n_rx: int = 0
    counter: int | None = None
    line: str = ""


class StreamError(AssertionError):
    """The stream held bytes that are neither a valid frame nor a text line."""


@dataclass
class Splitter:
    """Split the firmware's byte stream into frames and lines, failing on anything else."""

    buf: bytearray = field(default_factory=bytearray)

    def feed(self, data: bytes) -> list[Item]:
        self.buf += data
        out: list[Item] = []
        buf = self.buf
        while buf:
            if buf[:2] == SYNC:
                if len(buf) < 7:
                    break
                version, n_tx, n_rx, counter = struct.unpack_from("<BBBH", buf, 2)
                if version != 1 or not (1 <= n_tx <= 21 and 1 <= n_rx <= 12):
                    raise StreamError(f"bad frame header {bytes(buf[:7]).hex(' ')}")
                size = 11 + 2 * n_tx * n_rx
                if len(buf) < size:
                    break
                body = bytes(buf[2 : size - 4])
                crc = struct.unpack_from("<I", buf, size - 4)[0]
                if zlib.crc32(body) != crc:
                    raise StreamError(f"bad CRC in frame {counter} ({n_tx}x{n_rx})")
                values = np.frombuffer(body[5:], dtype="<u2").astype(np.int64)
                out.append(Item("binary", values, n_tx, n_rx, counter))
                del buf[:size]
                continue
            end = buf.find(b"\r\n")
            if end < 0:
                if len(buf) > 2000 or (buf and buf[0] == SYNC[0] and len(buf) == 1):
                    if len(buf) > 2000:
                        raise StreamError(f"no line end in {bytes(buf[:60])!r}...")
                break
            line = bytes(buf[:end])
            del buf[: end + 2]
            if _TEXT_FRAME.fullmatch(line):
                values = np.array([int(v) for v in line.split(b",")], dtype=np.int64)
                out.append(Item("text", values))
            elif _PRINTABLE.fullmatch(line) and line:
                out.append(Item("line", line=line.decode("ascii")))
            else:
                raise StreamError(f"garbage in the stream: {line[:80]!r}")
        return out


class Link:
    """A host on the emulated board's port: send lines, collect what comes back."""

    def __init__(self, path: str, baud: int = 1_000_000) -> None:
        import serial

        self.ser = serial.Serial(path, baud, timeout=0.05)
        self.splitter = Splitter()
        self.items: list[Item] = []
        self.n_bytes = 0

    def close(self) -> None:
        self.ser.close()

    def pump(self) -> list[Item]:
        data = self.ser.read(max(1, self.ser.in_waiting))
        self.n_bytes += len(data)
        new = self.splitter.feed(data)
        self.items += new
        return new

    def wait_for(self, predicate, timeout_s: float = 20.0) -> list[Item]:
        """Read until ``predicate(items_since_call)`` holds; returns those items."""
        seen: list[Item] = []

        def done() -> bool:
            seen.extend(self.pump())
            return predicate(seen)

        def what() -> str:
            lines = [i.line for i in seen if i.kind == "line"]
            return f"the board ({len(seen)} items, lines {lines[-5:]})"

        if not predicate(seen):
            wait_until(done, what, timeout_s, interval_s=0.0)
        return seen

    def send(self, text: str | bytes) -> None:
        self.ser.write(text.encode() if isinstance(text, str) else text)
        self.ser.flush()

    def command(self, line: str, n_frames: int = 1) -> tuple[str, list[Item]]:
        """Send one command; its reply, then the items up to ``n_frames`` frames after it."""
        self.send(line + "\n")
        got = self.wait_for(lambda s: _lines(s) and _frames_after_first_line(s) >= n_frames)
        first = next(i for i, it in enumerate(got) if it.kind == "line")
        return got[first].line, got


def _lines(items: list[Item]) -> bool:
    return any(i.kind == "line" for i in items)


def _frames_after_first_line(items: list[Item]) -> int:
    first = next(i for i, it in enumerate(items) if it.kind == "line")
    return sum(1 for it in items[first + 1 :] if it.kind != "line")


def pattern(scan: int, tx_lines: list[int], rx_lines: list[int]) -> np.ndarray:
    """The harness's built-in values for the selected lines, TX-major."""
    return np.array(
        [((scan & 0xFF) << 8) | (t * 12 + r) for t in tx_lines for r in rx_lines], dtype=np.int64
    )


def check_pattern_frame(item: Item, tx_lines: list[int], rx_lines: list[int]) -> int:
    """Check a frame against the pattern of the selected lines; returns its scan (mod 256)."""
    assert item.values is not None
    if item.kind == "binary":
        assert (item.n_tx, item.n_rx) == (len(tx_lines), len(rx_lines)), (
            f"grid {item.n_tx}x{item.n_rx}, selected {len(tx_lines)}x{len(rx_lines)}"
        )
    assert item.values.size == len(tx_lines) * len(rx_lines)
    scan = int(item.values[0]) >> 8
    expected = pattern(scan, tx_lines, rx_lines)
    assert np.array_equal(item.values, expected), (
        f"frame values differ from the emulated ones: {item.values[:8]} vs {expected[:8]}"
    )
    return scan


VERSION = "skinloc_muca 1.1.0"
HELP = "commands: v | f text|binary | g N | l TXMASK RXMASK | c | ?"
CMD_MAX = 47  # characters the firmware keeps of a line; a longer one is refused whole
_GAIN = re.compile(r"g (\d+)")
_LINES = re.compile(r"l ([01]{1,21}) ([01]{1,12})")


@dataclass
class BoardModel:
    """What the firmware must answer and stream, command by command (firmware/README.md).

    ``check(items)`` walks the items in order: each reply line must be the next expected one
    (and applies its command), each frame must carry the pattern of the lines selected then,
    one scan after the frame before it.
    """

    tx_lines: list[int] = field(default_factory=lambda: list(range(8)))
    rx_lines: list[int] = field(default_factory=lambda: list(range(8)))
    text: bool = False
    gain: int = 8
    controller: str = "ok"
    pending: list[tuple[str, object]] = field(default_factory=list)
    last_scan: int | None = None
    last_binary: tuple[int, int] | None = None  # (counter, scan) of the last binary frame
    n_frames: int = 0
    n_replies: int = 0

    def expect(self, raw_line: bytes) -> int:
        """Queue the reply to one line the host sends (without its newline); returns 0 or 1."""
        line = raw_line.replace(b"\r", b"")
        if not line:
            return 0
        if len(line) > CMD_MAX:
            self.pending.append(("error command too long; send ? for the list", None))
            return 1
        text = line.split(b"\0")[0].decode("latin-1")
        reply, effect = "error unknown command; send ? for the list", None
        if text == "v":
            reply, effect = "", ("v", None)
        elif text.startswith("f"):
            if text in ("f text", "f binary"):
                reply, effect = f"ok format {text[2:]}", ("f", text == "f text")
            else:
                reply = "error usage: f text|binary"
        elif text.startswith("g"):
            m = _GAIN.fullmatch(text)
            if m and 1 <= int(m.group(1)) <= 31:
                g = int(m.group(1))
                reply, effect = f"ok gain {g}", ("g", g)
            else:
                reply = "error gain must be 1-31"
        elif text.startswith("l"):
            m = _LINES.fullmatch(text)
            if m and "1" in m.group(1) and "1" in m.group(2):
                tx = [i for i, c in enumerate(m.group(1)) if c == "1"]
                rx = [i for i, c in enumerate(m.group(2)) if c == "1"]
                reply, effect = f"ok lines {len(tx)}x{len(rx)}", ("l", (tx, rx))
            else:
                reply = "error usage: l TXMASK RXMASK, e.g. l 11111111 11111111"
        elif text == "c":
            reply, effect = "ok recalibrated", ("c", None)
        elif text == "?":
            reply = HELP
        self.pending.append((reply, effect))
        return 1

    def version_line(self) -> str:
        fmt = "text" if self.text else "binary"
        return (
            f"{VERSION} grid {len(self.tx_lines)}x{len(self.rx_lines)} format {fmt} "
            f"gain {self.gain} controller {self.controller}"
        )

    def check(self, items: list[Item]) -> None:
        for it in items:
            if it.kind == "line":
                assert self.pending, f"unexpected line {it.line!r}"
                reply, effect = self.pending.pop(0)
                if effect is not None and effect[0] == "v":
                    reply = self.version_line()
                assert it.line == reply, f"got {it.line!r}, expected {reply!r}"
                self.n_replies += 1
                if effect is not None:
                    kind, value = effect
                    if kind == "f":
                        self.text = bool(value)
                    elif kind == "g":
                        self.gain = int(value)  # type: ignore[arg-type]
                    elif kind == "l":
                        self.tx_lines, self.rx_lines = value  # type: ignore[misc]
                    elif kind == "c" and self.last_scan is not None:
                        # 'c' makes a trial scan, which sends no frame
                        self.last_scan = (self.last_scan + 1) & 0xFF
                        if self.last_binary is not None:
                            counter, seen = self.last_binary
                            self.last_binary = (counter, (seen + 1) & 0xFF)
                continue
            assert (it.kind == "text") == self.text, f"a {it.kind} frame in the other format"
            scan = check_pattern_frame(it, self.tx_lines, self.rx_lines)
            if self.last_scan is not None:
                assert scan == (self.last_scan + 1) & 0xFF, "a frame is missing or repeated"
            if it.counter is not None:
                if self.last_binary is not None:  # the counter counts every frame sent
                    counter, seen = self.last_binary
                    assert (it.counter - counter) & 0xFF == (scan - seen) & 0xFF
                self.last_binary = (it.counter, scan)
            self.last_scan = scan
            self.n_frames += 1
