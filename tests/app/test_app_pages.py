"""An app page is one registry entry (issue 31.1): a toy page added from this module alone.

The toy page declares its routes, its state (a counter) and its tab and files in one
``AppPage``; the app serves them, and its state-changing route is refused without the app's
token like every other action (only the app's own page may change its state).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

with warnings.catch_warnings():  # starlette's note that it prefers httpx2 to httpx
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient  # noqa: E402

from pydantic import BaseModel, Field  # noqa: E402

from skinloc.app.pages import (  # noqa: E402
    AppPage,
    PageContext,
    app_page,
    app_pages,
    builtin_pages,
    register_page,
    unregister_page,
)
from skinloc.app.routes.common import actions_router  # noqa: E402
from skinloc.app.server import create_app  # noqa: E402
from skinloc.app.workspace import AppConfig, Workspace  # noqa: E402

A = {"X-Skinloc-Client": "tab-a"}
B = {"X-Skinloc-Client": "tab-b"}


@dataclass
class Counter:
    """The toy page's own state."""

    count: int = 0
    default_mesh_faces: int = 0


class AddBody(BaseModel):
    n: int = Field(1, ge=1, le=10)


def counter_state(workspace: Workspace) -> Counter:
    # A page's state may read the workspace's declared state.
    return Counter(default_mesh_faces=len(workspace.default_mesh.faces))


def toy_routes(ctx: PageContext) -> None:
    counter: Counter = ctx.state
    router = actions_router()

    @router.get("/api/toy")
    def read() -> dict[str, int]:
        return {"count": counter.count, "faces": counter.default_mesh_faces}

    @router.post("/api/toy/add")
    def add(body: AddBody) -> dict[str, int]:
        counter.count += body.n
        return {"count": counter.count}

    ctx.app.include_router(router)


@pytest.fixture
def toy_page(tmp_path):
    static = tmp_path / "toy-static"
    static.mkdir()
    (static / "toy.js").write_text('document.title += " toy";\n', encoding="utf-8")
    page = register_page(
        AppPage(
            "toy",
            toy_routes,
            state=counter_state,
            title="Toy <1>",
            section='<div class="card" id="toy-card">the toy page</div>',
            static=static,
            scripts=("toy.js",),
        )
    )
    yield page
    unregister_page("toy")


@pytest.fixture
def app(toy_page, tmp_path):
    return create_app(AppConfig(data_dir=tmp_path / "data"))


def test_a_registered_page_is_served_with_its_tab_state_and_files(app):
    with TestClient(app) as client:
        index = client.get("/").text
        assert '<button data-page="toy">Toy &lt;1&gt;</button></nav>' in index
        assert '<section id="page-toy" class="page"><div class="card" id="toy-card">' in index
        assert '<script type="module" src="/pages/toy/toy.js"></script></body>' in index
        script = client.get("/pages/toy/toy.js")
        assert script.status_code == 200 and "toy" in script.text
        assert client.get("/pages/toy/missing.js").status_code == 404
        r = client.get("/api/toy")
        assert r.status_code == 200
        assert r.json() == {"count": 0, "faces": len(app.state.workspace.default_mesh.faces)}
    # the built-in pages still come first, in their order
    assert [p.name for p in app_pages()] == [p.name for p in builtin_pages()] + ["toy"]


def test_a_registered_page_changes_state_only_from_the_apps_own_page(app):
    token = app.state.token
    counter = app.state.workspace.page_state("toy")
    with TestClient(app) as client:
        no_token = client.post("/api/toy/add", json={"n": 2}, headers=A)
        assert no_token.status_code == 403 and "X-Skinloc-Token" in no_token.json()["detail"]
        wrong = client.post("/api/toy/add", json={"n": 2}, headers={**A, "X-Skinloc-Token": "x"})
        assert wrong.status_code == 403
        foreign = client.post(
            "/api/toy/add",
            json={"n": 2},
            headers={**A, "X-Skinloc-Token": token, "Origin": "http://evil.example"},
        )
        assert foreign.status_code == 403
        form = client.post(
            "/api/toy/add",
            content=b"n=2",
            headers={**A, "X-Skinloc-Token": token, "Content-Type": "text/plain"},
        )
        assert form.status_code == 415
        assert counter.count == 0  # nothing refused reached the page
        ok = client.post("/api/toy/add", json={"n": 2}, headers={**A, "X-Skinloc-Token": token})
        assert ok.status_code == 200 and ok.json() == {"count": 2}
        # an action of the page takes control of the skin like every other one: while tab a
        # is open (its stream), tab b is told the skin is busy
        url = f"/ws?client=tab-a&token={token}"
        with client.websocket_connect(url, headers={"origin": "http://testserver"}) as ws_a:
            assert ws_a.receive_json()["type"] == "state"
            busy = client.post(
                "/api/toy/add", json={"n": 1}, headers={**B, "X-Skinloc-Token": token}
            )
            assert busy.status_code == 409 and "busy" in busy.json()["detail"]
        bad = client.post("/api/toy/add", json={"n": 99}, headers={**A, "X-Skinloc-Token": token})
        assert bad.status_code == 422
    assert counter.count == 2 and app.state.workspace.page_state("toy") is counter


