"""ROS 2 for real: the DDS sink read by an independent DDS subscriber, the bag by mcap-ros2-support.

The subscriber's message types are written here again, from the ROS 2 ``.msg`` files, not
imported from skinloc: a layout or naming mistake in ``skinloc.ros2.msgs`` shows up as
missing or wrong messages. Cyclone is kept on the loopback interface, unicast, on a domain
picked per test run, so parallel runs and the network do not interfere.
"""

# No ``from __future__ import annotations``: cyclonedds reads the field types at class creation.

import json
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np
import pytest
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float32, float64, int32, sequence, uint8, uint32

from skinloc.geometry.mesh import cone_skin
from skinloc.live.core import Contact
from skinloc.live.sinks import SkinInfo, make_sink
from tests._helpers import scaled, wait_until

# ----------------------------------------------------------------------------- the subscriber's
# own ROS 2 types (ROS 2 Humble .msg files, DDS names as rmw_cyclonedds registers them)


@dataclass
class T(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Hdr(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: T = field(default_factory=T)
    frame_id: str = ""


@dataclass
class P(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Q(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 0.0


@dataclass
class V3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class PS(IdlStruct, typename="geometry_msgs::msg::dds_::PointStamped_"):
    header: Hdr = field(default_factory=Hdr)
    point: P = field(default_factory=P)


@dataclass
class Po(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: P = field(default_factory=P)
    orientation: Q = field(default_factory=Q)


@dataclass
class PA(IdlStruct, typename="geometry_msgs::msg::dds_::PoseArray_"):
    header: Hdr = field(default_factory=Hdr)
    poses: sequence[Po] = field(default_factory=list)


@dataclass
class Str(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@dataclass
class Tf(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: V3 = field(default_factory=V3)
    rotation: Q = field(default_factory=Q)


@dataclass
class TfS(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Hdr = field(default_factory=Hdr)
    child_frame_id: str = ""
    transform: Tf = field(default_factory=Tf)


@dataclass
class TfM(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TfS] = field(default_factory=list)


@dataclass
class Col(IdlStruct, typename="std_msgs::msg::dds_::ColorRGBA_"):
    r: float32 = 0.0
    g: float32 = 0.0
    b: float32 = 0.0
    a: float32 = 0.0


@dataclass
class Dur(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class CImg(IdlStruct, typename="sensor_msgs::msg::dds_::CompressedImage_"):
    header: Hdr = field(default_factory=Hdr)
    format: str = ""
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class UV(IdlStruct, typename="visualization_msgs::msg::dds_::UVCoordinate_"):
    u: float32 = 0.0
    v: float32 = 0.0


@dataclass
class MF(IdlStruct, typename="visualization_msgs::msg::dds_::MeshFile_"):
    filename: str = ""
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class Mk(IdlStruct, typename="visualization_msgs::msg::dds_::Marker_"):
    header: Hdr = field(default_factory=Hdr)
    ns: str = ""
    id: int32 = 0
    type: int32 = 0
    action: int32 = 0
    pose: Po = field(default_factory=Po)
    scale: V3 = field(default_factory=V3)
    color: Col = field(default_factory=Col)
    lifetime: Dur = field(default_factory=Dur)
    frame_locked: bool = False
    points: sequence[P] = field(default_factory=list)
    colors: sequence[Col] = field(default_factory=list)
    texture_resource: str = ""
    texture: CImg = field(default_factory=CImg)
    uv_coordinates: sequence[UV] = field(default_factory=list)
    text: str = ""
    mesh_resource: str = ""
    mesh_file: MF = field(default_factory=MF)
    mesh_use_embedded_materials: bool = False


@dataclass
class MkA(IdlStruct, typename="visualization_msgs::msg::dds_::MarkerArray_"):
    markers: sequence[Mk] = field(default_factory=list)


# ----------------------------------------------------------------------------- helpers

_LOOPBACK = (
    "<CycloneDDS><Domain Id='any'><General><Interfaces><NetworkInterface name='lo'/>"
    "</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery>"
    "<ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>"
    "<Peers><Peer address='127.0.0.1'/></Peers></Discovery></Domain></CycloneDDS>"
)


@pytest.fixture
def domain(monkeypatch, ros_domain):
    """A DDS domain of this test alone, on loopback (plain DDS, rclpy installed or not)."""
    monkeypatch.setenv("CYCLONEDDS_URI", _LOOPBACK)
    monkeypatch.setenv("SKINLOC_ROS2_BACKEND", "dds")
    return ros_domain


def _contact(state="move", k=0, pos=(0.01, 0.02, 0.03), t0=100.0, skin="arm"):
    return Contact(skin, t0 + 0.01 * k, k, state, pos, pos, 0.8, 20.0, math.nan, 15.0, 1)


def _mc(state, track, slot, pos, t, strength, skin="arm"):
    """One contact of a multi-contact frame (protocol B track id and slot)."""
    return Contact(
        skin, t, 0, state, pos, pos, 0.8, 20.0, math.nan, 15.0, 1,
        track_id=track, slot=slot, strength=strength,
    )  # fmt: skip


A0, B0, A1 = (0.01, 0.02, 0.03), (-0.02, 0.01, 0.04), (0.012, 0.021, 0.03)


def _two_finger_frames(sink, skin="arm"):
    """Track 5 (slot 1) and track 7 (slot 0) land; 7 lifts; then 5 lifts. 10 ms apart."""
    sink.emit_contacts(
        skin,
        100.0,
        [_mc("start", 5, 1, A0, 100.0, 50.0, skin), _mc("start", 7, 0, B0, 100.0, 80.0, skin)],
    )
    sink.emit_contacts(
        skin,
        100.01,
        [_mc("move", 5, 1, A1, 100.01, 90.0, skin), _mc("end", 7, 0, B0, 100.01, 0.0, skin)],
    )
    sink.emit_contacts(skin, 100.02, [_mc("end", 5, 1, A1, 100.02, 0.0, skin)])
    sink.emit_gesture(skin, 100.02, GESTURE)


GESTURE = {
    "event": "gesture", "skin": "arm", "kind": "two_finger_tap", "direction": None,
    "start_s": 100.0, "end_s": 100.02, "timestamp_s": 100.02, "track_ids": [5, 7],
    "confidence": 0.55,
}  # fmt: skip


def _check_two_finger_frames(point, poses, markers, gestures, frame_of, stamp_of):
    """What ``_two_finger_frames`` must publish, whichever reader decoded it."""
    # /contact: the strongest touching contact of each frame that has one
    assert len(point) == 2
    assert [frame_of(m) for m in point] == ["skin/arm"] * 2
    assert (point[0].point.x, point[0].point.y, point[0].point.z) == pytest.approx(B0)
    assert (point[1].point.x, point[1].point.y, point[1].point.z) == pytest.approx(A1)
    # /contacts: every touching contact, by slot (track 7 in slot 0 first)
    assert [len(m.poses) for m in poses] == [2, 1, 0]
    p0 = [(q.position.x, q.position.y, q.position.z) for q in poses[0].poses]
    assert p0 == [pytest.approx(B0), pytest.approx(A0)]
    assert poses[1].poses[0].position.x == pytest.approx(A1[0])
    assert poses[1].poses[0].orientation.w == pytest.approx(1.0)
    stamps = [stamp_of(m) for m in poses]
    assert stamps[1] - stamps[0] == pytest.approx(0.01, abs=2e-6)
    assert stamps[2] - stamps[0] == pytest.approx(0.02, abs=2e-6)
    # /markers: a sphere per track (id = track id, colour by slot), DELETE when it ends
    assert len(markers) == 3
    f0 = {m.id: m for m in markers[0].markers}
    assert set(f0) == {5, 7}
    assert all(m.type == 2 and m.action == 0 and m.ns == "skinloc/contacts" for m in f0.values())
    assert all(frame_of(m) == "skin/arm" and m.scale.x == pytest.approx(0.01) for m in f0.values())
    assert (f0[5].pose.position.x, f0[7].pose.position.z) == pytest.approx((A0[0], B0[2]))
    assert (f0[5].color.r, f0[5].color.g) != (f0[7].color.r, f0[7].color.g)  # slot colours
    assert f0[5].color.a > 0.5
    assert stamp_of(markers[0].markers[0]) == pytest.approx(stamps[0], abs=2e-6)
    f1 = sorted((m.id, m.action) for m in markers[1].markers)
    assert f1 == [(5, 0), (7, 2)]
    assert [(m.id, m.action) for m in markers[2].markers] == [(5, 2)]
    # /gestures: the event as JSON, with the stamp of the other topics
    (g,) = gestures
    event = json.loads(g.data)
    assert event["kind"] == "two_finger_tap" and event["track_ids"] == [5, 7]
    assert event["confidence"] == pytest.approx(0.55)  # the count's confidence is carried
    assert event["skin"] == "arm" and event["stamp"] == pytest.approx(stamps[2], abs=2e-6)


def _skins(**mount):
    mesh = cone_skin()
    return [SkinInfo("arm", mesh.vertices, mesh.faces, n_tx=8, n_rx=8, **mount)]


class _Sub:
    """A DDS reader of one ROS 2 topic with ROS 2's naming and QoS."""

    def __init__(self, dp, topic, cls, latched=False):
        from cyclonedds.core import Policy, Qos
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        qos = Qos(
            Policy.Reliability.Reliable(duration(milliseconds=100)),
            Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile,
            Policy.History.KeepLast(100),
        )
        self.reader = DataReader(dp, Topic(dp, "rt" + topic, cls, qos=qos), qos=qos)
        self.topic = topic
        self.got: list = []

    def take(self):
        self.got += self.reader.take(N=100)
        return self.got


def _matched(sink, sub):
    """Whether the sink's writer (in its publisher process) and the subscriber matched."""
    return sink.matched(sub.topic) > 0 and len(sub.reader.get_matched_publications()) > 0


# ----------------------------------------------------------------------------- the DDS sink


def test_dds_sink_received_by_an_independent_subscriber(domain):
    from cyclonedds.domain import DomainParticipant

    sink = make_sink("ros2:skinloc_test")
    sink.domain_id = domain
    sink.backend = "dds"  # a ROS install on the test machine must not change what is tested
    mount = {"parent_frame": "fr3_link7", "translation_m": (0.0, 0.0, 0.107)}
    mount["rotation_xyzw"] = (0.0, 0.0, math.sin(0.3), math.cos(0.3))
    sink.open(_skins(**mount))
    dp = DomainParticipant(domain)
    try:
        # the latched topics were written before the subscriber existed
        mesh = _Sub(dp, "/skinloc/arm/mesh", Mk, latched=True)
        tf = _Sub(dp, "/tf_static", TfM, latched=True)
        point = _Sub(dp, "/skinloc/arm/contact", PS)
        poses = _Sub(dp, "/skinloc/arm/contacts", PA)
        gest = _Sub(dp, "/skinloc/arm/gestures", Str)
        marks = _Sub(dp, "/skinloc/arm/markers", MkA)
        for sub in (point, poses, gest, marks):
            wait_until(lambda s=sub: _matched(sink, s), f"a match on {sub.topic}")
        # the single-contact path: one emit per frame, no track id
        sink.emit(_contact("start", 0, (0.01, 0.02, 0.03)))
        sink.emit(_contact("move", 1, (0.011, 0.021, 0.031)))
        sink.emit(_contact("end", 2, (0.011, 0.021, 0.031)))
        sink.emit_gesture("arm", 100.05, {**GESTURE, "kind": "tap"})
        wait_until(lambda: len(point.take()) >= 2 and len(poses.take()) >= 3, "contacts")
        wait_until(lambda: gest.take() and mesh.take() and tf.take(), "gesture, mesh, tf")
        wait_until(lambda: len(marks.take()) >= 3, "3 marker arrays")
    finally:
        sink.close()
    # strongest contact: only while touching
    assert len(point.got) == 2
    p0, p1 = point.got
    assert p0.header.frame_id == "skin/arm"
    assert (p0.point.x, p0.point.y, p0.point.z) == pytest.approx((0.01, 0.02, 0.03))
    assert (p1.point.x, p1.point.y, p1.point.z) == pytest.approx((0.011, 0.021, 0.031))
    stamp = [s.header.stamp.sec + s.header.stamp.nanosec * 1e-9 for s in point.got]
    assert stamp[1] - stamp[0] == pytest.approx(0.01, abs=2e-6)  # the frames' own interval
    assert abs(stamp[0] - time.time()) < 600  # wall clock, not the frames' clock
    # every contact of a frame; the touch's end is an empty array
    assert [len(m.poses) for m in poses.got] == [1, 1, 0]
    assert poses.got[0].header.frame_id == "skin/arm"
    o = poses.got[1].poses[0]
    assert (o.position.x, o.orientation.w) == pytest.approx((0.011, 1.0))
    event = json.loads(gest.got[0].data)
    assert event["kind"] == "tap" and event["skin"] == "arm" and event["stamp"] > 1e9
    # without a track id the sphere's id is the touch number; the end deletes it
    assert [[(m.id, m.action) for m in a.markers] for a in marks.got] == [
        [(1, 0)],
        [(1, 0)],
        [(1, 2)],
    ]
    assert sink.stats()["dropped"] == 0 and sink.stats()["sent"] == 4
    # the skin mesh as a triangle list, in the skin frame
    m = mesh.got[-1]
    assert m.header.frame_id == "skin/arm" and m.type == 11 and m.action == 0
    assert len(m.points) == 3 * len(cone_skin().faces)
    # the skin frame on the robot
    (ts,) = tf.got[-1].transforms
    assert ts.header.frame_id == "fr3_link7" and ts.child_frame_id == "skin/arm"
    assert ts.transform.translation.z == pytest.approx(0.107)
    assert ts.transform.rotation.z == pytest.approx(math.sin(0.3))


def test_dds_sink_publishes_multi_contact_frames(domain):
    """Two fingers through ``emit_contacts``: contact, contacts, markers and gestures."""
    from cyclonedds.domain import DomainParticipant

    from skinloc.live.sinks.ros2.sink import Ros2Sink

    sink = Ros2Sink(domain_id=domain, backend="dds")
    sink.open(_skins())
    dp = DomainParticipant(domain)
    try:
        subs = {
            "contact": _Sub(dp, "/skinloc/arm/contact", PS),
            "contacts": _Sub(dp, "/skinloc/arm/contacts", PA),
            "markers": _Sub(dp, "/skinloc/arm/markers", MkA),
            "gestures": _Sub(dp, "/skinloc/arm/gestures", Str),
        }
        for name, sub in subs.items():
            wait_until(lambda s=sub: _matched(sink, s), f"a match on /skinloc/arm/{name}")
        _two_finger_frames(sink)
        want = {"contact": 2, "contacts": 3, "markers": 3, "gestures": 1}
        wait_until(lambda: all(len(subs[k].take()) >= n for k, n in want.items()), str(want))
    finally:
        sink.close()
    _check_two_finger_frames(
        subs["contact"].got,
        subs["contacts"].got,
        subs["markers"].got,
        subs["gestures"].got,
        frame_of=lambda m: m.header.frame_id,
        stamp_of=lambda m: m.header.stamp.sec + m.header.stamp.nanosec * 1e-9,
    )
    assert abs(subs["contacts"].got[0].header.stamp.sec - time.time()) < 600  # wall clock


def _pipe_writes(monkeypatch, sink):
    """The sizes of the sink's writes to its publisher's pipe, as they happen."""
    from skinloc.live.sinks.ros2 import sink as ros2_sink

    writes: list[int] = []
    write = os.write

    def spy(fd, data):
        n = write(fd, data)
        if fd == sink._w:
            writes.append(n)
        return n

    monkeypatch.setattr(ros2_sink.os, "write", spy)
    return writes


def test_a_turns_records_go_to_the_publisher_in_one_write_and_arrive_the_same(domain, monkeypatch):
    """Once its owner ends turns, a turn's frames are one pipe write; subscribers see no change."""
    from cyclonedds.domain import DomainParticipant

    from skinloc.live.sinks.ros2 import sink as ros2_sink

    monkeypatch.setattr(ros2_sink, "_BATCH_WAIT_S", 3600.0)  # a stall here must not cut the turn
    sink = ros2_sink.Ros2Sink(domain_id=domain, backend="dds")
    sink.open(_skins())
    dp = DomainParticipant(domain)
    try:
        subs = {
            "contact": _Sub(dp, "/skinloc/arm/contact", PS),
            "contacts": _Sub(dp, "/skinloc/arm/contacts", PA),
            "markers": _Sub(dp, "/skinloc/arm/markers", MkA),
            "gestures": _Sub(dp, "/skinloc/arm/gestures", Str),
        }
        for name, sub in subs.items():
            wait_until(lambda s=sub: _matched(sink, s), f"a match on /skinloc/arm/{name}")
        writes = _pipe_writes(monkeypatch, sink)
        sink.end_turn()
        _two_finger_frames(sink)  # three frames and a gesture in one turn
        assert writes == []  # gathered
        sink.end_turn()
        assert len(writes) == 1 and writes[0] > 3 * 100
        sink.end_turn()  # nothing gathered: no write
        assert len(writes) == 1
        want = {"contact": 2, "contacts": 3, "markers": 3, "gestures": 1}
        wait_until(lambda: all(len(subs[k].take()) >= n for k, n in want.items()), str(want))
    finally:
        sink.close()
    _check_two_finger_frames(
        subs["contact"].got,
        subs["contacts"].got,
        subs["markers"].got,
        subs["gestures"].got,
        frame_of=lambda m: m.header.frame_id,
        stamp_of=lambda m: m.header.stamp.sec + m.header.stamp.nanosec * 1e-9,
    )
    assert sink.stats()["sent"] == 4 and sink.n_dropped == 0


def test_a_long_turn_is_cut_into_atomic_writes_and_a_sync_sends_what_is_gathered(
    domain, monkeypatch
):
    """A turn of many frames: whole records, no write over PIPE_BUF; stats() sends the rest."""
    from skinloc.live.sinks.ros2 import sink as ros2_sink

    monkeypatch.setattr(ros2_sink, "_BATCH_WAIT_S", 3600.0)  # only the size cuts the turn
    sink = ros2_sink.Ros2Sink(domain_id=domain, backend="dds")
    sink.open([SkinInfo("arm")])
    try:
        writes = _pipe_writes(monkeypatch, sink)
        sink.emit(_contact("move", 0))  # no end_turn yet (a program's own loop): at once
        assert len(writes) == 1
        sink.end_turn()
        for k in range(1, 301):
            sink.emit(_contact("move", k))
        assert 1 + 300 > len(writes) >= 3
        assert all(n <= ros2_sink._PIPE_BUF for n in writes)
        st = sink.stats()  # the rest of the turn goes before the sync: all published
        assert st["sent"] == 301 and st["dropped"] == 0 and st["pending"] == 0
    finally:
        sink.close()


def test_a_record_waits_at_most_the_batch_wait_for_the_end_of_its_turn(domain, monkeypatch):
    """A long turn: the batch goes out with the first record made after its oldest's wait."""
    from skinloc.live.sinks.ros2 import sink as ros2_sink
    from skinloc.live.sinks.ros2.records import pack_frame

    sink = ros2_sink.Ros2Sink(domain_id=domain, backend="dds")
    sink.open([SkinInfo("arm")])
    try:
        writes = _pipe_writes(monkeypatch, sink)
        sink.end_turn()
        t0, wait = 50.0, ros2_sink._BATCH_WAIT_S
        record = pack_frame(0, 1.0, t0, [_contact("move", 0)])
        sink._put(record, False, t0)
        sink._put(record, False, t0 + 0.5 * wait)
        assert writes == []
        sink._put(record, False, t0 + 1.01 * wait)  # the first has waited long enough: all go
        assert writes == [3 * len(record)]
        sink._put(record, False, t0 + 1.6 * wait)  # a new batch, young
        assert len(writes) == 1
        sink.end_turn()
        assert writes == [3 * len(record), len(record)]
        assert sink.stats()["sent"] == 4
    finally:
        sink.close()


def test_only_the_thread_that_ends_turns_gathers_its_records(domain, monkeypatch):
    """A frame emitted on another thread (a program beside the runner) is written at once."""
    import threading

    from skinloc.live.sinks.ros2.sink import Ros2Sink

    sink = Ros2Sink(domain_id=domain, backend="dds")
    sink.open([SkinInfo("arm"), SkinInfo("leg")])
    try:
        writes = _pipe_writes(monkeypatch, sink)
        sink.end_turn()
        sink.emit(_contact("move", 0))  # this thread's turn: gathered
        other = threading.Thread(target=sink.emit, args=(_contact("move", 0, skin="leg"),))
        other.start()
        other.join()
        assert len(writes) == 1  # the other thread's frame, alone
        st = sink.stats()  # the sync sends this thread's turn first
        assert st["sent"] == 2 and st["pending"] == 0 and len(writes) == 3
    finally:
        sink.close()


@pytest.mark.parametrize("turn", [0, 4], ids=["frame-by-frame", "turns-of-4"])
def test_dds_sink_never_blocks_the_pipeline_and_counts_what_it_drops(domain, turn):
    """A stopped publisher: ``emit`` still returns at once; a full pipe drops and counts, frame
    by frame or a loop turn's records at once (``turn`` frames, then ``end_turn``)."""
    import signal

    from skinloc.live.sinks.ros2.sink import Ros2Sink

    sink = Ros2Sink(domain_id=domain, backend="dds", queue_frames=4)  # one page of pipe
    sink.open([SkinInfo("arm")])
    pid = sink.publisher_pid
    os.kill(pid, signal.SIGSTOP)  # the publisher reads nothing while stopped
    try:
        for k in range(2000):
            sink.emit(_contact("move", k, (0.01, 0.02, 0.03)))
            if turn and k % turn == turn - 1:
                sink.end_turn()
        if turn:
            sink.end_turn()
        assert sink.n_put == 2000 and 0 < sink.n_dropped < 2000
    finally:
        os.kill(pid, signal.SIGCONT)
    try:
        assert sink.flush(60.0)
        st = sink.stats()
        assert st["queued"] == 2000 and st["sent"] + st["dropped"] == 2000
        assert st["errors"] == 0 and st["pending"] == 0
        assert st["publish_delay_p99_us"] > 0
    finally:
        sink.close()


def test_dds_sink_reports_a_failed_start_in_one_line(domain, monkeypatch):
    """The publisher's own errors (here: two skins on one topic) are raised by ``open``."""
    from skinloc.live.sinks.ros2.sink import Ros2Sink

    sink = Ros2Sink(domain_id=domain, backend="dds")
    with pytest.raises(ValueError, match="would share the ROS 2 topics"):
        sink.open([SkinInfo("left arm"), SkinInfo("left_arm")])
    assert sink.publisher_pid is None  # the publisher ended; nothing left running
    sink.close()


def test_a_publisher_gone_mid_run_drops_and_says_so_once(domain, caplog):
    import signal

    from skinloc.live.sinks.ros2.sink import Ros2Sink

    sink = Ros2Sink(domain_id=domain, backend="dds")
    sink.open([SkinInfo("arm")])
    os.kill(sink.publisher_pid, signal.SIGKILL)
    sink._proc.wait(30)
    with caplog.at_level("ERROR"):
        for k in range(5):
            sink.emit(_contact("move", k))
    assert sink.n_dropped == 5
    assert sum("publisher process ended" in r.message for r in caplog.records) == 1
    sink.close()  # no error, no wait


def test_dds_sink_is_what_make_sink_builds_and_checks_its_domain(monkeypatch):
    from skinloc.live.sinks.ros2.sink import Ros2Sink

    monkeypatch.setenv("ROS_DOMAIN_ID", "17")
    sink = make_sink("ros2:arm_node")
    assert isinstance(sink, Ros2Sink) and sink.node_name == "arm_node" and sink.domain_id == 17
    monkeypatch.setenv("ROS_DOMAIN_ID", "x")
    with pytest.raises(ValueError, match="ROS_DOMAIN_ID"):
        make_sink("ros2")
    with pytest.raises(ValueError, match="0..232"):
        Ros2Sink(domain_id=300)
    with pytest.raises(ValueError, match="backend"):
        Ros2Sink(backend="zenoh")


def test_encoders_match_the_idl_serializer():
    from skinloc.ros2.cdr import check_encoders
    from skinloc.ros2.msgs import PointStamped, msg_definition

    check_encoders()
    text = msg_definition(PointStamped)
    assert text.startswith("std_msgs/Header header\ngeometry_msgs/Point point\n")
    assert "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec" in text


# ----------------------------------------------------------------------------- the bag


def _read_bag(path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append((schema.name, message, decoded))
    return out


def test_ros2_bag_decodes_with_mcap_ros2_support(tmp_path):
    path = tmp_path / "run.mcap"
    sink = make_sink(f"mcap-ros2:{path}")
    sink.open(_skins(parent_frame="base_link", translation_m=(0.1, 0.0, 0.0)))
    frame = np.arange(64, dtype=np.float32) * 1.5
    sink.emit_frame("arm", frame, 100.0, 7)
    sink.emit(_contact("start", 0))
    sink.emit(_contact("end", 1))
    sink.emit_gesture("arm", 100.01, {"type": "swipe"})
    assert not path.exists()  # written under a temporary name until closed
    sink.close()
    bag = _read_bag(path)
    schema, _, ps = bag["/skinloc/arm/contact"][0]
    assert schema == "geometry_msgs/msg/PointStamped" and ps.header.frame_id == "skin/arm"
    assert (ps.point.x, ps.point.y, ps.point.z) == pytest.approx((0.01, 0.02, 0.03))
    assert [len(d.poses) for _, _, d in bag["/skinloc/arm/contacts"]] == [1, 0]
    schema, msg, img = bag["/skinloc/arm/frames"][0]
    assert schema == "sensor_msgs/msg/Image" and img.encoding == "32FC1"
    assert (img.height, img.width, img.step, msg.sequence) == (8, 8, 32, 7)
    assert np.frombuffer(bytes(img.data), "<f4") == pytest.approx(frame)
    # stamps: the frames' intervals, log time = header stamp
    _, m0, p0 = bag["/skinloc/arm/contacts"][0]
    _, m1, p1 = bag["/skinloc/arm/contacts"][1]
    assert m0.log_time == p0.header.stamp.sec * 10**9 + p0.header.stamp.nanosec
    assert (m1.log_time - m0.log_time) / 1e9 == pytest.approx(0.01, abs=2e-6)
    _, _, mk = bag["/skinloc/arm/mesh"][0]
    assert mk.type == 11 and len(mk.points) == 3 * len(cone_skin().faces)
    _, _, tf = bag["/tf_static"][0]
    assert tf.transforms[0].child_frame_id == "skin/arm"
    assert tf.transforms[0].transform.translation.x == pytest.approx(0.1)
    assert json.loads(bag["/skinloc/arm/gestures"][0][2].data)["type"] == "swipe"
    # the QoS ros2 bag play publishes with: latched topics stay transient local
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        channels = {c.topic: c for c in make_reader(fh).get_summary().channels.values()}
    for topic, durability in (
        ("/tf_static", 1),
        ("/skinloc/arm/mesh", 1),
        ("/skinloc/arm/contact", 2),
    ):
        text = channels[topic].metadata["offered_qos_profiles"]
        lines = [ln.strip() for ln in text.splitlines()]
        assert lines[0] == "- history: 1" and "reliability: 1" in lines
        assert f"durability: {durability}" in lines


def test_ros2_bag_of_multi_contact_frames_decodes(tmp_path):
    path = tmp_path / "two.mcap"
    sink = make_sink(f"mcap-ros2:{path}")
    sink.open(_skins())
    _two_finger_frames(sink)
    sink.close()
    bag = _read_bag(path)
    schemas = {t: v[0][0] for t, v in bag.items()}
    assert schemas["/skinloc/arm/markers"] == "visualization_msgs/msg/MarkerArray"
    assert schemas["/skinloc/arm/contacts"] == "geometry_msgs/msg/PoseArray"

    def decoded(topic):
        return [d for _, _, d in bag.get(topic, [])]

    _check_two_finger_frames(
        decoded("/skinloc/arm/contact"),
        decoded("/skinloc/arm/contacts"),
        decoded("/skinloc/arm/markers"),
        decoded("/skinloc/arm/gestures"),
        frame_of=lambda m: m.header.frame_id,
        stamp_of=lambda m: m.header.stamp.sec + m.header.stamp.nanosec * 1e-9,
    )
    # log time = header stamp, as rosbag2 records
    (_, msg, d), *_ = bag["/skinloc/arm/markers"]
    stamp = d.markers[0].header.stamp
    assert msg.log_time == stamp.sec * 10**9 + stamp.nanosec


def test_ros2_bag_never_overwrites(tmp_path):
    path = tmp_path / "run.mcap"
    path.write_bytes(b"precious")
    sink = make_sink(f"mcap-ros2:{path}")
    with pytest.raises(FileExistsError, match="never overwrites"):
        sink.open(_skins())
    assert path.read_bytes() == b"precious"
    with pytest.raises(ValueError, match="needs a file name"):
        make_sink("mcap-ros2:")


# ----------------------------------------------------------------------------- bag -> replay


def test_frames_recorded_by_the_runner_replay_from_the_bag(tmp_path):
    from skinloc.live.core import PipelineConfig
    from skinloc.live.runner import Pipeline
    from skinloc.live.sinks import ListSink
    from tests._live import model_path, stream_recording

    bag = tmp_path / "run.mcap"
    first, again = ListSink(), ListSink()
    cfg = PipelineConfig(drift_tracking=False)
    with Pipeline(
        model_path("map"), str(stream_recording()), name="arm", realtime=False, config=cfg,
        sinks=[first, f"mcap-ros2:{bag}"],
    ) as p:  # fmt: skip
        for _ in p:
            pass
    frames = _read_bag(bag)["/skinloc/arm/frames"]
    assert len(frames) == 1500
    assert [m.sequence for _, m, _ in frames] == list(range(1500))
    with Pipeline(
        model_path("map"), str(bag), name="arm", realtime=False, config=cfg, sinks=[again]
    ) as p:
        for _ in p:
            pass
    assert p.stats()[0]["frames"] == 1500
    a, b = first.contacts, again.contacts
    assert [c.state for c in a] == [c.state for c in b] and len(a) > 10
    assert [c.index for c in a] == [c.index for c in b]
    assert np.allclose([c.position_m for c in a], [c.position_m for c in b], equal_nan=True)
    assert np.allclose([c.timestamp_s for c in a], [c.timestamp_s for c in b], atol=1e-6)


def test_run_cli_replays_a_bag_and_refuses_a_broken_one(tmp_path):
    from typer.testing import CliRunner

    from skinloc.cli.main import app
    from skinloc.live.sinks.ros2.bag import Ros2BagSink
    from tests._live import model_path

    bag = tmp_path / "b.mcap"
    sink = Ros2BagSink(bag)
    sink.open(_skins())
    rng = np.random.default_rng(0)
    for k in range(120):
        sink.emit_frame("arm", 1000 + rng.normal(0, 2, 64), 5.0 + k / 100, k)
    sink.close()
    res = CliRunner().invoke(
        app, ["run", "--model", str(model_path("map")), "--source", str(bag), "--fast", "--stats"]
    )
    assert res.exit_code == 0, res.output
    assert '"frames": 120' in res.output
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\nnot a bag")
    res = CliRunner().invoke(
        app, ["run", "--model", str(model_path("map")), "--source", str(broken)]
    )
    assert res.exit_code != 0 and "Traceback" not in res.output
    assert "broken.mcap" in res.output


# ----------------------------------------------------------------------------- TF config


def test_skins_file_mounts_skins_on_robot_links(tmp_path):
    from skinloc.live.runner import Runner
    from skinloc.live.sinks.ros2.sink import quaternion_from_rpy
    from skinloc.live.skins_file import load_skins
    from tests._live import model_path

    cfg = tmp_path / "robot.toml"
    cfg.write_text(
        f'[defaults]\nmodel = "{model_path("map")}"\nsource = "sim"\n'
        '[[skin]]\nname = "fore"\nparent_frame = "fr3_link6"\ntranslation = [0, 0.05, 0.1]\n'
        "rpy = [0, 0, 1.5707963]\n"
        '[[skin]]\nname = "upper"\nparent_frame = "fr3_link4"\nrotation = [0, 0, 0, 1]\n'
        '[[skin]]\nname = "loose"\n'
    )
    specs, _ = load_skins(cfg)
    t, q = specs[0].mount
    assert t == (0.0, 0.05, 0.1)
    assert q == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    assert quaternion_from_rpy(0.3, 0, 0) == pytest.approx((math.sin(0.15), 0, 0, math.cos(0.15)))
    infos = [Runner(specs)._skin_info(i) for i in range(3)]
    assert [i.parent_frame for i in infos] == ["fr3_link6", "fr3_link4", None]
    assert infos[0].rotation_xyzw == pytest.approx(q) and infos[0].n_tx == 8


@pytest.mark.parametrize(
    ("extra", "match"),
    [
        ("rotation = [0, 0, 0, 2]", "unit quaternion"),
        ("rotation = [0, 0, 1]", "4 finite numbers"),
        ("rpy = [0, 0, 0]\nrotation = [0, 0, 0, 1]", "not both"),
        ('translation = [0, "a", 0]', "3 numbers"),
        ('parent_frame = ""', "frame name"),
    ],
)
def test_skins_file_mount_errors(tmp_path, extra, match):
    from skinloc.live.skins_file import load_skins

    cfg = tmp_path / "robot.toml"
    cfg.write_text(f'[[skin]]\nname = "s"\nmodel = "m.h5"\n{extra}\n')
    with pytest.raises(ValueError, match=match):
        load_skins(cfg)


def test_frames_from_a_serial_port_are_recorded(tmp_path):
    """Port-fed skins are parsed inside SkinCore.feed: their frames reach the bag too."""
    from skinloc.live.runner import Runner, SkinConfig
    from skinloc.sim.virtual_device import VirtualSkin
    from tests._live import model_path

    bag = tmp_path / "port.mcap"
    with VirtualSkin(fmt="binary", rate_hz=200) as dev:
        spec = SkinConfig(model=model_path("map"), source=dev.path, wire_format="binary", name="p")
        runner = Runner([spec], sinks=[f"mcap-ros2:{bag}"])
        runner.start()
        wait_until(lambda: runner.stats()[0]["frames"] >= 100, "100 frames")
        runner.close()
        n = runner.stats()[0]["frames"]
    frames = _read_bag(bag)["/skinloc/p/frames"]
    assert len(frames) == n
    seq = [m.sequence for _, m, _ in frames]
    assert seq == sorted(seq) and len(set(seq)) == n  # the device's counter
    assert frames[0][2].height * frames[0][2].width == 64


def test_dds_sink_close_leaves_no_thread_and_no_process(domain):
    from skinloc.live.sinks.ros2.sink import Ros2Sink

    def threads():
        return len(os.listdir("/proc/self/task"))

    before = threads()
    for _ in range(2):
        sink = Ros2Sink(domain_id=domain, backend="dds")
        sink.open([SkinInfo("a")])
        proc = sink._proc
        sink.emit(_contact(skin="a"))
        sink.close()
        assert proc.poll() == 0  # the publisher drained, ended and was reaped
        assert sink.stats()["sent"] == 1
    # the DDS participant lives in the publisher: this process never starts Cyclone's threads
    assert threads() <= before


def test_a_bag_recorded_when_the_run_stops_mid_touch_ends_with_the_finger_lifted(tmp_path):
    """``close`` with a finger down (Ctrl-C, SIGTERM, ``--duration``): the bag has the end."""
    from skinloc.live.runner import Pipeline
    from tests._live import held_recording, model_path

    bag = tmp_path / "held.mcap"
    seen = []
    pipeline = Pipeline(
        model_path("map"), str(held_recording(300.0)), sinks=[f"mcap-ros2:{bag}"], name="arm"
    )
    pipeline.start(seen.append)
    try:
        wait_until(lambda: any(c.state == "move" for c in seen), "a held touch", 120.0)
    finally:
        pipeline.close()
    topics = _read_bag(bag)
    poses = [m for _, _, m in topics["/skinloc/arm/contacts"]]
    assert any(p.poses for p in poses) and not poses[-1].poses
    last_action = {}
    for _, _, msg in topics["/skinloc/arm/markers"]:
        for m in msg.markers:
            last_action[m.id] = m.action
    assert last_action and set(last_action.values()) == {2}  # every sphere DELETEd


def test_a_frame_that_ends_a_track_waits_for_room_in_a_full_pipe(domain, monkeypatch):
    """Other frames are dropped when the publisher lags; an end is not (bounded wait)."""
    import signal
    import threading

    from skinloc.live.sinks.ros2 import sink as ros2_sink

    monkeypatch.setattr(ros2_sink, "_END_WAIT_S", scaled(60.0))  # a loaded machine
    sink = ros2_sink.Ros2Sink(domain_id=domain, backend="dds", queue_frames=16)
    sink.open([SkinInfo("a")])
    waiting = threading.Event()
    wait_for_room = sink._wait_for_room

    def wait_and_tell(n: int, timeout_s: float) -> None:
        waiting.set()
        wait_for_room(n, timeout_s)

    monkeypatch.setattr(sink, "_wait_for_room", wait_and_tell)
    pid = sink._proc.pid
    os.kill(pid, signal.SIGSTOP)  # the publisher lags: the pipe fills
    try:
        for k in range(10_000):
            sink.emit(_contact("move", k, skin="a"))
            if sink.n_dropped:
                break
        dropped = sink.n_dropped
        assert dropped == 1
        end = threading.Thread(target=sink.emit, args=(_contact("end", k + 1, skin="a"),))
        end.start()
        assert waiting.wait(scaled(30.0))
    finally:
        os.kill(pid, signal.SIGCONT)
    end.join(scaled(60.0))
    assert not end.is_alive()
    sink.close()
    assert sink.n_dropped == dropped  # the end went through once there was room
    assert sink.stats()["sent"] == sink.n_put - dropped


def test_an_encoder_mismatch_is_one_clear_error(monkeypatch):
    from skinloc.ros2 import cdr as ros2_cdr

    monkeypatch.setattr(ros2_cdr, "_ENCAPSULATION", b"\x00\x00\x00\x00")  # big-endian tag
    with pytest.raises(RuntimeError, match="PointStamped encoder disagrees"):
        ros2_cdr.check_encoders()


def test_skinloc_run_publishes_to_a_subscriber_in_another_process(tmp_path, domain):
    """`skinloc run --config robot.toml --sink ros2` as its own process, as a ROS user runs it."""
    import signal
    import subprocess

    from cyclonedds.domain import DomainParticipant

    from tests._helpers import Lines, start_skinloc, stop_and_wait
    from tests._live import model_path

    cfg = tmp_path / "robot.toml"
    cfg.write_text(
        f'[[skin]]\nname = "arm"\nmodel = "{model_path("map")}"\nsource = "sim"\n'
        'parent_frame = "fr3_link5"\ntranslation = [0.0, 0.02, 0.0]\nrpy = [0.0, 0.0, 0.0]\n'
    )
    dp = DomainParticipant(domain)
    point = _Sub(dp, "/skinloc/arm/contact", PS)
    tf = _Sub(dp, "/tf_static", TfM, latched=True)
    mesh = _Sub(dp, "/skinloc/arm/mesh", Mk, latched=True)
    proc = start_skinloc(
        "run", "--config", cfg, "--sink", "ros2", "--duration", "600",
        env={"ROS_DOMAIN_ID": str(domain)}, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        err = Lines(proc.stderr)
        # Generous: a loaded machine may take long to start the process (imports, the
        # compiled kernels); the wait ends as soon as everything arrived.
        wait_until(
            lambda: point.take() and tf.take() and mesh.take(),
            lambda: f"contact, tf and mesh from skinloc run; its stderr: {err.text[-2000:]}",
            180.0,
            proc=proc,
        )
        stop_and_wait(proc, signal.SIGINT, "skinloc run --sink ros2")  # one Ctrl-C
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.rest()
    # stopped cleanly: the publisher process drained and ended, the run's summary printed
    assert proc.returncode == 0 and "Traceback" not in text, text[-2000:]
    assert "frames" in text
    assert point.got[0].header.frame_id == "skin/arm"
    assert math.isfinite(point.got[0].point.x)
    assert tf.got[-1].transforms[0].header.frame_id == "fr3_link5"
    assert tf.got[-1].transforms[0].transform.translation.y == pytest.approx(0.02)
    assert mesh.got[-1].header.frame_id == "skin/arm"


def test_a_touch_held_when_skinloc_run_stops_ends_for_a_subscriber_in_another_process(domain):
    """Ctrl-C with a finger down: the subscriber gets the empty PoseArray and the DELETEs.

    Without them a node that follows the touches believes the skin is touched forever.
    """
    import signal
    import subprocess

    from cyclonedds.domain import DomainParticipant

    from tests._helpers import Lines, start_skinloc, stop_and_wait
    from tests._live import held_recording, model_path

    dp = DomainParticipant(domain)
    poses = _Sub(dp, "/skinloc/skin/contacts", PA)
    markers = _Sub(dp, "/skinloc/skin/markers", MkA)

    def data(sub: _Sub, cls: type) -> list:
        """The messages taken (a writer that goes away also leaves samples without data)."""
        return [m for m in sub.take() if isinstance(m, cls)]

    def touched() -> bool:
        markers.take()
        return any(m.poses for m in data(poses, PA))

    def ended() -> bool:
        markers.take()
        got = data(poses, PA)
        return bool(got) and not got[-1].poses

    proc = start_skinloc(
        "run", "--model", model_path("map"), "--source", held_recording(300.0), "--sink", "ros2",
        "--duration", "600", env={"ROS_DOMAIN_ID": str(domain)}, stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        err = Lines(proc.stderr)
        wait_until(
            touched,
            lambda: f"a finger on /contacts from skinloc run; its stderr: {err.text[-2000:]}",
            180.0,
            proc=proc,
        )
        stop_and_wait(proc, signal.SIGINT, "skinloc run --sink ros2")  # the finger still down
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.rest()
    assert proc.returncode == 0 and "Traceback" not in text, text[-2000:]
    # what was published before the publisher ended is delivered (reliable): take it all
    wait_until(ended, "an empty PoseArray after the last finger", 30.0)
    last_action: dict[int, int] = {}
    for msg in data(markers, MkA):
        for m in msg.markers:
            last_action[m.id] = m.action
    assert last_action and set(last_action.values()) == {2}  # every sphere DELETEd


@pytest.mark.slow  # a multi-process benchmark
def test_bench_functions_with_the_ros2_sink_run_small(domain):
    import sklearn  # noqa: F401 - sets OpenMP variables on import, which is not the bench's doing

    from skinloc.bench.online import many_skins
    from skinloc.bench.sinks import sink_cost
    from tests._live import model_path

    env = dict(os.environ)
    cost = sink_cost(300, n_skins=3, rounds=1)
    assert set(cost) == {
        "jsonl",
        "ros2 (DDS, no subscriber)",
        "ros2 (DDS, 1 subscriber)",
        "mcap-ros2 (bag)",
    }
    assert all(v["contacts"] == 300 and v["emit_median_us"] > 0 for v in cost.values())
    assert all(v["dropped"] == 0 for v in cost.values())
    # the ROS 2 sink works in its publisher process; the others on the caller's thread
    assert cost["ros2 (DDS, no subscriber)"]["publisher_cpu_us_per_contact"] > 0
    assert cost["jsonl"]["publisher_cpu_us_per_contact"] == 0
    assert cost["ros2 (DDS, 1 subscriber)"]["samples_taken_by_subscriber"] > 0
    m = many_skins(model_path("map"), n_skins=3, rate_hz=50.0, duration_s=2.0, sinks=("ros2",))
    assert m["sinks"] == ["ros2"] and m["frames_processed"] > 0
    st = m["sink_stats"]["ros2"]
    assert st["queued"] > 0 and st["sent"] == st["queued"] and st["pending"] == 0
    assert dict(os.environ) == env  # the benchmarks configure DDS without touching it
    assert m["sink_frames_dropped"] == 0


def test_skin_names_become_valid_ros_names(tmp_path):
    from skinloc.live.sinks.ros2.sink import ros_name
    from skinloc.sources.mcap_ros2 import McapReplaySource

    assert ros_name("left-forearm") == "left_forearm" and ros_name("2nd.link") == "_2nd_link"
    bag = tmp_path / "n.mcap"
    sink = make_sink(f"mcap-ros2:{bag}")
    sink.open([SkinInfo("left-forearm", n_tx=2, n_rx=2)])
    sink.emit(_contact(skin="left-forearm"))
    sink.emit_frame("left-forearm", np.ones(4), 1.0, 0)
    with pytest.raises(ValueError, match="would share the ROS 2 topics"):
        sink.open([SkinInfo("left_forearm")])
    sink.close()
    topics = _read_bag(bag)
    (_, _, ps) = topics["/skinloc/left_forearm/contact"][0]
    assert ps.header.frame_id == "skin/left-forearm"
    assert McapReplaySource(bag, skin="left-forearm").n_tx == 2


def test_the_diagnostics_p99_is_numpys_percentile_of_the_finite_latencies():
    """``p99`` (the latency p99 of a skin's status) is ``np.percentile(..., 99)`` of the ring's
    finite entries, whatever their number; nan for none."""
    from skinloc.live.sinks.ros2.sink import p99

    rng = np.random.default_rng(1)
    for n in (1, 2, 3, 50, 99, 100, 101, 255, 256):
        ring = np.full(256, np.nan)
        ring[rng.choice(256, n, replace=False)] = rng.lognormal(5.0, 1.5, n)
        assert p99(ring) == pytest.approx(np.percentile(ring[np.isfinite(ring)], 99), rel=1e-12)
    assert math.isnan(p99(np.full(8, np.nan)))
