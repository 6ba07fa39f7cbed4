"""The browser app's HTTP API and WebSocket, driven through FastAPI's TestClient.

A simulated skin streams in real time (fast, 400 Hz) and the scripted finger touches each
target, as in the browser; the tests wait for what the app reports, with generous limits.
"""

from __future__ import annotations

import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

with warnings.catch_warnings():  # starlette's note that it prefers httpx2 to httpx
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient  # noqa: E402

from skinloc.app.server import create_app  # noqa: E402
from skinloc.app.workspace import AppConfig  # noqa: E402
from skinloc.data.recording import read_recording  # noqa: E402
from skinloc.geometry.mesh import cone_skin  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from tests._helpers import wait_until  # noqa: E402

#: The default localiser (it trains in seconds); tests may pass overrides here.
FAST_TRAIN: dict = {}
A = {"X-Skinloc-Client": "tab-a"}
B = {"X-Skinloc-Client": "tab-b"}


def page_client(app) -> TestClient:
    """A client that acts as the app's own page: it sends the launch token with every action."""
    client = TestClient(app)
    client.headers.update({"X-Skinloc-Token": app.state.token})
    return client


def make_client(data: Path, source: bool = True) -> TestClient:
    config = AppConfig(data_dir=data, train_options=FAST_TRAIN, finger_delay_s=0.05)
    spec = SourceOptions(source="sim", rate_hz=400.0, seed=3) if source else None
    return page_client(create_app(config, spec))


def stream(client: TestClient, tab: str):
    """The page's WebSocket: its own origin and the launch token."""
    token = client.headers["X-Skinloc-Token"]
    return client.websocket_connect(
        f"/ws?client={tab}&token={token}", headers={"origin": "http://testserver"}
    )


def wait_for(client: TestClient, check, what: str, timeout_s: float = 180.0) -> dict:
    """Poll the state until ``check(state)``; fails naming ``what`` after ``timeout_s``."""
    last: dict = {}

    def reached() -> dict | None:
        last.update(state=client.get("/api/state").json())
        return last["state"] if check(last["state"]) else None

    return wait_until(reached, lambda: f"{what}; last state: {last.get('state')}", timeout_s, 0.05)


def new_session(client: TestClient, n_points: int = 8, **kw) -> str:
    body = {"name": "test skin", "n_points": n_points, "samples": 10, "baseline_frames": 20, **kw}
    r = client.post("/api/sessions", json=body, headers=A)
    assert r.status_code == 200, r.text
    return r.json()["id"]


def calibrate(client: TestClient, until: int | None = None) -> dict:
    assert client.post("/api/finger", json={"on": True}, headers=A).status_code == 200
    r = client.post("/api/calibrate/start", headers=A)
    assert r.status_code == 200, r.text
    if until is None:
        return wait_for(client, lambda s: s["message"] == "calibration complete", "calibration")
    state = wait_for(
        client,
        lambda s: s["guided"] is not None and s["guided"]["index"] >= until,
        f"{until} touches",
    )
    # The finger first: on a busy machine it may press once more before the stop lands.
    client.post("/api/finger", json={"on": False}, headers=A)
    client.post("/api/capture/stop", headers=A)
    return state


