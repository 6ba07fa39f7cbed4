"""The firmware's commands as the virtual skin answers them (``firmware/README.md``)."""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from skinloc.hardware.protocol import WireFormat

__all__ = ["FIRMWARE_VERSION", "answer_command"]

#: Version string the virtual device reports, the same as the firmware it imitates.
FIRMWARE_VERSION = "skinloc_muca 1.1.0"


_GAIN = re.compile(r"g (\d+)")
_LINES = re.compile(r"l ([01]{1,21}) ([01]{1,12})")
_UNKNOWN = "error unknown command; send ? for the list"


def answer_command(dev: Any, line: str) -> str:
    """A ``VirtualSkin``'s answer to one command line (empty: none); sets its format or gain.

    The firmware's answers, word for word (``firmware/README.md``; checked against the real
    firmware in the emulator by ``tests/firmware``), plus the scripted finger's ``touch X Y Z``
    and ``lift``, which answer nothing.
    """
    text = line.replace("\r", "").rstrip("\n")  # as the firmware: spaces count
    if not text:
        return ""
    skin = dev.skin
    words = text.split()
    if words[:1] == ["touch"] and len(words) == 4:  # the scripted finger, not the firmware
        try:
            point = np.array([float(a) for a in words[1:]])
        except ValueError:
            return _UNKNOWN
        skin.touch_near(point)
        dev.counts["touches"] += 1
        return ""
    if text == "lift":
        skin.release()
        return ""
    if len(text) > 47:  # the firmware keeps 47 characters of a line and refuses longer ones
        return "error command too long; send ? for the list"
    if text == "v":
        return (
            f"{FIRMWARE_VERSION} grid {skin.n_tx}x{skin.n_rx} format {dev.fmt.value} "
            f"gain {dev.gain} controller ok rate {dev.rate_hz:g} virtual"
        )
    if text.startswith("f"):
        if text not in ("f text", "f binary"):
            return "error usage: f text|binary"
        dev._flush_pending()
        dev.fmt = WireFormat(text[2:])
        return f"ok format {dev.fmt.value}"
    if text.startswith("g"):
        m = _GAIN.fullmatch(text)
        if not m or not 1 <= int(m.group(1)) <= 31:  # the FT5x06's range
            return "error gain must be 1-31"
        dev.gain = int(m.group(1))
        return f"ok gain {dev.gain}"
    if text.startswith("l") and text != "lift":
        # Checked and acknowledged like the firmware; the simulated grid stays as it is.
        m = _LINES.fullmatch(text)
        if not m or "1" not in m.group(1) or "1" not in m.group(2):
            return "error usage: l TXMASK RXMASK, e.g. l 11111111 11111111"
        return f"ok lines {m.group(1).count('1')}x{m.group(2).count('1')}"
    if text == "?":
        return "commands: v | f text|binary | g N | l TXMASK RXMASK | c | ? | touch X Y Z | lift"
    if text == "c":
        return "ok recalibrated"
    return _UNKNOWN
