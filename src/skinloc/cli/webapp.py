"""The ``skinloc app`` command: serve the browser app on this machine and open it."""

from __future__ import annotations

import ipaddress
import logging
import socket
import threading
from pathlib import Path
from typing import Annotated

import typer

log = logging.getLogger(__name__)

__all__ = ["register"]


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _bind(host: str, port: int) -> socket.socket:
    """The listening socket for ``host:port`` (port 0: any free port), or a one-line ValueError.

    Binding here, before the server starts, is what lets ``--port 0`` print the port it got
    and lets the page's own origin name it.
    """
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise ValueError(
            f"cannot serve on {host}:{port} ({exc.strerror or exc}): pass another --port"
        ) from None
    return sock


def register(app: typer.Typer) -> None:
    """Add ``skinloc app`` to the main command line."""
    from skinloc.cli.common import console, err_console, friendly_errors

    @app.command("app")
    @friendly_errors
    def serve(
        source: Annotated[
            str | None,
            typer.Option(
                "--source",
                help="'sim' for the simulated skin, or a serial port (no pyserial URL); "
                "default: choose in the page.",
            ),
        ] = None,
        mesh: Annotated[
            Path | None, typer.Option(help="Skin mesh of new sessions; default: the paper's cone.")
        ] = None,
        units: Annotated[str, typer.Option(help="Units of --mesh: auto, m or mm.")] = "auto",
        data: Annotated[Path, typer.Option(help="Folder of sessions and recordings.")] = Path(
            "skinloc-sessions"
        ),
        host: Annotated[str, typer.Option(help="Address to serve on.")] = "127.0.0.1",
        port: Annotated[
            int, typer.Option(min=0, max=65535, help="TCP port to serve on (0: any free port).")
        ] = 8765,
        tx: Annotated[int, typer.Option(min=1, max=21, help="TX lines the device sends.")] = 8,
        rx: Annotated[int, typer.Option(min=1, max=12, help="RX lines the device sends.")] = 8,
        baud: Annotated[int, typer.Option(min=50, help="Baud rate of --source PORT.")] = 115200,
        fmt: Annotated[
            str, typer.Option("--format", help="Wire format of the port: auto, text, binary.")
        ] = "auto",
        seed: Annotated[int, typer.Option(min=0, help="Seed of the simulated skin.")] = 0,
        no_browser: Annotated[
            bool, typer.Option("--no-browser", help="Do not open a browser tab.")
        ] = False,
    ) -> None:
        """Serve the browser app: connect, calibrate on the 3D skin, train, validate, live.

        Sessions are kept in --data; the page lists them and resumes unfinished ones.

        Example: skinloc app --source sim
        """
        try:
            import uvicorn

            from skinloc.app.server import create_app, own_origins
            from skinloc.app.workspace import AppConfig
            from skinloc.sources.base import SourceOptions
        except ImportError as exc:  # pragma: no cover - dependencies of a plain install
            raise ValueError(f"the app needs {exc.name}: pip install skinloc") from None
        from skinloc.geometry.mesh import load_mesh

        if fmt not in ("auto", "text", "binary"):
            raise ValueError(f"unknown --format {fmt!r}; choose one of: auto, text, binary")
        if data.exists() and not data.is_dir():
            raise ValueError(f"--data {data} is a file: give a folder of sessions")
        surface = None if mesh is None else load_mesh(mesh, units)
        if not _is_loopback(host):
            err_console.print(
                f"[bold yellow]warning:[/] serving on {host}: anyone who reaches this address "
                "controls the skin and reads the sessions (there is no login)",
                highlight=False,
            )
        sock = _bind(host, port)
        try:
            port = sock.getsockname()[1]
            config = AppConfig(
                data_dir=data,
                mesh=surface,
                mesh_name=mesh.name if mesh is not None else AppConfig.mesh_name,
            )
            spec = None
            if source is not None:
                spec = SourceOptions(source, n_tx=tx, n_rx=rx, baud=baud, format=fmt, seed=seed)
            hosts = ["127.0.0.1", "localhost", "[::1]", host, f"[{host}]"]
            # The page's own origins only: another site's page gets no stream and no actions.
            web = create_app(config, spec, allowed_hosts=hosts, origins=own_origins(host, port))
            shown = f"[{host}]" if ":" in host else host
            url = f"http://{shown}:{port}/"
            console.print(
                f"skinloc app on {url} (sessions in {data}/); Ctrl-C stops", soft_wrap=True
            )
            if not no_browser:
                import webbrowser

                threading.Timer(1.0, lambda: webbrowser.open(url)).start()
            server = uvicorn.Server(
                uvicorn.Config(web, log_level="warning", ws="websockets-sansio")
            )
            server.run(sockets=[sock])
        finally:
            sock.close()