def test_full_session_calibrate_train_validate_live(tmp_path):
    with make_client(tmp_path) as client:
        sid = new_session(client, n_points=8)
        calibrate(client)
        rec = read_recording(tmp_path / sid / "calibration.h5")
        assert rec.n_point_logs == 8
        assert len(rec.meta["app"]["flags"]) == 8
        np.testing.assert_allclose(rec.targets, rec.planned_targets)
        detail = client.get("/api/session").json()
        assert len(detail["calibration"]["done"]) == 8
        mesh = client.get("/api/session/mesh").json()
        assert mesh["id"] == sid and len(mesh["faces"]) == len(cone_skin().faces)

        assert client.post("/api/train", headers=A).status_code == 200
        state = wait_for(
            client,
            lambda s: s["training"] and not s["training"].get("running"),
            "training",
        )
        result = state["training"]["result"]
        # every touch predicted by a model that did not see it, with the mean's interval
        assert "cross-validation" in result["how"] and result["n_point_logs"] == 8
        assert len(result["touch_errors"]["error_mm"]) == 8
        low, high = result["ci95_mm"]
        assert np.isfinite(result["mean_mm"]) and low <= result["mean_mm"] <= high
        assert (tmp_path / sid / "model.h5").is_file()
        # the Train page's curve: scored on one fold, with and without the prior
        curve = result["prior_curve"]
        assert curve["sizes"][-1] < 8
        assert len(curve["prior_mm"]) == len(curve["no_prior_mm"]) == len(curve["sizes"])
        assert all(curve["prior_applied"])  # 8 touches: within the prior's reach
        ref = client.get("/api/accuracy/reference").json()
        assert {"default", "default, no prior", "paper"} <= set(ref["curves"])
        assert ref["probing_floor_mm"] > 0

        r = client.post("/api/validate/start", json={"n_points": 3}, headers=A)
        assert r.status_code == 200, r.text
        state = wait_for(client, lambda s: s["session"]["validation"] is not None, "validation")
        assert state["session"]["validation"]["n"] == 3
        val = read_recording(tmp_path / sid / "validation.h5")
        assert val.n_point_logs == 3 and len(val.meta["app"]["errors_mm"]) == 3
        assert state["session"]["validation"]["retaken"] == 0

        # Retaking a validation touch is recorded: the result keeps the attempt taken back.
        first_error = val.meta["app"]["errors_mm"][0]
        r = client.post(
            "/api/capture/retake", json={"index": 0, "recording": "validation"}, headers=A
        )
        assert r.status_code == 200, r.text
        state = wait_for(
            client,
            lambda s: (
                s["session"]["validation"]["retaken"] == 1 and s["session"]["validation"]["n"] == 3
            ),
            "the retaken validation touch",
        )
        result = state["session"]["validation"]
        assert result["n_attempts"] == 4 and result["complete"]
        assert result["all_attempts"]["n"] == 4
        assert result["taken_back"][0]["reason"] == "retake"
        assert result["taken_back"][0]["error_mm"] == pytest.approx(first_error, abs=1e-2)
        val = read_recording(tmp_path / sid / "validation.h5")
        assert val.n_point_logs == 3 and len(val.meta["app"]["taken_back"]) == 1
        listed = client.get("/api/sessions").json()["sessions"][0]["validation"]
        assert listed["retaken"] == 1 and listed["n_attempts"] == 4

        assert client.post("/api/finger", json={"on": False}, headers=A).status_code == 200
        assert client.post("/api/live/start", headers=A).status_code == 200
        wait_for(client, lambda s: s["mode"] == "live", "live mode")
        target = rec.targets[0]
        with stream(client, "tab-a") as ws:
            r = client.post("/api/sim/touch", json={"point": target.tolist()}, headers=A)
            assert r.status_code == 200
            for _ in range(2000):
                msg = ws.receive_json()
                if msg["type"] == "live" and msg["contacts"]:
                    break
            else:
                pytest.fail("no live contact while touching")
            # The live pipeline's contacts, as every sink gets them.
            contact = msg["contacts"][0]
            assert contact["state"] in ("start", "move") and contact["skin"] == "skin"
            point = np.asarray(contact["position_m"])
            assert point.shape == (3,) and np.all(np.isfinite(point))
            assert np.linalg.norm(point - target) < 0.05
            client.post("/api/sim/touch", json={"point": None}, headers=A)
            for _ in range(2000):
                msg = ws.receive_json()
                if msg["type"] == "live" and any(c["state"] == "end" for c in msg["contacts"]):
                    break
            else:
                pytest.fail("no end of the touch after lifting")


def test_undo_skip_retake_keep_everything(tmp_path):
    with make_client(tmp_path) as client:
        sid = new_session(client, n_points=6)
        calibrate(client, until=3)
        path = tmp_path / sid / "calibration.h5"
        before = read_recording(path)
        assert before.n_point_logs >= 3
        n = before.n_point_logs

        client.post("/api/finger", json={"on": False}, headers=A)
        client.post("/api/calibrate/start", headers=A)
        assert client.post("/api/capture/undo", headers=A).status_code == 200
        rec = read_recording(path)
        assert rec.n_point_logs == n - 1
        # The undone target is prompted again, and the touch is kept in the history.
        np.testing.assert_allclose(rec.planned_targets[n - 1], before.targets[n - 1])
        detail = client.get("/api/session").json()
        assert detail["history"] == 1

        assert client.post("/api/capture/skip", headers=A).status_code == 200
        rec = read_recording(path)
        assert len(rec.planned_targets) == 5 and len(rec.meta["app"]["skipped"]) == 1

        r = client.post("/api/capture/retake", json={"index": 0}, headers=A)
        assert r.status_code == 200, r.text
        rec = read_recording(path)
        assert rec.n_point_logs == n - 2
        np.testing.assert_allclose(rec.planned_targets[n - 2], before.targets[0])
        np.testing.assert_allclose(rec.planned_targets[: rec.n_point_logs], rec.targets)
        assert client.get("/api/session").json()["history"] == 2
        assert client.post("/api/capture/retake", json={"index": 99}, headers=A).status_code == 400


