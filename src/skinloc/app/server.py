"""The app's web server: JSON actions over HTTP, the live stream over a WebSocket, the page.

``create_app`` builds the FastAPI application around one ``Workspace``; the pages (their routes,
one module per concern in ``skinloc.app.routes``, and their state) come from the registry
``skinloc.app.pages``, and the guard that lets only the app's own page act is
``skinloc.app.guard``. Every action that changes something names its tab in the
``X-Skinloc-Client`` header; a tab without control gets 409 and the message that the session
is busy. Errors a person can fix come back as 400 with a one-line ``detail``.

Only the app's own page drives it (docs/app.md, Security): the page carries a per-launch secret
that every request other than GET/HEAD sends back in ``X-Skinloc-Token``, JSON actions take
JSON bodies only, and the WebSocket wants the app's own Origin and the secret. Host headers
other than the app's names are refused (DNS rebinding).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
from collections.abc import AsyncIterator, Iterable

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.datastructures import Headers
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.types import Scope

from skinloc.app.guard import RequestGuard, own_origins
from skinloc.app.hub import Hub
from skinloc.app.pages import mount_pages
from skinloc.app.store import SessionBusyError
from skinloc.app.workspace import AppConfig, BusyError, Workspace
from skinloc.errors import SkinlocError
from skinloc.sources.base import SourceOptions

log = logging.getLogger(__name__)

__all__ = ["create_app", "own_origins"]

#: Longest ``detail`` sent back, characters (no request is ever echoed at length).
MAX_DETAIL = 300


def create_app(
    config: AppConfig | None = None,
    source: SourceOptions | None = None,
    allowed_hosts: list[str] | None = None,
    token: str | None = None,
    origins: Iterable[str] | None = None,
) -> FastAPI:
    """The app, with its workspace; connects to ``source`` at once when given.

    Parameters
    ----------
    config : AppConfig, optional
        Data folder, default mesh, training options.
    source : SourceOptions, optional
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

    if source is not None:
        from skinloc.hardware.ports import check_source

        check_source(source.source)
    hub = Hub()
    workspace = Workspace(config, hub)
    if source is not None:
        workspace.connect(source)

    @contextlib.asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        yield
        await asyncio.to_thread(workspace.shutdown)

    app = FastAPI(title="skinloc", lifespan=lifespan, docs_url=None, redoc_url=None)
    app.state.workspace = workspace
    app.state.token = token
    hosts = allowed_hosts or ["127.0.0.1", "localhost", "[::1]", "testserver"]
    # The last added runs first: the Host check, then the token.
    app.add_middleware(RequestGuard, token=token, own_origins=accepted_origins)
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

    # Every page's state, routes and files: the registry (skinloc.app.pages).
    mount_pages(app, workspace, hub, token, accepted_origins)
    return app


def _one_line(exc: object) -> str:
    """The first line of a message, at most ``MAX_DETAIL`` characters."""
    text = str(exc).strip()
    line = text.splitlines()[0] if text else repr(exc)
    return line if len(line) <= MAX_DETAIL else line[: MAX_DETAIL - 3] + "..."
