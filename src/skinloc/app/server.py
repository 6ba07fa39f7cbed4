"""The app's web server: JSON actions over HTTP, the live stream over a WebSocket, the page.

``create_app`` builds the FastAPI application around one ``Workspace``. Every action that
changes something names its tab in the ``X-Skinloc-Client`` header; a tab without control gets
409 and the message that the session is busy. Errors a person can fix come back as 400 with a
one-line ``detail``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Header, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field
from starlette.middleware.trustedhost import TrustedHostMiddleware

from skinloc.app.device import SourceSpec
from skinloc.app.hub import Hub, to_json
from skinloc.app.store import SessionBusyError
from skinloc.app.workspace import AppConfig, BusyError, Workspace
from skinloc.errors import SkinlocError

log = logging.getLogger(__name__)

__all__ = ["create_app"]

STATIC = Path(str(resources.files("skinloc.app") / "static"))
MAX_UPLOAD_BYTES = 64 * 1024 * 1024
#: Seconds of silence on a tab's WebSocket after which the server sends it a heartbeat.
HEARTBEAT_S = 0.25
ClientHeader = Header(default=None, alias="X-Skinloc-Client")


class ConnectBody(BaseModel):
    """``POST /api/connect``."""

    source: str = "sim"
    tx: int = Field(8, ge=1, le=21)
    rx: int = Field(8, ge=1, le=12)
    baud: int = Field(115200, ge=50, le=12_000_000)
    format: str = "auto"
    seed: int = 0
    rate_hz: float = Field(100.0, gt=0, le=2000)


class SessionBody(BaseModel):
    """``POST /api/sessions``."""

    name: str = Field("session", max_length=80)
    n_points: int = Field(80, ge=1, le=2000)
    mode: str = "even"
    samples: int = Field(50, ge=1, le=1000)
    baseline_frames: int = Field(50, ge=2, le=5000)
    seed: int = 0
    mesh_file: str | None = None
    targets_csv: str | None = Field(None, max_length=1_000_000)
    n_validation: int = Field(20, ge=1, le=500)


class TouchBody(BaseModel):
    """``POST /api/sim/touch``: a point in m, or none to lift."""

    point: list[float] | None = None


class IndexBody(BaseModel):
    """An index of a touch (0-based) and which recording it is in."""

    index: int
    recording: str = "calibration"


class FlagBody(BaseModel):
    """A switch."""

    on: bool


class ValidateBody(BaseModel):
    """``POST /api/validate/start``."""

    n_points: int | None = Field(None, ge=1, le=500)


def create_app(
    config: AppConfig | None = None,
    spec: SourceSpec | None = None,
    allowed_hosts: list[str] | None = None,
) -> FastAPI:
    """The app, with its workspace; connects to ``spec`` at once when given.

    Parameters
    ----------
    config : AppConfig, optional
        Data folder, default mesh, training options.
    spec : SourceSpec, optional
        Skin to open at start (errors propagate, so the command line can report them).
    allowed_hosts : list of str, optional
        Host headers accepted (a guard against DNS rebinding); loopback names by default.
    """
    config = config or AppConfig()
    hub = Hub()
    workspace = Workspace(config, hub)
    if spec is not None:
        workspace.connect(spec)

    @contextlib.asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        yield
        await asyncio.to_thread(workspace.shutdown)

    app = FastAPI(title="skinloc", lifespan=lifespan, docs_url=None, redoc_url=None)
    app.state.workspace = workspace
    hosts = allowed_hosts or ["127.0.0.1", "localhost", "[::1]", "testserver"]
    app.add_middleware(TrustedHostMiddleware, allowed_hosts=hosts)

    @app.exception_handler(BusyError)
    @app.exception_handler(SessionBusyError)
    async def busy(_: Request, exc: Exception) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=409)

    @app.exception_handler(SkinlocError)
    @app.exception_handler(ValueError)
    @app.exception_handler(OSError)
    async def bad(_: Request, exc: Exception) -> JSONResponse:
        return JSONResponse(
            {"detail": str(exc).splitlines()[0] if str(exc) else repr(exc)}, status_code=400
        )

    ok = {"ok": True}

    # ------------------------------------------------------------------ page and state
    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/api/state")
    def state() -> Response:
        return _json(workspace.snapshot())

    @app.get("/api/session")
    def session() -> Response:
        return _json(workspace.session_detail())

    @app.get("/api/session/mesh")
    def session_mesh() -> Response:
        return _json(workspace.session_mesh())

    @app.post("/api/lease")
    def take_over(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.take_over(client or "anonymous")
        return ok

    # ------------------------------------------------------------------ device
    @app.get("/api/ports")
    def ports() -> list[dict[str, Any]]:
        from skinloc.sources.serial import list_ports

        return [p.__dict__ for p in list_ports()]

    @app.post("/api/connect")
    def connect(body: ConnectBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.connect(SourceSpec(**body.model_dump()))
        return ok

    @app.post("/api/disconnect")
    def disconnect(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.disconnect()
        return ok

    @app.post("/api/rezero")
    def rezero(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.rezero()
        return ok

    @app.post("/api/sim/touch")
    def sim_touch(body: TouchBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.sim_touch(body.point)
        return ok

    # ------------------------------------------------------------------ sessions
    @app.get("/api/sessions")
    def sessions() -> Response:
        return _json(workspace.sessions())

    @app.post("/api/sessions")
    def create_session(body: SessionBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        return {"id": workspace.create_session(**body.model_dump())}

    @app.post("/api/sessions/{session_id}/open")
    def open_session(session_id: str, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.open_session(session_id)
        return ok

    @app.post("/api/session/close")
    def close_session(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.close_session()
        return ok

    @app.post("/api/recordings/import")
    def import_recording(
        path: str = Query(...), client: str | None = ClientHeader
    ) -> dict[str, Any]:
        workspace.require(client)
        return {"id": workspace.import_recording(path)}

    @app.post("/api/meshes")
    async def upload_mesh(
        request: Request, filename: str = Query(...), client: str | None = ClientHeader
    ) -> dict[str, Any]:
        await asyncio.to_thread(workspace.require, client)
        body = await request.body()
        if len(body) > MAX_UPLOAD_BYTES:
            raise ValueError(f"mesh file too large ({len(body)} bytes; at most 64 MB)")
        return await asyncio.to_thread(_save_mesh, workspace, filename, body)

    @app.get("/api/sessions/{session_id}/targets.{fmt}")
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

    # ------------------------------------------------------------------ guided capture
    @app.post("/api/calibrate/start")
    def calibrate(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.start_calibration()
        return ok

    @app.post("/api/validate/start")
    def validate(body: ValidateBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.start_validation(body.n_points)
        return ok

    @app.post("/api/capture/retake")
    def retake(body: IndexBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.retake(body.index, body.recording)
        return ok

    @app.post("/api/capture/{action}")
    def capture(action: str, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        actions = {
            "now": workspace.capture_now,
            "undo": workspace.undo,
            "skip": workspace.skip,
            "stop": workspace.stop,
        }
        if action not in actions:
            raise ValueError(f"unknown capture action {action!r}; one of {', '.join(actions)}")
        actions[action]()
        return ok

    @app.post("/api/finger")
    def finger(body: FlagBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.set_finger(body.on)
        return ok

    # ------------------------------------------------------------------ train and live
    @app.post("/api/train")
    def train(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.train()
        return ok

    @app.post("/api/live/start")
    def live(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        workspace.start_live()
        return ok

    # ------------------------------------------------------------------ the stream
    @app.websocket("/ws")
    async def stream(websocket: WebSocket, client: str = Query("anonymous")) -> None:
        origin = websocket.headers.get("origin")
        if origin and origin.split("://", 1)[-1].split(":")[0].strip("[]") not in {
            h.strip("[]") for h in hosts
        }:
            await websocket.close(code=1008)
            return
        await websocket.accept()
        key, tab = hub.attach(client)
        await websocket.send_text(to_json(await asyncio.to_thread(workspace.snapshot)))

        async def send() -> None:
            while True:
                try:
                    texts = await asyncio.wait_for(hub.drain(tab), HEARTBEAT_S)
                except TimeoutError:
                    # Nothing to send: a heartbeat, so the tab knows the app and the link live.
                    texts = [to_json(workspace.link_status())]
                for text in texts:
                    await websocket.send_text(text)

        async def receive() -> None:
            while True:
                await websocket.receive_text()  # only to notice the tab closing

        tasks = [asyncio.create_task(send()), asyncio.create_task(receive())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        except WebSocketDisconnect:
            pass
        finally:
            for t in tasks:
                t.cancel()
            for t in tasks:
                with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
                    await t
            hub.detach(key)
            await asyncio.to_thread(workspace.release, client)

    return app


def _json(obj: Any) -> Response:
    return Response(to_json(obj), media_type="application/json")


def _save_mesh(workspace: Workspace, filename: str, body: bytes) -> dict[str, Any]:
    from skinloc.geometry import load_mesh

    name = Path(filename).name
    if Path(name).suffix.lower() not in (".obj", ".stl", ".ply"):
        raise ValueError(f"upload an OBJ, STL or PLY mesh, not {name!r}")
    folder = workspace.mesh_dir
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_bytes(body)
    try:
        mesh = load_mesh(path)
    except SkinlocError:
        path.unlink(missing_ok=True)
        raise
    return {
        "name": name,
        "n_faces": len(mesh.faces),
        "extents_mm": [round(float(e) * 1e3, 1) for e in mesh.extents],
    }


def _sheet_input(workspace: Workspace, session_id: str):
    """Mesh, planned targets, which are done, and the name of a session."""
    import numpy as np

    from skinloc.dataset import read_recording
    from skinloc.geometry import mesh_from_arrays

    folder = workspace.store.get(session_id)
    vertices, faces, targets = folder.read_plan()
    done = np.zeros(len(targets), dtype=bool)
    if folder.calibration.is_file():
        rec = read_recording(folder.calibration)
        if rec.planned_targets is not None:
            targets = rec.planned_targets
            done = np.arange(len(targets)) < rec.n_point_logs
    return mesh_from_arrays(vertices, faces), targets, done, folder.read_info().get("name", "")