def test_an_app_made_without_the_page_has_none_of_it(tmp_path):
    app = create_app(AppConfig(data_dir=tmp_path))
    with TestClient(app) as client:
        assert client.get("/api/toy").status_code == 404
        assert 'data-page="toy"' not in client.get("/").text
    with pytest.raises(ValueError, match="no app page named 'toy'"):
        app.state.workspace.page_state("toy")


def test_the_decorator_registers_and_names_are_checked(tmp_path):
    @app_page("toy-two")
    def routes(ctx: PageContext) -> None:
        @ctx.app.get("/api/toy-two")
        def read() -> dict[str, bool]:
            return {"stateless": ctx.state is None}

    try:
        with TestClient(create_app(AppConfig(data_dir=tmp_path))) as client:
            assert client.get("/api/toy-two").json() == {"stateless": True}
        with pytest.raises(ValueError, match="registered already"):
            register_page(AppPage("toy-two", routes))
    finally:
        unregister_page("toy-two")
    with pytest.raises(ValueError, match="registered already"):
        register_page(AppPage("stream", routes))  # a built-in page's name
    with pytest.raises(ValueError, match="page name"):
        AppPage("Toy Page", routes)
    with pytest.raises(ValueError, match="static folder"):
        AppPage("toy", routes, static=tmp_path / "nowhere")
    with pytest.raises(ValueError, match="need a static folder"):
        AppPage("toy", routes, scripts=("a.js",))
    with pytest.raises(ValueError, match="file name"):
        AppPage("toy", routes, static=tmp_path, scripts=("../a.js",))
    with pytest.raises(ValueError, match="no added app page"):
        unregister_page("stream")


PLUGIN = """
from skinloc.app.pages import AppPage
from skinloc.app.routes.common import actions_router


def routes(ctx):
    router = actions_router()

    @router.post("/api/plugged/ping")
    def ping() -> dict:
        return {"pong": True}

    ctx.app.include_router(router)


PAGE = AppPage("plugged", routes, title="Plugged")
STREAM = AppPage("stream", routes)  # a built-in page's name
"""


def test_an_installed_package_adds_a_page_by_entry_point(tmp_path, monkeypatch, caplog):
    """A package on the path that declares ``skinloc.app_pages`` entry points: the good one is
    served (its action behind the token), the broken ones are logged and left out."""
    import sys

    from skinloc.app import pages

    site = tmp_path / "site"
    site.mkdir()
    (site / "skinloc_plugin_pages.py").write_text(PLUGIN, encoding="utf-8")
    info = site / "skinloc_plugin_pages-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: skinloc-plugin-pages\nVersion: 0.1\n", encoding="utf-8"
    )
    (info / "entry_points.txt").write_text(
        "[skinloc.app_pages]\n"
        "plugged = skinloc_plugin_pages:PAGE\n"
        "misnamed = skinloc_plugin_pages:PAGE\n"
        "missing = skinloc_plugin_pages_nowhere:PAGE\n"
        "stream = skinloc_plugin_pages:STREAM\n",
        encoding="utf-8",
    )
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.setattr(pages, "_entry_points_loaded", False)
    try:
        app = create_app(AppConfig(data_dir=tmp_path / "data"))
        assert [p.name for p in app_pages()] == [p.name for p in builtin_pages()] + ["plugged"]
        with TestClient(app) as client:
            assert '<button data-page="plugged">Plugged</button>' in client.get("/").text
            refused = client.post("/api/plugged/ping", headers=A)
            assert refused.status_code == 403
            headers = {**A, "X-Skinloc-Token": app.state.token}
            assert client.post("/api/plugged/ping", headers=headers).json() == {"pong": True}
    finally:
        if "plugged" in [p.name for p in app_pages()]:
            unregister_page("plugged")
        sys.modules.pop("skinloc_plugin_pages", None)
    left_out = [r.getMessage() for r in caplog.records if "left out" in r.getMessage()]
    assert len(left_out) == 3, left_out
    assert any("'misnamed'" in m and "AppPage named 'misnamed'" in m for m in left_out)
    assert any("'missing'" in m for m in left_out)
    assert any("'stream'" in m and "registered already" in m for m in left_out)
