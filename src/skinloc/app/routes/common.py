"""What the route modules share: what a page gets, the tab's header, taking control, answers."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fastapi import APIRouter, Depends, FastAPI, Header, Request
from fastapi.responses import Response
from starlette.datastructures import Headers
from starlette.types import Scope

from skinloc.app.hub import Hub, to_json
from skinloc.app.workspace import Workspace

__all__ = ["OK", "ClientHeader", "PageContext", "actions_router", "json_response", "take_control"]

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
