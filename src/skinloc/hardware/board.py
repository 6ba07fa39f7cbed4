r"""Ask a board what it runs, at which baud, and set its gain and lines.

skinloc's firmware (``firmware/skinloc_muca``) answers ``v`` with its version, grid, format,
gain and the controller's state; ``v`` changes nothing, so asking does not disturb the stream.
The paper's text firmware answers nothing but streams lines of counts. ``detect`` finds which
one is on a port and at which baud: it tries 1 000 000 (skinloc's firmware) and then 115 200
(the paper's), and tells a silent board, a board at an unknown baud and a board without a
controller apart, each with a one-line message that says what to check.

Opening the port resets an Uno (DTR); its bootloader and ``setup()`` take a second or two, so
every probe waits for the board to come up. The firmware keeps the gain and the lines in EEPROM,
so ``configure`` sets them in one session and they hold in the next.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from skinloc.hardware.protocol import MAX_RX, MAX_TX

__all__ = [
    "BAUDS",
    "BoardError",
    "BoardInfo",
    "configure",
    "detect",
    "parse_lines",
    "probe",
]

#: Baud rates ``detect`` tries, in order: skinloc's firmware, then the paper's text firmware.
BAUDS = (1_000_000, 115_200)
#: How long one probe listens, s: an Uno needs up to ~2 s after the reset of opening its port.
PROBE_S = 3.0

_VERSION = re.compile(
    rb"(skinloc_muca [0-9][^ \r\n]*) grid (\d+)x(\d+) format (text|binary) gain (\d+)"
    rb"(?: controller (ok|missing|silent))?(?: rate [0-9.]+ (virtual))?"
)
_TROUBLE = re.compile(rb"error (no controller|controller answers but does not scan)[^\r\n]*")
_REPLY = re.compile(rb"(ok [ -~]*|error [ -~]*)\r?\n")
_TEXT_LINE = re.compile(rb"(?:^|\n)(\d{1,5}(?:,\d{1,5}){3,}),?\r?(?=\n)")


class BoardError(ValueError):
    """A board that cannot be used as it is; the message says what to check (one line)."""


@dataclass(frozen=True)
class BoardInfo:
    """What a probe learned of the board on a port.

    Attributes
    ----------
    port : str
        The port.
    baud : int
        The baud at which it answered or streamed.
    firmware : str or None
        ``"skinloc_muca 1.1.0"``; ``None`` for a board that streams without answering ``v``
        (the paper's text firmware).
    n_tx, n_rx : int or None
        The grid it sends (skinloc's firmware); ``None`` when unknown.
    n_values : int or None
        Values per frame seen on the wire (text lines or binary frames), if any came.
    format : str or None
        ``"binary"`` or ``"text"``.
    gain : int or None
        Analog gain (skinloc's firmware).
    controller : str or None
        ``"ok"``, ``"missing"`` or ``"silent"``; ``None`` when the firmware does not say.
    virtual : bool
        ``skinloc virtual-skin`` rather than a board.
    """

    port: str
    baud: int
    firmware: str | None = None
    n_tx: int | None = None
    n_rx: int | None = None
    n_values: int | None = None
    format: str | None = None
    gain: int | None = None
    controller: str | None = None
    virtual: bool = False

    @property
    def is_skinloc(self) -> bool:
        """Whether it runs skinloc's firmware (it answers ``v``)."""
        return self.firmware is not None

    def describe(self) -> str:
        """One line: what runs there, e.g. ``skinloc_muca 1.1.0, 8x8, gain 8, controller ok``."""
        if self.firmware is None:
            what = f"{self.format or 'unknown'} stream"
            if self.n_values:
                what += f", {self.n_values} values per frame"
            return f"{what} at {self.baud} baud (does not answer 'v': not skinloc's firmware)"
        state = f", controller {self.controller}" if self.controller else ""
        return (
            f"{self.firmware}{' (virtual)' if self.virtual else ''}, grid {self.n_tx}x{self.n_rx}"
            f", {self.format}, gain {self.gain}{state}, {self.baud} baud"
        )

    def check_controller(self) -> None:
        """Raise ``BoardError`` when the firmware reports no working controller."""
        if self.controller == "missing":
            raise BoardError(
                f"the board on {self.port} runs {self.firmware} but finds no touch controller "
                "(FT5x06 at I2C 0x38): check the SDA/SCL wiring (A4/A5 on an Uno), the "
                "controller's supply and GND (firmware/README.md)"
            )
        if self.controller == "silent":
            raise BoardError(
                f"the board on {self.port} runs {self.firmware}; its touch controller answers "
                "but does not scan: check the controller's supply voltage and reset it (power "
                "cycle the board)"
            )


def _open(port: str, baud: int) -> Any:
    import serial

    from skinloc.hardware.serial import why_not_open

    try:
        return serial.serial_for_url(port, baudrate=baud, timeout=0.05, write_timeout=1.0)
    except (serial.SerialException, OSError, ValueError) as exc:
        raise BoardError(f"cannot open serial port {port}: {why_not_open(exc)}") from None


def _binary_lock(data: bytes) -> int | None:
    """Values per frame when ``data`` holds at least two intact binary frames."""
    from skinloc.hardware.framing import BinaryParser

    frames = BinaryParser().feed(data)
    return frames[-1].values.size if len(frames) >= 2 else None


def _text_lock(data: bytes) -> int | None:
    """Values per line when ``data`` holds at least three lines of counts of one length."""
    lengths = [m.group(1).count(b",") + 1 for m in _TEXT_LINE.finditer(data)]
    for n in set(lengths):
        if lengths.count(n) >= 3:
            return n
    return None


def _info(port: str, baud: int, data: bytes) -> BoardInfo | None:
    """What ``data`` (all a probe read) says about the board; None if nothing usable."""
    answers = list(_VERSION.finditer(data))
    if answers:
        m = answers[-1]  # the newest state
        controller = m.group(6).decode() if m.group(6) else None
        return BoardInfo(
            port,
            baud,
            firmware=m.group(1).decode(),
            n_tx=int(m.group(2)),
            n_rx=int(m.group(3)),
            format=m.group(4).decode(),
            gain=int(m.group(5)),
            controller=controller,
            virtual=m.group(7) is not None,
            n_values=_binary_lock(data) or _text_lock(data),
        )
    n = _binary_lock(data)
    if n:
        return BoardInfo(port, baud, format="binary", n_values=n)
    n = _text_lock(data)
    if n:
        return BoardInfo(port, baud, format="text", n_values=n)
    return None


def probe(
    port: str,
    baud: int,
    *,
    timeout_s: float = PROBE_S,
    commands: tuple[str, ...] = (),
    opener: Callable[[str, int], Any] = _open,
) -> tuple[BoardInfo | None, bytes, list[str]]:
    """Open ``port`` at ``baud``, send ``commands`` then ``v``, and listen.

    Returns
    -------
    info : BoardInfo or None
        What answered; None when nothing answered ``v`` and no frame was recognised.
    data : bytes
        Everything read.
    replies : list of str
        The ``ok ...`` / ``error ...`` lines read, in order (the replies to ``commands``).
    """
    ser = opener(port, baud)
    data = bytearray()
    ask = "".join(f"{c}\n" for c in (*commands, "v")).encode()
    try:
        start = time.monotonic()
        first_ask = asked = 0.0
        while True:
            chunk = ser.read(4096)
            if chunk:
                data += chunk
            now = time.monotonic()
            if now - start >= timeout_s:
                break
            replies = _REPLY.findall(bytes(data))
            last_reply = max((m.end() for m in _REPLY.finditer(bytes(data))), default=0)
            if len(replies) >= len(commands) and _VERSION.search(data, last_reply):
                break  # it answered, after its replies to the commands
            if first_ask and now - first_ask > 1.2 and (_binary_lock(data) or _text_lock(data)):
                break  # it streams but does not answer 'v': not skinloc's firmware
            # Ask until it answers: an Uno's bootloader drops what comes while it runs.
            if now - start >= 0.2 and now - asked >= 0.6:
                ser.write(ask)
                asked = now
                first_ask = first_ask or now
    except OSError as exc:  # serial.SerialException is an OSError: unplugged while asked
        raise BoardError(f"lost {port} while asking the board: {exc}") from None
    finally:
        ser.close()
    replies = [r.decode().strip() for r in _REPLY.findall(bytes(data))]
    return _info(port, baud, bytes(data)), bytes(data), replies


def detect(
    port: str,
    baud: int | None = None,
    *,
    timeout_s: float = PROBE_S,
    opener: Callable[[str, int], Any] = _open,
) -> BoardInfo:
    """What runs on ``port`` and at which baud (``baud`` given: only that one is tried).

    Raises
    ------
    BoardError
        Nothing answered or streamed at any baud tried (the message says what to check).
    """
    bauds = (baud,) if baud else BAUDS
    seen: dict[int, int] = {}
    for b in bauds:
        info, data, _ = probe(port, b, timeout_s=timeout_s, opener=opener)
        if info is not None:
            return info
        seen[b] = len(data)
        if _TROUBLE.search(data):  # an old firmware's start-up line, or one that lost 'v'
            raise BoardError(f"{port}: {_TROUBLE.search(data).group(0).decode()}")
    tried = " or ".join(str(b) for b in bauds)
    if not any(seen.values()):
        raise BoardError(
            f"no answer from {port} at {tried} baud within {timeout_s:g} s: check that the board "
            "is powered and runs the sketch (flash firmware/skinloc_muca), the USB cable (data, "
            "not charge-only)"
            + ("" if baud else ", and --baud if the sketch was built for another")
        )
    raise BoardError(
        f"{port} sends bytes at {tried} baud but neither frames nor replies: give --baud, the "
        "rate the sketch was built with (skinloc's firmware: 1000000; the paper's: 115200)"
    )


def parse_lines(text: str) -> tuple[str, str]:
    """``TXMASK,RXMASK`` (or a space between) as the two masks; ``ValueError`` if malformed.

    Examples
    --------
    >>> parse_lines("111111110000,11111111")
    ('111111110000', '11111111')
    """
    parts = re.split(r"[,\s]+", text.strip())
    ok = len(parts) == 2 and all(re.fullmatch(r"[01]+", p) and "1" in p for p in parts)
    if not ok or len(parts[0]) > MAX_TX or len(parts[1]) > MAX_RX:
        raise ValueError(
            f"--lines must be TXMASK,RXMASK: up to {MAX_TX} and {MAX_RX} digits 0/1 with at "
            f"least one 1 each (1 = line used), e.g. 11111111,11111111; got {text!r}"
        )
    return parts[0], parts[1]


def configure(
    info: BoardInfo,
    *,
    gain: int | None = None,
    lines: tuple[str, str] | None = None,
    opener: Callable[[str, int], Any] = _open,
) -> BoardInfo:
    """Set the gain and the lines of a board running skinloc's firmware; returns its new state.

    Raises
    ------
    BoardError
        The board does not run skinloc's firmware, refused a setting (its reply is quoted), or
        stopped answering.
    """
    commands: list[str] = []
    if gain is not None:
        if not 1 <= gain <= 31:
            raise BoardError(f"--gain must be 1-31 (the controller's range), got {gain}")
        commands.append(f"g {gain}")
    if lines is not None:
        commands.append(f"l {lines[0]} {lines[1]}")
    if not commands:
        return info
    if not info.is_skinloc:
        raise BoardError(
            f"{info.port} does not answer 'v' (not skinloc's firmware): --gain and --lines "
            "need firmware/skinloc_muca"
        )
    new, _, replies = probe(info.port, info.baud, commands=tuple(commands), opener=opener)
    for r in replies:
        if r.startswith("error"):
            raise BoardError(f"the board on {info.port} refused a setting: {r}")
    if new is None or not new.is_skinloc:
        raise BoardError(f"the board on {info.port} stopped answering while being set up")
    if lines is not None and (new.n_tx, new.n_rx) != (lines[0].count("1"), lines[1].count("1")):
        if not new.virtual:  # the virtual skin acknowledges lines but keeps its grid
            raise BoardError(f"the board on {info.port} did not take --lines: {new.describe()}")
    return new
