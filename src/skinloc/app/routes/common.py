"""What the route modules share: the tab's header, taking control, the plain answers."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, Header, Request
from fastapi.responses import Response

from skinloc.app.hub import to_json

__all__ = ["OK", "ClientHeader", "actions_router", "json_response", "take_control"]

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
