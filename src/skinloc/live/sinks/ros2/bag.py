"""A ROS 2 bag (MCAP, what ``ros2 bag play`` reads) of the ROS 2 sink's topics and the raw frames.

The same topics, types and stamps as ``Ros2Sink`` (``live.sinks.ros2.sink``), each message CDR
encoded exactly as on the DDS wire (``message_encoding`` ``cdr``) with its ``.msg`` definition
as schema (``ros2msg``), plus ``/skinloc/<skin>/frames``: every raw frame as a
``sensor_msgs/Image`` (``32FC1``, TX rows by RX columns, raw counts), its frame counter kept as
the message's sequence number, so ``skinloc run --source FILE.mcap`` replays the bag.

The file is written under a temporary name next to it and renamed when closed, so a crash never
leaves a truncated bag under the final name; an existing file is never overwritten.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

from skinloc._lazy import require_extra
from skinloc.live.sinks.base import SinkSpec, SkinInfo
from skinloc.live.sinks.ros2.topics import Ros2Topics, require_msgs

__all__ = ["CHUNK_BYTES", "Ros2BagSink", "bag_requirements", "offered_qos"]


def offered_qos(latched: bool, depth: int) -> str:
    """The ``offered_qos_profiles`` channel metadata (YAML) of a topic of the bag.

    rosbag2 stores it and ``ros2 bag play`` publishes with it: one reliable keep-last profile,
    transient local when ``latched``.

    Numeric enums (rmw's: history 1 keep last; reliability 1 reliable; durability 1 transient
    local, 2 volatile; liveliness 1 automatic) and zero durations (the defaults), the form
    rosbag2 has written since Foxy.
    """
    zero = "\n    sec: 0\n    nsec: 0"
    return (
        f"- history: 1\n  depth: {depth}\n  reliability: 1\n  durability: {1 if latched else 2}"
        f"\n  deadline:{zero}\n  lifespan:{zero}\n  liveliness: 1"
        f"\n  liveliness_lease_duration:{zero}\n  avoid_ros_namespace_conventions: false"
    )


#: Uncompressed bytes per MCAP chunk: small, so the file on disk (and the size the app shows)
#: grows every second or two of raw frames, and a killed writer loses little (mcap's default is
#: 1 MiB, half a minute of one skin's frames).
CHUNK_BYTES = 64 * 1024


def _require_mcap() -> Any:
    writer = require_extra("mcap.writer", "the ROS 2 bag sink")
    return writer.Writer, writer.CompressionType


def bag_requirements() -> Any:
    """The MCAP writer and its compression types, once the ROS 2 messages import too.

    Raises one ``MissingExtraError`` naming the extra (``live``) when either is missing, so a
    user installs once rather than learning of ``mcap`` and then of ``cyclonedds``.
    """
    found = _require_mcap()
    require_msgs()
    return found


class Ros2BagSink(Ros2Topics):
    """Write the ROS 2 topics (and raw frames) to an MCAP ROS 2 bag.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file to create; it must not exist yet.
    frames : bool, default=True
        Record the raw frames (``/skinloc/<skin>/frames``).
    """

    name = "mcap-ros2"

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> Ros2BagSink:
        """``mcap-ros2:FILE``: a new ROS 2 bag at FILE, raw frames included."""
        return cls(spec.file())

    def __init__(self, path: str | Path, *, frames: bool = True) -> None:
        super().__init__()
        self.path = Path(path)
        self.wants_frames = frames
        self._writer: Any = None
        self._fh: Any = None
        self._tmp: Path | None = None
        self._channels: dict[str, int] = {}
        self._schemas: dict[type, int] = {}
        self._seq: dict[str, int] = {}

    def open(self, skins: list[SkinInfo]) -> None:
        """Create the file (under a temporary name) and write meshes and transforms."""
        if self._writer is not None:
            for s in skins:
                if s.name not in self._skins:
                    self._add_skin(s)
            return
        writer_cls, compression = bag_requirements()  # before any file exists
        if self.path.exists():
            raise FileExistsError(f"{self.path} exists; the ROS 2 bag sink never overwrites a file")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent
        )
        self._tmp = Path(tmp)
        self._fh = os.fdopen(fd, "wb")
        try:
            self._writer = writer_cls(
                self._fh, chunk_size=CHUNK_BYTES, compression=compression.ZSTD
            )
            self._writer.start(profile="ros2", library="skinloc")
            self._open_topics(skins)
        except BaseException:  # nothing was recorded yet: leave no file behind
            self._fh.close()
            self._tmp.unlink(missing_ok=True)
            self._writer = self._fh = None
            raise

    def _advertise(self, topic: str, cls: type, latched: bool) -> None:
        if topic in self._channels:
            return
        m = self._msgs
        schema = self._schemas.get(cls)
        if schema is None:
            schema = self._schemas[cls] = self._writer.register_schema(
                name=m.ros_type_name(cls),
                encoding="ros2msg",
                data=m.msg_definition(cls).encode(),
            )
        self._channels[topic] = self._writer.register_channel(
            topic=topic,
            message_encoding="cdr",
            schema_id=schema,
            metadata={"offered_qos_profiles": offered_qos(latched, 1 if latched else 10)},
        )

    def _write(self, topic: str, data: bytes, t_ns: int, sequence: int | None = None) -> None:
        if sequence is None:
            sequence = self._seq.get(topic, 0)
        self._seq[topic] = sequence + 1
        self._writer.add_message(
            channel_id=self._channels[topic],
            log_time=t_ns,
            publish_time=t_ns,
            data=data,
            sequence=sequence,
        )

    @property
    def n_bytes(self) -> int:
        """Bytes written so far (the file's size once closed; 0 before ``open``)."""
        if self._fh is not None:
            return self._fh.tell()
        return self.path.stat().st_size if self.path.is_file() else 0

    def close(self) -> None:
        """Finish the file and give it its name."""
        if self._writer is None:
            return
        try:
            self._writer.finish()
            self._fh.close()
            if self.path.exists():  # appeared meanwhile: keep both
                raise FileExistsError(
                    f"{self.path} appeared while recording; bag left at {self._tmp}"
                )
            os.replace(self._tmp, self.path)
        finally:
            self._writer = None
            self._fh = None
