"""Sinks: JSON lines, UDP, WebSocket, Foxglove (live and MCAP), LSL (ROS 2: test_ros2.py)."""

from __future__ import annotations

import json
import math
import socket

import numpy as np
import pytest

from skinloc.geometry.mesh import cone_skin
from skinloc.live.core import Contact
from skinloc.live.sinks import CallbackSink, SkinInfo, make_sink
from skinloc.live.sinks.websocket import WebSocketSink
from tests._helpers import wait_until


def _contact(state: str = "move", k: int = 0) -> Contact:
    return Contact(
        "arm",
        1.0 + k,
        k,
        state,
        (0.01, 0.02, 0.03),
        (0.01, 0.02, 0.031),
        0.8,
        20.0,
        math.nan,
        15.0,
        1,
    )


def _skins() -> list[SkinInfo]:
    mesh = cone_skin()
    return [SkinInfo("arm", np.asarray(mesh.vertices), np.asarray(mesh.faces))]


def test_jsonl_file(tmp_path):
    sink = make_sink(f"jsonl:{tmp_path / 'out.jsonl'}")
    sink.open(_skins())
    for k in range(3):
        sink.emit(_contact(k=k))
    sink.close()
    lines = (tmp_path / "out.jsonl").read_text().splitlines()
    assert [json.loads(ln)["index"] for ln in lines] == [0, 1, 2]


def test_jsonl_stdout(capsys):
    sink = make_sink("jsonl")
    sink.open([])
    sink.emit(_contact("start"))
    sink.close()
    assert json.loads(capsys.readouterr().out)["state"] == "start"


def test_udp_datagrams():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(30.0)  # generous: a busy machine; a lost datagram still fails
    port = rx.getsockname()[1]
    sink = make_sink(f"udp://127.0.0.1:{port}")
    assert sink.address == ("127.0.0.1", port)
    with sink:
        sink.emit(_contact("start"))
        data = rx.recv(65536)
    rx.close()
    assert json.loads(data)["position_m"] == [0.01, 0.02, 0.03]


def test_websocket_hello_then_contacts():
    from websockets.sync.client import connect

    sink = make_sink("ws://127.0.0.1:0")
    assert isinstance(sink, WebSocketSink)
    assert sink.port == 0  # port 0 is kept, not replaced by the default
    sink.open(_skins())
    try:
        assert sink.port > 0 and sink.url == f"ws://127.0.0.1:{sink.port}"
        with connect(sink.url, open_timeout=30) as ws:
            hello = json.loads(ws.recv(timeout=30))
            assert hello["type"] == "hello" and hello["skins"][0]["name"] == "arm"
            assert hello["url"] == sink.url
            assert len(hello["skins"][0]["faces"]) == len(cone_skin().faces)
            # The server learns of the client on its own thread.
            wait_until(lambda: sink.n_clients == 1, "the server to see the client")
            sink.emit(_contact("start"))
            msg = json.loads(ws.recv(timeout=30))
        assert msg["type"] == "contact" and msg["state"] == "start"
    finally:
        sink.close()
    assert sink._thread is None


def test_port_zero_means_any_free_port_for_every_server_sink(tmp_path):
    """``:0`` used to become the default port (a falsy-zero test), so two sinks collided."""
    specs = ["ws://127.0.0.1:0", "ws://127.0.0.1:0", "foxglove://127.0.0.1:0", "foxglove://:0"]
    sinks = [make_sink(s) for s in specs]
    assert [s.port for s in sinks] == [0, 0, 0, 0]
    try:
        for sink in sinks:
            sink.open(_skins())
        ports = [s.port for s in sinks]
        assert all(p > 0 for p in ports) and len(set(ports)) == len(ports)
        assert [s.url for s in sinks] == [f"ws://127.0.0.1:{p}" for p in ports]
    finally:
        for sink in sinks:
            sink.close()
    with pytest.raises(ValueError, match="1-65535"):
        make_sink("udp://127.0.0.1:0")  # datagrams need a real destination port


def test_default_ports_differ_from_the_app():
    """``skinloc app`` serves on 8765; the sinks' defaults must not take it."""
    import typer.main

    from skinloc.cli.main import app

    command = typer.main.get_command(app).commands["app"]
    app_port = next(p.default for p in command.params if p.name == "port")
    ws, fox, udp = make_sink("ws://127.0.0.1"), make_sink("foxglove://"), make_sink("udp://")
    assert ws.port == 8767 and fox.port == 8766 and udp.address[1] == 9870
    assert app_port not in (ws.port, fox.port)


def test_websocket_port_in_use_is_one_clear_error():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        sink = make_sink(f"ws://127.0.0.1:{port}")
        with pytest.raises(OSError, match=f"cannot listen on 127.0.0.1:{port}"):
            sink.open(_skins())
    assert sink._thread is None and sink._sock is None
    with pytest.raises(ValueError, match="0-65535"):
        make_sink("ws://127.0.0.1:70000")  # any-port-ok: an invalid port, never bound
    with pytest.raises(ValueError, match="0 \\(any free port\\) or 1-65535"):
        WebSocketSink(port=-1)


