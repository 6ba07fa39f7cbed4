"""ROS 2: contacts as standard ROS 2 messages, over DDS without a ROS install, or through rclpy.

Per skin ``S`` (frame ``skin/S``, stamps from the frame timestamps, see ``Ros2Topics``; in
topic names ``S`` has every character other than letters, digits and ``_`` replaced by ``_``):

==============================  ===================================  ===========================
topic                           type                                 QoS
==============================  ===================================  ===========================
``/skinloc/S/contact``          ``geometry_msgs/msg/PointStamped``   reliable, volatile, last 10
``/skinloc/S/contacts``         ``geometry_msgs/msg/PoseArray``      reliable, volatile, last 10
``/skinloc/S/mesh``             ``visualization_msgs/msg/Marker``    reliable, transient local, 1
``/skinloc/S/gestures``         ``std_msgs/msg/String`` (JSON)       reliable, volatile, last 10
``/tf_static``                  ``tf2_msgs/msg/TFMessage``           reliable, transient local, 1
==============================  ===================================  ===========================

``contact`` is the strongest contact of a frame (published while touching); ``contacts`` holds
every contact of the frame (empty when a touch ends), so several simultaneous contacts need no
new message type. ``/tf_static`` carries ``parent_frame -> skin/S`` for every skin whose pose on
the robot is configured (skins file keys ``parent_frame``, ``translation``, ``rotation``/``rpy``).

Without ``rclpy`` the sink is a plain DDS participant (Cyclone DDS, the ``cyclonedds`` wheel)
that writes on ``rt/<topic>`` with the DDS type names and CDR encoding a ROS 2 node uses, on
domain ``ROS_DOMAIN_ID`` (default 0): ``ros2 topic echo /skinloc/S/contact`` on the same
machine or network sees it with no bridge. With ``rclpy`` importable (a sourced ROS 2 install)
it is a real node named ``NODE`` publishing the same bytes.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import threading
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from skinloc.live.sinks.base import Sink, SkinInfo

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = ["Ros2Sink", "Ros2Topics", "dds_available", "rclpy_available", "ros2_available"]

_DEPTH = 10  # keep-last depth of the data topics (rclpy's default QoS profile)


def ros_name(skin: str) -> str:
    """The skin's name as a ROS 2 topic name token: ``left-forearm`` -> ``left_forearm``.

    ROS 2 topic names allow letters, digits and underscores, not starting with a digit; frame
    ids keep the skin's own name (``skin/left-forearm``).
    """
    token = re.sub(r"[^A-Za-z0-9_]", "_", skin) or "_"
    return f"_{token}" if token[0].isdigit() else token


def topic_base(skin: str) -> str:
    """``/skinloc/<ros_name(skin)>``, the prefix of a skin's topics."""
    return f"/skinloc/{ros_name(skin)}"


def rclpy_available() -> bool:
    """Whether ``rclpy`` imports (a sourced ROS 2 installation)."""
    try:
        import rclpy  # noqa: F401
        import rclpy.serialization  # noqa: F401
    except ImportError:
        return False
    return True


def dds_available() -> bool:
    """Whether the ``cyclonedds`` Python binding imports."""
    try:
        import cyclonedds.domain  # noqa: F401
    except ImportError:
        return False
    return True


def ros2_available() -> bool:
    """Whether the ROS 2 sink can run: through rclpy or plain DDS."""
    return rclpy_available() or dds_available()


def _require_msgs() -> Any:
    try:
        import skinloc.live.sinks.ros2_msgs as ros2_msgs
    except ImportError:
        raise ImportError(
            "the ROS 2 sinks need the cyclonedds Python binding (ROS 2 message types and CDR): "
            "pip install 'skinloc[live]' (or pip install cyclonedds)"
        ) from None
    return ros2_msgs


def quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Quaternion ``(x, y, z, w)`` of fixed-axis roll, pitch, yaw (rad), as ROS's ``tf2``."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )


