"""Only the app's own page drives the app (issue 11): token, JSON bodies, Origin, sources, uploads.

The TestClient checks each refusal; ``test_attacks_replayed_on_a_running_app`` replays them all
against a real ``skinloc app`` process with ``bench/app_attacks.py`` (docs/reliability.md).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import socket
import sys
import warnings
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

with warnings.catch_warnings():  # starlette's note that it prefers httpx2 to httpx
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient  # noqa: E402
    from starlette.websockets import WebSocketDisconnect  # noqa: E402

from skinloc.app.routes import meshes as mesh_routes  # noqa: E402
from skinloc.app.server import create_app, own_origins  # noqa: E402
from skinloc.app.workspace import AppConfig  # noqa: E402
from skinloc.geometry.mesh import cone_skin  # noqa: E402
from skinloc.hardware.ports import check_source  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
A = {"X-Skinloc-Client": "tab-a"}
#: Every action, with a body the page would send.
ACTIONS = [
    ("/api/lease", None),
    ("/api/connect", {"source": "sim"}),
    ("/api/disconnect", None),
    ("/api/rezero", None),
    ("/api/sim/touch", {"point": None}),
    ("/api/sessions", {"n_points": 3}),
    ("/api/sessions/x/open", None),
    ("/api/session/close", None),
    ("/api/recordings/import?path=x.h5", None),
    ("/api/meshes?filename=x.stl", None),
    ("/api/calibrate/start", None),
    ("/api/validate/start", {}),
    ("/api/capture/retake", {"index": 0}),
    ("/api/capture/undo", None),
    ("/api/capture/stop", None),
    ("/api/finger", {"on": True}),
    ("/api/train", None),
    ("/api/live/start", None),
]


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def app(tmp_path):
    return create_app(AppConfig(data_dir=tmp_path))


@pytest.fixture
def page(app):
    """A client acting as the app's own page (the token in every request)."""
    with TestClient(app) as client:
        client.headers.update({"X-Skinloc-Token": app.state.token, **A})
        yield client


def test_page_carries_a_fresh_token(app, tmp_path):
    with TestClient(app) as client:
        r = client.get("/")
    assert r.status_code == 200 and r.headers["cache-control"] == "no-store"
    assert f'<meta name="skinloc-token" content="{app.state.token}">' in r.text
    assert r.headers["x-frame-options"] == "DENY"
    assert len(app.state.token) >= 40
    other = create_app(AppConfig(data_dir=tmp_path / "b"))
    assert other.state.token != app.state.token
    assert create_app(AppConfig(data_dir=tmp_path / "c"), token="fixed").state.token == "fixed"


@pytest.mark.parametrize(("path", "body"), ACTIONS)
def test_actions_without_the_token_are_refused(app, page, path, body):
    page.post("/api/sessions", json={"n_points": 3, "name": "kept"})
    before = page.get("/api/state").json()
    evil = TestClient(app)
    for headers in (
        {},  # as fetch(..., {mode: "no-cors"}) from another page sends it
        {"X-Skinloc-Token": "guess"},
        {"X-Skinloc-Token": app.state.token, "Origin": "http://127.0.0.1:9999"},  # any-port-ok
    ):
        r = evil.post(path, json=body, headers={**headers, "X-Skinloc-Client": "tab-evil"})
        assert r.status_code == 403, (path, headers, r.text)
        assert "refused" in r.json()["detail"]
    after = page.get("/api/state").json()
    assert after["session"]["id"] == before["session"]["id"]
    assert after["lease"] == before["lease"] == "tab-a"


def test_actions_take_json_bodies_only(page):
    for kind in ("text/plain;charset=UTF-8", "application/x-www-form-urlencoded", None):
        headers = {"Content-Type": kind} if kind else {}
        r = page.post("/api/sessions", content=b'{"n_points": 3}', headers=headers)
        assert r.status_code == 415 and "JSON" in r.json()["detail"], kind
    assert page.get("/api/sessions").json()["sessions"] == []
    assert page.post("/api/sessions", json={"n_points": 3}).status_code == 200


def test_the_page_itself_may_send_its_own_origin(page):
    r = page.post("/api/lease", headers={"Origin": "http://testserver"})
    assert r.status_code == 200


