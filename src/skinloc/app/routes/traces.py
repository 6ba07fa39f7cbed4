"""Traces: a sensor's recent signal, a recorded touch's frames (reads only)."""

from __future__ import annotations

from typing import Literal

from fastapi import Query
from fastapi.responses import Response

from skinloc.app.routes.common import PageContext, actions_router, json_response


def add_routes(ctx: PageContext) -> None:
    """``GET /api/trace/sensor?tx=&rx=&seconds=``, ``GET /api/session/touch?index=&recording=``."""
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @router.get("/api/trace/sensor")
    def sensor(
        tx: int = Query(..., ge=0, le=63),
        rx: int = Query(..., ge=0, le=63),
        seconds: float = Query(10.0, gt=0, le=20),
    ) -> Response:
        return json_response(workspace.sensor_trace(tx, rx, seconds))

    @router.get("/api/session/touch")
    def touch(
        index: int = Query(..., ge=0, le=100_000),
        recording: Literal["calibration", "validation"] = "calibration",
    ) -> Response:
        return json_response(workspace.touch_frames(index, recording))

    app.include_router(router)
