"""The commands that ask a board about itself: ``skinloc ports`` and ``skinloc doctor``.

``doctor`` walks a new board through its checks, each with what to do when it fails.
"""

from __future__ import annotations

import json
import os
import sys
from typing import Annotated, Any

import numpy as np
import typer

from skinloc.cli.common import console, friendly_errors

__all__ = ["register"]


def _port_line(port: str) -> str:
    """What the system says the port is."""
    from skinloc.hardware.ports import list_ports

    for p in list_ports():
        if p.device == port or os.path.realpath(p.device) == os.path.realpath(port):
            return f"{port} ({p.description})" if p.description else port
    return f"{port} (not a USB serial port the system lists: a pseudo-terminal or an adapter)"


def diagnose(
    port: str, *, baud: int | None = None, seconds: float = 3.0, allow_url: bool = False
) -> list[dict[str, Any]]:
    """Run the checks in order; each is ``{"check", "ok", "detail", "hint"}``.

    Stops at a failure that makes the next checks meaningless.
    """
    from skinloc.errors import FrameTimeoutError
    from skinloc.hardware.board import BoardError, detect
    from skinloc.hardware.ports import check_source
    from skinloc.sensors.health import line_health
    from skinloc.sources.base import SourceOptions, make_source

    steps: list[dict[str, Any]] = []

    def step(check: str, ok: bool, detail: str, hint: str = "") -> bool:
        steps.append({"check": check, "ok": ok, "detail": detail, "hint": hint})
        return ok

    try:
        check_source(port, allow_urls=allow_url, allow_sim=False, opt_in="pass --allow-url")
    except ValueError as exc:
        step("port", False, str(exc), "plug the board in; `skinloc ports` lists the ports")
        return steps
    step("port", True, _port_line(port))
    try:
        info = detect(port, baud)
    except BoardError as exc:
        step("firmware", False, str(exc), "flash firmware/skinloc_muca (firmware/README.md)")
        return steps
    if info.is_skinloc:
        step("firmware", True, info.describe())
    else:
        step(
            "firmware",
            True,
            info.describe(),
            "the paper's text firmware works; skinloc's (firmware/skinloc_muca) adds checksums, "
            "frame counters, the full grid at 1000000 baud and these checks",
        )
    if info.controller is not None:
        try:
            info.check_controller()
        except BoardError as exc:
            step("controller", False, str(exc), "fix the wiring, then send c or reopen the port")
            return steps
        step("controller", True, "FT5x06 at I2C 0x38 answers and scans")
    n_tx, n_rx = info.n_tx or 8, info.n_rx or 8
    if not info.is_skinloc and info.n_values not in (None, 64):
        step("stream", False, f"{info.n_values} values per frame", "run skinloc monitor --tx --rx")
        return steps
    src = make_source(SourceOptions(port, n_tx=n_tx, n_rx=n_rx, baud=info.baud))
    try:
        with src:
            src.read(5.0)  # an Uno restarts when its port opens: a second or two
            got = [src.read(2.0)]
            while got[-1].timestamp_s - got[0].timestamp_s < seconds or len(got) < 10:
                got.append(src.read(2.0))
            stats = src.stats()
    except FrameTimeoutError as exc:
        step("stream", False, str(exc), "the board answers but does not stream: send c")
        return steps
    frames = np.stack([f.values for f in got])
    times = np.array([f.timestamp_s for f in got])
    span = float(times[-1] - times[0]) if len(times) > 1 else 0.0
    rate = (len(times) - 1) / span if span > 0 else 0.0
    faults = stats.n_lost + stats.n_corrupted + stats.n_dropped
    step(
        "stream",
        faults == 0,
        f"{rate:.1f} frames/s ({len(frames)} frames in {span:.1f} s), {stats.n_lost} lost, "
        f"{stats.n_corrupted} corrupted, {stats.n_dropped} dropped",
        "" if faults == 0 else "check the USB cable and the baud; close other programs on the port",
    )
    health = line_health(frames, n_tx, n_rx)
    level = (
        f"{len(frames)} no-touch frames: median {health.median_counts:.0f} counts, noise "
        f"{health.median_noise:.1f} counts"
    )
    problems = []
    for kind, dead, noisy in (
        ("TX", health.dead_tx, health.noisy_tx),
        ("RX", health.dead_rx, health.noisy_rx),
    ):
        problems += [f"{kind} {i} dead" for i in dead] + [f"{kind} {i} noisy" for i in noisy]
    if health.healthy:
        step("lines", True, f"no dead or noisy line; {level}")
    else:
        mask = _mask_hint(health, n_tx, n_rx)
        step(
            "lines",
            False,
            f"{', '.join(problems)} (0-based, in the order the board sends them); {level}",
            "keep the skin untouched while this runs; a dead line is a broken or unconnected "
            f"wire: fix it, or leave it out ({mask})",
        )
    return steps


