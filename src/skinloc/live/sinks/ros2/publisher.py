"""The ROS 2 publisher process: DDS (or rclpy) writes of the live ROS 2 sink, off its process.

``skinloc.live.sinks.ros2.sink.Ros2Sink`` starts this module as a process of its own
(``python -m skinloc.live.sinks.ros2.publisher IN OUT CONFIG``) and writes records
(``skinloc.live.sinks.ros2.records``) to the pipe ``IN``. This process rebuilds each frame's
contacts, encodes the ROS 2 messages (``Ros2Topics``) and writes them, then answers on the pipe
``OUT`` with JSON lines: ``{"ready": ...}`` once the domain is joined and the first skins are
advertised (or ``{"error": ..., "type": ...}``), ``{"sync": TOKEN, "stats": ...}`` for every
``SYNC`` record, and ``{"final": stats}`` at the end.

It ignores SIGINT (a Ctrl-C reaches the whole process group; the sink's owner decides when to
stop) and ends at the end of ``IN``: when the sink closes, or when its process is gone, so it
is never left behind. Everything queued before the end is published first.
"""

from __future__ import annotations

import array
import functools
import io
import json
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from skinloc.live.sinks.base import SkinInfo
from skinloc.live.sinks.ros2.records import (
    CONTROL,
    FRAME,
    GESTURE,
    MATCHED,
    SKINS,
    SYNC,
    RecordReader,
)
from skinloc.live.sinks.ros2.topics import Ros2Topics, rclpy_available, require_msgs

log = logging.getLogger(__name__)

__all__ = ["Ros2Publisher", "main"]

_DEPTH = 10  # keep-last depth of the data topics (rclpy's default QoS profile)
_DELAYS = 1 << 17  # publishing delays kept for the statistics (the latest ones)
_CLOSE_S = 5.0  # the longest the node's teardown is waited for before the process exits
_READ_BYTES = 1 << 20  # the most one read takes from the pipe (the pipe holds about as much)


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

    def write(self, topic: str, data: bytes) -> None:
        """Write CDR bytes on ``topic``."""
        # the bytes are already CDR (the struct encoders): hand them to the C writer as
        # DataWriter.write does after serialize(), padded to 4 bytes
        if len(data) % 4:
            data += b"\x00" * (-len(data) % 4)
        ret = self._ddspy_write(self._refs[topic], data)
        if ret < 0:
            raise OSError(f"DDS write on {topic} failed ({ret})")

    def sender(self, topic: str) -> Callable[[bytes], None]:
        """What writes CDR bytes on ``topic`` (advertised), called once a message."""
        return functools.partial(self.write, topic)

    def matched(self, topic: str) -> int:
        w = self.writers.get(topic)
        return len(w.get_matched_subscriptions()) if w is not None else 0

    def control(self, message: dict[str, Any]) -> None:
        """No node: parameters, services and diagnostics are not served (the sink said so)."""

    def close(self) -> None:
        self.writers.clear()
        self._refs.clear()
        self.participant = None  # the participant and its entities are freed with it


class _RclpyBackend:
    """A ROS 2 node (rclpy) publishing the same CDR bytes (``Publisher.publish`` takes bytes).

    Its parameters, services and ``/diagnostics`` are ``node.NodeServices``'s. A message type
    whose Python package is missing (``tf2_msgs``: no wheel of it) goes out through a plain DDS
    writer beside the node (``_DdsBackend``), with the same type name and CDR bytes.
    """

    def __init__(self, node_name: str, domain_id: int, ask: Any = None) -> None:
        import rclpy
        from rclpy.signals import SignalHandlerOptions

        from skinloc.live.sinks.ros2.node import NodeServices

        self._own_init = False
        self.domain_id = domain_id
        if not rclpy.ok():
            # no signal handlers: the sink's owner ends this process by closing its pipe
            rclpy.init(domain_id=domain_id, signal_handler_options=SignalHandlerOptions.NO)
            self._own_init = True
        self.node = rclpy.create_node(node_name)
        self.pubs: dict[str, Any] = {}
        self._dds: _DdsBackend | None = None  # for types without a Python package here
        self.services = NodeServices(self.node, ask) if ask is not None else None

    def advertise(self, topic: str, cls: type, latched: bool) -> None:
        import importlib

        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        from skinloc.ros2.msgs import ros_type_name

        if topic in self.pubs:
            return
        pkg, _, name = ros_type_name(cls).split("/")
        try:
            msg_type = getattr(importlib.import_module(f"{pkg}.msg"), name)
        except ImportError:
            if self._dds is None:
                self._dds = _DdsBackend(self.domain_id)
            self._dds.advertise(topic, cls, latched)
            return
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST,
            depth=1 if latched else _DEPTH,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
        )
        self.pubs[topic] = self.node.create_publisher(msg_type, topic, qos)

    def sender(self, topic: str) -> Callable[[bytes], None]:
        """What publishes CDR bytes on ``topic`` (advertised), called once a message.

        rclpy's own ``publish_raw``, which ``Publisher.publish`` calls for bytes after two type
        checks and taking the handle (about a microsecond a message, three messages a frame);
        the node is destroyed only once the publishing loop has ended (``close``).
        """
        pub = self.pubs.get(topic)
        if pub is None:
            assert self._dds is not None  # advertised through the DDS writer
            return self._dds.sender(topic)
        raw = getattr(pub.handle, "publish_raw", None)
        return raw if raw is not None else pub.publish

    def matched(self, topic: str) -> int:
        p = self.pubs.get(topic)
        if p is None and self._dds is not None:
            return self._dds.matched(topic)
        return p.get_subscription_count() if p is not None else 0

    def control(self, message: dict[str, Any]) -> None:
        if self.services is not None:
            self.services.control(message)

    def close(self) -> None:
        import rclpy

        if self.services is not None:
            self.services.close()
        if self._dds is not None:
            self._dds.close()
        self.node.destroy_node()
        if self._own_init:
            rclpy.shutdown()


