"""Live settings (issue 22, section 4): the live pipeline's thresholds and filter, shown and saved
to the session's skins file, the one ``skinloc run --config`` reads, and applied at once."""

from __future__ import annotations

import warnings

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient  # noqa: E402

from skinloc.app.server import create_app  # noqa: E402
from skinloc.app.workspace import AppConfig  # noqa: E402
from skinloc.app.workspace.settings import EDITABLE, toml_text  # noqa: E402
from skinloc.live.config import PipelineConfig  # noqa: E402
from skinloc.live.skins_file import load_skins  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402

A = {"X-Skinloc-Client": "tab-a"}


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    """A trained session on the simulated skin."""
    data = tmp_path_factory.mktemp("settings")
    app = create_app(
        AppConfig(data_dir=data, finger_delay_s=0.05),
        SourceOptions(source="sim", rate_hz=400.0, seed=3),
    )
    with TestClient(app) as c:
        c.headers.update({"X-Skinloc-Token": app.state.token, **A})
        ws = app.state.workspace
        ws.create_session("settings", n_points=6, samples=10, baseline_frames=20)
        ws.set_finger(True)
        ws.start_calibration()
        _wait(lambda: ws.message == "calibration complete", "calibration")
        ws.set_finger(False)
        ws.train()
        _wait(lambda: not ws.training.get("running"), "training", 300)
        yield c


def test_defaults_are_shown_until_saved(client):
    d = client.get("/api/live/settings").json()
    assert [f["name"] for f in d["fields"]] == list(EDITABLE)
    defaults = PipelineConfig()
    for f in d["fields"]:
        assert f["value"] == f["default"] == getattr(defaults, f["name"]) and f["help"]
    assert d["file"] == "skins.toml" and d["command"].startswith("skinloc run --config ")


def test_saved_settings_are_what_skinloc_run_reads_and_the_live_view_uses(client):
    ws = client.app.state.workspace
    assert client.post("/api/live/start").status_code == 200
    _wait(lambda: ws.mode.value == "live" and ws._live_pipeline is not None, "live mode")
    old = ws._live_pipeline
    r = client.post(
        "/api/live/settings",
        json={
            "values": {"touch_on_z": 10.0, "touch_off_z": 5, "filter": "none", "max_contacts": 2}
        },
    )
    assert r.status_code == 200, r.text
    shown = {f["name"]: f["value"] for f in r.json()["fields"]}
    assert shown["touch_on_z"] == 10.0 and shown["filter"] == "none" and shown["max_contacts"] == 2
    path = ws.active.folder.path / "skins.toml"
    skins, sinks = load_skins(path)  # what `skinloc run --config` reads
    cfg = skins[0].config
    assert (cfg.touch_on_z, cfg.touch_off_z, cfg.filter, cfg.max_contacts) == (10.0, 5, "none", 2)
    assert skins[0].model == str(ws.active.folder.model) and skins[0].source == "sim"
    assert (skins[0].n_tx, skins[0].n_rx) == (8, 8) and sinks == []
    # The live view started again with them.
    _wait(lambda: ws._live_pipeline is not None and ws._live_pipeline is not old, "live again")
    assert ws._live_pipeline.core.config.touch_on_z == 10.0
    assert ws._live_pipeline.core.config.filter == "none"
    client.post("/api/capture/stop")


def test_bad_settings_change_nothing_and_say_so_in_one_line(client):
    ws = client.app.state.workspace
    path = ws.active.folder.path / "skins.toml"
    client.post("/api/live/settings", json={"values": {"touch_on_z": 9.0}})
    before = path.read_bytes()
    for body, code, text in (
        ({"values": {"touch_off_z": 20.0}}, 400, "touch_off_z must be <= touch_on_z"),
        ({"values": {"filter": "kalman"}}, 400, "filter must be one of one-euro, none"),
        ({"values": {"baseline_frames": 3}}, 400, "unknown setting(s) baseline_frames"),
        ({"values": {"touch_on_z": [1]}}, 422, "values"),
        ({"values": "fast"}, 422, "values"),
        ({}, 422, "values"),
    ):
        r = client.post("/api/live/settings", json=body)
        assert r.status_code == code, (body, r.text)
        detail = r.json()["detail"]
        assert text in detail and "\n" not in detail, detail
    assert path.read_bytes() == before
    evil = TestClient(client.app)
    r = evil.post("/api/live/settings", json={"values": {"touch_on_z": 12.0}}, headers=A)
    assert r.status_code == 403 and path.read_bytes() == before


def test_a_hand_edited_skins_file_keeps_its_other_keys(client):
    ws = client.app.state.workspace
    path = ws.active.folder.path / "skins.toml"
    path.write_text(
        'sinks = ["jsonl"]\n\n[[skin]]\nname = "arm"\nmodel = "model.h5"\n'
        'parent_frame = "link7"\npipeline = { touch_on_z = 7.0, stale_s = 2.0 }\n'
    )
    assert client.get("/api/live/settings").json()["fields"][0]["value"] == 7.0
    r = client.post("/api/live/settings", json={"values": {"beta": 5.0}})
    assert r.status_code == 200, r.text
    skins, sinks = load_skins(path)
    assert sinks == ["jsonl"] and skins[0].name == "arm" and skins[0].parent_frame == "link7"
    assert skins[0].config.stale_s == 2.0 and skins[0].config.touch_on_z == 7.0
    assert skins[0].config.beta == 5.0
    path.write_text("[[skin]\n")
    r = client.get("/api/live/settings")
    assert r.status_code == 400 and r.json()["detail"].startswith("cannot read skins.toml")
    path.unlink()


def test_no_session_is_refused(tmp_path):
    with TestClient(create_app(AppConfig(data_dir=tmp_path))) as c:
        r = c.get("/api/live/settings")
        assert r.status_code == 400 and r.json()["detail"].startswith("no session open")


def test_toml_text_reads_back():
    import tomllib

    doc = {
        "sinks": ["jsonl", 'ws://"q"'],
        "defaults": {"baud": 115200, "pipeline": {"touch_on_z": 8.5}},
        "skin": [{"name": "a b", "up": [0.0, 0.0, 1.0], "wait": False, "pipeline": {"x": 1}}],
    }
    assert tomllib.loads(toml_text(doc, header="two\nlines")) == doc
