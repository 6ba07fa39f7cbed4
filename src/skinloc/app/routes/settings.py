"""The live pipeline's settings: shown, and saved to the session's skins file."""

from __future__ import annotations

from fastapi.responses import Response

from skinloc.app.routes.bodies import SettingsBody
from skinloc.app.routes.common import PageContext, actions_router, json_response


def add_routes(ctx: PageContext) -> None:
    """``GET /api/live/settings``, ``POST /api/live/settings``."""
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @router.get("/api/live/settings")
    def current() -> Response:
        return json_response(workspace.live_settings())

    @router.post("/api/live/settings")
    def save(body: SettingsBody) -> Response:
        return json_response(workspace.set_live_settings(body.values))

    app.include_router(router)
