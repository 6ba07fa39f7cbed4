"""The ROS 2 messages skinloc publishes, as Cyclone DDS IDL structs: one definition of each.

Each class is the ROS 2 message of the same name, field for field (ROS 2 Humble and newer),
registered under its DDS type name (``geometry_msgs::msg::dds_::PointStamped_``, what a ROS 2
node on Cyclone DDS or Fast DDS announces), so that

* the DDS sink writes them on ``rt/<topic>`` and a ROS 2 node reads them with no bridge, and
* the ROS 2 bag writer serialises them with the same code (``msg.serialize()``: a 4-byte
  encapsulation header, ``00 01 00 00`` = plain CDR little endian, then XCDR1, which is what
  ``rmw`` puts on the wire and ``rosbag2`` stores) and describes them with ``msg_definition``,
  the ``.msg`` text generated from the same fields (MCAP ``ros2msg`` schema).

The per-frame messages go out through the ``struct`` encoders of
``skinloc.ros2.cdr``, checked byte for byte against these classes' ``serialize()``.

Needs the ``cyclonedds`` Python binding (``pip install 'skinloc[live]'``; the wheel bundles the
Cyclone C library). Constants of ``visualization_msgs/Marker`` are plain class attributes.
"""

# No ``from __future__ import annotations``: cyclonedds reads the field types at class creation.

import typing
from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float32, float64, int32, sequence, uint8, uint32

__all__ = [
    "ROS2_TYPES",
    "CompressedImage",
    "ColorRGBA",
    "Duration",
    "Header",
    "Image",
    "Marker",
    "MarkerArray",
    "MeshFile",
    "Point",
    "PointStamped",
    "Pose",
    "PoseArray",
    "Quaternion",
    "String",
    "TFMessage",
    "Time",
    "Transform",
    "TransformStamped",
    "UVCoordinate",
    "Vector3",
    "dds_type_name",
    "msg_definition",
    "ros_type_name",
    "stamp_of",
    "stamp_parts",
]


def _dds(pkg: str, name: str) -> str:
    return f"{pkg}::msg::dds_::{name}_"


# ----------------------------------------------------------------------------- builtin / std


@dataclass
class Time(IdlStruct, typename=_dds("builtin_interfaces", "Time")):
    """``builtin_interfaces/Time``: seconds and nanoseconds."""

    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Duration(IdlStruct, typename=_dds("builtin_interfaces", "Duration")):
    """``builtin_interfaces/Duration`` (0: forever, for a marker's lifetime)."""

    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename=_dds("std_msgs", "Header")):
    """``std_msgs/Header``: stamp and frame id."""

    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class ColorRGBA(IdlStruct, typename=_dds("std_msgs", "ColorRGBA")):
    """``std_msgs/ColorRGBA``, each in [0, 1]."""

    r: float32 = 0.0
    g: float32 = 0.0
    b: float32 = 0.0
    a: float32 = 0.0


@dataclass
class String(IdlStruct, typename=_dds("std_msgs", "String")):
    """``std_msgs/String``."""

    data: str = ""


# ----------------------------------------------------------------------------- geometry


@dataclass
class Point(IdlStruct, typename=_dds("geometry_msgs", "Point")):
    """``geometry_msgs/Point``, m."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Vector3(IdlStruct, typename=_dds("geometry_msgs", "Vector3")):
    """``geometry_msgs/Vector3``."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename=_dds("geometry_msgs", "Quaternion")):
    """``geometry_msgs/Quaternion`` (x, y, z, w)."""

    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename=_dds("geometry_msgs", "Pose")):
    """``geometry_msgs/Pose``."""

    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PointStamped(IdlStruct, typename=_dds("geometry_msgs", "PointStamped")):
    """``geometry_msgs/PointStamped``."""

    header: Header = field(default_factory=Header)
    point: Point = field(default_factory=Point)


@dataclass
class PoseArray(IdlStruct, typename=_dds("geometry_msgs", "PoseArray")):
    """``geometry_msgs/PoseArray``."""

    header: Header = field(default_factory=Header)
    poses: sequence[Pose] = field(default_factory=list)


@dataclass
class Transform(IdlStruct, typename=_dds("geometry_msgs", "Transform")):
    """``geometry_msgs/Transform``: translation (m) and rotation."""

    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename=_dds("geometry_msgs", "TransformStamped")):
    """``geometry_msgs/TransformStamped``: ``child_frame_id`` in ``header.frame_id``."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename=_dds("tf2_msgs", "TFMessage")):
    """``tf2_msgs/TFMessage`` (``/tf``, ``/tf_static``)."""

    transforms: sequence[TransformStamped] = field(default_factory=list)


# ----------------------------------------------------------------------------- sensor


@dataclass
class CompressedImage(IdlStruct, typename=_dds("sensor_msgs", "CompressedImage")):
    """``sensor_msgs/CompressedImage`` (only as a field of ``Marker``)."""

    header: Header = field(default_factory=Header)
    format: str = ""
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class Image(IdlStruct, typename=_dds("sensor_msgs", "Image")):
    """``sensor_msgs/Image``: skinloc's raw frames as ``32FC1``, ``height`` TX by ``width`` RX."""

    header: Header = field(default_factory=Header)
    height: uint32 = 0
    width: uint32 = 0
    encoding: str = ""
    is_bigendian: uint8 = 0
    step: uint32 = 0
    data: sequence[uint8] = field(default_factory=list)


# ----------------------------------------------------------------------------- visualization


@dataclass
class UVCoordinate(IdlStruct, typename=_dds("visualization_msgs", "UVCoordinate")):
    """``visualization_msgs/UVCoordinate``."""

    u: float32 = 0.0
    v: float32 = 0.0