def test_resume_after_restart(tmp_path):
    with make_client(tmp_path) as client:
        sid = new_session(client, n_points=6)
        state = calibrate(client, until=2)
        n_done = read_recording(tmp_path / sid / "calibration.h5").n_point_logs
        assert state["guided"]["total"] == 6
    # A new server on the same folder (the first one is gone, as after a crash).
    with make_client(tmp_path) as client:
        sessions = client.get("/api/sessions").json()["sessions"]
        assert [s["id"] for s in sessions] == [sid]
        assert sessions[0]["n_done"] == n_done
        assert client.post(f"/api/sessions/{sid}/open", headers=A).status_code == 200
        assert client.post("/api/calibrate/start", headers=A).status_code == 200
        state = wait_for(client, lambda s: s["mode"] == "calibrate", "resumed calibration")
        assert state["guided"]["index"] == n_done
        client.post("/api/capture/stop", headers=A)


def test_two_tabs_one_is_told_busy(tmp_path):
    with make_client(tmp_path) as client:
        with (
            stream(client, "tab-a") as ws_a,
            stream(client, "tab-b") as ws_b,
        ):
            assert ws_a.receive_json()["type"] == "state"
            assert ws_b.receive_json()["type"] == "state"
            new_session(client)  # tab a takes control
            r = client.post("/api/calibrate/start", headers=B)
            assert r.status_code == 409 and "busy" in r.json()["detail"]
            # Tab b takes over explicitly; tab a is told.
            assert client.post("/api/lease", headers=B).status_code == 200
            for _ in range(500):
                msg = ws_a.receive_json()
                if msg["type"] == "state" and msg["lease"] == "tab-b":
                    break
            else:
                pytest.fail("tab a was not told it lost control")
            assert client.post("/api/capture/stop", headers=A).status_code == 409
        # Tab b closed: control is free again for tab a.
        assert client.post("/api/capture/stop", headers=A).status_code == 200


def test_a_session_opens_in_one_process_only(tmp_path):
    with make_client(tmp_path, source=False) as first:
        sid = new_session(first)
        with make_client(tmp_path, source=False) as second:
            r = second.post(f"/api/sessions/{sid}/open", headers=A)
            assert r.status_code == 409 and "another skinloc app" in r.json()["detail"]


def test_target_sheets(tmp_path):
    with make_client(tmp_path, source=False) as client:
        sid = new_session(client, n_points=12)
        svg = client.get(f"/api/sessions/{sid}/targets.svg")
        assert svg.status_code == 200 and svg.headers["content-type"].startswith("image/svg")
        assert svg.text.count("<circle") == 12 and 'width="297mm"' in svg.text
        pdf = client.get(f"/api/sessions/{sid}/targets.pdf")
        assert pdf.status_code == 200 and pdf.content.startswith(b"%PDF")
        assert client.get(f"/api/sessions/{sid}/targets.png").status_code == 400
        assert client.get("/api/sessions/nope/targets.svg").status_code == 400


def test_target_list_and_mesh_upload(tmp_path):
    from skinloc.geometry.mesh import sample_targets

    with make_client(tmp_path, source=False) as client:
        pts = sample_targets(cone_skin(), 4, "random", random_state=1) * 1e3
        csv = "x,y,z\n" + "\n".join(",".join(f"{v:.4f}" for v in p) for p in pts)
        sid = new_session(client, mode="list", targets_csv=csv)
        detail = client.get("/api/session").json()
        assert detail["id"] == sid and len(detail["calibration"]["planned"]) == 4
        bad = client.post(
            "/api/sessions", json={"mode": "list", "targets_csv": "0,0,500"}, headers=A
        )
        assert bad.status_code == 400 and "off the skin" in bad.json()["detail"]
        bad = client.post("/api/sessions", json={"mode": "spiral"}, headers=A)
        assert bad.status_code == 400 and "spiral" in bad.json()["detail"]

        stl = cone_skin().export(file_type="stl")
        r = client.post("/api/meshes?filename=cone.stl", content=stl, headers=A)
        assert r.status_code == 200, r.text
        assert r.json()["n_faces"] == len(cone_skin().faces)
        r = client.post("/api/meshes?filename=junk.obj", content=b"not a mesh", headers=A)
        assert r.status_code == 400
        assert not (tmp_path / "meshes" / "junk.obj").exists()
        r = client.post("/api/sessions", json={"n_points": 5, "mesh_file": "cone.stl"}, headers=A)
        assert r.status_code == 200, r.text


