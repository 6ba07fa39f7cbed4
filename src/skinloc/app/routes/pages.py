"""The page itself, its static files, and what it reads of the state."""

from __future__ import annotations

import html
import re
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.responses import HTMLResponse, Response
from fastapi.staticfiles import StaticFiles

from skinloc.app.routes.common import OK, ClientHeader, json_response
from skinloc.app.workspace import Workspace
from skinloc.live.contact import TRACK_COLOURS

STATIC = Path(str(resources.files("skinloc.app") / "static"))


def add_routes(app: FastAPI, workspace: Workspace, token: str) -> None:
    """``/``, ``/static``, ``GET /api/state``, ``/api/session[/coverage|/mesh]``, the lease.

    ``GET /api/accuracy/reference``: the real skin's error against calibration touches with
    and without the map prior and the paper's network, and the probing floor (the reference
    the Train page draws the session's own ``prior_curve`` against).
    """

    @app.get("/", include_in_schema=False)
    def index() -> HTMLResponse:
        page = (STATIC / "index.html").read_text(encoding="utf-8")
        meta = f'<meta name="skinloc-token" content="{html.escape(token)}">'
        # the one palette of fingers, shared with the ROS 2 and Foxglove sinks
        meta += f'<meta name="skinloc-track-colours" content="{" ".join(TRACK_COLOURS)}">'
        page = re.sub(r"(<head[^>]*>)", lambda m: m.group(1) + meta, page, count=1)
        headers = {
            "Cache-Control": "no-store",  # the token changes with every launch
            "Content-Security-Policy": "frame-ancestors 'none'",
            "X-Frame-Options": "DENY",
            "Referrer-Policy": "no-referrer",
        }
        return HTMLResponse(page, headers=headers)

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/api/state")
    def state() -> Response:
        return json_response(workspace.snapshot())

    @app.get("/api/session")
    def session() -> Response:
        return json_response(workspace.session_detail())

    @app.get("/api/session/coverage")
    def session_coverage() -> Response:
        return json_response(workspace.coverage())

    @app.get("/api/session/mesh")
    def session_mesh() -> Response:
        return json_response(workspace.session_mesh())

    @app.get("/api/accuracy/reference")
    def accuracy_reference() -> Response:
        from skinloc.experiments.demo import reference_curves

        return json_response(reference_curves())

    # The one action that does not first take control (``actions_router``): it takes it over.
    @app.post("/api/lease")
    def take_over(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.take_over(client or "anonymous")
        return OK
