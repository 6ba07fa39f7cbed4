"""Commands for a skin on a serial port: ports, monitor, record, collect, virtual-skin."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add the hardware commands to the main ``skinloc`` app."""