def test_bad_requests_get_one_line_errors(tmp_path):
    with make_client(tmp_path, source=False) as client:
        r = client.post("/api/connect", json={"source": "/dev/no-such-port"}, headers=A)
        assert r.status_code == 400 and "/dev/no-such-port" in r.json()["detail"]
        assert "\n" not in r.json()["detail"]
        r = client.post("/api/calibrate/start", headers=A)
        assert r.status_code == 400 and "session" in r.json()["detail"]
        r = client.post("/api/capture/dance", headers=A)
        assert r.status_code == 400
        r = client.post("/api/sessions/..%2Fetc/open", headers=A)
        assert r.status_code in (400, 404)
        assert client.get("/", headers={"host": "evil.example"}).status_code == 400


def test_connect_page_reports_sensors(tmp_path):
    with make_client(tmp_path) as client:
        client.post("/api/sessions", json={"n_points": 5}, headers=A)
        with stream(client, "tab-a") as ws:
            seen = set()
            for _ in range(3000):
                msg = ws.receive_json()
                seen.add(msg["type"])
                if msg["type"] == "sensors":
                    break
            assert {"state", "frame", "sensors"} <= seen
        assert len(msg["noise"]) == 64 and len(msg["status"]) == 64
        # The simulated skin has a noisy sensor at TX 1, RX 7 (docs/simulator.md).
        assert msg["status"][1 * 8 + 7] == "noisy"
        state = client.get("/api/state").json()
        assert state["device"]["rate_hz"] > 0 and state["device"]["dropped"] == 0


@pytest.mark.skipif(not hasattr(__import__("os"), "openpty"), reason="needs a POSIX pty")
def test_calibrate_over_a_serial_port_with_the_virtual_skin(tmp_path):
    """The virtual skin device on a pty; its scripted finger is driven over the port."""
    from skinloc.sim.skin import SimulatedSkin
    from skinloc.sim.virtual_device import VirtualSkin

    with VirtualSkin(SimulatedSkin(random_state=0), fmt="binary", rate_hz=200) as dev:
        config = AppConfig(data_dir=tmp_path, finger_delay_s=0.05)
        with page_client(create_app(config, SourceOptions(source=dev.path))) as client:
            state = client.get("/api/state").json()
            assert state["device"]["name"] == dev.path and not state["device"]["sim"]
            sid = new_session(client, n_points=4)
            calibrate(client)
            rec = read_recording(tmp_path / sid / "calibration.h5")
            assert rec.n_point_logs == 4 and rec.meta["source"] == dev.path
            state = client.get("/api/state").json()
            assert state["device"]["received"] > 0 and state["device"]["corrupted"] == 0
            r = client.post("/api/sim/touch", json={"point": [0, 0, 0]}, headers=A)
            assert r.status_code == 400 and "simulated skin" in r.json()["detail"]


def test_reconnecting_the_skin_mid_session_carries_on(tmp_path):
    with make_client(tmp_path) as client:
        sid = new_session(client, n_points=5)
        calibrate(client, until=2)
        body = {"source": "sim", "rate_hz": 400.0, "seed": 3}
        assert client.post("/api/connect", json=body, headers=A).status_code == 200
        calibrate(client)
        assert read_recording(tmp_path / sid / "calibration.h5").n_point_logs == 5


def _stream_until(ws, check, what: str, timeout_s: float = 20.0) -> dict:
    """Read messages from ``ws`` until ``check(msg)``; fails naming ``what`` after ``timeout_s``.

    The WebSocket never goes quiet for long (the server sends a heartbeat when there is nothing
    else), so the deadline is checked between messages.
    """
    last: dict = {}

    def received() -> dict | None:
        last.update(msg=ws.receive_json())
        return last["msg"] if check(last["msg"]) else None

    return wait_until(received, what, timeout_s, interval_s=0)


