"""The firmware's commands as the virtual skin answers them (``firmware/README.md``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from skinloc.hardware.protocol import WireFormat

__all__ = ["FIRMWARE_VERSION", "answer_command"]

#: Version string the virtual device reports, the same as the firmware it imitates.
FIRMWARE_VERSION = "skinloc_muca 1.0.0"


def answer_command(dev: Any, line: str) -> str:
    """A ``VirtualSkin``'s answer to one command line (empty: none); sets its format or gain."""
    words = line.split()
    if not words:
        return ""
    cmd, args = words[0].lower(), words[1:]
    skin = dev.skin
    try:
        if cmd in ("v", "version"):
            return (
                f"{FIRMWARE_VERSION} grid {skin.n_tx}x{skin.n_rx} format {dev.fmt.value} "
                f"gain {dev.gain} rate {dev.rate_hz:g} virtual"
            )
        if cmd == "f" and args and args[0] in ("text", "binary"):
            dev._flush_pending()
            dev.fmt = WireFormat(args[0])
            return f"ok format {dev.fmt.value}"
        if cmd == "g" and args:
            gain = int(args[0])
            if not 0 <= gain <= 255:
                return "error gain must be 0-255"
            dev.gain = gain
            return f"ok gain {gain}"
        if cmd == "l" and len(args) == 2:
            # Checked and acknowledged like the firmware; the simulated grid stays as it is.
            tx, rx = args
            ok = all(set(m) <= {"0", "1"} and "1" in m for m in (tx, rx))
            if not ok or len(tx) > 21 or len(rx) > 12:
                return "error usage: l TXMASK RXMASK, e.g. l 11111111 11111111"
            return f"ok lines {tx.count('1')}x{rx.count('1')}"
        if cmd == "?":
            return (
                "commands: v | f text|binary | g N | l TXMASK RXMASK | c | ? | touch X Y Z | lift"
            )
        if cmd == "c":
            return "ok recalibrated"
        if cmd == "touch" and len(args) == 3:
            point = np.array([float(a) for a in args])
            skin.touch_near(point)
            dev.counts["touches"] += 1
            return ""
        if cmd == "lift":
            skin.release()
            return ""
    except ValueError:
        pass
    return f"error unknown command {line[:40]!r}; try v, f text|binary, g N, l TX RX, c"
