"""The skin: listing ports, connecting, zeroing the heat map, touching the simulated skin."""

from __future__ import annotations

from typing import Any

from skinloc.app.routes.bodies import ConnectBody, TouchBody
from skinloc.app.routes.common import OK, PageContext, actions_router
from skinloc.hardware.ports import check_source
from skinloc.sources.base import SourceOptions


def add_routes(ctx: PageContext) -> None:
    """Add the skin's routes.

    ``GET /api/ports``, ``POST /api/connect``, ``/api/disconnect``, ``/api/rezero``,
    ``/api/sim/touch``.
    """
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @router.get("/api/ports")
    def ports() -> list[dict[str, Any]]:
        from skinloc.hardware.serial import list_ports

        return [p.__dict__ for p in list_ports()]

    @router.post("/api/connect")
    def connect(body: ConnectBody) -> dict[str, Any]:
        check_source(body.source)  # before the skin in use is closed
        workspace.connect(
            SourceOptions(
                body.source,
                n_tx=body.tx,
                n_rx=body.rx,
                baud=body.baud,
                format=body.format,
                seed=body.seed,
                rate_hz=body.rate_hz,
            )
        )
        return OK

    @router.post("/api/disconnect")
    def disconnect() -> dict[str, Any]:
        workspace.disconnect()
        return OK

    @router.post("/api/rezero")
    def rezero() -> dict[str, Any]:
        workspace.rezero()
        return OK

    @router.post("/api/sim/touch")
    def sim_touch(body: TouchBody) -> dict[str, Any]:
        if body.path is not None:
            workspace.sim_path(body.path)
        else:
            workspace.sim_touch(body.point)
        return OK

    app.include_router(router)