def test_heartbeat_when_nothing_else_is_sent(tmp_path):
    with make_client(tmp_path, source=False) as client:
        client.headers.update({"X-Skinloc-Token": getattr(client.app.state, "token", "") or ""})
        with stream(client, "tab-a") as ws:
            assert ws.receive_json()["type"] == "state"
            beat = _stream_until(ws, lambda m: m["type"] == "heartbeat", "heartbeat")
            assert beat["device"] is False and beat["link_up"] is False


def test_the_link_is_up_until_the_reader_counts_it_lost(tmp_path):
    """Issue 33: the heartbeat said the link was down when the reader was merely late with its
    frames (a busy machine), while the server counted no loss. Every message now carries the
    reader's verdict, the one that counts ``link_losses``."""
    app = create_app(AppConfig(data_dir=tmp_path / "data"), SourceOptions(source="sim"))
    ws = app.state.workspace
    device = ws.device
    read, go_on = device.source.read, threading.Event()

    def late_read(timeout_s=None):
        go_on.wait(30)  # the reader thread held up (not the skin: its frames are waiting)
        return read(timeout_s)

    try:
        wait_until(lambda: device.monitor.n_frames > 5, "frames")
        device.source.read = late_read
        wait_until(lambda: not device.link_now(), "a frame older than the link's limit", 30)
        assert ws.link_status()["link_up"] is True and device.stats()["link_up"] is True
        go_on.set()
        n = device.monitor.n_frames
        wait_until(lambda: device.monitor.n_frames > n + 5, "frames again")
        assert device.link_losses == 0 and ws.link_status()["link_up"] is True
    finally:
        go_on.set()
        ws.disconnect()


def test_a_lost_links_reason_reaches_the_tabs_when_it_comes_after_the_verdict(tmp_path):
    """A loaded-run failure: the port was found lost while the reader still had a buffered
    frame, so the link-lost state went out with no reason, and the reason read after it
    (``device.error``) never reached the tabs. The reader now tells them again."""
    from skinloc.app.device import DeviceLink
    from skinloc.errors import FrameTimeoutError

    told: list[tuple[bool, str]] = []
    device = DeviceLink(SourceOptions(source="sim"), lambda frame, link: None)
    device.on_link = lambda up, link: told.append((up, link.error))
    source = device.source
    source.connect()
    buffered = source.read(timeout_s=5.0)
    port_up, reads = [True], [0]

    def read(timeout_s=None):
        reads[0] += 1
        if reads[0] == 1:
            port_up[0] = False  # the port's reader finds it gone; one frame is still buffered
            return buffered
        time.sleep(0.01)
        raise FrameTimeoutError("no frame from /dev/ttyACM0 within 0.2 s; the link is down")

    source.read = read
    device._source_link_up = lambda: port_up[0]
    device._thread = threading.Thread(target=device._run, daemon=True)
    device._thread.start()
    try:
        wait_until(lambda: len(told) >= 2, "the link-lost verdict and its reason", 30)
    finally:
        device.stop()
    assert told[0] == (False, "")  # the verdict, before any reason was read
    assert told[1][0] is False and "the link is down" in told[1][1]
    assert device.link_losses == 1  # told twice, lost once
    assert len(told) == 2  # the same reason is not told again


@pytest.fixture
def virtual_skin_app(tmp_path):
    """``(dev, app)``: the virtual skin on a pty (200 Hz, stopped and started again at the same
    path) and an app connected to it, its data under ``tmp_path / "data"``."""
    if not hasattr(__import__("os"), "openpty"):
        pytest.skip("needs a POSIX pty")
    from skinloc.sim.skin import SimulatedSkin
    from skinloc.sim.virtual_device import VirtualSkin

    dev = VirtualSkin(SimulatedSkin(random_state=0), rate_hz=200, link_dir=tmp_path / "port")
    dev.start()
    try:
        config = AppConfig(data_dir=tmp_path / "data", finger_delay_s=0.05)
        yield dev, create_app(config, SourceOptions(source=dev.path))
    finally:
        dev.stop()