def _mask_hint(health: Any, n_tx: int, n_rx: int) -> str:
    tx = "".join("0" if i in health.dead_tx + health.noisy_tx else "1" for i in range(n_tx))
    rx = "".join("0" if j in health.dead_rx + health.noisy_rx else "1" for j in range(n_rx))
    return f"--tx-mask {tx} --rx-mask {rx}"


def register(app: typer.Typer) -> None:
    """Add ``skinloc ports`` and ``skinloc doctor`` to the main ``skinloc`` app."""

    # -------------------------------------------------------------------------------- ports
    @app.command()
    @friendly_errors
    def ports(
        as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
        ask: Annotated[
            bool,
            typer.Option(
                "--ask/--no-ask",
                help="Ask each likely board 'v' (opening the port restarts an Uno).",
            ),
        ] = True,
    ) -> None:
        """List serial ports; the likely Arduino is marked, running virtual skins are listed.

        A likely board is asked 'v': one running skinloc's firmware says what it is.

        Example: skinloc ports
        """
        import json

        from skinloc.hardware.board import BoardError, detect
        from skinloc.hardware.ports import list_ports

        found = list_ports()
        boards: dict[str, str] = {}
        for p in found if ask else []:
            if p.likely_arduino or p.virtual:
                try:
                    boards[p.device] = detect(p.device, timeout_s=2.5).describe()
                except BoardError as exc:
                    boards[p.device] = f"no skinloc firmware: {str(exc).split(':', 1)[-1].strip()}"
        if as_json:
            rows = [{**p.__dict__, "board": boards.get(p.device)} for p in found]
            sys.stdout.write(json.dumps(rows, indent=2) + "\n")
            return
        if not found:
            console.print(
                "No serial port found. Plug the Arduino in (a data cable, not charge-only), "
                "or start 'skinloc virtual-skin'."
            )
            return
        from rich.table import Table

        table = Table("", "port", "description", "hardware id", *(["board"] if boards else []))
        for p in found:
            mark = "* Arduino?" if p.likely_arduino else ("virtual" if p.virtual else "")
            board = boards.get(p.device, "")
            if board.startswith("skinloc_muca"):
                mark = "* skinloc board" if not p.virtual else "virtual"
            table.add_row(mark, p.device, p.description, p.hwid, *([board] if boards else []))
        console.print(table)

    # -------------------------------------------------------------------------------- doctor
    @app.command()
    @friendly_errors
    def doctor(
        port: Annotated[str, typer.Option("--port", "-p", help="Serial port of the board.")],
        baud: Annotated[
            int | None, typer.Option(min=50, help="Baud rate; default: found by itself.")
        ] = None,
        seconds: Annotated[
            float, typer.Option(min=0.5, max=60, help="Length of the no-touch baseline, s.")
        ] = 3.0,
        as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
        allow_url: Annotated[
            bool, typer.Option("--allow-url", help="Let --port be a pyserial URL.")
        ] = False,
    ) -> None:
        """Check a board step by step: port, firmware, controller, frame rate, dead lines.

        Keep the skin untouched: the last check reads a short baseline and flags dead or noisy
        lines. Exit code 1 when a check fails.

        Example: skinloc doctor --port /dev/ttyACM0
        """
        steps = diagnose(port, baud=baud, seconds=seconds, allow_url=allow_url)
        healthy = all(s["ok"] for s in steps) and len(steps) >= 5
        if as_json:
            sys.stdout.write(json.dumps({"healthy": healthy, "checks": steps}, indent=2) + "\n")
        else:
            for s in steps:
                mark = "[green]ok  [/]" if s["ok"] else "[bold red]FAIL[/]"
                console.print(f"{mark} {s['check']:<10} {s['detail']}", highlight=False)
                if s["hint"]:
                    console.print(f"     {'':<10} -> {s['hint']}", highlight=False)
            console.print("healthy" if healthy else "[bold red]not ready[/]: see FAIL above")
        if not healthy:
            raise typer.Exit(1)
