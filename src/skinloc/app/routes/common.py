"""What the route modules share: what a page gets, the tab's header, taking control, answers."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, FastAPI, Header, HTTPException, Request
from fastapi.responses import Response
from starlette.datastructures import Headers
from starlette.types import Scope

from skinloc.app.hub import Hub, to_json
from skinloc.app.workspace import Workspace

__all__ = [
    "OK",
    "ClientHeader",
    "PageContext",
    "actions_router",
    "json_response",
    "received_upload",
    "take_control",
]

#: The tab an action comes from (its control of the skin is checked).
ClientHeader = Header(default=None, alias="X-Skinloc-Client")
#: The answer of an action that has nothing else to say.
OK: dict[str, Any] = {"ok": True}


def json_response(obj: Any) -> Response:
    """``obj`` as JSON, numpy arrays and non-finite floats included (``hub.to_json``)."""
    return Response(to_json(obj), media_type="application/json")


def take_control(request: Request, client: str | None = ClientHeader) -> None:
    """Before any action (every method but GET and HEAD), give its tab control of the skin.

    ``Workspace.require``: a ``BusyError`` (409) when another tab has it. Reads change nothing
    and need no control.
    """
    if request.method not in ("GET", "HEAD"):
        request.app.state.workspace.require(client)


def actions_router() -> APIRouter:
    """A router whose every action first takes control (``take_control``).

    A route added to it cannot forget to.
    """
    return APIRouter(dependencies=[Depends(take_control)])


@dataclass(frozen=True)
class PageContext:
    """What a page's ``add_routes`` receives.

    Attributes
    ----------
    app : FastAPI
        The application to add routes to.
    workspace : Workspace
        The app's shared state and actions (``skinloc.app.workspace``).
    hub : Hub
        Where messages to the tabs go.
    token : str
        The launch secret (the page's ``<meta name="skinloc-token">``).
    origins : callable
        ``(headers, scope) -> frozenset of str``: the app's own origins for a request.
    state : Any
        This page's own state (what its ``AppPage.state`` built), or None.
    pages : tuple of skinloc.app.pages.AppPage
        Every page of the app, in order (the index page shows the tabs of the added ones).
    """

    app: FastAPI
    workspace: Workspace
    hub: Hub
    token: str
    origins: Callable[[Headers, Scope], frozenset[str]]
    state: Any = None
    pages: tuple[Any, ...] = ()


@contextlib.asynccontextmanager
async def received_upload(
    request: Request, folder: Path, suffix: str, max_bytes: int, what: str
) -> AsyncIterator[tuple[Path, int]]:
    """The request's body streamed into a hidden file in ``folder``: ``(path, bytes)``.

    Counted as it comes: past ``max_bytes`` it stops with a 413 naming ``what`` ("mesh file"),
    so a stored file of the same name is replaced only by what the caller installs from the
    hidden one; the hidden file is removed on leaving.
    """
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".upload-", suffix=suffix, dir=folder)
    try:
        size = 0
        with os.fdopen(fd, "wb") as fh:
            async for chunk in request.stream():
                size += len(chunk)
                if size > max_bytes:
                    raise HTTPException(413, f"{what} too large (more than {max_bytes >> 20} MB)")
                fh.write(chunk)
        yield Path(tmp), size
    finally:
        Path(tmp).unlink(missing_ok=True)
