"""ROS 2: contacts as standard ROS 2 messages, over DDS without a ROS install, or through rclpy.

The topics, types and stamps are ``skinloc.live.sinks.ros2_topics``'s (``/skinloc/S/contact``,
``contacts``, ``markers``, ``mesh``, ``gestures`` and ``/tf_static``).

Without ``rclpy`` the sink is a plain DDS participant (Cyclone DDS, the ``cyclonedds`` wheel)
that writes on ``rt/<topic>`` with the DDS type names and CDR encoding a ROS 2 node uses, on
domain ``ROS_DOMAIN_ID`` (default 0): ``ros2 topic echo /skinloc/S/contact`` on the same
machine or network sees it with no bridge. With ``rclpy`` importable (a sourced ROS 2 install)
it is a real node named ``NODE`` publishing the same bytes.

The pipeline's thread only queues each frame's contacts (``emit_contacts``, ``emit_gesture``):
a publisher thread encodes and writes them, every batch it finds at a wake-up, from a bounded
queue that drops its oldest frame when full (``stats()["dropped"]``) and never blocks the
pipeline. ``close`` publishes what is queued, joins the thread and leaves the domain.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from skinloc.live.sinks.base import SkinInfo
from skinloc.live.sinks.publisher import PublisherThread
from skinloc.live.sinks.ros2_topics import Ros2Topics, _require_msgs, rclpy_available

# the runner, the bag source and users' code import these from here
from skinloc.live.sinks.ros2_topics import quaternion_from_rpy as quaternion_from_rpy
from skinloc.live.sinks.ros2_topics import ros_name as ros_name
from skinloc.live.sinks.ros2_topics import topic_base as topic_base

if TYPE_CHECKING:
    from skinloc.live.contact import Contact

log = logging.getLogger(__name__)

__all__ = ["Ros2Sink"]

_DEPTH = 10  # keep-last depth of the data topics (rclpy's default QoS profile)


class _DdsBackend:
    """A Cyclone DDS participant with one writer per topic, ROS 2 naming and QoS."""

    def __init__(self, domain_id: int) -> None:
        from cyclonedds._clayer import ddspy_write
        from cyclonedds.domain import DomainParticipant

        self._ddspy_write = ddspy_write  # looked up once: it runs three times per frame
        self.domain_id = domain_id
        self.participant = DomainParticipant(domain_id)
        self.writers: dict[str, Any] = {}
        self._refs: dict[str, Any] = {}  # the C writers, for ddspy_write

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
        self._refs[topic] = self.writers[topic]._ref

    def write(self, topic: str, data: bytes, t_ns: int = 0, sequence: int | None = None) -> None:
        """Write CDR bytes on ``topic`` (``t_ns``, ``sequence``: the sink's signature, unused)."""
        # the bytes are already CDR (the struct encoders): hand them to the C writer as
        # DataWriter.write does after serialize(), padded to 4 bytes
        if len(data) % 4:
            data += b"\x00" * (-len(data) % 4)
        ret = self._ddspy_write(self._refs[topic], data)
        if ret < 0:
            raise OSError(f"DDS write on {topic} failed ({ret})")

    def close(self) -> None:
        self.writers.clear()
        self._refs.clear()
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

        from skinloc.data.ros2_msgs import ros_type_name

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
    """Publish contacts on ROS 2 topics (see ``skinloc.live.sinks.ros2_topics``).

    Parameters
    ----------
    node_name : str
        The node's name (rclpy only; over plain DDS there is no node graph entry).
    domain_id : int, optional
        DDS domain (default: ``ROS_DOMAIN_ID``, else 0).
    backend : {"auto", "dds", "rclpy"}
        ``auto``: rclpy when importable, else plain DDS.
    queue_frames : int, default=4096
        Frames (and gesture events) the publisher thread's queue holds; when full, the oldest
        is dropped and counted. 4096 is 0.4 s of 100 skins at 100 Hz.
    """

    name = "ros2"

    def __init__(
        self,
        node_name: str = "skinloc",
        *,
        domain_id: int | None = None,
        backend: str = "auto",
        queue_frames: int = 4096,
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
        if queue_frames < 1:
            raise ValueError(f"the ROS 2 sink's queue holds at least 1 frame, not {queue_frames}")
        self.node_name = node_name
        self.domain_id = domain_id
        self.backend = backend
        self.queue_frames = int(queue_frames)
        self._io: Any = None
        self._pub: PublisherThread | None = None
        self._last_stats: dict[str, Any] = {}

    def open(self, skins: list[SkinInfo]) -> None:
        """Join the DDS domain (or create the node), advertise, publish meshes and transforms."""
        if self._io is not None:
            with self._lock:
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
        if not use_rclpy:
            self._write = self._io.write  # one call less per message (three per frame)
        with self._lock:
            self._open_topics(skins)
        self._pub = PublisherThread(
            self._publish_batch, name=f"skinloc-ros2-{self.node_name}", maxsize=self.queue_frames
        )

    def _advertise(self, topic: str, cls: type, latched: bool) -> None:
        self._io.advertise(topic, cls, latched)

    def _write(self, topic: str, data: bytes, t_ns: int, sequence: int | None = None) -> None:
        self._io.write(topic, data)

    # ------------------------------------------------------------------ the pipeline's side
    def emit(self, contact: Contact) -> None:
        """Queue the one contact of a single-contact pipeline's frame (see ``Ros2Topics.emit``)."""
        if self._pub is None:
            self.open([])
        self._pub.put((contact.skin, contact.timestamp_s, (contact,)))

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Contact]) -> None:
        """Queue one frame of ``skin`` for the publisher thread (see ``Ros2Topics``)."""
        if self._pub is None:
            self.open([])
        self._pub.put((skin, timestamp_s, tuple(contacts)))

    def emit_gesture(self, skin: str, timestamp_s: float, event: Mapping[str, Any]) -> None:
        """Queue a gesture event of ``skin`` (published as JSON on ``/skinloc/S/gestures``)."""
        if self._pub is None:
            self.open([])
        self._pub.put((skin, timestamp_s, dict(event)))

    # ------------------------------------------------------------------ the publisher thread
    def _publish_batch(self, batch: list[tuple[str, float, Any]]) -> None:
        with self._lock:
            for skin, t, what in batch:
                if isinstance(what, dict):
                    self._publish_gesture(skin, t, what)
                else:
                    self._publish_frame(skin, t, what)

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Wait until every frame queued so far is published; False on timeout."""
        return self._pub.flush(timeout_s) if self._pub is not None else True

    def stats(self) -> dict[str, Any]:
        """The publisher thread's counters (frames queued, dropped, sent; batches; CPU s)."""
        return self._pub.stats() if self._pub is not None else dict(self._last_stats)

    def close(self) -> None:
        """Publish what is queued, join the publisher thread, leave the domain (destroy the node).

        Idempotent.
        """
        if self._pub is not None:
            self._pub.close()
            self._last_stats = self._pub.stats()
            self._pub = None
        if self._io is not None:
            self._io.close()
            self._io = None
            self.__dict__.pop("_write", None)
        self._msgs = None
        self._enc.clear()
        self._skins.clear()