class Ros2Topics(Sink):
    """The ROS 2 topic layout of skinloc, shared by the live sink and the bag writer.

    Subclasses provide ``_advertise(topic, cls, latched)`` and ``_write(topic, data, t_ns,
    sequence)`` (``data``: CDR bytes with their encapsulation header).

    Stamps: a frame's timestamp plus a per-skin offset fixed at the skin's first message, so the
    first stamp is the wall-clock time (what ``tf2`` and RViz compare stamps against) and every
    interval is the frames' own (serial ports stamp frames with ``time.monotonic()``, recordings
    with their recorded time).
    """

    #: whether the runner should hand raw frames to ``emit_frame``
    wants_frames = False

    def __init__(self) -> None:
        self._msgs: Any = None
        self._skins: dict[str, SkinInfo] = {}
        self._enc: dict[str, Any] = {}
        self._offset_s: dict[str, float] = {}
        self._last_s: dict[str, float] = {}
        self._lock = threading.Lock()
        self.n_sent = 0

    # ------------------------------------------------------------------ to implement
    def _advertise(self, topic: str, cls: type, latched: bool) -> None:
        raise NotImplementedError

    def _write(self, topic: str, data: bytes, t_ns: int, sequence: int | None = None) -> None:
        raise NotImplementedError

    # ------------------------------------------------------------------ layout
    def _open_topics(self, skins: Sequence[SkinInfo]) -> None:
        self._msgs = m = _require_msgs()
        if not getattr(Ros2Topics, "_checked", False):
            m.check_encoders()  # the struct encoders agree with the IDL definitions
            Ros2Topics._checked = True
        for s in skins:
            self._add_skin(s)
        self._publish_tf_static()

    def _add_skin(self, info: SkinInfo) -> None:
        m = self._msgs
        name = info.name
        base = topic_base(name)
        clash = [n for n in self._skins if n != name and topic_base(n) == base]
        if clash:
            raise ValueError(
                f"skins {clash[0]!r} and {name!r} would share the ROS 2 topics {base}/...; "
                "rename one (ROS 2 names allow letters, digits and underscores)"
            )
        self._skins[name] = info
        self._enc[name] = m.HeaderEncoder(f"skin/{name}")
        self._advertise(f"{base}/contact", m.PointStamped, False)
        self._advertise(f"{base}/contacts", m.PoseArray, False)
        self._advertise(f"{base}/gestures", m.String, False)
        if self.wants_frames:
            self._advertise(f"{base}/frames", m.Image, False)
        if info.vertices is not None and info.faces is not None:
            self._advertise(f"{base}/mesh", m.Marker, True)
            self._write(f"{base}/mesh", self._mesh_marker(info).serialize(), time.time_ns())

    def _mesh_marker(self, info: SkinInfo) -> Any:
        m = self._msgs
        tri = np.asarray(info.vertices, dtype=float)[np.asarray(info.faces).reshape(-1)]
        return m.Marker(
            header=m.Header(stamp=m.stamp_of(time.time()), frame_id=f"skin/{info.name}"),
            ns="skinloc/mesh",
            id=0,
            type=m.Marker.TRIANGLE_LIST,
            action=m.Marker.ADD,
            scale=m.Vector3(1.0, 1.0, 1.0),
            color=m.ColorRGBA(0.8, 0.75, 0.7, 0.6),
            points=[m.Point(float(x), float(y), float(z)) for x, y, z in tri],
        )

    def _publish_tf_static(self) -> None:
        m = self._msgs
        now = m.stamp_of(time.time())
        transforms = []
        for info in self._skins.values():
            if not info.parent_frame:
                continue
            tx, ty, tz = info.translation_m
            qx, qy, qz, qw = info.rotation_xyzw
            transforms.append(
                m.TransformStamped(
                    header=m.Header(stamp=now, frame_id=info.parent_frame),
                    child_frame_id=f"skin/{info.name}",
                    transform=m.Transform(m.Vector3(tx, ty, tz), m.Quaternion(qx, qy, qz, qw)),
                )
            )
        if transforms:
            self._advertise("/tf_static", m.TFMessage, True)
            self._write("/tf_static", m.TFMessage(transforms).serialize(), time.time_ns())

    def _ensure_skin(self, skin: str) -> None:
        if self._msgs is None:
            self.open([SkinInfo(skin)])
        if skin not in self._enc:
            self._add_skin(SkinInfo(skin))

    def stamp_s(self, skin: str, t_s: float) -> float:
        """The ROS stamp (s since the epoch) of a frame timestamp of ``skin``.

        A non-finite timestamp (the end event of a touch whose source ended) gets the skin's
        last stamp.
        """
        if not math.isfinite(t_s):
            return self._last_s.get(skin, time.time())
        off = self._offset_s.get(skin)
        if off is None:
            off = self._offset_s[skin] = time.time() - float(t_s)
        t = self._last_s[skin] = float(t_s) + off
        return t

    # ------------------------------------------------------------------ data
    def emit(self, contact: Contact) -> None:
        """Publish one frame's output (its contacts, as a list of one or none)."""
        x = contact.position_m[0]
        touching = contact.state in ("start", "move") and x == x
        self.emit_contacts(contact.skin, contact.timestamp_s, [contact] if touching else [])

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Publish every contact of one frame of ``skin`` (empty: nothing touches).

        Parameters
        ----------
        skin : str
            Skin name.
        timestamp_s : float
            The frame's timestamp, s.
        contacts : sequence of Contact
            The frame's contacts; ``/contact`` gets the one with the highest ``signal_z``.
        """
        with self._lock:
            self._ensure_skin(skin)
            enc = self._enc[skin]
            t = self.stamp_s(skin, timestamp_s)
            stamp = self._msgs.stamp_of(t)
            t_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
            base = topic_base(skin)
            if contacts:
                best = max(contacts, key=lambda c: c.signal_z if c.signal_z == c.signal_z else -1)
                self._write(f"{base}/contact", enc.point_stamped(stamp, best.position_m), t_ns)
            positions = [c.position_m for c in contacts]
            self._write(f"{base}/contacts", enc.pose_array(stamp, positions), t_ns)
            self.n_sent += 1

    def emit_gesture(self, skin: str, timestamp_s: float, event: Mapping[str, Any]) -> None:
        """Publish a gesture event of ``skin`` as JSON in a ``std_msgs/String``.

        Parameters
        ----------
        skin : str
            Skin name.
        timestamp_s : float
            Timestamp of the frame that completed the gesture, s.
        event : mapping
            JSON-ready; ``skin`` and ``stamp`` (s since the epoch, as the other topics) are
            added.
        """
        with self._lock:
            self._ensure_skin(skin)
            t = self.stamp_s(skin, timestamp_s)
            payload = json.dumps({**event, "skin": skin, "stamp": t}, separators=(",", ":"))
            data = self._msgs.String(payload).serialize()
            self._write(f"{topic_base(skin)}/gestures", data, int(t * 1e9))

    def emit_frame(self, skin: str, values: np.ndarray, timestamp_s: float, index: int) -> None:
        """Record a raw frame as ``sensor_msgs/Image`` ``32FC1``, TX rows by RX columns.

        Parameters
        ----------
        skin : str
            Skin name.
        values : (n_tx * n_rx,) float
            Raw counts, TX-major.
        timestamp_s : float
            The frame's timestamp, s.
        index : int
            Frame counter (kept as the MCAP message sequence number).
        """
        with self._lock:
            self._ensure_skin(skin)
            info = self._skins[skin]
            n = int(np.size(values))
            n_tx = info.n_tx or 1
            n_rx = info.n_rx or n // n_tx
            stamp = self._msgs.stamp_of(self.stamp_s(skin, timestamp_s))
            t_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
            data = self._enc[skin].image_32fc1(stamp, values, n_tx, n_rx)
            self._write(f"{topic_base(skin)}/frames", data, t_ns, int(index) & 0xFFFFFFFF)


# -------------------------------------------------------------------------------- live sink


class _DdsBackend:
    """A Cyclone DDS participant with one writer per topic, ROS 2 naming and QoS."""

    def __init__(self, domain_id: int) -> None:
        from cyclonedds.domain import DomainParticipant

        self.domain_id = domain_id
        self.participant = DomainParticipant(domain_id)
        self.writers: dict[str, Any] = {}

    def advertise(self, topic: str, cls: type, latched: bool) -> None:
        from cyclonedds.core import Policy, Qos
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic
        from cyclonedds.util import duration

        if topic in self.writers:
            return
        qos = Qos(
            Policy.Reliability.Reliable(duration(milliseconds=100)),
            Policy.Durability.TransientLocal if latched else Policy.Durability.Volatile,
            Policy.History.KeepLast(1 if latched else _DEPTH),
            Policy.DataRepresentation(use_cdrv0_representation=True),
        )
        # ROS 2 prefixes topics with "rt" ("ROS topic") on the DDS side
        dds_topic = Topic(self.participant, "rt" + topic, cls, qos=qos)
        self.writers[topic] = DataWriter(self.participant, dds_topic, qos=qos)

    def write(self, topic: str, data: bytes) -> None:
        from cyclonedds._clayer import ddspy_write

        # the bytes are already CDR (the struct encoders): hand them to the C writer as
        # DataWriter.write does after serialize(), padded to 4 bytes
        if len(data) % 4:
            data += b"\x00" * (-len(data) % 4)
        ret = ddspy_write(self.writers[topic]._ref, data)
        if ret < 0:
            raise OSError(f"DDS write on {topic} failed ({ret})")

    def close(self) -> None:
        self.writers.clear()
        self.participant = None  # the participant and its entities are freed with it


class _RclpyBackend:
    """A ROS 2 node (rclpy) publishing the same CDR bytes (``Publisher.publish`` takes bytes)."""

    def __init__(self, node_name: str) -> None:
        import rclpy

        self._own_init = False
        if not rclpy.ok():
            rclpy.init()
            self._own_init = True
        self.node = rclpy.create_node(node_name)
        self.pubs: dict[str, Any] = {}

    def advertise(self, topic: str, cls: type, latched: bool) -> None:
        import importlib

        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        from skinloc.live.sinks.ros2_msgs import ros_type_name

        if topic in self.pubs:
            return
        pkg, _, name = ros_type_name(cls).split("/")
        msg_type = getattr(importlib.import_module(f"{pkg}.msg"), name)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=1 if latched else _DEPTH,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        )
        self.pubs[topic] = self.node.create_publisher(msg_type, topic, qos)

    def write(self, topic: str, data: bytes) -> None:
        self.pubs[topic].publish(data)

    def close(self) -> None:
        import rclpy

        self.node.destroy_node()
        if self._own_init:
            rclpy.shutdown()


class Ros2Sink(Ros2Topics):
    """Publish contacts on ROS 2 topics (see the module docstring for topics and types).

    Parameters
    ----------
    node_name : str
        The node's name (rclpy only; over plain DDS there is no node graph entry).
    domain_id : int, optional
        DDS domain (default: ``ROS_DOMAIN_ID``, else 0).
    backend : {"auto", "dds", "rclpy"}
        ``auto``: rclpy when importable, else plain DDS.
    """

    name = "ros2"

    def __init__(
        self, node_name: str = "skinloc", *, domain_id: int | None = None, backend: str = "auto"
    ) -> None:
        super().__init__()
        if backend not in ("auto", "dds", "rclpy"):
            raise ValueError(f"unknown ROS 2 backend {backend!r}; use auto, dds or rclpy")
        if domain_id is None:
            env = os.environ.get("ROS_DOMAIN_ID", "").strip()
            try:
                domain_id = int(env) if env else 0
            except ValueError:
                raise ValueError(f"ROS_DOMAIN_ID must be an integer, not {env!r}") from None
        if not 0 <= domain_id <= 232:
            raise ValueError(f"a ROS 2 domain id is in 0..232, not {domain_id}")
        self.node_name = node_name
        self.domain_id = domain_id
        self.backend = backend
        self._io: Any = None

    def open(self, skins: list[SkinInfo]) -> None:
        """Join the DDS domain (or create the node), advertise, publish meshes and transforms."""
        if self._io is not None:
            for s in skins:
                if s.name not in self._skins:
                    self._add_skin(s)
            return
        use_rclpy = self.backend == "rclpy" or (self.backend == "auto" and rclpy_available())
        _require_msgs()
        if use_rclpy:
            if not rclpy_available():
                raise ImportError("backend 'rclpy' needs a sourced ROS 2 installation")
            self._io = _RclpyBackend(self.node_name)
        else:
            self._io = _DdsBackend(self.domain_id)
        self.backend_used = "rclpy" if use_rclpy else "dds"
        self._open_topics(skins)

    def _advertise(self, topic: str, cls: type, latched: bool) -> None:
        self._io.advertise(topic, cls, latched)

    def _write(self, topic: str, data: bytes, t_ns: int, sequence: int | None = None) -> None:
        self._io.write(topic, data)

    def close(self) -> None:
        """Leave the domain (destroy the node)."""
        if self._io is not None:
            self._io.close()
            self._io = None
        self._msgs = None
        self._enc.clear()
        self._skins.clear()
