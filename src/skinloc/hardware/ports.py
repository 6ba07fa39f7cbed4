"""Which ports a skin may be on: the serial ports of this machine, and the check of a named source.

``check_source`` is the one place a source a person or a page names is checked: only ``sim``, a
serial device or a running virtual skin pass (pyserial URLs only on opt-in).
"""

from __future__ import annotations

import glob
import os
import re
import stat
import tempfile
from dataclasses import dataclass

__all__ = [
    "ALLOWED_SOURCES",
    "VIRTUAL_GLOB",
    "PortInfo",
    "PortMissingError",
    "check_source",
    "list_ports",
]

#: USB vendor ids of Arduino boards and the USB-serial chips on their clones.
ARDUINO_VIDS = {
    0x2341: "Arduino",
    0x2A03: "Arduino",
    0x1B4F: "SparkFun",
    0x239A: "Adafruit",
    0x1A86: "CH340 (Arduino clone)",
    0x0403: "FTDI",
    0x10C4: "CP210x",
}
#: Where ``skinloc virtual-skin`` puts the stable links to its pseudo-terminals.
VIRTUAL_GLOB = os.path.join(tempfile.gettempdir(), "skinloc-virtual-*", "ttySKIN*")


#: What ``check_source`` lets through, for its messages.
ALLOWED_SOURCES = (
    "'sim' (the simulated skin), a serial port such as /dev/ttyACM0 or COM3, or a running "
    "virtual skin's port (`skinloc ports` lists both)"
)


class PortMissingError(ValueError):
    """A source names a device path that does not exist (not plugged in yet, or a typo)."""


def check_source(
    source: str, *, allow_urls: bool = False, allow_sim: bool = True, opt_in: str = ""
) -> str:
    """``source`` if it names ``sim`` or a serial device; raise ``ValueError`` otherwise.

    A pyserial URL (anything with ``://``: ``spy://`` writes a log to any file, ``socket://``
    opens a network connection, ``loop://``, ``rfc2217://``, ``hwgrep://``) reaches far more
    than a skin, so it passes only with ``allow_urls``. A path must be a character device (a
    USB serial port, or the pseudo-terminal of ``skinloc virtual-skin``); nothing is opened.
    A path that does not exist raises ``PortMissingError`` (a ``ValueError``), so a caller
    may wait for the device instead.

    Parameters
    ----------
    source : str
        What a person or a page named.
    allow_urls : bool
        Let pyserial URLs through (the command line's ``--allow-url``; the app never does).
    allow_sim : bool
        Accept ``sim``.
    opt_in : str
        How to opt in to URLs, added to the message (e.g. ``"pass --allow-url"``).

    Examples
    --------
    >>> check_source("sim")
    'sim'
    >>> check_source("loop://", allow_urls=True)
    'loop://'
    """
    if not isinstance(source, str) or not source.strip():
        raise ValueError(f"choose a source: {ALLOWED_SOURCES}")
    if allow_sim and source == "sim":
        return source
    if "://" in source:
        if allow_urls:
            return source
        hint = f"; {opt_in} to open it anyway" if opt_in else ""
        raise ValueError(
            f"{source!r} is a pyserial URL, which is not accepted{hint}: give {ALLOWED_SOURCES}"
        )
    if os.name == "nt" and re.fullmatch(r"(\\\\\.\\)?COM\d+", source, re.IGNORECASE):
        return source  # Windows ports are names, not files
    try:
        mode = os.stat(source).st_mode
    except FileNotFoundError:
        raise PortMissingError(
            f"cannot open serial port {source}: no such device (is the board plugged in? "
            "`skinloc ports` lists the ports)"
        ) from None
    except (OSError, ValueError):
        raise ValueError(
            f"cannot open serial port {source}: no such device (is the board plugged in? "
            "`skinloc ports` lists the ports)"
        ) from None
    if not stat.S_ISCHR(mode):
        raise ValueError(f"{source} is not a serial port: give {ALLOWED_SOURCES}")
    return source


@dataclass(frozen=True)
class PortInfo:
    """A serial port found on this machine."""

    device: str
    description: str
    hwid: str
    likely_arduino: bool
    virtual: bool = False


def list_ports() -> list[PortInfo]:
    r"""Serial ports present, likely Arduinos first, then running ``skinloc virtual-skin``\ s."""
    from serial.tools import list_ports as lp

    found = []
    for p in lp.comports():
        text = f"{p.description} {p.manufacturer or ''} {p.product or ''}".lower()
        arduino = p.vid in ARDUINO_VIDS or "arduino" in text
        desc = p.description or ""
        if p.vid in ARDUINO_VIDS and ARDUINO_VIDS[p.vid].lower() not in desc.lower():
            desc = f"{desc} [{ARDUINO_VIDS[p.vid]}]".strip()
        found.append(PortInfo(p.device, desc, p.hwid or "", arduino))
    found.sort(key=lambda p: (not p.likely_arduino, p.device))
    for link in sorted(glob.glob(VIRTUAL_GLOB)):
        if os.path.exists(link) and _owner_alive(os.path.join(os.path.dirname(link), "pid")):
            found.append(PortInfo(link, "skinloc virtual skin", "pty", False, virtual=True))
    return found


def _owner_alive(pid_file: str) -> bool:
    """Whether the process named in a virtual skin's pid file still runs."""
    try:
        with open(pid_file) as fh:
            pid = int(fh.read().strip())
        os.kill(pid, 0)
    except PermissionError:
        return True  # it runs, as another user
    except (OSError, ValueError):
        return False
    return True
