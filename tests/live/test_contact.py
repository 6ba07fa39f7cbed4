"""One palette of fingers: the app's page, the ROS 2 markers and the Foxglove scene agree."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from skinloc.geometry.mesh import cone_skin
from skinloc.live.contact import TRACK_COLOURS, Contact, colour_index, track_colour
from skinloc.live.sinks import SkinInfo, make_sink


def _finger(track_id: int, slot: int, state: str = "move") -> Contact:
    c = Contact("arm", 1.0, 1, state, (0.01, 0.02, 0.03), (0.01, 0.02, 0.03), 0.8, 20.0, 1.0, 1, 1)
    c.track_id, c.slot = track_id, slot
    return c


FINGERS = [_finger(n, n % 3) for n in range(9)] + [_finger(n, -1) for n in range(9)]


def _rgb(hex_: str) -> tuple[float, float, float]:
    return tuple(int(hex_[i : i + 2], 16) / 255 for i in (1, 3, 5))


def test_ros2_markers_foxglove_spheres_and_the_page_give_a_finger_one_colour(tmp_path, monkeypatch):
    pytest.importorskip("mcap_ros2")
    messages = pytest.importorskip("foxglove.messages")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    mesh = cone_skin()
    skins = [SkinInfo("arm", np.asarray(mesh.vertices), np.asarray(mesh.faces), max_contacts=3)]
    # ROS 2 (a bag: the same messages the DDS sink writes)
    bag = tmp_path / "run.mcap"
    ros = make_sink(f"mcap-ros2:{bag}")
    ros.open(skins)
    # Foxglove: the colours of the spheres the sink draws (opaque SDK objects: record them)
    fox = make_sink(f"mcap:{tmp_path / 'fox.mcap'}")
    fox.open(skins)
    real_colour, spheres = messages.Color, []

    def colour(**rgba):
        if rgba["a"] == 1.0:  # the contact spheres (the mesh is translucent)
            spheres.append((rgba["r"], rgba["g"], rgba["b"]))
        return real_colour(**rgba)

    monkeypatch.setattr(messages, "Color", colour)
    for k, c in enumerate(FINGERS):
        c.timestamp_s = c.index = 1.0 + 0.01 * k
        ros.emit_contacts("arm", c.timestamp_s, [c])
        fox.emit_contacts("arm", c.timestamp_s, [c])
    ros.close()
    fox.close()
    markers = []
    with bag.open("rb") as fh:
        for _, channel, _, msg in make_reader(
            fh, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            if channel.topic == "/skinloc/arm/markers":
                markers.append(msg.markers[0])
    assert len(markers) == len(spheres) == len(FINGERS)
    # the page: the palette it is given, indexed by the colour the server sends with a contact
    page = _page_palette(tmp_path)
    assert page == list(TRACK_COLOURS)
    for c, mk, sp in zip(FINGERS, markers, spheres, strict=True):
        want = track_colour(c)
        assert (mk.color.r, mk.color.g, mk.color.b) == pytest.approx(want)
        assert sp == pytest.approx(want)
        assert _rgb(page[colour_index(c) % len(page)]) == pytest.approx(want)
    # fingers down at once never share a colour
    assert len({track_colour(_finger(7, s)) for s in range(3)}) == 3


def _page_palette(tmp_path: Path) -> list[str]:
    """The palette the app writes into its page, and the colour index of its live messages."""
    pytest.importorskip("fastapi")
    from fastapi.testclient import TestClient

    import skinloc.app
    from skinloc.app.hub import Hub
    from skinloc.app.live_io import TabSink
    from skinloc.app.server import create_app
    from skinloc.app.workspace import AppConfig

    with TestClient(create_app(AppConfig(data_dir=tmp_path / "app"))) as client:
        page = client.get("/").text
    palette = re.search(r'<meta name="skinloc-track-colours" content="([^"]*)">', page).group(1)
    sent = []
    hub = Hub()
    hub.publish = sent.append  # type: ignore[method-assign]
    TabSink(hub).emit_contacts("arm", 1.0, FINGERS)
    assert [c["colour"] for c in sent[0]["contacts"]] == [colour_index(c) for c in FINGERS]
    viewer = (Path(skinloc.app.__file__).parent / "static" / "viewer.js").read_text()
    assert not re.search(r"TRACK_COLOURS = \[", viewer)  # no palette of its own
    return palette.split(" ")


def test_colour_index_uses_the_slot_then_the_track_then_the_touch():
    assert colour_index(_finger(9, 2)) == 2
    assert colour_index(_finger(9, -1)) == 9
    c = _finger(-1, -1)
    c.touch_id = 4
    assert colour_index(c) == 3
    assert all(not math.isnan(v) for v in track_colour(c))
