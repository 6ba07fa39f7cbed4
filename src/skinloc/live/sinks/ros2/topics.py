"""The ROS 2 topic layout of skinloc: names, types, stamps and the per-frame messages.

Shared by the live sink (``skinloc.live.sinks.ros2.sink``, DDS or rclpy) and the bag writer
(``skinloc.live.sinks.ros2.bag``). Per skin ``S`` (frame ``skin/S``, stamps from the frame
timestamps; in topic names ``S`` has every character other than letters, digits and ``_``
replaced by ``_``):

==============================  ======================================  ========================
topic                           type                                    QoS
==============================  ======================================  ========================
``/skinloc/S/contact``          ``geometry_msgs/msg/PointStamped``      reliable, volatile, 10
``/skinloc/S/contacts``         ``geometry_msgs/msg/PoseArray``         reliable, volatile, 10
``/skinloc/S/markers``          ``visualization_msgs/msg/MarkerArray``  reliable, volatile, 10
``/skinloc/S/mesh``             ``visualization_msgs/msg/Marker``       reliable, transient local
``/skinloc/S/gestures``         ``std_msgs/msg/String`` (JSON)          reliable, volatile, 10
``/tf_static``                  ``tf2_msgs/msg/TFMessage``              reliable, transient local
==============================  ======================================  ========================

Per frame: ``contact`` is the strongest touching contact (published while something touches);
``contacts`` every touching contact ordered by slot (empty when nothing touches); ``markers``
one sphere per track (``id`` = the track id, the finger's colour) and a ``DELETE`` of each track
that ended in the frame. ``/tf_static`` carries ``parent_frame -> skin/S`` for every skin: its
pose on the robot from the skins file (keys ``parent_frame``, ``translation``,
``rotation``/``rpy``), else the identity under ``DEFAULT_PARENT`` (``base_link``), so RViz shows
every skin at once.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from skinloc._lazy import extra_installed, require_extra
from skinloc.geometry.skin_frame import quaternion_from_rpy  # re-exported: the pose's maths
from skinloc.live.contact import TRACK_RGB, colour_index
from skinloc.live.sinks.base import Sink, SkinInfo
from skinloc.ros2.names import ros_name, topic_base

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

__all__ = [
    "DEFAULT_PARENT",
    "Ros2Topics",
    "dds_available",
    "quaternion_from_rpy",
    "rclpy_available",
    "ros2_available",
    "ros_name",
    "topic_base",
]

_TOUCHING = ("start", "move")
#: the parent frame of a skin whose pose on the robot is not configured (REP 105's robot base)
DEFAULT_PARENT = "base_link"


def _touching(c: Contact) -> bool:
    return c.state in _TOUCHING and c.position_m[0] == c.position_m[0]


def _strength_key(c: Contact) -> tuple[float, float]:
    """Strongest first by ``strength`` (counts), then ``signal_z``; nan counts as weakest."""
    s, z = c.strength, c.signal_z
    return (s if s == s else -math.inf, z if z == z else -math.inf)


def _slot_key(c: Contact) -> tuple[int, int, int]:
    """By slot; contacts without a slot after those with one, by track id."""
    return (c.slot < 0, c.slot, c.track_id)


def _marker_id(c: Contact) -> int:
    """The track id; for a contact without one (single-contact pipeline) its touch number."""
    return c.track_id if c.track_id >= 0 else c.touch_id


#: the fingers' colours as marker colours, RGBA in [0, 1]
_RGBA = tuple((*rgb, 0.9) for rgb in TRACK_RGB)


def _colour(c: Contact) -> tuple[float, float, float, float]:
    """The finger's colour (``skinloc.live.contact.track_colour``), RGBA in [0, 1]."""
    return _RGBA[colour_index(c) % len(_RGBA)]


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
    return extra_installed("cyclonedds.domain")


def ros2_available() -> bool:
    """Whether the ROS 2 sink can run: through rclpy or plain DDS."""
    return rclpy_available() or dds_available()


