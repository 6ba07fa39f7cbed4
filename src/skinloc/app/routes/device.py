"""The skin: listing ports, connecting, zeroing the heat map, touching the simulated skin."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI

from skinloc.app.device import SourceSpec
from skinloc.app.routes.bodies import ConnectBody, TouchBody
from skinloc.app.routes.common import OK, ClientHeader
from skinloc.app.workspace import Workspace


def add_routes(app: FastAPI, workspace: Workspace) -> None:
    """Add the skin's routes.

    ``GET /api/ports``, ``POST /api/connect``, ``/api/disconnect``, ``/api/rezero``,
    ``/api/sim/touch``.
    """

    @app.get("/api/ports")
    def ports() -> list[dict[str, Any]]:
        from skinloc.hardware.serial import list_ports

        return [p.__dict__ for p in list_ports()]

    @app.post("/api/connect")
    def connect(body: ConnectBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        spec = SourceSpec(**body.model_dump())
        spec.check()  # before the skin in use is closed
        workspace.connect(spec)
        return OK

    @app.post("/api/disconnect")
    def disconnect(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.disconnect()
        return OK

    @app.post("/api/rezero")
    def rezero(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.rezero()
        return OK

    @app.post("/api/sim/touch")
    def sim_touch(body: TouchBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.sim_touch(body.point)
        return OK