@dataclass
class MeshFile(IdlStruct, typename=_dds("visualization_msgs", "MeshFile")):
    """``visualization_msgs/MeshFile``."""

    filename: str = ""
    data: sequence[uint8] = field(default_factory=list)


@dataclass
class Marker(IdlStruct, typename=_dds("visualization_msgs", "Marker")):
    """``visualization_msgs/Marker`` (the Humble-and-newer layout, with texture and mesh file)."""

    header: Header = field(default_factory=Header)
    ns: str = ""
    id: int32 = 0
    type: int32 = 0
    action: int32 = 0
    pose: Pose = field(default_factory=Pose)
    scale: Vector3 = field(default_factory=Vector3)
    color: ColorRGBA = field(default_factory=ColorRGBA)
    lifetime: Duration = field(default_factory=Duration)
    frame_locked: bool = False
    points: sequence[Point] = field(default_factory=list)
    colors: sequence[ColorRGBA] = field(default_factory=list)
    texture_resource: str = ""
    texture: CompressedImage = field(default_factory=CompressedImage)
    uv_coordinates: sequence[UVCoordinate] = field(default_factory=list)
    text: str = ""
    mesh_resource: str = ""
    mesh_file: MeshFile = field(default_factory=MeshFile)
    mesh_use_embedded_materials: bool = False


# Class attributes outside the dataclass fields (IdlStruct would take annotated ones as fields).
Marker.SPHERE = 2
Marker.TRIANGLE_LIST = 11
Marker.ADD = 0
Marker.DELETE = 2
Marker.DELETEALL = 3


@dataclass
class MarkerArray(IdlStruct, typename=_dds("visualization_msgs", "MarkerArray")):
    """``visualization_msgs/MarkerArray``."""

    markers: sequence[Marker] = field(default_factory=list)


ROS2_TYPES: tuple[type[IdlStruct], ...] = (
    Time,
    Duration,
    Header,
    ColorRGBA,
    String,
    Point,
    Vector3,
    Quaternion,
    Pose,
    PointStamped,
    PoseArray,
    Transform,
    TransformStamped,
    TFMessage,
    CompressedImage,
    Image,
    UVCoordinate,
    MeshFile,
    Marker,
    MarkerArray,
)

# ----------------------------------------------------------------------------- helpers


def dds_type_name(cls: type[IdlStruct]) -> str:
    """The DDS type name, e.g. ``geometry_msgs::msg::dds_::PointStamped_``."""
    return cls.__idl_typename__.replace(".", "::")


def ros_type_name(cls: type[IdlStruct], *, with_msg: bool = True) -> str:
    """The ROS 2 type name: ``geometry_msgs/msg/PointStamped`` (or without ``msg/``)."""
    pkg, _, _, name = dds_type_name(cls).split("::")
    return f"{pkg}/msg/{name[:-1]}" if with_msg else f"{pkg}/{name[:-1]}"


_PRIMITIVES = {
    "int32": "int32",
    "uint32": "uint32",
    "uint8": "uint8",
    "float32": "float32",
    "float64": "float64",
}


def _field_type(tp: typing.Any, deps: list[type[IdlStruct]]) -> str:
    """The ``.msg`` spelling of one field type; nested structs are appended to ``deps``."""
    if tp is str:
        return "string"
    if tp is bool:
        return "bool"
    if typing.get_origin(tp) is typing.Annotated:
        base, meta = typing.get_args(tp)[:2]
        if isinstance(meta, sequence):
            return _field_type(meta.subtype, deps) + "[]"
        if isinstance(meta, str) and meta in _PRIMITIVES:
            return _PRIMITIVES[meta]
        raise TypeError(f"no .msg spelling for {tp!r}")
    if isinstance(tp, type) and issubclass(tp, IdlStruct):
        if tp not in deps:
            deps.append(tp)
        return ros_type_name(tp, with_msg=False)
    raise TypeError(f"no .msg spelling for {tp!r}")


def _own_text(cls: type[IdlStruct], deps: list[type[IdlStruct]]) -> str:
    hints = typing.get_type_hints(cls, include_extras=True)
    return "\n".join(f"{_field_type(hints[f], deps)} {f}" for f in cls.__dataclass_fields__)


def msg_definition(cls: type[IdlStruct]) -> str:
    """The full ``.msg`` definition of ``cls`` as rosbag2 stores it (MCAP ``ros2msg`` schema).

    The type's own fields, then every type it uses, each after a line of 80 ``=`` and a line
    ``MSG: pkg/Name``.
    """
    deps: list[type[IdlStruct]] = []
    parts = [_own_text(cls, deps)]
    k = 0
    while k < len(deps):  # breadth-first; deps grows while walking
        dep = deps[k]
        parts.append(
            "=" * 80 + f"\nMSG: {ros_type_name(dep, with_msg=False)}\n" + _own_text(dep, deps)
        )
        k += 1
    return "\n".join(parts) + "\n"


def stamp_parts(t_s: float) -> tuple[int, int]:
    """``(sec, nanosec)`` of a time in seconds (``t_s`` >= 0; negative times clamp to 0)."""
    t_s = max(float(t_s), 0.0)
    sec = int(t_s)
    return sec, min(int(round((t_s - sec) * 1e9)), 999_999_999)


def stamp_of(t_s: float) -> Time:
    """A ``Time`` from seconds (``t_s`` >= 0; negative times clamp to 0)."""
    sec, nsec = stamp_parts(t_s)
    return Time(sec=sec, nanosec=nsec)
