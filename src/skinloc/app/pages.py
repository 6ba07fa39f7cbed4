"""The app's pages, one registry: each page declares its routes, its files and its state.

A page (or a concern of one, such as the live stream) is one ``AppPage``: the function that adds
its routes, the state it keeps (built once per app from the workspace, handed to its routes), and,
for a page that is not part of ``static/index.html``, its tab (``title`` and ``section``) and its
own static files and scripts. The built-in pages are the table of ``builtin_pages``; another module
(a plug-in, a test) adds one with ``register_page`` or the ``app_page`` decorator, and an installed
package by an entry point in the ``skinloc.app_pages`` group (``toy = "package.module:PAGE"``, an
``AppPage`` named ``toy``), read when an app is first made, as sinks' ``skinloc.sinks``.
``skinloc.app.server.create_app`` only reads the registry (``mount_pages``).

Whatever a page adds sits behind the app's guard (``skinloc.app.guard``): every request other than
GET/HEAD needs the launch token, and an action on an ``actions_router`` (``routes.common``) first
takes control of the skin for its tab.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.datastructures import Headers
from starlette.types import Scope

from skinloc.app.hub import Hub
from skinloc.app.routes import (
    capture,
    device,
    export,
    meshes,
    pages,
    recalibrate,
    record,
    sessions,
    settings,
    stream,
    traces,
)
from skinloc.app.routes.common import PageContext
from skinloc.app.workspace import Workspace

log = logging.getLogger(__name__)

__all__ = [
    "ENTRY_POINT_GROUP",
    "AppPage",
    "PageContext",
    "app_page",
    "app_pages",
    "builtin_pages",
    "mount_pages",
    "register_page",
    "unregister_page",
]

#: A page's name: it names its routes' state, its static folder and its ``<section>`` id.
_NAME = re.compile(r"^[a-z][a-z0-9-]{0,31}$")


@dataclass(frozen=True)
class AppPage:
    """One page of the app: its routes, the state it keeps, its tab and files.

    Attributes
    ----------
    name : str
        Lower-case name (letters, digits, ``-``): the key of its state
        (``Workspace.page_state``), its ``<section id="page-NAME">`` and its static folder's
        address, ``/pages/NAME/``.
    add_routes : callable
        ``add_routes(ctx: PageContext) -> None``: adds the page's routes to ``ctx.app``.
        Actions go on a ``routes.common.actions_router()`` (control first, then the action).
    state : callable or None
        ``state(workspace) -> object``: the page's own state, built once when the app is made,
        kept by the workspace (``Workspace.page_state(name)``) and given to ``add_routes`` as
        ``ctx.state``. Its class says what the page keeps; what it may touch of the rest is
        ``Workspace``'s declared state and actions (``workspace.state.WorkspaceState``).
    title : str or None
        The tab's label in the page's navigation bar; None for the built-in pages (their tabs
        are in ``static/index.html``) and for routes without a tab.
    section : str
        The tab's HTML, put in ``<section id="page-NAME" class="page">`` of the served page.
    static : Path or None
        A folder served at ``/pages/NAME/``.
    scripts : tuple of str
        Files of ``static`` the served page loads as ES modules, in order.
    """

    name: str
    add_routes: Callable[[PageContext], None]
    state: Callable[[Workspace], Any] | None = None
    title: str | None = None
    section: str = ""
    static: Path | None = None
    scripts: tuple[str, ...] = field(default=())

    def __post_init__(self) -> None:
        if not _NAME.match(self.name):
            raise ValueError(
                f"page name must be lower-case letters, digits or '-' (at most 32), "
                f"got {self.name!r}"
            )
        if self.scripts and self.static is None:
            raise ValueError(f"page {self.name!r}: scripts need a static folder")
        if self.static is not None and not Path(self.static).is_dir():
            raise ValueError(f"page {self.name!r}: static folder {self.static} does not exist")
        for script in self.scripts:
            if "/" in script or "\\" in script or script.startswith("."):
                raise ValueError(f"page {self.name!r}: script {script!r} must be a file name")


def builtin_pages() -> tuple[AppPage, ...]:
    """The app's own pages, in the order their routes are added: one entry each."""
    return (
        AppPage("main", pages.add_routes),  # `/`, `/static`, the state and the session
        AppPage("connect", device.add_routes),
        AppPage("sessions", sessions.add_routes),
        AppPage("meshes", meshes.add_routes),
        AppPage("calibrate", capture.add_routes),
        AppPage("export", export.add_routes),
        AppPage("record", record.add_routes),
        AppPage("traces", traces.add_routes),
        AppPage("settings", settings.add_routes),
        AppPage("stream", stream.add_routes),  # `/ws`
        # a tab of its own, not in index.html: its section and script are its own
        AppPage(
            "recalibrate",
            recalibrate.add_routes,
            title="Recalibrate",
            section=recalibrate.SECTION,
            static=recalibrate.STATIC,
            scripts=("recalibrate.js",),
        ),
    )


