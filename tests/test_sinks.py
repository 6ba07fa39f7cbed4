"""Sinks: JSON lines, UDP, WebSocket, Foxglove (live and MCAP), LSL (ROS 2: test_ros2.py)."""

from __future__ import annotations

import json
import math
import socket

import numpy as np
import pytest

from skinloc.geometry import cone_skin
from skinloc.pipeline import Contact
from skinloc.sinks import CallbackSink, SkinInfo, make_sink


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
    rx.settimeout(5.0)
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
    sink.open(_skins())
    try:
        with connect(sink.url, open_timeout=5) as ws:
            hello = json.loads(ws.recv(timeout=5))
            assert hello["type"] == "hello" and hello["skins"][0]["name"] == "arm"
            assert len(hello["skins"][0]["faces"]) == len(cone_skin().faces)
            for _ in range(100):  # the server learns of the client asynchronously
                if sink.n_clients:
                    break
                import time

                time.sleep(0.02)
            sink.emit(_contact("start"))
            msg = json.loads(ws.recv(timeout=5))
        assert msg["type"] == "contact" and msg["state"] == "start"
    finally:
        sink.close()
    assert sink._thread is None


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
    assert info.name() == "skinloc-test-arm" and info.channel_count() == 9
    assert info.type() == "Contact" and pylsl is not None
    sink.close()


def test_make_sink_errors_and_callback():
    with pytest.raises(ValueError, match="unknown sink"):
        make_sink("carrier-pigeon://x")
    with pytest.raises(ValueError, match="needs a file"):
        make_sink("mcap:")
    with pytest.raises(ValueError, match="port"):
        make_sink("udp://127.0.0.1:99999")
    got = []
    sink = make_sink(CallbackSink(got.append))
    sink.emit(_contact())
    assert len(got) == 1
