"""Binary records between the ROS 2 sink and its publisher process (one pipe, one direction).

The live pipeline must not share its interpreter lock with the ROS 2 encoding and DDS writes
(measured: the writes hold the lock, and at 100 skins the loop's p99 latency went from about
1 ms to 5-9 ms with them on a thread beside it; docs/benchmarks.md, "ROS 2 sinks"). So the
sink packs each frame's contacts into a small record and writes it to a pipe; the publisher
process (``skinloc.live.sinks.ros2.publisher``) reads, rebuilds the contacts and publishes.

A record is ``<I`` total length (header included), ``<B`` kind, then the payload:

* ``FRAME``: ``<HddB`` skin number, frame timestamp (s), the sink's ``time.monotonic()`` at
  ``emit`` (s), contact count; then per contact ``<Bqqqqddddd``: state, frame index, touch id,
  track id, slot, x, y, z (m), strength (counts), peak signal (noise units).
* ``GESTURE``: ``<Hdd`` skin number, timestamp, emit time; then the event as UTF-8 JSON.
* ``SKINS``: a pickle of ``list[SkinInfo]``, numbered from the first unnumbered skin.
* ``SYNC``: ``<I`` token: the publisher answers once everything before it is published.
* ``MATCHED``: ``<I`` token, then a topic name (UTF-8): the publisher answers with the number of
  subscriptions its writer of that topic has matched.
* ``CONTROL``: UTF-8 JSON for the node (``skinloc.live.sinks.ros2.node``): each skin's settings
  (``{"settings": ...}``), an answer to one of its requests (``{"answer": ID, ...}``) and the
  diagnostics (``{"diagnostics": [...]}``).

Frame records are far below ``PIPE_BUF`` (4096 bytes), so a non-blocking write of one is atomic:
it goes in whole or raises ``BlockingIOError`` (the pipe is full: the record is dropped and
counted), and the stream never holds half a record.
"""

from __future__ import annotations

import json
import math
import pickle
import struct
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any

from skinloc.live.contact import Contact

if TYPE_CHECKING:
    from skinloc.live.sinks.base import SkinInfo

__all__ = [
    "CONTROL",
    "FRAME",
    "GESTURE",
    "MATCHED",
    "SKINS",
    "SYNC",
    "RecordReader",
    "pack_control",
    "pack_frame",
    "pack_gesture",
    "pack_matched",
    "pack_skins",
    "pack_sync",
]

FRAME, GESTURE, SKINS, SYNC, MATCHED, CONTROL = 1, 2, 3, 4, 5, 6

_HEAD = struct.Struct("<IB")  # record length, kind
_FRAME = struct.Struct("<HddB")  # skin, timestamp s, emitted at (monotonic s), n contacts
_GESTURE = struct.Struct("<Hdd")  # skin, timestamp s, emitted at
# state, index, touch id, track id, slot, position x y z (m), strength, signal_z
_CONTACT = struct.Struct("<Bqqqqddddd")
_SYNC = struct.Struct("<I")

_STATES = ("idle", "start", "move", "end")
_STATE_CODE = {s: i for i, s in enumerate(_STATES)}
_NAN3 = (math.nan, math.nan, math.nan)


def pack_frame(
    skin: int, timestamp_s: float, emitted_s: float, contacts: Sequence[Contact]
) -> bytes:
    """One frame's contacts as a ``FRAME`` record (what the publisher needs of each).

    Parameters
    ----------
    skin : int
        The skin's number (its order in the ``SKINS`` records).
    timestamp_s : float
        The frame's timestamp, s.
    emitted_s : float
        ``time.monotonic()`` when the pipeline handed the frame over, s (the publisher reports
        how long each frame took to reach DDS).
    contacts : sequence of Contact
        At most 255.
    """
    parts = [b"", _FRAME.pack(skin, timestamp_s, emitted_s, len(contacts))]
    for c in contacts:
        x, y, z = c.position_m
        parts.append(
            _CONTACT.pack(
                _STATE_CODE.get(c.state, 0),
                c.index,
                c.touch_id,
                c.track_id,
                c.slot,
                x,
                y,
                z,
                c.strength,
                c.signal_z,
            )
        )
    n = _HEAD.size + _FRAME.size + _CONTACT.size * len(contacts)
    parts[0] = _HEAD.pack(n, FRAME)
    return b"".join(parts)


