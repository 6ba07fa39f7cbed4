"""Record: the live stream to an HDF5 or MCAP file of the open session, started and stopped."""

from __future__ import annotations

from typing import Any

from fastapi.responses import Response

from skinloc.app.routes.bodies import RecordBody
from skinloc.app.routes.common import PageContext, actions_router, json_response


def add_routes(ctx: PageContext) -> None:
    """``GET /api/record``, ``POST /api/record/start``, ``POST /api/record/stop``."""
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @router.get("/api/record")
    def status() -> Response:
        return json_response(workspace.recording_status())

    @router.post("/api/record/start")
    def start(body: RecordBody) -> dict[str, Any]:
        return workspace.start_recording(body.format)

    @router.post("/api/record/stop")
    def stop() -> dict[str, Any]:
        return workspace.stop_recording()

    app.include_router(router)