@pytest.mark.parametrize(
    "origin",
    [
        "http://localhost:1234",  # any-port-ok: foreign origins, never bound
        "http://127.0.0.1:9999",  # any-port-ok
        "https://localhost",
        "https://testserver",
        "null",
        None,
    ],
)
def test_websocket_refuses_other_origins(app, origin):
    headers = {} if origin is None else {"origin": origin}
    with TestClient(app) as client:
        with pytest.raises(WebSocketDisconnect):
            with client.websocket_connect(f"/ws?token={app.state.token}", headers=headers):
                pass


def test_websocket_wants_the_token(app):
    with TestClient(app) as client:
        for url in ("/ws", "/ws?token=guess"):
            with pytest.raises(WebSocketDisconnect):
                with client.websocket_connect(url, headers={"origin": "http://testserver"}):
                    pass
        url = f"/ws?client=tab-a&token={app.state.token}"
        with client.websocket_connect(url, headers={"origin": "http://testserver"}) as ws:
            assert ws.receive_json()["type"] == "state"


def test_websocket_on_the_ipv6_loopback(tmp_path):
    app = create_app(AppConfig(data_dir=tmp_path), origins=own_origins("::1", 8765))
    url = f"/ws?token={app.state.token}"
    with TestClient(app, base_url="http://[::1]:8765") as client:
        with client.websocket_connect(url, headers={"origin": "http://[::1]:8765"}) as ws:
            assert ws.receive_json()["type"] == "state"
        for origin in ("http://[::1]:9999", "http://127.0.0.1:8765"):  # any-port-ok
            with pytest.raises(WebSocketDisconnect):
                with client.websocket_connect(url, headers={"origin": origin}):
                    pass
    assert own_origins("127.0.0.1", 80) == ["http://127.0.0.1:80", "http://localhost:80"]


def test_dns_rebinding_is_still_refused(page):
    assert page.get("/", headers={"host": "evil.example"}).status_code == 400
    assert page.post("/api/lease", headers={"host": "evil.example"}).status_code == 400


def test_check_source():
    assert check_source("sim") == "sim"
    for url in ("spy://loop://?file=/x", "socket://127.0.0.1:1", "rfc2217://h:1", "loop://"):
        with pytest.raises(ValueError, match="pyserial URL.*'sim'"):
            check_source(url)
        assert check_source(url, allow_urls=True) == url
    with pytest.raises(ValueError, match="--allow-url"):
        check_source("loop://", opt_in="pass --allow-url")
    with pytest.raises(ValueError, match="not a serial port"):
        check_source(__file__)
    with pytest.raises(ValueError, match="no such device"):
        check_source("/dev/skinloc-no-such-port")
    with pytest.raises(ValueError, match="no such device"):
        check_source("sim", allow_sim=False)
    if os.path.exists("/dev/null"):  # a character device (as a serial port or a pty is)
        assert check_source("/dev/null") == "/dev/null"


def test_connect_refuses_urls_and_files(page, tmp_path):
    victim = tmp_path / "precious.txt"
    victim.write_text("keep me\n")
    h = sha(victim)
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        srv.settimeout(0.5)
        sources = [
            f"spy://loop://?file={victim}",
            f"socket://127.0.0.1:{srv.getsockname()[1]}",
            "loop://",
            "hwgrep://.*",
            str(victim),
            str(tmp_path),
        ]
        for source in sources:
            r = page.post("/api/connect", json={"source": source})
            assert r.status_code == 400 and "'sim'" in r.json()["detail"], source
        with pytest.raises(TimeoutError):
            srv.accept()  # socket:// opened no connection
    assert sha(victim) == h and victim.read_text() == "keep me\n"


def test_upload_limit_is_enforced_while_streaming(page, tmp_path, monkeypatch):
    monkeypatch.setattr(mesh_routes, "MAX_UPLOAD_BYTES", 10_000)
    sent = []

    def body():
        for _ in range(100):  # 100 kB offered, in 1 kB pieces
            sent.append(1)
            yield b"\0" * 1000

    r = page.post("/api/meshes?filename=big.stl", content=body())
    assert r.status_code == 413 and "too large" in r.json()["detail"]
    r = page.post(
        "/api/meshes?filename=big.stl", content=b"\0" * 20_000, headers={"Content-Length": "20000"}
    )
    assert r.status_code == 413
    meshes = tmp_path / "meshes"
    assert not any(meshes.iterdir())  # no partial or hidden file left


