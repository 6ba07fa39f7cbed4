"""The Recalibrate page: a model of an earlier session brought to today's skin.

``GET /api/recalibrate`` (the models offered, the job, the last result), ``POST
/api/recalibrate/start`` (``RecalibrateBody``: the model, k, the strategy), ``POST
/api/recalibrate/models?filename=`` (a model file uploaded, the body is the file). The touches
go through the guided capture's own actions (``/api/capture/...``); the workspace's part is
``workspace.recalibration``.
"""

from __future__ import annotations

import asyncio
import os
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi import Query, Request
from fastapi.responses import Response

from skinloc.app.routes.bodies import RecalibrateBody
from skinloc.app.routes.common import (
    OK,
    PageContext,
    actions_router,
    json_response,
    received_upload,
)
from skinloc.errors import SkinlocError

#: The page's own files (its script), served at ``/pages/recalibrate/``.
STATIC = Path(str(resources.files("skinloc.app") / "static" / "recalibrate"))
#: The largest model file accepted, bytes.
MAX_MODEL_BYTES = 256 * 1024 * 1024
#: The tab's HTML (the 3D view with the target moves into its ``viewer-slot``).
SECTION = """
<div class="card" id="recal-card">
  <h2>Recalibrate</h2>
  <p class="hint">A model of an earlier session, brought to today's skin: a fresh baseline,
  then k touches where the old map most likely disagrees with the skin. The old model stays
  as it is; the recalibrated one is saved beside it.</p>
  <div class="row">
    <label>Model <select class="recal-model"></select></label>
    <label>Upload a model <input type="file" class="recal-upload" accept=".h5"></label>
    <label>Touches k <input type="number" class="recal-k" min="0" max="50" value="10"></label>
    <button class="recal-start">Start</button>
    <button class="recal-now">Capture now</button>
    <button class="recal-undo">Undo</button>
    <button class="recal-skip">Skip</button>
    <button class="recal-stop">Stop</button>
  </div>
  <div class="recal-guide hint"></div>
  <div class="recal-result"></div>
</div>
<div class="viewer-slot" data-for="recalibrate"></div>
"""


def add_routes(ctx: PageContext) -> None:
    """The Recalibrate page's routes (see the module)."""
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @app.get("/api/recalibrate")
    def status() -> Response:
        return json_response(workspace.recalibration_status())

    @router.post("/api/recalibrate/start")
    def start(body: RecalibrateBody) -> dict[str, Any]:
        session = body.session
        if session is None and body.file is None:  # the open session's own model
            session = workspace.active.folder.id if workspace.active is not None else None
            if session is None:
                raise ValueError("open a session first: the touches are recorded in it")
        workspace.start_recalibration(session, body.file, body.k, body.strategy)
        return OK

    @router.post("/api/recalibrate/models")
    async def upload(request: Request, filename: str = Query(..., max_length=255)) -> Any:
        from skinloc.app.workspace.recalibration import MODEL_NAME

        name = Path(filename.replace("\\", "/")).name
        if not MODEL_NAME.match(name):
            raise ValueError(f"upload a skinloc model file (.h5), not {name[:80]!r}")
        folder = workspace.model_dir
        async with received_upload(request, folder, ".h5", MAX_MODEL_BYTES, "model file") as (
            tmp,
            _,
        ):
            return await asyncio.to_thread(_install_model, tmp, folder / name)

    app.include_router(router)


def _install_model(tmp: Path, path: Path) -> dict[str, Any]:
    """Load the uploaded ``tmp``; only a model replaces ``path`` (atomically)."""
    from skinloc.models.localizer import ContactLocalizer

    try:
        model = ContactLocalizer.load(tmp)
    except (SkinlocError, ValueError, OSError) as exc:
        why = str(exc).replace(str(tmp), path.name)
        raise ValueError(f"{path.name} is not a skinloc model: {why}") from None
    os.replace(tmp, path)
    return {"name": path.name, "n_sensors": int(model.n_features_in_)}