def test_foxglove_live_and_mcap(tmp_path):
    path = tmp_path / "run.mcap"
    sink = make_sink(f"foxglove://127.0.0.1:0?mcap={path}")
    sink.open(_skins())
    assert sink.port > 0
    for k in range(5):
        sink.emit(_contact("move", k))
    sink.emit(_contact("end", 5))
    sink.close()
    data = path.read_bytes()
    assert data[:8] == b"\x89MCAP0\r\n" and data[-8:] == b"\x89MCAP0\r\n"
    for topic in (b"/skinloc/scene", b"/skinloc/contacts", b"/skinloc/arm/contact"):
        assert topic in data


def test_mcap_only(tmp_path):
    sink = make_sink(f"mcap:{tmp_path / 'x.mcap'}")
    sink.open(_skins())
    sink.emit(_contact())
    sink.close()
    assert (tmp_path / "x.mcap").stat().st_size > 1000


def test_lsl_outlet():
    pylsl = pytest.importorskip("pylsl")
    sink = make_sink("lsl:skinloc-test")
    sink.open(_skins())
    sink.emit(_contact())
    outlet = sink._outlets["arm"]
    info = outlet.get_info()
    assert info.name() == "skinloc-test-arm" and info.channel_count() == 11  # K = 1
    assert info.type() == "Contact" and pylsl is not None
    sink.close()


# ---------------------------------------------------------------------------- several contacts


def _frame_contacts() -> list[Contact]:
    """One frame, two fingers: slot 0 (track 4) moves, slot 2 (track 7) starts."""
    a = _contact("move", 3)
    a.track_id, a.slot, a.strength = 4, 0, 120.0
    b = _contact("start", 3)
    b.position_m, b.track_id, b.slot = (0.04, 0.05, 0.06), 7, 2
    return [a, b]


GESTURE = {
    "event": "gesture",
    "skin": "arm",
    "kind": "swipe",
    "direction": "up",
    "start_s": 1.0,
    "end_s": 1.3,
    "timestamp_s": 1.3,
    "track_ids": [7],
    "path_m": [[0.0, 0.0, 0.0], [0.0, 0.04, 0.0]],
    "speed_m_s": 0.13,
    "confidence": 0.55,
}


def _check_lines(lines: list[dict]) -> None:
    contacts = [d for d in lines if d.get("event") != "gesture"]
    gestures = [d for d in lines if d.get("event") == "gesture"]
    assert [(d["track_id"], d["slot"], d["state"]) for d in contacts] == [
        (4, 0, "move"),
        (7, 2, "start"),
    ]
    assert contacts[0]["strength"] == 120.0 and contacts[1]["strength"] is None  # nan
    assert len(gestures) == 1
    g = gestures[0]
    assert {k: g[k] for k in GESTURE} == GESTURE


def test_jsonl_carries_every_contact_and_gesture_lines(tmp_path):
    sink = make_sink(f"jsonl:{tmp_path / 'out.jsonl'}")
    sink.open(_skins())
    sink.emit_contacts("arm", 4.0, _frame_contacts())
    sink.emit_gesture("arm", 4.0, dict(GESTURE, speed_m_s=0.13))
    sink.emit_gesture("arm", 4.1, {"kind": "tap", "bad": math.nan})  # nan -> null, keys set
    sink.close()
    lines = [json.loads(ln) for ln in (tmp_path / "out.jsonl").read_text().splitlines()]
    _check_lines(lines[:3])
    assert lines[3] == {"kind": "tap", "bad": None, "event": "gesture", "skin": "arm"}


def test_udp_carries_every_contact_and_gestures():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(30.0)
    sink = make_sink(f"udp://127.0.0.1:{rx.getsockname()[1]}")
    with sink:
        sink.emit_contacts("arm", 4.0, _frame_contacts())
        sink.emit_gesture("arm", 4.0, GESTURE)
        lines = [json.loads(rx.recv(65536)) for _ in range(3)]
    rx.close()
    _check_lines(lines)


def test_websocket_carries_every_contact_and_gestures():
    from websockets.sync.client import connect

    sink = make_sink("ws://127.0.0.1:0")
    sink.open(_skins())
    try:
        with connect(sink.url, open_timeout=30) as ws:
            json.loads(ws.recv(timeout=30))  # hello
            wait_until(lambda: sink.n_clients == 1, "the server to see the client")
            sink.emit_contacts("arm", 4.0, _frame_contacts())
            sink.emit_gesture("arm", 4.0, GESTURE)
            msgs = [json.loads(ws.recv(timeout=30)) for _ in range(3)]
    finally:
        sink.close()
    assert [m["type"] for m in msgs] == ["contact", "contact", "gesture"]
    _check_lines(msgs)


