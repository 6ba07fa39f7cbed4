"""The live view's contacts and gestures: every contact of a frame and every gesture event the
live pipeline delivers (``Sink.emit_contacts``, ``Sink.emit_gesture``) reach the tabs.

A stand-in pipeline plays synthetic multi-touch streams through the app's sink exactly as the
live pipeline does (two tracks per frame, their ends, gesture events in the shared format), on
the frames the app hands it; the real pipeline's single contact is in ``test_app_api``.
"""

from __future__ import annotations

import json
import math
import threading

import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

from skinloc.app.hub import Hub, to_json  # noqa: E402
from skinloc.app.live_io import FrameQueue, TabSink  # noqa: E402
from skinloc.errors import FrameTimeoutError  # noqa: E402
from skinloc.live.contact import Contact  # noqa: E402
from skinloc.sources.base import Frame  # noqa: E402
from tests.app.test_app_api import A, make_client, new_session, stream, wait_for  # noqa: E402

SWIPE = {
    "event": "gesture",
    "skin": "skin",
    "kind": "swipe",
    "direction": "up",
    "start_s": 0.1,
    "end_s": 0.4,
    "timestamp_s": 0.45,
    "track_ids": [3],
    "path_m": [[0.0, 0.0, 0.01], [0.0, 0.0, 0.03]],
    "speed_m_s": 0.07,
}
TWO_FINGER_TAP = {
    "event": "gesture",
    "skin": "skin",
    "kind": "two_finger_tap",
    "direction": None,
    "start_s": 0.5,
    "end_s": 0.6,
    "timestamp_s": 0.9,
    "track_ids": [3, 4],
}


def contact(track: int, slot: int, state: str, t: float, z: float) -> Contact:
    """A contact of track ``track`` at height ``z`` m (x = slot * 20 mm)."""
    p = (0.02 * slot, 0.0, z)
    return Contact(
        "skin", t, int(t * 100), state, p, p, 0.9, 20.0, 3.0, 50.0, track, track, slot, 140.0
    )


class FakePipeline:
    """Reads the app's frames like the live pipeline and delivers two tracks, then gestures.

    Frame k (from 0): tracks 3 (slot 0) and 4 (slot 1) from k = 0 to 9, both ending at k = 10;
    the swipe at k = 11, the two-finger tap at k = 12; nothing after.
    """

    def __init__(self, sink, queue: FrameQueue) -> None:
        self.sink, self.queue = sink, queue
        self.baseline = None
        self.core = self
        self.closed = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def set_baseline(self, frames: np.ndarray) -> None:
        self.baseline = np.asarray(frames)

    def start(self) -> None:
        self.queue.connect()
        self.thread.start()

    def _run(self) -> None:
        k = 0
        while not self.closed.is_set():
            try:
                frame = self.queue.read(timeout_s=0.1)
            except FrameTimeoutError:
                continue
            t = frame.timestamp_s
            if k < 10:
                state = "start" if k == 0 else "move"
                cs = [contact(3, 0, state, t, 0.01 + 0.002 * k), contact(4, 1, state, t, 0.05)]
                self.sink.emit_contacts("skin", t, cs)
            elif k == 10:
                cs = [contact(3, 0, "end", t, 0.028), contact(4, 1, "end", t, 0.05)]
                self.sink.emit_contacts("skin", t, cs)
            elif k == 11:
                self.sink.emit_gesture("skin", t, SWIPE)
            elif k == 12:
                self.sink.emit_gesture("skin", t, TWO_FINGER_TAP)
            k += 1

    def close(self) -> None:
        self.closed.set()
        self.thread.join(5)
        self.queue.disconnect()


class StubModel:
    """Enough of a trained model for the live view's checks (the fake pipeline needs none)."""

    n_features_in_ = 64


def _live_client(tmp_path, monkeypatch, fakes: list[FakePipeline]):
    client = make_client(tmp_path)
    client.__enter__()
    new_session(client, n_points=4)
    ws = client.app.state.workspace

    def make(model, queue):
        assert model is ws.active.model
        fakes.append(FakePipeline(ws.live_sink, queue))
        return fakes[-1]

    monkeypatch.setattr(ws, "_make_live_pipeline", make)
    ws.active.model = StubModel()
    return client


