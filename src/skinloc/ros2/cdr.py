"""Fast CDR encoders of the per-frame ROS 2 messages, checked against the IDL serialiser.

``IdlStruct.serialize`` is pure Python (about 0.1 ms for a ``PoseArray``, more for a
``MarkerArray``), too slow for every frame of 100 skins at 100 Hz. The per-frame messages are
therefore packed with ``struct`` from per-skin prefixes; ``check_encoders`` compares every
encoder with ``serialize()`` of the same message (``skinloc.ros2.msgs``), so those
dataclasses stay the one definition of each layout.

CDR (XCDR1, little endian): each primitive is aligned to its size, counted from the end of the
4-byte encapsulation header; strings are a ``uint32`` length (NUL included), the bytes and the
NUL; sequences a ``uint32`` count, then the elements.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from operator import itemgetter
from typing import Any

import numpy as np

from skinloc.ros2.msgs import (
    ColorRGBA,
    Duration,
    Header,
    Image,
    Marker,
    MarkerArray,
    Point,
    PointStamped,
    Pose,
    PoseArray,
    Quaternion,
    Time,
    Vector3,
)

__all__ = ["MARKER_NS", "SPHERE_M", "HeaderEncoder", "SphereMarker", "check_encoders"]

#: ``ns`` of the contact spheres on ``/skinloc/<skin>/markers``
MARKER_NS = "skinloc/contacts"
#: diameter of a contact sphere, m
SPHERE_M = 0.01

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR little endian (XCDR1), options 0
_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")
_ONE = _ENCAPSULATION + _U32.pack(1)  # a sequence of one

#: ``(x, y, z, id, action, r, g, b, a)`` of one sphere of a ``MarkerArray``: position m, id,
#: ``Marker.ADD`` or ``Marker.DELETE``, colour in [0, 1]
SphereMarker = tuple[float, float, float, int, int, float, float, float, float]


def _cdr_string(text: str) -> bytes:
    data = text.encode() + b"\x00"
    return _U32.pack(len(data)) + data


class _Layout:
    """A CDR layout of fixed size compiled for one start offset (mod 8), packed in one call.

    ``fields``: ``(code, value)`` with ``code`` a ``struct`` code (``i I d f ?``) or ``s``
    (string); ``value`` None for what ``pack`` fills in, else a constant baked in now. The
    layout is one ``struct.Struct`` whose runs of constant bytes (padding included) are ``Ns``
    fields: ``pack`` appends the constants to the values and puts every argument in its place
    with one ``itemgetter`` (one C call each, where a loop over the runs cost a microsecond or
    two a marker).
    """

    def __init__(self, fields: Sequence[tuple[str, Any]], start: int) -> None:
        fmt = "<"
        const = bytearray()
        consts: list[bytes] = []
        order: list[tuple[str, int]] = []  # per argument: ("v", value index) or ("c", const)
        n_var = 0
        off = start

        def end_const() -> None:
            nonlocal fmt
            if const:
                fmt += f"{len(const)}s"
                order.append(("c", len(consts)))
                consts.append(bytes(const))
                const.clear()

        for code, value in fields:
            size = 4 if code == "s" else struct.calcsize("<" + code)
            pad = -off % size
            if value is None:
                end_const()
                fmt += "x" * pad + code
                order.append(("v", n_var))
                n_var += 1
            else:
                data = _cdr_string(value) if code == "s" else struct.pack("<" + code, value)
                const += b"\x00" * pad + data
                size = len(data)
            off += pad + size
        end_const()
        self.struct = struct.Struct(fmt)
        self.size = off - start
        self.n_values = n_var
        self._consts = tuple(consts)
        self._order = itemgetter(*(i if kind == "v" else n_var + i for kind, i in order))

    def pack(self, values: tuple[Any, ...]) -> bytes:
        """The encoded bytes; ``values`` fill the variable fields in order."""
        return self.struct.pack(*self._order(values + self._consts))


def _sphere_fields(frame_id: str) -> list[tuple[str, Any]]:
    """A ``visualization_msgs/Marker`` sphere: stamp, id, action, position, colour vary."""
    var = None
    return [
        ("i", var), ("I", var), ("s", frame_id),  # header
        ("s", MARKER_NS), ("i", var), ("i", Marker.SPHERE), ("i", var),  # ns, id, type, action
        ("d", var), ("d", var), ("d", var),  # pose.position
        ("d", 0.0), ("d", 0.0), ("d", 0.0), ("d", 1.0),  # pose.orientation
        ("d", SPHERE_M), ("d", SPHERE_M), ("d", SPHERE_M),  # scale
        ("f", var), ("f", var), ("f", var), ("f", var),  # color
        ("i", 1), ("I", 0),  # lifetime 1 s: a sphere whose DELETE was lost goes away
        ("?", False),  # frame_locked
        ("I", 0), ("I", 0),  # points, colors
        ("s", ""),  # texture_resource
        ("i", 0), ("I", 0), ("s", ""), ("s", ""), ("I", 0),  # texture (CompressedImage)
        ("I", 0), ("s", ""), ("s", ""),  # uv_coordinates, text, mesh_resource
        ("s", ""), ("I", 0),  # mesh_file
        ("?", False),  # mesh_use_embedded_materials
    ]  # fmt: skip


class HeaderEncoder:
    """Packs the per-frame messages of one frame id (``skin/<name>``) as CDR bytes.

    Parameters
    ----------
    frame_id : str
        The ``header.frame_id`` of every message.
    """

    def __init__(self, frame_id: str) -> None:
        self.frame_id = frame_id
        self._frame = _cdr_string(frame_id)
        self._after_header = 8 + len(self._frame)  # stamp + frame id
        fields = _sphere_fields(frame_id)
        self._spheres = {start: _Layout(fields, start) for start in (0, 4)}
        # one struct call a message: the encapsulation, the stamp, the frame id (padded to
        # what follows) and the fields (the constant runs passed as ``Ns`` fields)
        after = self._after_header
        self._point_head = self._frame + self._pad(after, 8)
        self._point = struct.Struct(f"<4siI{len(self._point_head)}s3d")
        self._poses_head = self._frame + self._pad(after, 4)
        off = after + len(self._pad(after, 4)) + 4  # the count
        self._poses_gap = self._pad(off, 8)  # before the first pose
        self._poses: dict[int, struct.Struct] = {}  # by count
        self._poses_fmt = f"<4siI{len(self._poses_head)}sI{len(self._poses_gap)}x"
        self._no_poses = struct.Struct(f"<4siI{len(self._poses_head)}sI")

    @staticmethod
    def _pad(offset: int, align: int) -> bytes:
        return b"\x00" * (-offset % align)

    def point_stamped(self, stamp: tuple[int, int], xyz: Sequence[float]) -> bytes:
        """``geometry_msgs/PointStamped`` (m)."""
        x, y, z = xyz
        return self._point.pack(_ENCAPSULATION, stamp[0], stamp[1], self._point_head, x, y, z)

    def pose_array(self, stamp: tuple[int, int], positions: Sequence[Sequence[float]]) -> bytes:
        """``geometry_msgs/PoseArray``: one identity-oriented pose per position (m)."""
        n = len(positions)
        sec, nsec = stamp
        if n == 0:
            return self._no_poses.pack(_ENCAPSULATION, sec, nsec, self._poses_head, 0)
        st = self._poses.get(n)
        if st is None:
            st = self._poses[n] = struct.Struct(self._poses_fmt + "7d" * n)
        if n == 1:  # the common frame
            x, y, z = positions[0]
            return st.pack(
                _ENCAPSULATION, sec, nsec, self._poses_head, 1, x, y, z, 0.0, 0.0, 0.0, 1.0
            )
        values: list[Any] = [_ENCAPSULATION, sec, nsec, self._poses_head, n]
        for x, y, z in positions:
            values += (x, y, z, 0.0, 0.0, 0.0, 1.0)
        return st.pack(*values)

    def sphere_markers(self, stamp: tuple[int, int], spheres: Sequence[SphereMarker]) -> bytes:
        """``visualization_msgs/MarkerArray`` of spheres (see ``SphereMarker``), m."""
        sec, nsec = stamp
        if len(spheres) == 1:  # the common frame: the first marker starts at offset 4
            x, y, z, mid, action, r, g, b, a = spheres[0]
            return _ONE + self._spheres[4].pack((sec, nsec, mid, action, x, y, z, r, g, b, a))
        out = [_ENCAPSULATION, _U32.pack(len(spheres))]
        off = 4
        for x, y, z, mid, action, r, g, b, a in spheres:
            if off % 4:  # the next marker starts with an int32
                out.append(b"\x00" * (-off % 4))
                off += -off % 4
            layout = self._spheres[off % 8]
            out.append(layout.pack((sec, nsec, mid, action, x, y, z, r, g, b, a)))
            off += layout.size
        return b"".join(out)

    def image_32fc1(self, stamp: tuple[int, int], values: Any, height: int, width: int) -> bytes:
        """``sensor_msgs/Image``, encoding ``32FC1``, little endian: ``values`` (h * w,) float."""
        data = np.ascontiguousarray(values, dtype="<f4").tobytes()
        off = self._after_header
        pad4 = self._pad(off, 4)
        off += len(pad4) + 8
        enc = _cdr_string("32FC1")
        off += len(enc) + 1  # is_bigendian, uint8
        pad_step = self._pad(off, 4)
        return b"".join(
            (
                _ENCAPSULATION,
                _STAMP.pack(*stamp),
                self._frame,
                pad4,
                struct.pack("<II", height, width),
                enc,
                b"\x00",
                pad_step,
                struct.pack("<II", 4 * width, len(data)),
                data,
            )
        )


def sphere_message(frame_id: str, stamp: Time, spheres: Sequence[SphereMarker]) -> MarkerArray:
    """The ``MarkerArray`` that ``HeaderEncoder.sphere_markers`` encodes, as a dataclass."""
    return MarkerArray(
        [
            Marker(
                header=Header(stamp=stamp, frame_id=frame_id),
                ns=MARKER_NS,
                id=mid,
                type=Marker.SPHERE,
                action=action,
                pose=Pose(Point(x, y, z), Quaternion(0.0, 0.0, 0.0, 1.0)),
                scale=Vector3(SPHERE_M, SPHERE_M, SPHERE_M),
                color=ColorRGBA(r, g, b, a),
                lifetime=Duration(sec=1, nanosec=0),
            )
            for x, y, z, mid, action, r, g, b, a in spheres
        ]
    )


def check_encoders() -> None:
    """Raise ``RuntimeError`` if a fast encoder disagrees with ``serialize()``.

    Run once per process by the sinks, for frame ids of every length modulo 8.
    """

    def same(fast: bytes, ref: bytes, what: str) -> None:
        if fast != ref:
            raise RuntimeError(
                f"skinloc's {what} encoder disagrees with cyclonedds's serialiser "
                f"({fast.hex()} != {ref.hex()}); please report this with your cyclonedds version"
            )

    stamp = Time(sec=12, nanosec=345)
    parts = (12, 345)
    for n in range(8):
        frame = "skin/" + "x" * n
        enc = HeaderEncoder(frame)
        header = Header(stamp=stamp, frame_id=frame)
        xyz = (0.1, -0.2, 0.3)
        ref = PointStamped(header=header, point=Point(*xyz)).serialize()
        same(enc.point_stamped(parts, xyz), ref, "PointStamped")
        for k in (0, 1, 3):
            pos = [(0.01 * i, 0.02, -0.03 * i) for i in range(k)]
            poses = [Pose(position=Point(*p)) for p in pos]
            ref = PoseArray(header=header, poses=poses).serialize()
            same(enc.pose_array(parts, pos), ref, "PoseArray")
            spheres = [
                (0.01 * i, 0.02, -0.03, 7 + i, (Marker.ADD, Marker.DELETE)[i % 2], 0.5, 0.25, 1, 1)
                for i in range(k)
            ]
            ref = sphere_message(frame, stamp, spheres).serialize()
            same(enc.sphere_markers(parts, spheres), ref, "MarkerArray")
        vals = np.arange(6, dtype=np.float32)
        data = vals.astype("<f4").tobytes()
        img = Image(header, 2, 3, "32FC1", 0, 12, list(data))
        same(enc.image_32fc1(parts, vals, 2, 3), img.serialize(), "Image")