def test_failed_upload_keeps_the_good_mesh_and_meshes_stay_listed(page, app, tmp_path):
    stl = cone_skin().export(file_type="stl")
    assert page.post("/api/meshes?filename=cone.stl", content=stl).status_code == 200
    good = tmp_path / "meshes" / "cone.stl"
    h = sha(good)
    for junk in (b"not a mesh", stl[:300], b"", b"\x89PNG\r\n\x1a\n" + bytes(100)):
        r = page.post("/api/meshes?filename=cone.stl", content=junk)
        assert r.status_code == 400, junk[:20]
        assert ".upload" not in r.json()["detail"]  # named as uploaded, not the temp file
        assert sha(good) == h
    assert [m["name"] for m in page.get("/api/meshes").json()] == ["cone.stl"]
    # A new app on the same folder (a restart; a reload asks the same) still lists it.
    with TestClient(create_app(AppConfig(data_dir=tmp_path))) as again:
        assert [m["name"] for m in again.get("/api/meshes").json()] == ["cone.stl"]


def test_validation_errors_do_not_echo_the_request(page):
    marker = "ECHO" + "x" * 50_000
    for path, body in (
        ("/api/sessions", {"name": marker}),
        ("/api/connect", {"tx": marker}),
        ("/api/capture/retake", {"index": marker}),
    ):
        r = page.post(path, json=body)
        assert r.status_code == 422 and "ECHO" not in r.text and len(r.content) < 1000
        assert isinstance(r.json()["detail"], str)
    r = page.post(
        "/api/connect", content=b'{"source": "si', headers={"Content-Type": "application/json"}
    )
    assert r.status_code == 422 and r.json()["detail"] == "the body is not valid JSON"


def _bench():
    spec = importlib.util.spec_from_file_location("app_attacks", ROOT / "bench" / "app_attacks.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("app_attacks", module)  # its dataclass looks itself up there
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # the app served and attacked over HTTP
def test_attacks_replayed_on_a_running_app(tmp_path):
    """bench/app_attacks.py against a real ``skinloc app`` process: every attack refused."""
    pytest.importorskip("websockets")
    bench = _bench()
    rows = bench.run_all(tmp_path, oversize=bench.LIMIT + 2 * bench.MB, browser=False)
    failed = [f"{r.group}: {r.attack}: {r.got}" for r in rows if not r.ok or r.untouched is False]
    assert not failed, "\n".join(failed)
    groups = {r.group for r in rows}
    assert {"cross-site", "websocket", "sources", "upload", "bad input"} <= groups


def _actions(app) -> list[tuple[str, str]]:
    """Every ``(method, path)`` of the app's route table that may change something (not GET)."""
    paths = app.openapi()["paths"]
    out = [
        (m.upper(), path) for path, ops in paths.items() for m in ops if m not in ("get", "head")
    ]
    # path parameters filled in with something that routes (what they hold does not matter)
    return [(m, p.replace("{session_id}", "x").replace("{action}", "now")) for m, p in out]


def test_every_action_of_the_route_table_refuses_a_request_without_the_token(app, page):
    page.post("/api/sessions", json={"n_points": 3, "name": "kept"})
    before = page.get("/api/state").json()
    evil = TestClient(app)
    actions = _actions(app)
    assert len(actions) >= 15  # the table is read, not a list kept by hand
    for method, path in actions:
        for headers in ({}, {"X-Skinloc-Token": "guess"}):
            r = evil.request(method, path, json={}, headers={**headers, **A})
            assert r.status_code == 403, (method, path, headers, r.text)
    after = page.get("/api/state").json()
    assert after["session"]["id"] == before["session"]["id"]


def test_every_action_but_taking_over_first_takes_control(app, page):
    url = f"/ws?client=tab-a&token={app.state.token}"
    with page.websocket_connect(url, headers={"origin": "http://testserver"}) as ws:
        assert ws.receive_json()["type"] == "state"  # tab-a is open ...
        page.post("/api/sessions", json={"n_points": 3, "name": "kept"})  # ... and has control
        other = {"X-Skinloc-Token": app.state.token, "X-Skinloc-Client": "tab-b"}
        for method, path in _actions(app):
            if path == "/api/lease":  # takes control over whoever has it
                continue
            r = page.request(method, path, json={}, headers=other)
            assert r.status_code == 409, (method, path, r.text)
            assert "busy" in r.json()["detail"]
