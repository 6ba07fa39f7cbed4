"""The app's web server: JSON actions over HTTP, the live stream over a WebSocket, the page.

``create_app`` builds the FastAPI application around one ``Workspace``. Every action that
changes something names its tab in the ``X-Skinloc-Client`` header; a tab without control gets
409 and the message that the session is busy. Errors a person can fix come back as 400 with a
one-line ``detail``.

Only the app's own page drives it (docs/app.md, Security): the page carries a per-launch secret
that every request other than GET/HEAD sends back in ``X-Skinloc-Token`` (a header another
site's page cannot set without a CORS preflight, which is never granted), JSON actions take
JSON bodies only, and the WebSocket wants the app's own Origin and the secret. Host headers
other than the app's names are refused (DNS rebinding).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import html
import logging
import os
import re
import secrets
import tempfile
from collections.abc import AsyncIterator, Callable, Iterable
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import FastAPI, Header, HTTPException, Query, Request, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.responses import HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field
from starlette.datastructures import Headers
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from skinloc.app.device import SourceSpec
from skinloc.app.hub import Hub, to_json
from skinloc.app.store import SessionBusyError
from skinloc.app.workspace import AppConfig, BusyError, Workspace
from skinloc.errors import SkinlocError

log = logging.getLogger(__name__)

__all__ = ["create_app"]

STATIC = Path(str(resources.files("skinloc.app") / "static"))
MAX_UPLOAD_BYTES = 64 * 1024 * 1024
MESH_SUFFIXES = (".obj", ".stl", ".ply")
TOKEN_HEADER = "X-Skinloc-Token"
#: Requests that change nothing; every other method needs the token.
SAFE_METHODS = frozenset({"GET", "HEAD"})
#: Endpoints whose body is a file, not JSON.
RAW_BODY_PATHS = frozenset({"/api/meshes"})
#: Longest ``detail`` sent back, characters (no request is ever echoed at length).
MAX_DETAIL = 300
#: Seconds of silence on a tab's WebSocket after which the server sends it a heartbeat.
HEARTBEAT_S = 0.25
ClientHeader = Header(default=None, alias="X-Skinloc-Client")


class ConnectBody(BaseModel):
    """``POST /api/connect``."""

    source: str = "sim"
    tx: int = Field(8, ge=1, le=21)
    rx: int = Field(8, ge=1, le=12)
    baud: int = Field(115200, ge=50, le=12_000_000)
    format: Literal["auto", "text", "binary"] = "auto"
    seed: int = Field(0, ge=0, le=2**32 - 1)
    rate_hz: float = Field(100.0, gt=0, le=2000)


class SessionBody(BaseModel):
    """``POST /api/sessions``."""

    name: str = Field("session", max_length=80)
    n_points: int = Field(80, ge=1, le=2000)
    mode: str = "even"
    samples: int = Field(50, ge=1, le=1000)
    baseline_frames: int = Field(50, ge=2, le=5000)
    seed: int = Field(0, ge=0, le=2**32 - 1)
    mesh_file: str | None = None
    targets_csv: str | None = Field(None, max_length=1_000_000)
    n_validation: int = Field(20, ge=1, le=500)


#: A coordinate of a touch, m: any skin fits in +-10 m, and larger numbers are a mistake.
Coordinate = Annotated[float, Field(ge=-10.0, le=10.0)]


class TouchBody(BaseModel):
    """``POST /api/sim/touch``: a point in m, or none to lift."""

    point: list[Coordinate] | None = Field(None, min_length=3, max_length=3)


class IndexBody(BaseModel):
    """An index of a touch (0-based) and which recording it is in."""

    index: int = Field(ge=0)
    recording: Literal["calibration", "validation"] = "calibration"


class FlagBody(BaseModel):
    """A switch."""

    on: bool


class ValidateBody(BaseModel):
    """``POST /api/validate/start``."""

    n_points: int | None = Field(None, ge=1, le=500)


class _Guard:
    """Refuse requests not sent by the app's own page (pure ASGI, so streams stay streams).

    Every HTTP method but GET/HEAD needs the launch token in ``X-Skinloc-Token`` and, when it
    says where it comes from, the app's own Origin; bodies other than uploads must be JSON.
    Refusals are 403 (415 for a foreign body type) with a one-line ``detail``.
    """

    def __init__(
        self, app: ASGIApp, token: str, own_origins: Callable[[Headers, Scope], frozenset[str]]
    ) -> None:
        self.app = app
        self.token = token.encode()
        self.own_origins = own_origins

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if scope["method"] not in SAFE_METHODS:
            problem = self.refusal(scope)
            if problem is not None:
                status, detail = problem
                await JSONResponse({"detail": detail}, status_code=status)(scope, receive, send)
                return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                # No sniffing a JSON answer into a script or a page.
                message.setdefault("headers", []).append((b"x-content-type-options", b"nosniff"))
            await send(message)

        await self.app(scope, receive, send_with_headers)

    def refusal(self, scope: Scope) -> tuple[int, str] | None:
        """Status and message when a state-changing request is refused, else None."""
        headers = Headers(scope=scope)
        origin = headers.get("origin")
        if origin is not None and origin not in self.own_origins(headers, scope):
            return 403, f"refused: a request from another site ({origin[:80]})"
        sent = headers.get(TOKEN_HEADER, "").encode("utf-8", "replace")
        if not sent or not hmac.compare_digest(sent, self.token):
            return 403, (
                f"refused: {'wrong' if sent else 'no'} {TOKEN_HEADER}; actions come from the "
                "app's own page (reload it if the app was restarted)"
            )
        body = headers.get("content-length", "0") != "0" or "transfer-encoding" in headers
        if body and scope["path"] not in RAW_BODY_PATHS:
            kind = headers.get("content-type", "").split(";")[0].strip().lower()
            if kind != "application/json":
                return 415, f"send JSON (Content-Type: application/json), not {kind[:60]!r}"
        return None


def own_origins(host: str, port: int) -> list[str]:
    """The origins a page served on ``host:port`` has (the names that reach that address).

    Parameters
    ----------
    host : str
        Address served on, as given to ``skinloc app --host``.
    port : int
        TCP port served on.
    """
    shown = f"[{host.strip('[]')}]" if ":" in host else host
    names = {shown}
    if host in ("127.0.0.1", "localhost", "0.0.0.0", "::", "[::]"):
        names |= {"127.0.0.1", "localhost"}
    if host in ("::1", "[::1]", "localhost", "::", "[::]"):
        names |= {"[::1]", "localhost"}
    return sorted(f"http://{name}:{port}" for name in names)


def create_app(
    config: AppConfig | None = None,
    spec: SourceSpec | None = None,
    allowed_hosts: list[str] | None = None,
    token: str | None = None,
    origins: Iterable[str] | None = None,
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
    token : str, optional
        The secret the page sends back with every action; a fresh random one by default
        (``app.state.token``).
    origins : iterable of str, optional
        The app's own origins (``http://127.0.0.1:8765``; ``own_origins`` lists them); by
        default the origin of the (checked) Host header the request came to.
    """
    config = config or AppConfig()
    token = token or secrets.token_urlsafe(32)
    fixed_origins = frozenset(origins) if origins is not None else None

    def accepted_origins(headers: Headers, scope: Scope) -> frozenset[str]:
        if fixed_origins is not None:
            return fixed_origins
        scheme = "https" if scope.get("scheme") in ("https", "wss") else "http"
        return frozenset({f"{scheme}://{headers.get('host', '')}"})

    if spec is not None:
        spec.check()
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
    app.state.token = token
    hosts = allowed_hosts or ["127.0.0.1", "localhost", "[::1]", "testserver"]
    # The last added runs first: the Host check, then the token.
    app.add_middleware(_Guard, token=token, own_origins=accepted_origins)
    app.add_middleware(TrustedHostMiddleware, allowed_hosts=hosts)

    @app.exception_handler(BusyError)
    @app.exception_handler(SessionBusyError)
    async def busy(_: Request, exc: Exception) -> JSONResponse:
        return JSONResponse({"detail": _one_line(exc)}, status_code=409)

    @app.exception_handler(SkinlocError)
    @app.exception_handler(ValueError)
    @app.exception_handler(OSError)
    async def bad(_: Request, exc: Exception) -> JSONResponse:
        return JSONResponse({"detail": _one_line(exc)}, status_code=400)

    @app.exception_handler(RequestValidationError)
    async def invalid(_: Request, exc: RequestValidationError) -> JSONResponse:
        # FastAPI's own answer echoes the whole input; name the fields and the rule only.
        parts = []
        for err in exc.errors()[:5]:
            if err.get("type") == "json_invalid":
                parts.append("the body is not valid JSON")
                continue
            where = ".".join(str(x) for x in err.get("loc", ()) if x not in ("body", "query"))
            parts.append(f"{where or 'body'}: {err.get('msg', 'invalid')}")
        return JSONResponse({"detail": _one_line("; ".join(parts))}, status_code=422)

    ok = {"ok": True}

    # ------------------------------------------------------------------ page and state
    @app.get("/", include_in_schema=False)
    def index() -> HTMLResponse:
        page = (STATIC / "index.html").read_text(encoding="utf-8")
        meta = f'<meta name="skinloc-token" content="{html.escape(token)}">'
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
        return _json(workspace.snapshot())

    @app.get("/api/session")
    def session() -> Response:
        return _json(workspace.session_detail())

    @app.get("/api/session/coverage")
    def session_coverage() -> Response:
        return _json(workspace.coverage())

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
        from skinloc.hardware.serial import list_ports

        return [p.__dict__ for p in list_ports()]

    @app.post("/api/connect")
    def connect(body: ConnectBody, client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.require(client)
        spec = SourceSpec(**body.model_dump())
        spec.check()  # before the skin in use is closed
        workspace.connect(spec)
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

    @app.get("/api/meshes")
    def meshes() -> list[dict[str, Any]]:
        return _list_meshes(workspace.mesh_dir)

    @app.post("/api/meshes")
    async def upload_mesh(
        request: Request,
        filename: str = Query(..., max_length=255),
        client: str | None = ClientHeader,
    ) -> dict[str, Any]:
        await asyncio.to_thread(workspace.require, client)
        name = _mesh_name(filename)
        declared = request.headers.get("content-length", "")
        if declared.isdigit() and int(declared) > MAX_UPLOAD_BYTES:
            raise HTTPException(413, f"mesh file too large ({int(declared)} bytes; at most 64 MB)")
        folder = workspace.mesh_dir
        folder.mkdir(parents=True, exist_ok=True)
        # Into a hidden file beside the meshes, counted as it comes: a file over the limit
        # stops there, and a stored mesh of that name is replaced only by one that loads.
        fd, tmp = tempfile.mkstemp(prefix=".upload-", suffix=Path(name).suffix, dir=folder)
        try:
            size = 0
            with os.fdopen(fd, "wb") as fh:
                async for chunk in request.stream():
                    size += len(chunk)
                    if size > MAX_UPLOAD_BYTES:
                        raise HTTPException(413, "mesh file too large (more than 64 MB)")
                    fh.write(chunk)
            if size == 0:
                raise ValueError(f"{name} is empty: upload an OBJ, STL or PLY mesh")
            return await asyncio.to_thread(_install_mesh, Path(tmp), folder / name)
        finally:
            Path(tmp).unlink(missing_ok=True)

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
    async def stream(
        websocket: WebSocket, client: str = Query("anonymous", max_length=100)
    ) -> None:
        # A browser always sends Origin with a WebSocket: no Origin, or another one, is not
        # the app's page. Closing before accepting answers the handshake with 403.
        origin = websocket.headers.get("origin")
        sent = websocket.query_params.get("token", "").encode("utf-8", "replace")
        if (
            origin is None
            or origin not in accepted_origins(websocket.headers, websocket.scope)
            or not hmac.compare_digest(sent, token.encode())
        ):
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


def _one_line(exc: object) -> str:
    """The first line of a message, at most ``MAX_DETAIL`` characters."""
    text = str(exc).strip()
    line = text.splitlines()[0] if text else repr(exc)
    return line if len(line) <= MAX_DETAIL else line[: MAX_DETAIL - 3] + "..."


def _mesh_name(filename: str) -> str:
    """The stored name of an uploaded mesh (no folders, a mesh suffix, not hidden)."""
    name = Path(filename.replace("\\", "/")).name
    if Path(name).suffix.lower() not in MESH_SUFFIXES or name.startswith("."):
        raise ValueError(f"upload an OBJ, STL or PLY mesh, not {name[:80]!r}")
    return name


def _list_meshes(folder: Path) -> list[dict[str, Any]]:
    """The uploaded meshes, by name."""
    if not folder.is_dir():
        return []
    return [
        {"name": p.name, "bytes": p.stat().st_size}
        for p in sorted(folder.iterdir())
        if p.suffix.lower() in MESH_SUFFIXES and not p.name.startswith(".") and p.is_file()
    ]


def _install_mesh(tmp: Path, path: Path) -> dict[str, Any]:
    """Load the uploaded ``tmp``; only if it is a mesh does it replace ``path`` (atomically)."""
    from skinloc.geometry.mesh import load_mesh

    try:
        mesh = load_mesh(tmp)
    except (SkinlocError, ValueError) as exc:
        # Name the file as the person did, not the hidden file it was received into.
        raise ValueError(str(exc).replace(str(tmp), path.name)) from None
    os.replace(tmp, path)
    return {
        "name": path.name,
        "n_faces": len(mesh.faces),
        "extents_mm": [round(float(e) * 1e3, 1) for e in mesh.extents],
    }


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
