"""The WebSocket: state, heat maps, sensor reports, live contacts and gestures, heartbeats.

It wants the app's own Origin and the launch token; a tab without them is refused before the
handshake completes (403).
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac

from fastapi import Query, WebSocket, WebSocketDisconnect

from skinloc.app.hub import to_json
from skinloc.app.routes.common import PageContext

#: Seconds of silence on a tab's WebSocket after which the server sends it a heartbeat.
HEARTBEAT_S = 0.25


def add_routes(ctx: PageContext) -> None:
    """``/ws?client=TAB&token=TOKEN``."""
    app, workspace, hub, token = ctx.app, ctx.workspace, ctx.hub, ctx.token
    accepted_origins = ctx.origins

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