def require_msgs() -> Any:
    """``skinloc.ros2.msgs`` (needs cyclonedds), or one clear ``MissingExtraError``."""
    require_extra("cyclonedds.idl", "the ROS 2 sink")
    import skinloc.ros2.msgs as ros2_msgs

    return ros2_msgs


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
        self._topics: dict[str, tuple[str, str, str]] = {}  # contact, contacts, markers
        self._offset_s: dict[str, float] = {}
        self._last_s: dict[str, float] = {}
        self._lock = threading.RLock()  # the live sink may open a skin while publishing
        self.n_sent = 0

    # ------------------------------------------------------------------ to implement
    def _advertise(self, topic: str, cls: type, latched: bool) -> None:
        raise NotImplementedError

    def _write(self, topic: str, data: bytes, t_ns: int, sequence: int | None = None) -> None:
        raise NotImplementedError

    # ------------------------------------------------------------------ layout
    def _open_topics(self, skins: Sequence[SkinInfo]) -> None:
        self._msgs = require_msgs()
        from skinloc.ros2.cdr import check_encoders

        if not getattr(Ros2Topics, "_checked", False):
            check_encoders()  # the struct encoders agree with the IDL definitions
            Ros2Topics._checked = True
        for s in skins:
            self._add_skin(s)
        self._publish_tf_static()

    def _add_skin(self, info: SkinInfo) -> None:
        from skinloc.ros2.cdr import HeaderEncoder

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
        self._enc[name] = HeaderEncoder(f"skin/{name}")
        self._topics[name] = (f"{base}/contact", f"{base}/contacts", f"{base}/markers")
        self._advertise(f"{base}/contact", m.PointStamped, False)
        self._advertise(f"{base}/contacts", m.PoseArray, False)
        self._advertise(f"{base}/markers", m.MarkerArray, False)
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
            tx, ty, tz = info.translation_m
            qx, qy, qz, qw = info.rotation_xyzw
            transforms.append(
                m.TransformStamped(
                    header=m.Header(stamp=now, frame_id=info.parent_frame or DEFAULT_PARENT),
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
        """Publish one frame's output of a single-contact pipeline (one contact, any state)."""
        self.emit_contacts(contact.skin, contact.timestamp_s, [contact])

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Publish one frame of ``skin``: its contacts, one per track, ended tracks included.

        Parameters
        ----------
        skin : str
            Skin name.
        timestamp_s : float
            The frame's timestamp, s.
        contacts : sequence of Contact
            The frame's contacts: ``start``/``move`` ones touch (``/contact`` gets the
            strongest, ``/contacts`` all of them by slot, ``/markers`` a sphere each), an ``end``
            one deletes its track's sphere; others (``idle``) publish an empty ``/contacts``.
        """
        with self._lock:
            self._publish_frame(skin, timestamp_s, contacts)

    def _publish_frame(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        enc = self._enc.get(skin)
        if enc is None:
            self._ensure_skin(skin)
            enc = self._enc[skin]
        stamp = self._msgs.stamp_parts(self.stamp_s(skin, timestamp_s))
        t_ns = stamp[0] * 1_000_000_000 + stamp[1]
        contact_topic, contacts_topic, markers_topic = self._topics[skin]
        write = self._write
        if len(contacts) == 1:  # the common frame: no sorting
            touching = list(contacts) if _touching(contacts[0]) else []
        else:
            touching = sorted((c for c in contacts if _touching(c)), key=_slot_key)
        if touching:
            best = max(touching, key=_strength_key) if len(touching) > 1 else touching[0]
            write(contact_topic, enc.point_stamped(stamp, best.position_m), t_ns)
            positions = [c.position_m for c in touching]
            spheres = [(*c.position_m, _marker_id(c), 0, *_colour(c)) for c in touching]
        else:
            positions, spheres = [], []
        write(contacts_topic, enc.pose_array(stamp, positions), t_ns)
        if len(touching) < len(contacts):  # the tracks that ended: a DELETE each
            spheres += [
                (0.0, 0.0, 0.0, _marker_id(c), 2, *_colour(c))  # Marker.DELETE
                for c in contacts
                if c.state == "end"
            ]
        if spheres:
            write(markers_topic, enc.sphere_markers(stamp, spheres), t_ns)
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
            JSON-ready (the gesture event of ``skinloc.live``); ``skin`` and ``stamp`` (s since
            the epoch, as the other topics' header stamps) are added.
        """
        with self._lock:
            self._publish_gesture(skin, timestamp_s, event)

    def _publish_gesture(self, skin: str, timestamp_s: float, event: Mapping[str, Any]) -> None:
        self._ensure_skin(skin)
        t = self.stamp_s(skin, timestamp_s)
        payload = json.dumps({**event, "skin": skin, "stamp": t}, separators=(",", ":"))
        sec, nsec = self._msgs.stamp_parts(t)
        data = self._msgs.String(payload).serialize()
        self._write(f"{topic_base(skin)}/gestures", data, sec * 1_000_000_000 + nsec)

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
            stamp = self._msgs.stamp_parts(self.stamp_s(skin, timestamp_s))
            t_ns = stamp[0] * 1_000_000_000 + stamp[1]
            data = self._enc[skin].image_32fc1(stamp, values, n_tx, n_rx)
            self._write(f"{topic_base(skin)}/frames", data, t_ns, int(index) & 0xFFFFFFFF)