def test_every_tab_is_told_when_the_link_drops_and_comes_back(virtual_skin_app):
    """The virtual skin stops: both tabs get a link-lost state; it starts again: link back."""
    dev, app = virtual_skin_app
    with TestClient(app) as client:
        client.headers.update({"X-Skinloc-Token": getattr(app.state, "token", "") or ""})
        with (
            stream(client, "tab-a") as ws_a,
            stream(client, "tab-b") as ws_b,
        ):
            for ws in (ws_a, ws_b):
                _stream_until(ws, lambda m: m["type"] == "frame", "frame")
            dev.stop()
            for ws in (ws_a, ws_b):
                lost = _stream_until(
                    ws,
                    lambda m: m["type"] == "state" and not m["device"]["link_up"],
                    "link-lost state",
                )
                assert "link lost" in lost["message"]
                beat = _stream_until(ws, lambda m: m["type"] == "heartbeat", "heartbeat")
                assert beat["device"] and not beat["link_up"]
            device = client.get("/api/state").json()["device"]
            # No stale "200 Hz" from before the stop.
            assert device["link_up"] is False and device["rate_hz"] == 0
            dev.start()  # the same port path: the serial source reopens it
            for ws in (ws_a, ws_b):
                back = _stream_until(
                    ws,
                    lambda m: m["type"] == "state" and m["device"]["link_up"],
                    "link-back state",
                )
                assert "link back" in back["message"]
            state = client.get("/api/state").json()["device"]
            # >= 1: on a loaded machine the reopened link may also stall past the limit
            assert state["link_losses"] >= 1 and state["reconnects"] >= 1


def test_a_baseline_cut_by_a_lost_link_is_captured_when_it_comes_back(virtual_skin_app, tmp_path):
    """Calibration started while the skin is silent: the baseline waits, never gives up."""
    dev, app = virtual_skin_app
    with page_client(app) as client:
        sid = new_session(client, n_points=3)
        dev.stop()
        wait_for(client, lambda s: not s["device"]["link_up"], "the link to drop")
        assert client.post("/api/calibrate/start", headers=A).status_code == 200
        state = wait_for(client, lambda s: "captured again" in s["message"], "the baseline to wait")
        assert state["mode"] == "baseline"
        dev.start()  # the same port path: the serial source reopens it
        calibrate(client)
        rec = read_recording(tmp_path / "data" / sid / "calibration.h5")
        assert rec.n_point_logs == 3 and np.isfinite(rec.baseline).all()


def test_active_sampling_then_the_coverage_map_of_the_trained_model(tmp_path):
    """The 'active' mode: a few planned (even) targets, then each chosen from the touches;
    after training, the coverage map of the model."""
    from skinloc.calibration.active import N_START
    from skinloc.calibration.session import CalibrationSession
    from skinloc.sim.skin import SimulatedSkin

    with make_client(tmp_path) as client:
        r = client.post(
            "/api/sessions", json={"name": "x", "n_points": 6, "mode": "smart"}, headers=A
        )
        assert 400 <= r.status_code < 500 and "active" in r.json()["detail"]
        sid = new_session(client, n_points=7, mode="active")
        plan = np.asarray(client.get("/api/session").json()["calibration"]["planned"])
        assert plan.shape == (7, 3)
        calibrate(client, until=N_START + 1)
        # Closed and reopened, the session asks what the recorded touches call for.
        assert client.post("/api/session/close", headers=A).status_code == 200
        assert client.post(f"/api/sessions/{sid}/open", headers=A).status_code == 200
        path = tmp_path / sid / "calibration.h5"
        n = read_recording(path).n_point_logs
        assert N_START < n < 7
        with SimulatedSkin(cone_skin(), random_state=3) as skin:
            expected = CalibrationSession.resume(skin, path).target_for(n)
        assert client.post("/api/finger", json={"on": False}, headers=A).status_code == 200
        assert client.post("/api/calibrate/start", headers=A).status_code == 200
        state = wait_for(client, lambda s: s["guided"] is not None, "the resumed calibration")
        assert state["guided"]["index"] == n
        np.testing.assert_allclose(state["guided"]["target"], expected, atol=1e-9)
        calibrate(client)
        rec = read_recording(path)
        assert rec.n_point_logs == 7 and rec.meta["sampling_mode"] == "active"
        np.testing.assert_allclose(rec.targets[:N_START], plan[:N_START])
        assert np.linalg.norm(rec.targets[N_START:] - plan[N_START:], axis=1).min() > 1e-6
        assert len(np.unique(np.round(rec.targets, 6), axis=0)) == 7
        # The page's view of the plan shows what was asked.
        np.testing.assert_allclose(rec.planned_targets, rec.targets)
        # The coverage map comes from the trained model: refused before, drawn after.
        r = client.get("/api/session/coverage")
        assert r.status_code == 400 and "train a model first" in r.json()["detail"]
        assert client.post("/api/train", headers=A).status_code == 200
        wait_for(client, lambda s: s["training"] and not s["training"].get("running"), "training")
        r = client.get("/api/session/coverage")
        assert r.status_code == 200, r.text
        cov = r.json()
        pts, err = np.asarray(cov["points"]), np.asarray(cov["expected_mm"])
        assert pts.ndim == 2 and pts.shape[1] == 3 and err.shape == (len(pts),)
        assert np.isfinite(err).all() and (err > 0).all() and cov["unit"] == "mm"
        assert cov["expected_error_mm"]["mean"] == pytest.approx(err.mean(), abs=0.05)
        # Its colours span its own spread; the measured errors come with it, to compare.
        lo, hi = cov["scale_mm"]
        assert lo < hi and lo <= np.percentile(err, 5) + 0.1 and hi >= np.percentile(err, 95) - 0.1
        assert cov["measured"]["holdout"]["p95_mm"] > 0
        # On the skin: every point within a millimetre of the cone's surface.
        from skinloc.geometry.mesh import nearest_on_surface

        assert nearest_on_surface(cone_skin(), pts)[1].max() < 1e-3


