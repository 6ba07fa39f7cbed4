"""Sessions: listing, creating, opening, closing, importing a recording, the printable targets."""

from __future__ import annotations

from typing import Any

from fastapi import Query
from fastapi.responses import Response

from skinloc.app.routes.bodies import SessionBody
from skinloc.app.routes.common import OK, PageContext, actions_router, json_response
from skinloc.app.workspace import Workspace


def add_routes(ctx: PageContext) -> None:
    """Add the session routes.

    ``/api/sessions``, ``/api/sessions/{id}/open``, ``/api/session/close``,
    ``/api/recordings/import``, ``/api/sessions/{id}/targets.{svg,pdf}``.
    """
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @router.get("/api/sessions")
    def sessions() -> Response:
        return json_response(workspace.sessions())

    @router.post("/api/sessions")
    def create_session(body: SessionBody) -> dict[str, Any]:
        return {"id": workspace.create_session(**body.model_dump())}

    @router.post("/api/sessions/{session_id}/open")
    def open_session(session_id: str) -> dict[str, Any]:
        workspace.open_session(session_id)
        return OK

    @router.post("/api/session/close")
    def close_session() -> dict[str, Any]:
        workspace.close_session()
        return OK

    @router.post("/api/recordings/import")
    def import_recording(path: str = Query(...)) -> dict[str, Any]:
        return {"id": workspace.import_recording(path)}

    @router.get("/api/sessions/{session_id}/targets.{fmt}")
    def targets_sheet(session_id: str, fmt: str) -> Response:
        from skinloc.app.sheet import layout_sheet, render_pdf, render_svg

        if fmt not in ("svg", "pdf"):
            raise ValueError(f"targets sheets come as svg or pdf, not {fmt!r}")
        mesh, targets, done, name = _sheet_input(workspace, session_id)
        sheet = layout_sheet(mesh, targets, title=f"skinloc targets: {name}", done=done)
        filename = f"targets-{session_id}.{fmt}"
        headers = {"Content-Disposition": f'inline; filename="{filename}"'}
        if fmt == "svg":
            return Response(render_svg(sheet), media_type="image/svg+xml", headers=headers)
        return Response(render_pdf(sheet), media_type="application/pdf", headers=headers)

    app.include_router(router)


def _sheet_input(workspace: Workspace, session_id: str):
    """Mesh, planned targets, which are done, and the name of a session."""
    import numpy as np

    from skinloc.data.recording import read_recording
    from skinloc.geometry.mesh import mesh_from_arrays

    folder = workspace.store.get(session_id)
    vertices, faces, targets = folder.read_plan()
    done = np.zeros(len(targets), dtype=bool)
    if folder.calibration.is_file():
        rec = read_recording(folder.calibration)
        if rec.planned_targets is not None:
            targets = rec.planned_targets
            done = np.arange(len(targets)) < rec.n_point_logs
    return mesh_from_arrays(vertices, faces), targets, done, folder.read_info().get("name", "")
