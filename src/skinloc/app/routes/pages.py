"""The page itself, its static files, and what it reads of the state."""

from __future__ import annotations

import html
import re
from importlib import resources
from pathlib import Path
from typing import Any

from fastapi.responses import HTMLResponse, Response
from fastapi.staticfiles import StaticFiles

from skinloc.app.routes.common import OK, ClientHeader, PageContext, json_response
from skinloc.live.contact import TRACK_COLOURS

STATIC = Path(str(resources.files("skinloc.app") / "static"))


def add_routes(ctx: PageContext) -> None:
    """``/``, ``/static``, ``GET /api/state``, ``/api/session[/coverage|/mesh]``, the lease.

    The page served at ``/`` is ``static/index.html`` with the tabs of the pages registered
    beside the built-in ones (``skinloc.app.pages``: a nav button, a section, its scripts).

    ``GET /api/accuracy/reference``: the real skin's error against calibration touches with
    and without the map prior and the paper's network, and the probing floor (the reference
    the Train page draws the session's own ``prior_curve`` against).
    """
    app, workspace, token = ctx.app, ctx.workspace, ctx.token
    added = added_tabs(ctx.pages)

    @app.get("/", include_in_schema=False)
    def index() -> HTMLResponse:
        page = (STATIC / "index.html").read_text(encoding="utf-8")
        meta = f'<meta name="skinloc-token" content="{html.escape(token)}">'
        # the one palette of fingers, shared with the ROS 2 and Foxglove sinks
        meta += f'<meta name="skinloc-track-colours" content="{" ".join(TRACK_COLOURS)}">'
        page = re.sub(r"(<head[^>]*>)", lambda m: m.group(1) + meta, page, count=1)
        for end, extra in zip(("</nav>", "</main>", "</body>"), added, strict=True):
            if extra:
                page = page.replace(end, extra + end, 1)
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
        return json_response(workspace.snapshot())

    @app.get("/api/session")
    def session() -> Response:
        return json_response(workspace.session_detail())

    @app.get("/api/session/coverage")
    def session_coverage() -> Response:
        return json_response(workspace.coverage())

    @app.get("/api/session/mesh")
    def session_mesh() -> Response:
        return json_response(workspace.session_mesh())

    @app.get("/api/accuracy/reference")
    def accuracy_reference() -> Response:
        from skinloc.experiments.demo import reference_curves

        return json_response(reference_curves())

    # The one action that does not first take control (``actions_router``): it takes it over.
    @app.post("/api/lease")
    def take_over(client: str | None = ClientHeader) -> dict[str, Any]:
        workspace.take_over(client or "anonymous")
        return OK


def added_tabs(pages: tuple[Any, ...]) -> tuple[str, str, str]:
    """The HTML the served page gets for the added pages with a tab (``AppPage.title``).

    Returns
    -------
    tuple of str
        Their nav buttons, their ``<section class="page">`` and their script tags (the
        page's own ``app.js`` shows a section when its nav button is clicked).
    """
    nav, sections, scripts = [], [], []
    for page in pages:
        if page.title is None:
            continue
        nav.append(f'<button data-page="{page.name}">{html.escape(page.title)}</button>')
        sections.append(f'<section id="page-{page.name}" class="page">{page.section}</section>')
        scripts += [
            f'<script type="module" src="/pages/{page.name}/{html.escape(name)}"></script>'
            for name in page.scripts
        ]
    return "".join(nav), "".join(sections), "".join(scripts)