def test_a_mouse_path_moves_the_simulated_finger_at_its_pace(tmp_path):
    """``POST /api/sim/touch {path}``: the points with the page's event times are played on the
    server's clock, each piece after the last (a slow answer delays a stroke, never bunches it)."""
    with make_client(tmp_path) as client:
        skin = client.app.state.workspace.device.source
        a, b = cone_skin().vertices[[10, 60]]
        seen = []
        pressed = threading.Event()
        original = skin.press

        def press(point, **kw):  # every press and slide, in order (a slide presses too)
            seen.append(np.asarray(point).copy())
            pressed.set()
            original(point, **kw)

        skin.press = press
        r = client.post("/api/sim/touch", json={"path": [[5.0, a.tolist()]]}, headers=A)
        assert r.status_code == 200
        r = client.post(
            "/api/sim/touch", json={"path": [[5.02, b.tolist()], [5.04, None]]}, headers=A
        )
        assert r.status_code == 200
        wait_until(lambda: skin.contact is None and len(seen) >= 2, "the path played", 30)
        # pressed on the skin where the mouse pressed, slid where it moved, lifted at the end
        assert np.linalg.norm(seen[0] - a) < 1e-3 and np.linalg.norm(seen[-1] - b) < 1e-3
        # bad paths: times out of order, a point of two coordinates, an empty path
        for path in ([[2.0, a.tolist()], [1.0, None]], [[1.0, [0.0, 0.0]]], []):
            r = client.post("/api/sim/touch", json={"path": path}, headers=A)
            assert r.status_code in (400, 422), path
            assert "\n" not in str(r.json()["detail"])


def test_page_clock_keeps_the_mouse_pace_and_learns_the_delay():
    from skinloc.app.workspace.link import PageClock

    clock = PageClock(delay_s=0.02, max_delay_s=0.5)
    # a new path starts its delay after the first piece arrives; the page's spacing is kept
    assert clock.to_monotonic([10.0], now=100.0, lifted=False) == pytest.approx([100.02])
    got = clock.to_monotonic([10.01, 10.02], now=100.015, lifted=False)
    assert got == pytest.approx([100.03, 100.04])
    # a piece that arrives after its time pauses the path by its lateness (no jump) ...
    got = clock.to_monotonic([10.03, 10.05, 10.06], now=100.25, lifted=True)
    assert got == pytest.approx([100.25, 100.27, 100.28])
    # ... and the next path waits 1.5 x that lateness for its pieces
    assert clock.delay_s == pytest.approx(1.5 * 0.2)
    assert clock.to_monotonic([20.0], now=200.0, lifted=False) == pytest.approx([200.3])
    # never more than max_delay_s; a page reloaded mid-path (its clock restarted, or moved on)
    # plays from now on, neither in the past nor later than the largest delay
    clock.to_monotonic([20.1], now=210.0, lifted=False)
    assert clock.delay_s == 0.5
    for t in (1.0, 5000.0):
        (got,) = clock.to_monotonic([t], now=300.0, lifted=False)
        assert 300.0 <= got <= 300.5
