"""The records between the ROS 2 sink and its publisher process: what goes in comes out."""

import math
import pickle

import numpy as np
import pytest

from skinloc.live.contact import Contact
from skinloc.live.sinks.base import SkinInfo
from skinloc.live.sinks.ros2.records import (
    FRAME,
    GESTURE,
    MATCHED,
    SKINS,
    SYNC,
    RecordReader,
    pack_frame,
    pack_gesture,
    pack_matched,
    pack_skins,
    pack_sync,
)


def _c(state, pos, track=-1, slot=-1, strength=math.nan, skin="arm"):
    return Contact(skin, 12.5, 7, state, pos, pos, 0.8, 21.0, 1.5, 30.0, 3, track, slot, strength)


def test_every_record_comes_back_in_order_whatever_the_chunks():
    skins = [SkinInfo("arm", np.zeros((3, 3)), np.array([[0, 1, 2]]), n_tx=8, n_rx=8)]
    frame = [_c("start", (0.01, -0.02, 0.03), 4, 0, 120.0), _c("end", (math.nan,) * 3, 2, 1)]
    event = {"kind": "swipe", "direction": "up", "path_m": [[0.0, 0.1, 0.2]] * 300}
    stream = (
        pack_skins(skins)
        + pack_frame(0, 12.5, 99.0, frame)
        + pack_frame(0, 12.51, 99.01, [])
        + pack_gesture(0, 12.6, 99.1, event)
        + pack_sync(42)
    )
    assert len(pack_gesture(0, 12.6, 99.1, event)) > 4096  # a long swipe: over PIPE_BUF
    for step in (1, 7, 4096, len(stream)):  # records cut anywhere arrive whole
        reader = RecordReader()
        got = []
        for i in range(0, len(stream), step):
            got += list(reader.feed(stream[i : i + step]))
        assert [k for k, _ in got] == [SKINS, FRAME, FRAME, GESTURE, SYNC]
        assert got[0][1][0].name == "arm" and reader.names == ["arm"]
        skin, t, emitted, contacts = got[1][1]
        assert (skin, t, emitted) == (0, 12.5, 99.0)
        a, b = contacts
        assert a.skin == "arm" and a.state == "start" and a.position_m == (0.01, -0.02, 0.03)
        assert (a.track_id, a.slot, a.strength, a.signal_z, a.touch_id) == (4, 0, 120.0, 21.0, 3)
        assert b.state == "end" and math.isnan(b.position_m[0]) and math.isnan(b.strength)
        assert got[2][1][3] == []
        assert got[3][1][3] == event
        assert got[4][1] == 42


def test_a_frame_record_fits_an_atomic_pipe_write():
    contacts = [_c("move", (0.0, 0.0, 0.0), k, k) for k in range(3)]
    assert len(pack_frame(65535, 0.0, 0.0, contacts)) < 512  # PIPE_BUF is 512 on macOS


def test_a_corrupt_stream_is_an_error_not_a_hang():
    with pytest.raises(ValueError, match="unknown record kind"):
        list(RecordReader().feed(b"\x05\x00\x00\x00\x09"))
    with pytest.raises(ValueError, match="record length"):
        list(RecordReader().feed(b"\x01\x00\x00\x00\x01"))


def test_skins_records_number_skins_in_order():
    reader = RecordReader()
    list(reader.feed(pack_skins([SkinInfo("a")]) + pack_skins([SkinInfo("b"), SkinInfo("c")])))
    assert reader.names == ["a", "b", "c"]
    ((kind, (skin, *_)),) = reader.feed(pack_frame(2, 0.0, 0.0, [_c("move", (0, 0, 0), skin="c")]))
    assert kind == FRAME and reader.names[skin] == "c"
    assert pickle.loads(pack_skins([SkinInfo("d")])[5:])[0].name == "d"


def test_matched_records_carry_the_topic():
    ((kind, value),) = RecordReader().feed(pack_matched(9, "/skinloc/arm/contacts"))
    assert kind == MATCHED and value == (9, "/skinloc/arm/contacts")