class Ros2Publisher(Ros2Topics):
    """Publish on the ROS 2 topics from the calling thread (the publisher process's loop).

    Parameters
    ----------
    node_name : str
        The node's name (rclpy only).
    domain_id : int
        DDS domain.
    backend : {"auto", "dds", "rclpy"}
        ``auto``: rclpy when importable, else plain DDS.
    ask : callable(dict), optional
        Sends the node's requests to the skins' process (``node.NodeServices``); None: the
        node serves no parameters, services or diagnostics.
    """

    def __init__(
        self, node_name: str, domain_id: int, backend: str = "auto", ask: Any = None
    ) -> None:
        super().__init__()
        self.node_name = node_name
        self.domain_id = domain_id
        self.backend = backend
        self.backend_used = ""
        self._ask = ask
        self._io: Any = None
        self._send: dict[str, Callable[[bytes], None]] = {}  # per topic: its writer's call

    def open(self, skins: list[SkinInfo]) -> None:
        """Join the domain (or create the node), advertise, publish meshes and transforms."""
        if self._io is not None:
            for s in skins:
                if s.name not in self._skins:
                    self._add_skin(s)
            self._publish_tf_static()
            return
        use_rclpy = self.backend == "rclpy" or (self.backend == "auto" and rclpy_available())
        require_msgs()
        if use_rclpy:
            if not rclpy_available():
                raise ImportError("backend 'rclpy' needs a sourced ROS 2 installation")
            self._io = _RclpyBackend(self.node_name, self.domain_id, self._ask)
        else:
            self._io = _DdsBackend(self.domain_id)
        self.backend_used = "rclpy" if use_rclpy else "dds"
        self._open_topics(skins)

    def _advertise(self, topic: str, cls: type, latched: bool) -> None:
        self._io.advertise(topic, cls, latched)
        self._send[topic] = self._io.sender(topic)

    def _write(self, topic: str, data: bytes, t_ns: int, sequence: int | None = None) -> None:
        self._send[topic](data)

    def control(self, message: dict[str, Any]) -> None:
        """A ``CONTROL`` message of the skins' process, for the node."""
        if self._io is not None:
            self._io.control(message)

    def close(self) -> None:
        """Leave the domain (destroy the node). Idempotent."""
        if self._io is not None:
            self._io.close()
            self._io = None
        self._msgs = None
        self._send.clear()
        self._enc.clear()
        self._skins.clear()


class _Stats:
    """What the publisher process did: records published, errors, CPU and delays."""

    def __init__(self) -> None:
        self.sent = self.errors = self.reads = 0
        # s, a ring of the latest (an array of doubles: a store costs half NumPy's)
        self.delays = array.array("d", bytes(8 * _DELAYS))
        self.n_delays = 0
        self.cpu0 = time.process_time()  # reset once ready: start-up is not publishing

    def delay(self, emitted_s: float) -> None:
        self.delays[self.n_delays % _DELAYS] = time.monotonic() - emitted_s
        self.n_delays += 1

    def as_dict(self) -> dict[str, Any]:
        d = np.frombuffer(self.delays, dtype=np.float64)[: min(self.n_delays, _DELAYS)] * 1e6
        return {
            "sent": self.sent,
            "errors": self.errors,
            "batches": self.reads,
            "cpu_s": time.process_time() - self.cpu0,  # Cyclone's threads included
            "publish_delay_median_us": float(np.median(d)) if len(d) else None,
            "publish_delay_p99_us": float(np.percentile(d, 99)) if len(d) else None,
        }


