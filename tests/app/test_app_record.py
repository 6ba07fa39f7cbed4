"""Record (issue 22, section 4): the live stream to HDF5 or MCAP from the page.

The files are the package's own (``StreamAppender``, ``Ros2BagSink``): they open with
``skinloc info``, replay with ``skinloc run --source``, and the MCAP decodes with the independent
``mcap_ros2`` reader (what Foxglove reads). Stopping, disconnecting, closing the session and
closing the app each end the file with every frame so far.
"""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient  # noqa: E402

from skinloc.app.server import create_app  # noqa: E402
from skinloc.app.workspace import AppConfig  # noqa: E402
from skinloc.app.workspace.record import read_live_events  # noqa: E402
from skinloc.data.recording import read_recording  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from skinloc.sources.replay import read_stream  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402

A = {"X-Skinloc-Client": "tab-a"}


def _client(data, token: bool = True) -> TestClient:
    app = create_app(
        AppConfig(data_dir=data, finger_delay_s=0.05),
        SourceOptions(source="sim", rate_hz=400.0, seed=3),
    )
    client = TestClient(app)
    if token:
        client.headers.update({"X-Skinloc-Token": app.state.token, **A})
    return client


def mcap_counts(path) -> dict[str, int]:
    """Messages per topic of an MCAP file, from its summary (written only when it is finished)."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    stats = summary.statistics.channel_message_counts
    return {summary.channels[c].topic: n for c, n in stats.items()}


def _quiet(client) -> None:
    """Wait until the skin has sent untouched frames (the recording's baseline)."""
    monitor = client.app.state.workspace.device.monitor
    _wait(lambda: len(monitor.quiet_frames()) >= 20, "untouched frames")


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    """A client on a trained session with the live view running."""
    data = tmp_path_factory.mktemp("record")
    with _client(data) as client:
        ws = client.app.state.workspace
        ws.create_session("record", n_points=8, samples=10, baseline_frames=20)
        ws.set_finger(True)
        ws.start_calibration()
        _wait(lambda: ws.message == "calibration complete", "calibration")
        ws.set_finger(False)
        ws.train()
        _wait(lambda: ws.training and not ws.training.get("running"), "training", 300)
        assert client.post("/api/live/start").status_code == 200
        _wait(lambda: ws.mode.value == "live", "live mode")
        yield client, ws


def _record_a_touch(client, ws, fmt: str) -> dict:
    """Record while a finger presses the first target for a while, then lifts; the summary."""
    r = client.post("/api/record/start", json={"format": fmt})
    assert r.status_code == 200, r.text
    first = r.json()
    assert first["running"] and first["format"] == fmt and first["name"].endswith(f".{fmt}")
    assert client.get("/api/state").json()["recording"]["name"] == first["name"]
    target = ws.active.targets[0]
    # Untouched frames first: a replay (`skinloc run --source`) takes its baseline from them.
    _wait(lambda: client.get("/api/record").json()["frames"] > 300, "untouched frames recorded")
    client.post("/api/sim/touch", json={"point": target.tolist()})
    _wait(lambda: client.get("/api/record").json()["contacts"] > 20, "contacts recorded")
    client.post("/api/sim/touch", json={"point": None})
    _wait(lambda: client.get("/api/record").json()["seconds"] > 1.5, "a recording of 1.5 s")
    # the size is the file's as it grows, not its header until the end
    _wait(lambda: client.get("/api/record").json()["bytes"] > 1000, "the file growing")
    running = client.get("/api/record").json()
    assert running["running"] and running["frames"] > 100
    r = client.post("/api/record/stop")
    assert r.status_code == 200, r.text
    last = r.json()["last"]
    assert not last["running"] and last["frames"] >= running["frames"]
    assert client.get("/api/record").json()["last"]["name"] == first["name"]
    assert client.get("/api/state").json()["recording"] is None
    return last


def test_record_hdf5_frames_contacts_gestures(live, tmp_path):
    client, ws = live
    last = _record_a_touch(client, ws, "h5")
    path = ws.active.folder.path / last["name"]
    assert path.is_file() and path.stat().st_size == last["bytes"]
    assert not list(ws.active.folder.path.glob("*partial*"))
    frames, times, index = read_stream(path)
    assert len(frames) == last["frames"] and frames.shape[1] == 64
    assert np.all(np.diff(times) > 0) and times[-1] == pytest.approx(last["seconds"], abs=0.01)
    events = read_live_events(path)
    assert len(events["contacts"]) == last["contacts"] > 20
    assert {c["state"] for c in events["contacts"]} >= {"start", "move", "end"}
    assert len(events["gestures"]) == last["gestures"]
    # It opens with skinloc, and is listed for export.
    rec = read_recording(path)
    assert rec.n_point_logs == 0 and len(rec.baseline_frames) >= 2
    out = subprocess.run(
        [sys.executable, "-m", "skinloc", "info", str(path), "--json"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)["stream_frames"] == last["frames"]
    assert last["name"] in {f["name"] for f in client.get("/api/export").json()["files"]}
    r = client.get(f"/api/export/files/{last['name']}")
    assert r.status_code == 200 and r.content == path.read_bytes()


def test_record_mcap_opens_as_a_ros2_bag_and_replays(live, tmp_path):
    pytest.importorskip("mcap")
    reader_mod = pytest.importorskip("mcap.reader")
    decoder = pytest.importorskip("mcap_ros2.decoder")
    client, ws = live
    last = _record_a_touch(client, ws, "mcap")
    path = ws.active.folder.path / last["name"]
    assert path.is_file() and path.stat().st_size == last["bytes"]
    topics: dict[str, int] = {}
    with path.open("rb") as fh:
        reader = reader_mod.make_reader(fh, decoder_factories=[decoder.DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for _, channel, _, msg in reader.iter_decoded_messages():
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
            if channel.topic.endswith("/frames"):
                assert (msg.height, msg.width, msg.encoding) == (8, 8, "32FC1")
    assert topics["/skinloc/skin/frames"] == last["frames"]
    assert topics.get("/skinloc/skin/contact", 0) > 10
    # `skinloc run` replays the bag with the session's model.
    out = tmp_path / "replayed.jsonl"
    model = ws.active.folder.model
    cmd = [sys.executable, "-m", "skinloc", "run", "--model", str(model), "--source", str(path)]
    r = subprocess.run(
        [*cmd, "--fast", "--sink", f"jsonl:{out}"], capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stderr
    states = {json.loads(line).get("state") for line in out.read_text().splitlines()}
    assert {"start", "end"} <= states


def test_bad_requests_say_so_in_one_line(live):
    client, ws = live
    for body, code, text in (
        ({"format": "gif"}, 422, "format"),
        ({"format": 3}, 422, "format"),
    ):
        r = client.post("/api/record/start", json=body)
        assert r.status_code == code and text in r.json()["detail"], r.text
        assert "\n" not in r.json()["detail"]
    r = client.post("/api/record/stop")
    assert r.status_code == 400 and r.json()["detail"] == "not recording"
    assert client.post("/api/record/start", json={"format": "h5"}).status_code == 200
    r = client.post("/api/record/start", json={"format": "mcap"})
    assert r.status_code == 400 and r.json()["detail"].startswith("already recording")
    # Without the page's token nothing starts or stops.
    evil = TestClient(client.app)
    for path in ("/api/record/start", "/api/record/stop"):
        r = evil.post(path, json={"format": "h5"}, headers=A)
        assert r.status_code == 403
    assert client.get("/api/record").json()["running"]
    assert client.post("/api/record/stop").status_code == 200


def test_the_page_offers_only_the_formats_this_install_writes(live, monkeypatch):
    """Without the live extra MCAP is not offered, and asking for it says what to install
    (once, both packages at once) and leaves no file behind."""
    from skinloc.app.workspace import record

    client, ws = live
    assert set(client.get("/api/record").json()["formats"]) == {"h5", "mcap"}
    why = "MCAP recording needs mcap and cyclonedds: pip install 'skinloc[live]'"
    monkeypatch.setattr(record, "missing_format", lambda fmt: why if fmt == "mcap" else None)
    assert set(client.get("/api/record").json()["formats"]) == {"h5"}
    before = sorted(p.name for p in ws.active.folder.path.iterdir())
    r = client.post("/api/record/start", json={"format": "mcap"})
    assert r.status_code == 400 and r.json()["detail"] == why
    assert sorted(p.name for p in ws.active.folder.path.iterdir()) == before


def test_no_session_or_no_skin_is_refused(tmp_path):
    with _client(tmp_path) as client:
        r = client.post("/api/record/start", json={"format": "h5"})
        assert r.status_code == 400 and r.json()["detail"].startswith("no session open")
        client.post("/api/sessions", json={"n_points": 3})
        client.post("/api/disconnect")
        r = client.post("/api/record/start", json={})
        assert r.status_code == 400 and r.json()["detail"].startswith("no skin connected")


@pytest.mark.parametrize("how", ["disconnect", "close session", "open another", "exit"])
@pytest.mark.parametrize("fmt", ["h5", "mcap"])
def test_every_way_out_finishes_the_file(tmp_path, how, fmt):
    if fmt == "mcap":
        pytest.importorskip("mcap")
    client = _client(tmp_path)
    with client:
        sid = client.post("/api/sessions", json={"n_points": 3}).json()["id"]
        _quiet(client)
        name = client.post("/api/record/start", json={"format": fmt}).json()["name"]
        _wait(lambda: client.get("/api/record").json()["frames"] > 50, "frames recorded")
        if how == "disconnect":
            assert client.post("/api/disconnect").status_code == 200
        elif how == "close session":
            assert client.post("/api/session/close").status_code == 200
        elif how == "open another":
            assert client.post("/api/sessions", json={"n_points": 3}).status_code == 200
        if how != "exit":
            last = client.get("/api/record").json()["last"]
            assert last["name"] == name and not last["running"]
    # "exit": the app's shutdown (the TestClient's end) finishes it.
    path = tmp_path / sid / name
    assert path.is_file(), sorted(p.name for p in (tmp_path / sid).iterdir())
    assert not list((tmp_path / sid).glob("*partial*")) and not list((tmp_path / sid).glob(".*tmp"))
    if fmt == "h5":
        frames, _, _ = read_stream(path)
        assert len(frames) > 50
    else:
        assert mcap_counts(path)["/skinloc/skin/frames"] > 50


def test_the_file_being_written_is_not_offered_but_an_unfinished_one_is(tmp_path):
    import shutil

    with _client(tmp_path) as client:
        sid = client.post("/api/sessions", json={"n_points": 3}).json()["id"]
        _quiet(client)
        name = client.post("/api/record/start", json={"format": "h5"}).json()["name"]
        _wait(lambda: client.get("/api/record").json()["frames"] > 50, "frames recorded")
        listed = {f["name"] for f in client.get("/api/export").json()["files"]}
        assert not any(n.startswith("live-") for n in listed), listed
        client.post("/api/record/stop")
        # What a crash leaves: the side file of an HDF5 recording, frames flushed so far.
        left = tmp_path / sid / "live-20260101-000000.partial.h5"
        shutil.copy(tmp_path / sid / name, left)
        files = {f["name"]: f["kind"] for f in client.get("/api/export").json()["files"]}
        assert files[name] == "live recording" and "unfinished" in files[left.name]
        r = client.get(f"/api/export/files/{left.name}")
        assert r.status_code == 200 and r.content == left.read_bytes()
        assert len(read_stream(left)[0]) > 50


def test_a_full_disk_ends_the_recording_with_what_it_holds(tmp_path, monkeypatch):
    import errno

    from skinloc.data.appender import StreamAppender

    real_append = StreamAppender.append
    calls = {"n": 0}

    def append(self, *args, **kw):
        calls["n"] += 1
        if calls["n"] > 2:  # the third flush meets a full disk
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_append(self, *args, **kw)

    monkeypatch.setattr(StreamAppender, "append", append)
    with _client(tmp_path) as client:
        sid = client.post("/api/sessions", json={"n_points": 3}).json()["id"]
        _quiet(client)
        name = client.post("/api/record/start", json={"format": "h5"}).json()["name"]
        _wait(lambda: not client.get("/api/record").json()["running"], "the recording to stop")
        state = client.get("/api/state").json()
        assert state["recording"] is None
        assert state["message"].startswith("recording stopped:") and "space" in state["message"]
        frames, _, _ = read_stream(tmp_path / sid / name)
        assert len(frames) > 0  # the two flushes before the disk filled
