"""Options and set-up shared by the commands that read a board: ``--gain``, ``--lines``, the baud.

Before a command opens a serial port to stream, ``prepare_port`` asks the board what it runs
(``hardware.board.detect``: the baud, skinloc's firmware or the paper's, the grid, the
controller), refuses a board without a working controller with a one-line message, and sends
``--gain`` / ``--lines``, which the firmware keeps across the reset of the next open.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Annotated

import typer

__all__ = ["GainOpt", "LinesOpt", "PreparedPort", "prepare_port"]

GainOpt = Annotated[
    int | None,
    typer.Option(
        min=1, max=31, help="Analog gain of the controller, 1-31 (skinloc's firmware keeps it)."
    ),
]
LinesOpt = Annotated[
    str | None,
    typer.Option(
        help="Lines the board reads, TXMASK,RXMASK (1 = used), e.g. 11111111,11111111 "
        "(skinloc's firmware keeps them); the grid becomes the number of ones."
    ),
]


@dataclass(frozen=True)
class PreparedPort:
    """What the command opens: the baud and the grid (None: the caller's default)."""

    baud: int
    n_tx: int | None
    n_rx: int | None
    description: str = ""


def prepare_port(
    port: str,
    *,
    baud: int | None,
    gain: int | None = None,
    lines: str | None = None,
    n_tx: int | None = None,
    n_rx: int | None = None,
) -> PreparedPort:
    """Find the board's baud and grid, check its controller, set ``gain`` and ``lines``.

    A port that is a pyserial URL, or absent (waited for), is not asked: it gets ``baud`` or
    1 000 000. Nothing is asked either when ``baud`` is given and there is nothing to set.

    Raises
    ------
    ValueError
        With one line that says what to check (no answer, no controller, a refused setting,
        a grid that differs from ``--tx``/``--rx``).
    """
    from skinloc.hardware.board import configure, detect, parse_lines

    masks = parse_lines(lines) if lines is not None else None
    if masks is not None:
        grid = (masks[0].count("1"), masks[1].count("1"))
        if (n_tx is not None and n_tx != grid[0]) or (n_rx is not None and n_rx != grid[1]):
            raise ValueError(
                f"--lines selects {grid[0]} x {grid[1]} lines but --tx/--rx say "
                f"{n_tx} x {n_rx}: drop --tx/--rx"
            )
    asks = baud is None or gain is not None or masks is not None
    if "://" in port or not os.path.exists(port) or not asks:
        if gain is not None or masks is not None:
            if "://" in port or not os.path.exists(port):
                raise ValueError(f"--gain and --lines need the board on {port} plugged in")
        return PreparedPort(baud or 1_000_000, n_tx, n_rx)
    info = detect(port, baud)
    info.check_controller()
    info = configure(info, gain=gain, lines=masks)
    tx, rx = n_tx, n_rx
    if info.is_skinloc and not info.virtual:
        if (tx is not None and tx != info.n_tx) or (rx is not None and rx != info.n_rx):
            raise ValueError(
                f"the board on {port} sends {info.n_tx} x {info.n_rx} lines but --tx/--rx say "
                f"{tx} x {rx}: drop --tx/--rx, or select the lines with --lines"
            )
        tx, rx = info.n_tx, info.n_rx
    elif not info.is_skinloc and info.n_values and tx is None and rx is None:
        if info.n_values != 64:
            raise ValueError(
                f"the board on {port} sends {info.n_values} values per frame: give --tx and --rx"
            )
    return PreparedPort(info.baud, tx, rx, info.describe())