def _serve(fd_in: int, reply: Any, config: dict[str, Any]) -> int:
    """Read records from ``fd_in`` until its end; publish; answer on ``reply``."""
    lock = threading.Lock()  # the node's thread asks too

    def say(**msg: Any) -> None:
        line = json.dumps(msg) + "\n"
        with lock:
            reply.write(line)
            reply.flush()

    reader = RecordReader()
    pub = Ros2Publisher(
        config["node_name"], int(config["domain_id"]), config["backend"], lambda m: say(**m)
    )
    stats = _Stats()
    gather_s = float(config.get("gather_s", 0.001))
    opened = False
    # every read into one buffer: ``os.read(fd, 1 MB)`` allocates a megabyte and gives it back
    # each time (12 us a read here, where reading into a buffer costs 0.5 us)
    source = io.FileIO(fd_in, "rb", closefd=False)
    chunk = memoryview(bytearray(_READ_BYTES))
    try:
        while True:
            n = source.readinto(chunk)
            if not n:
                break
            stats.reads += 1
            for kind, value in reader.feed(chunk[:n]):
                if kind == FRAME:
                    skin, t, emitted, contacts = value
                    try:
                        pub.emit_contacts(reader.names[skin], t, contacts)
                        stats.sent += 1
                    except Exception:  # noqa: BLE001 - one bad frame must not end publishing
                        stats.errors += 1
                        if stats.errors == 1:
                            log.exception("publishing a frame failed")
                    stats.delay(emitted)
                elif kind == GESTURE:
                    skin, t, emitted, event = value
                    try:
                        pub.emit_gesture(reader.names[skin], t, event)
                        stats.sent += 1
                    except Exception:  # noqa: BLE001
                        stats.errors += 1
                        if stats.errors == 1:
                            log.exception("publishing a gesture failed")
                elif kind == SKINS:
                    try:
                        pub.open(value)
                    except Exception as exc:  # noqa: BLE001 - reported to the sink, which raises
                        say(error=str(exc), type=type(exc).__name__)
                        if not opened:
                            return 1
                        continue
                    if not opened:
                        opened = True
                        stats.cpu0 = time.process_time()
                        say(ready=True, backend=pub.backend_used, pid=os.getpid())
                elif kind == SYNC:
                    say(sync=value, stats=stats.as_dict())
                elif kind == CONTROL:
                    try:
                        pub.control(value)
                    except Exception:  # noqa: BLE001 - the node must go on publishing
                        stats.errors += 1
                        log.exception("serving the node failed")
                elif kind == MATCHED:
                    token, topic = value
                    say(matched=token, n=pub._io.matched(topic) if pub._io is not None else 0)
            if gather_s > 0:  # let the next batch gather: a bound on the wake-ups per second
                time.sleep(gather_s)
        say(final=stats.as_dict())
        return 0
    finally:
        _close_within(pub, _CLOSE_S)


def _close_within(pub: Ros2Publisher, timeout_s: float) -> None:
    """``pub.close()``, waited for at most ``timeout_s``.

    The sink waits for this process to end, and a DDS or rclpy teardown that stalls on a loaded
    machine must not hold its owner's Ctrl-C (the process then exits without Python's
    finalisation, see ``__main__``).
    """
    closing = threading.Thread(target=pub.close, name="skinloc-ros2-close", daemon=True)
    closing.start()
    closing.join(timeout_s)
    if closing.is_alive():
        log.warning("closing the ROS 2 node took over %.0f s; exiting without it", timeout_s)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the publisher process: ``IN OUT CONFIG_JSON``."""
    # a Ctrl-C reaches the whole process group: the sink's owner closes the pipe instead
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    args = sys.argv[1:] if argv is None else argv
    fd_in, fd_out, config = int(args[0]), int(args[1]), json.loads(args[2])
    logging.basicConfig(format="skinloc ROS 2 publisher: %(message)s", level=logging.WARNING)
    with os.fdopen(fd_out, "w") as reply:
        try:
            return _serve(fd_in, reply, config)
        except BrokenPipeError:  # the sink's process is gone: nobody to answer
            return 0
        except Exception as exc:  # noqa: BLE001 - the sink shows it as one line
            try:
                reply.write(json.dumps({"error": str(exc), "type": type(exc).__name__}) + "\n")
                reply.flush()
            except OSError:
                pass
            return 1


if __name__ == "__main__":
    code = main()
    logging.shutdown()
    # everything is closed (or given up on): skip the interpreter's finalisation, where a
    # daemon thread of rclpy or Cyclone DDS could hold the exit
    os._exit(code)