#: Pages added by other modules (``register_page``) and installed packages' entry points, after
#: the built-in ones.
_ADDED: dict[str, AppPage] = {}

#: The entry-point group in which an installed package declares its app pages.
ENTRY_POINT_GROUP = "skinloc.app_pages"
_entry_points_loaded = False


def _load_entry_points() -> None:
    """Register the pages installed packages declare under ``skinloc.app_pages`` (once).

    An entry point ``toy = "package.module:PAGE"`` names an ``AppPage`` whose name is ``toy``.
    One that does not load, is not such a page, or whose name is taken is logged and left out:
    the app starts without it.
    """
    global _entry_points_loaded
    if _entry_points_loaded:
        return
    _entry_points_loaded = True
    from importlib.metadata import entry_points

    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            page = ep.load()
            if not isinstance(page, AppPage) or page.name != ep.name:
                raise ValueError(f"it is not an AppPage named {ep.name!r}")
            register_page(page)
        except Exception as exc:  # noqa: BLE001 - a broken plug-in must not stop the app
            log.warning("app page %r of entry point %s left out: %s", ep.name, ep.value, exc)


def register_page(page: AppPage) -> AppPage:
    """Add ``page`` to the apps made from now on (``create_app``); returns it.

    A name already taken (a built-in page's or an added one's) is a ValueError.
    """
    if page.name in _ADDED or any(p.name == page.name for p in builtin_pages()):
        raise ValueError(f"an app page named {page.name!r} is registered already")
    _ADDED[page.name] = page
    return page


def unregister_page(name: str) -> None:
    """Remove an added page (apps made before keep it); a built-in or unknown name: ValueError."""
    if name not in _ADDED:
        raise ValueError(f"no added app page named {name!r}")
    del _ADDED[name]


def app_page(
    name: str,
    *,
    state: Callable[[Workspace], Any] | None = None,
    title: str | None = None,
    section: str = "",
    static: Path | None = None,
    scripts: Iterable[str] = (),
) -> Callable[[Callable[[PageContext], None]], Callable[[PageContext], None]]:
    """Register the decorated ``add_routes(ctx)`` as the page ``name`` (see ``AppPage``)."""

    def register(add_routes: Callable[[PageContext], None]) -> Callable[[PageContext], None]:
        register_page(AppPage(name, add_routes, state, title, section, static, tuple(scripts)))
        return add_routes

    return register


def app_pages() -> tuple[AppPage, ...]:
    """Every page of an app made now: the built-in ones, then the added ones."""
    _load_entry_points()
    return builtin_pages() + tuple(_ADDED.values())


def mount_pages(
    app: FastAPI,
    workspace: Workspace,
    hub: Hub,
    token: str,
    origins: Callable[[Headers, Scope], frozenset[str]],
) -> tuple[AppPage, ...]:
    """Give ``app`` every page of the registry (``app_pages``): state, routes, static files.

    Each page's state is built once (``AppPage.state(workspace)``) and kept by the workspace
    (``Workspace.page_state``); its ``add_routes`` then gets it as ``ctx.state``. Returns the
    pages, in the order they were added.
    """
    pages = app_pages()
    for page in pages:
        state = None if page.state is None else page.state(workspace)
        workspace.add_page_state(page.name, state)
        page.add_routes(PageContext(app, workspace, hub, token, origins, state, pages))
        if page.static is not None:
            files = StaticFiles(directory=page.static)
            app.mount(f"/pages/{page.name}", files, name=f"page-{page.name}")
    return pages
