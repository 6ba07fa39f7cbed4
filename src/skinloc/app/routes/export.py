"""Export: downloads of the open session's recordings, model, validation errors and error view.

Every route is a GET (it changes nothing); a file is named, never given as a path, and only the
session's own exportable files are found (``skinloc.app.workspace.export``).
"""

from __future__ import annotations

from fastapi import HTTPException
from fastapi.responses import Response

from skinloc.app.routes.common import PageContext, actions_router, json_response
from skinloc.app.workspace.export import NoSuchExport

#: Media type of each downloaded file, by suffix.
MEDIA = {
    "h5": "application/x-hdf5",
    "mcap": "application/octet-stream",
    "csv": "text/csv; charset=utf-8",
    "png": "image/png",
    "svg": "image/svg+xml",
}


def download(name: str, content: bytes | str) -> Response:
    """``content`` as a download saved as ``name`` (a plain file name the app made)."""
    media = MEDIA.get(name.rpartition(".")[2], "application/octet-stream")
    headers = {
        "Content-Disposition": f'attachment; filename="{name}"',
        "Cache-Control": "no-store",
        "X-Content-Type-Options": "nosniff",
    }
    return Response(content, media_type=media, headers=headers)


def add_routes(ctx: PageContext) -> None:
    """Add the downloads (every one a GET).

    ``GET /api/export``, ``/api/export/files/{name}``, ``/api/export/validation.csv``,
    ``/api/export/errors.{png,svg}``.
    """
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @router.get("/api/export")
    def export_list() -> Response:
        return json_response(workspace.export_list())

    @router.get("/api/export/files/{name}")
    def export_file(name: str) -> Response:
        try:
            return download(*workspace.export_file(name))
        except NoSuchExport as exc:
            raise HTTPException(404, str(exc)) from None

    @router.get("/api/export/validation.csv")
    def export_csv() -> Response:
        return download(*workspace.export_validation_csv())

    @router.get("/api/export/errors.{fmt}")
    def export_errors(fmt: str) -> Response:
        return download(*workspace.export_error_view(fmt))

    app.include_router(router)