def pack_gesture(skin: int, timestamp_s: float, emitted_s: float, event: Any) -> bytes:
    """A gesture event (JSON-ready dict) as a ``GESTURE`` record."""
    body = json.dumps(event, separators=(",", ":")).encode()
    n = _HEAD.size + _GESTURE.size + len(body)
    return _HEAD.pack(n, GESTURE) + _GESTURE.pack(skin, timestamp_s, emitted_s) + body


def pack_skins(skins: Sequence[SkinInfo]) -> bytes:
    """Skins to add, as a ``SKINS`` record (numbered in order after those already sent)."""
    body = pickle.dumps(list(skins), protocol=pickle.HIGHEST_PROTOCOL)
    return _HEAD.pack(_HEAD.size + len(body), SKINS) + body


def pack_sync(token: int) -> bytes:
    """A ``SYNC`` record: the publisher answers ``token`` once everything before it is out."""
    return _HEAD.pack(_HEAD.size + _SYNC.size, SYNC) + _SYNC.pack(token)


def pack_matched(token: int, topic: str) -> bytes:
    """A ``MATCHED`` record: asks how many subscriptions the writer of ``topic`` matched."""
    body = _SYNC.pack(token) + topic.encode()
    return _HEAD.pack(_HEAD.size + len(body), MATCHED) + body


def pack_control(message: dict[str, Any]) -> bytes:
    """A JSON-ready message for the node as a ``CONTROL`` record."""
    body = json.dumps(message, separators=(",", ":")).encode()
    return _HEAD.pack(_HEAD.size + len(body), CONTROL) + body


class RecordReader:
    """Split a byte stream into records, rebuilding contacts and events.

    ``feed(data)`` yields ``(kind, value)`` for every record completed by ``data``:
    ``FRAME``: ``(skin, timestamp_s, emitted_s, [Contact, ...])``; ``GESTURE``: ``(skin,
    timestamp_s, emitted_s, event dict)``; ``SKINS``: ``list[SkinInfo]``; ``SYNC``: the token;
    ``MATCHED``: ``(token, topic)``; ``CONTROL``: the message (dict).
    The contacts carry the skin's name once ``names`` (the numbered skins) has it.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.names: list[str] = []

    def feed(self, data: bytes | memoryview) -> Iterator[tuple[int, Any]]:
        """Records completed by ``data``, in order."""
        buf = self._buf
        buf += data
        pos = 0
        n_buf = len(buf)
        head = _HEAD.size
        while n_buf - pos >= head:
            n, kind = _HEAD.unpack_from(buf, pos)
            if n < head:
                raise ValueError(f"corrupt record stream (record length {n})")
            if n_buf - pos < n:
                break
            if kind == FRAME:  # decoded in place: most records are frames
                value: Any = self._frame(buf, pos + head)
            else:
                value = self._decode(kind, bytes(buf[pos + head : pos + n]))
            pos += n
            yield kind, value
        del buf[:pos]

    def _name(self, skin: int) -> str:
        return self.names[skin] if skin < len(self.names) else f"skin{skin}"

    def _frame(self, buf: bytes | bytearray, at: int) -> tuple[int, float, float, list[Contact]]:
        """A ``FRAME`` record's body at ``at`` of ``buf``."""
        skin, t, emitted, count = _FRAME.unpack_from(buf, at)
        name = self._name(skin)
        contacts = []
        at += _FRAME.size
        for _ in range(count):
            st, index, touch, track, slot, x, y, z, strength, z_sig = _CONTACT.unpack_from(buf, at)
            at += _CONTACT.size
            contacts.append(
                Contact(
                    name,
                    t,
                    index,
                    _STATES[st],
                    (x, y, z),
                    _NAN3,
                    math.nan,
                    z_sig,
                    math.nan,
                    math.nan,
                    touch,
                    track,
                    slot,
                    strength,
                )  # fmt: skip
            )
        return skin, t, emitted, contacts

    def _decode(self, kind: int, body: bytes) -> Any:
        if kind == GESTURE:
            skin, t, emitted = _GESTURE.unpack_from(body)
            return skin, t, emitted, json.loads(body[_GESTURE.size :])
        if kind == SKINS:
            skins = pickle.loads(body)  # noqa: S301 - our own parent, over a private pipe
            self.names += [s.name for s in skins]
            return skins
        if kind == SYNC:
            return _SYNC.unpack(body)[0]
        if kind == MATCHED:
            return _SYNC.unpack_from(body)[0], body[_SYNC.size :].decode()
        if kind == CONTROL:
            return json.loads(body)
        raise ValueError(f"corrupt record stream (unknown record kind {kind})")
