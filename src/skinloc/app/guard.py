"""The guard in front of the app: only its own page may change anything (docs/app.md, Security).

The page carries a per-launch secret that every request other than GET/HEAD sends back in
``X-Skinloc-Token`` (a header another site's page cannot set without a CORS preflight, which
is never granted); JSON actions take JSON bodies only.
"""

from __future__ import annotations

import hmac
from collections.abc import Callable

from fastapi.responses import JSONResponse
from starlette.datastructures import Headers
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["TOKEN_HEADER", "RequestGuard", "own_origins"]

TOKEN_HEADER = "X-Skinloc-Token"
#: Requests that change nothing; every other method needs the token.
SAFE_METHODS = frozenset({"GET", "HEAD"})
#: Endpoints whose body is a file, not JSON.
RAW_BODY_PATHS = frozenset({"/api/meshes", "/api/recalibrate/models"})


class RequestGuard:
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
        """Pass the request on, or answer it with the refusal."""
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
