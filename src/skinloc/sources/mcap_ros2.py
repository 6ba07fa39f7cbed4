"""Replay the raw frames of a ROS 2 bag (MCAP): ``skinloc run --source FILE.mcap``.

The frames are a ``sensor_msgs/msg/Image`` topic, as the ``mcap-ros2`` sink records them
(``/skinloc/<skin>/frames``, ``32FC1``, TX rows by RX columns); a bag recorded by another ROS 2
driver works too if its image holds one value per sensor (``32FC1``, ``64FC1``, ``16UC1``,
``mono16``, ``8UC1``, ``mono8``). Timestamps are the header stamps (s, made relative to the
first frame), frame counters the MCAP sequence numbers (a running count when a bag has none).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from skinloc._lazy import require_extra
from skinloc.errors import RecordingError
from skinloc.sources.base import SourceOptions
from skinloc.sources.replay import ArrayReplaySource

__all__ = ["McapReplaySource", "bag_summary", "image_topics"]

_IMAGE = "sensor_msgs/msg/Image"
_DTYPES = {
    "32FC1": "f4",
    "64FC1": "f8",
    "16UC1": "u2",
    "mono16": "u2",
    "8UC1": "u1",
    "mono8": "u1",
}


def _reader(fh):
    return require_extra("mcap.reader", "replaying a ROS 2 bag").make_reader(fh)


def image_topics(path: str | Path) -> list[str]:
    """The ``sensor_msgs/msg/Image`` topics of a bag, sorted."""
    try:
        with open(path, "rb") as fh:
            summary = _reader(fh).get_summary()
    except Exception as exc:  # noqa: BLE001 - mcap raises many kinds on a broken file
        raise RecordingError(f"cannot read the ROS 2 bag {path}: {exc}") from None
    if summary is None:
        raise RecordingError(f"{path} has no MCAP summary (not finished?)")
    return _image_topics(summary)


def _image_topics(summary: Any) -> list[str]:
    """The CDR ``sensor_msgs/msg/Image`` topics of an MCAP summary, sorted."""
    return sorted(
        ch.topic
        for ch in summary.channels.values()
        if summary.schemas.get(ch.schema_id) is not None
        and summary.schemas[ch.schema_id].name == _IMAGE
        and ch.message_encoding == "cdr"
    )


def bag_summary(path: str | Path) -> dict[str, Any]:
    """What an MCAP file holds, from its summary section (``skinloc info``).

    Keys: ``file``, ``format`` ("mcap"), ``profile`` (``ros2`` for a ROS 2 bag), ``library``
    (the writer), ``n_messages``, ``start_s``/``end_s`` (log times, s since the epoch),
    ``duration_s``, ``channels`` (one entry per channel: ``topic``, ``schema``, ``encoding``,
    ``n_messages``) and ``replayable`` (the image topics ``skinloc run --source FILE`` plays).
    ``RecordingError`` when the file is not a finished MCAP file.
    """
    path = Path(path)
    make_reader = require_extra("mcap.reader", "reading an MCAP file").make_reader
    try:
        with open(path, "rb") as fh:
            reader = make_reader(fh)
            header = reader.get_header()
            summary = reader.get_summary()
    except Exception as exc:  # noqa: BLE001 - mcap raises many kinds on a broken file
        raise RecordingError(f"cannot read the MCAP file {path}: {exc}") from None
    if summary is None or summary.statistics is None:
        raise RecordingError(f"{path} has no MCAP summary (not finished? a writer was stopped)")
    stats = summary.statistics
    counts = stats.channel_message_counts
    channels = []
    for cid, ch in sorted(summary.channels.items()):
        schema = summary.schemas.get(ch.schema_id)
        channels.append(
            {
                "topic": ch.topic,
                "schema": None if schema is None else schema.name,
                "encoding": ch.message_encoding,
                "n_messages": int(counts.get(cid, 0)),
            }
        )
    start, end = stats.message_start_time * 1e-9, stats.message_end_time * 1e-9
    return {
        "file": str(path),
        "format": "mcap",
        "profile": header.profile,
        "library": header.library,
        "n_messages": int(stats.message_count),
        "start_s": round(start, 6) if stats.message_count else None,
        "end_s": round(end, 6) if stats.message_count else None,
        "duration_s": round(end - start, 6) if stats.message_count else 0.0,
        "channels": channels,
        "replayable": _image_topics(summary),
    }


class McapReplaySource(ArrayReplaySource):
    """Play back the raw frames of a ROS 2 bag.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` bag.
    skin : str, optional
        Pick the topic ``/skinloc/<skin>/frames`` when the bag has it (``-`` and other
        characters ROS 2 names do not allow read as ``_``).
    topic : str, optional
        The image topic to play (default: the skin's, else the bag's only image topic).
    loop : bool, default=False
        Start again at the end instead of timing out.
    """

    _what = "bag"

    def __init__(
        self,
        path: str | Path,
        *,
        skin: str | None = None,
        topic: str | None = None,
        loop: bool = False,
    ) -> None:
        from skinloc.ros2.msgs import Image
        from skinloc.ros2.names import topic_base

        self.path = Path(path)
        topics = image_topics(self.path)
        if topic is None:
            own = f"{topic_base(skin)}/frames" if skin is not None else None
            if skin is not None and own in topics:
                topic = own
            elif len(topics) == 1:
                topic = topics[0]
            elif not topics:
                raise RecordingError(f"{self.path} has no sensor_msgs/msg/Image topic to replay")
            else:
                raise RecordingError(
                    f"{self.path} has several image topics ({', '.join(topics)}); name the "
                    f"skin after one (/skinloc/<skin>/frames)"
                )
        elif topic not in topics:
            raise RecordingError(f"{self.path} has no image topic {topic!r}")
        self.topic = topic
        frames, times, index = [], [], []
        shape = None
        try:
            with open(self.path, "rb") as fh:
                for _, _, msg in _reader(fh).iter_messages(topics=[topic]):
                    img = Image.deserialize(msg.data)
                    dtype = _DTYPES.get(img.encoding)
                    if dtype is None:
                        raise RecordingError(
                            f"{topic}: image encoding {img.encoding!r} is not one value per "
                            f"sensor ({', '.join(_DTYPES)})"
                        )
                    dt = np.dtype((">" if img.is_bigendian else "<") + dtype)
                    values = np.frombuffer(bytes(img.data), dtype=dt)
                    if values.size != img.height * img.width:
                        raise RecordingError(f"{topic}: image data does not match its size")
                    if shape is None:
                        shape = (int(img.height), int(img.width))
                    elif shape != (img.height, img.width):
                        raise RecordingError(f"{topic}: the image size changes")
                    frames.append(values.astype(np.float32))
                    times.append(img.header.stamp.sec + img.header.stamp.nanosec * 1e-9)
                    index.append(msg.sequence)
        except RecordingError:
            raise
        except Exception as exc:  # noqa: BLE001 - a corrupt bag fails in many ways
            raise RecordingError(f"cannot read {topic} of {self.path}: {exc}") from None
        if shape is None:
            raise RecordingError(f"{self.path}: {topic} has no frames")
        self.n_tx, self.n_rx = shape
        self._frames = np.stack(frames)
        t = np.asarray(times, dtype=np.float64)
        self._times = t - t[0]
        idx = np.asarray(index, dtype=np.int64)
        self._index = idx if len(set(index)) == len(index) else np.arange(len(idx))
        self.loop = loop
        self._pos = 0
        self._connected = False

    @classmethod
    def from_options(cls, options: SourceOptions, mesh: Any = None) -> McapReplaySource:
        """The bag ``options`` name (``skinloc.sources.base.make_source``): its skin's frames."""
        return cls(options.source, skin=options.skin, loop=options.loop)

    @property
    def name(self) -> str:
        """The file and topic."""
        return f"{self.path}:{self.topic}"