def test_foxglove_draws_a_sphere_per_track_and_logs_gestures(tmp_path):
    from mcap.reader import make_reader

    path = tmp_path / "multi.mcap"
    sink = make_sink(f"mcap:{path}")
    sink.open(_skins())
    sink.emit_contacts("arm", 4.0, _frame_contacts())
    end = _frame_contacts()[1]
    end.state = "end"
    sink.emit_contacts("arm", 4.01, [end])
    sink.emit_gesture("arm", 4.01, GESTURE)
    sink.close()
    by_topic: dict[str, list[bytes]] = {}
    with path.open("rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages():
            by_topic.setdefault(channel.topic, []).append(message.data)
    scene = by_topic["/skinloc/scene"]
    assert any(b"arm/slot0" in m and b"arm/slot2" in m for m in scene)  # both in one update
    assert b"arm/slot2" in scene[-1]  # the lifted finger's sphere is deleted
    assert len(by_topic["/skinloc/contacts"]) == 3
    assert b"swipe up (tracks 7, confidence 0.55)" in by_topic["/skinloc/gestures"][0]
    event = json.loads(by_topic["/skinloc/gesture_events"][0])
    assert event["kind"] == "swipe" and event["confidence"] == 0.55


def test_lsl_lays_out_k_slots_and_sends_gestures_as_markers():
    pytest.importorskip("pylsl")
    from skinloc.live.sinks.lsl import lsl_channels

    sink = make_sink("lsl:skinloc-multi")
    sink.open([SkinInfo("arm", max_contacts=3)])
    try:
        info = sink._outlets["arm"].get_info()
        assert info.channel_count() == 3 + 8 * 3 == len(lsl_channels(3))
        assert sink._markers["arm"].get_info().type() == "Markers"
        pushed = []

        class Capture:
            def push_sample(self, sample):
                pushed.append(sample)

        sink._outlets["arm"] = sink._markers["arm"] = Capture()
        sink.emit_contacts("arm", 4.0, _frame_contacts())
        sink.emit_gesture("arm", 4.0, GESTURE)
    finally:
        sink.close()
    sample = dict(zip(lsl_channels(3), pushed[0], strict=True))
    assert sample["s0_track_id"] == 4 and sample["s0_state"] == 2 and sample["s0_strength"] == 120
    assert sample["s2_track_id"] == 7 and sample["s2_x_m"] == 0.04 and sample["s2_state"] == 1
    assert all(math.isnan(v) for k, v in sample.items() if k.startswith("s1_"))  # empty slot
    assert sample["touch_id"] == 1
    assert json.loads(pushed[1][0])["kind"] == "swipe"
    assert json.loads(pushed[1][0])["confidence"] == 0.55


def test_make_sink_errors_and_callback():
    with pytest.raises(ValueError, match="unknown sink"):
        make_sink("carrier-pigeon://x")
    with pytest.raises(ValueError, match="needs a file"):
        make_sink("mcap:")
    with pytest.raises(ValueError, match="port"):
        make_sink("udp://127.0.0.1:99999")  # any-port-ok: an invalid port, never bound
    got = []
    sink = make_sink(CallbackSink(got.append))
    sink.emit(_contact())
    assert len(got) == 1


def test_the_registry_names_the_files_a_spec_writes():
    """What ``skinloc run`` checks before it starts: the files, as each sink's entry says."""
    from skinloc.live.sinks.base import register_sink, sink_files, unregister_sink

    assert sink_files("jsonl:out.jsonl") == ["out.jsonl"]
    assert sink_files("mcap:run.mcap") == sink_files("mcap-ros2:run.mcap") == ["run.mcap"]
    assert sink_files("foxglove://127.0.0.1:0?mcap=a.mcap&live=1") == ["a.mcap"]
    for spec in ("jsonl", "jsonl:-", "jsonl:", "ws://127.0.0.1:0?mcap=a.mcap", "lsl:skin"):
        assert sink_files(spec) == [], spec
    assert sink_files("nosuch:x") == []  # make_sink refuses it, with the known forms
    register_sink("toyname", CallbackSink, form="toyname:NAME")
    register_sink("toyfile", CallbackSink, form="toyfile:FILE", file_argument=True)
    try:  # a sink's files are what its entry declares
        assert sink_files("toyname:x") == [] and sink_files("toyfile:x") == ["x"]
    finally:
        unregister_sink("toyname")
        unregister_sink("toyfile")


def test_check_sink_refuses_an_unknown_sink_or_a_missing_extra_up_front(monkeypatch):
    import sys

    from skinloc.errors import MissingExtraError
    from skinloc.live.sinks.base import check_sink

    check_sink("jsonl:out.jsonl")  # nothing to say, and nothing written
    with pytest.raises(ValueError, match="unknown sink 'bogus'"):
        check_sink("bogus")
    monkeypatch.setitem(sys.modules, "pylsl", None)  # as if not installed
    with pytest.raises(MissingExtraError, match=r"pip install 'skinloc\[live\]'"):
        check_sink("lsl:skin")
