"""What the route modules share: the tab's header, the plain answers."""

from __future__ import annotations

from typing import Any

from fastapi import Header
from fastapi.responses import Response

from skinloc.app.hub import to_json

__all__ = ["OK", "ClientHeader", "json_response"]

#: The tab an action comes from (its control of the skin is checked).
ClientHeader = Header(default=None, alias="X-Skinloc-Client")
#: The answer of an action that has nothing else to say.
OK: dict[str, Any] = {"ok": True}


def json_response(obj: Any) -> Response:
    """``obj`` as JSON, numpy arrays and non-finite floats included (``hub.to_json``)."""
    return Response(to_json(obj), media_type="application/json")