def test_every_contact_of_a_frame_and_every_gesture_reach_the_tab(tmp_path, monkeypatch):
    fakes: list[FakePipeline] = []
    client = _live_client(tmp_path, monkeypatch, fakes)
    try:
        with stream(client, "tab-a") as ws:
            assert client.post("/api/live/start", headers=A).status_code == 200
            wait_for(client, lambda s: s["mode"] == "live", "live mode", timeout_s=60)
            (fake,) = fakes
            # The pipeline got the session's baseline frames (raw counts) before any frame.
            assert fake.baseline is not None and fake.baseline.shape == (20, 64)
            frames, gestures = [], []
            for _ in range(5000):
                msg = ws.receive_json()
                if msg["type"] == "live":
                    frames.append(msg)
                elif msg["type"] == "gesture":
                    gestures.append(msg)
                    if len(gestures) == 2:
                        break
            else:
                pytest.fail(f"no two gestures; got {len(frames)} live messages")
        # One message per frame, both tracks in each, in the pipeline's order.
        assert len(frames) == 11
        for msg in frames:
            assert [c["track_id"] for c in msg["contacts"]] == [3, 4]
            assert [c["slot"] for c in msg["contacts"]] == [0, 1]
            assert all(c["strength"] == 140.0 for c in msg["contacts"])
        assert [c["state"] for c in frames[0]["contacts"]] == ["start", "start"]
        assert [c["state"] for c in frames[-1]["contacts"]] == ["end", "end"]
        zs = [m["contacts"][0]["position_m"][2] for m in frames[:10]]
        assert zs == pytest.approx([0.01 + 0.002 * k for k in range(10)])
        assert frames[0]["timestamp_s"] == frames[0]["contacts"][0]["timestamp_s"]
        # Gestures as the pipeline sent them, in order, never dropped.
        swipe, tap = gestures
        for sent, got in ((SWIPE, swipe), (TWO_FINGER_TAP, tap)):
            assert {k: got[k] for k in sent} == sent
        # Stopping ends the pipeline (its thread joined).
        assert client.post("/api/capture/stop", headers=A).status_code == 200
        assert fakes[0].closed.is_set() and not fakes[0].thread.is_alive()
        assert client.get("/api/state").json()["mode"] == "idle"
    finally:
        client.__exit__(None, None, None)


def test_starting_again_or_closing_the_session_ends_the_pipeline(tmp_path, monkeypatch):
    fakes: list[FakePipeline] = []
    client = _live_client(tmp_path, monkeypatch, fakes)
    try:
        assert client.post("/api/live/start", headers=A).status_code == 200
        wait_for(client, lambda s: s["mode"] == "live", "live mode", timeout_s=60)
        assert client.post("/api/live/start", headers=A).status_code == 200
        wait_for(client, lambda s: s["mode"] == "live" and len(fakes) == 2, "live again")
        assert fakes[0].closed.is_set() and not fakes[1].closed.is_set()
        assert client.post("/api/session/close", headers=A).status_code == 200
        assert fakes[1].closed.is_set()
    finally:
        client.__exit__(None, None, None)


def test_live_start_is_refused_with_a_message(tmp_path, monkeypatch):
    fakes: list[FakePipeline] = []
    client = _live_client(tmp_path, monkeypatch, fakes)
    try:
        ws = client.app.state.workspace
        ws.active.model.n_features_in_ = 10
        r = client.post("/api/live/start", headers=A)
        assert r.status_code == 400 and "expects 10 sensors" in r.json()["detail"]
        ws.active.model = None
        r = client.post("/api/live/start", headers=A)
        assert r.status_code == 400 and "train a model first" in r.json()["detail"]
        assert not fakes and client.get("/api/state").json()["mode"] == "idle"
    finally:
        client.__exit__(None, None, None)


def test_tab_sink_single_contacts_and_json():
    """Contacts delivered one by one (``emit``) are frames of one; nan goes out as null."""
    sent = []

    class Recorder(Hub):
        def publish(self, msg, to=None):
            sent.append(to_json(msg))

    sink = TabSink(Recorder())
    c = contact(-1, -1, "move", 1.5, 0.02)
    c.strength = math.nan
    sink.emit(c)
    sink.emit_gesture("left", 2.0, {"event": "gesture", "kind": "tap", "direction": None})
    live, gesture = (json.loads(s) for s in sent)
    assert live["type"] == "live" and live["timestamp_s"] == 1.5
    assert live["contacts"][0]["strength"] is None and live["contacts"][0]["track_id"] == -1
    assert gesture == {
        "type": "gesture",
        "event": "gesture",
        "skin": "left",
        "timestamp_s": 2.0,
        "kind": "tap",
        "direction": None,
    }


def test_frame_queue_hands_frames_over_and_drops_the_oldest():
    q = FrameQueue(8, 8)
    q.connect()
    with pytest.raises(FrameTimeoutError):
        q.read(timeout_s=0.01)
    for i in range(300):
        q.put(Frame(np.full(64, i, dtype=np.float32), i * 0.01, i))
    assert q.n_dropped == 300 - 256
    assert q.read(timeout_s=0.1).index == 300 - 256
    got = []
    t = threading.Thread(target=lambda: got.append(q.read(timeout_s=5.0)))
    q.disconnect()
    q.connect()
    t.start()
    q.put(Frame(np.zeros(64, dtype=np.float32), 9.0, 999))
    t.join(5)
    assert got and got[0].index == 999
