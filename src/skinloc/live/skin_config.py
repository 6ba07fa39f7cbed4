"""One skin of a runner: ``SkinConfig`` (model, source, sinks, settings, pose on the robot).

The runner opens the skin's frame source through the one factory
(``skinloc.sources.base.make_source``) with the options ``SkinConfig.source_options`` gives.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skinloc.live.config import PipelineConfig, settings_from_dict
from skinloc.live.gestures import GestureConfig
from skinloc.live.sinks.base import SkinInfo
from skinloc.sources.base import FrameSource, SourceKind, SourceOptions, source_kind

if TYPE_CHECKING:
    from skinloc.live.core import SkinCore

__all__ = ["SkinConfig", "mount_pose", "skin_info"]


@dataclass
class SkinConfig:
    """One skin of a ``Runner``: model, source, sinks and settings.

    Attributes
    ----------
    model : str, Path, ContactLocalizer or Engine
        The localiser.
    source : str or FrameSource
        ``sim`` (simulated skin with a scripted finger; ``sim:SEED`` picks the skin), a serial
        port or pyserial URL, a recording (``.h5``, ``.mat``), or any ``FrameSource``.
    name : str
        Name carried by the contacts.
    sinks : list of str or Sink
        This skin's sinks (see ``skinloc.live.sinks.make_sink``).
    config : PipelineConfig
        Detection, drift and filter settings.
    baud : int
        Baud rate of a serial port.
    wire_format : {"auto", "binary", "text"}
        Wire format of a serial port.
    n_tx, n_rx : int or None
        Grid the device sends (default: the length of a mask given, else 8 x 8 for a
        64-input model).
    tx_mask, rx_mask : str or None
        Lines to keep, as for ``SerialSourceConfig``: the model takes the kept lines
        (``kept_grid``).
    realtime : bool
        Replay a recording at its recorded rate (``False``: as fast as possible); run the
        simulated skin in real time.
    loop : bool
        Replay a recording over and over.
    rate_hz : float
        Frame rate of the simulated skin, Hz.
    baseline : str, Path or None
        A recording whose baseline capture to use instead of capturing one at start.
    parent_frame : str or None
        The robot frame (link) the skin is mounted on, for ROS 2 ``/tf_static``
        (``parent_frame -> skin/<name>``); None: no transform is published.
    translation : (3,) float
        Origin of the skin's mesh frame in ``parent_frame``, m.
    rotation : (4,) float or None
        Orientation of the mesh frame in ``parent_frame``, quaternion ``x, y, z, w``.
    rpy : (3,) float or None
        The same as fixed-axis roll, pitch, yaw, rad (give ``rotation`` or ``rpy``, not both).
    up : (3,) float or None
        The skin's "up" in its mesh frame, for swipe directions; None: the mesh's long axis
        (``skinloc.geometry.skin_frame.skin_up_axis``).
    gestures : GestureConfig, dict or None
        The gesture recogniser's thresholds (a dict of ``GestureConfig`` fields, as a skins
        file's ``gestures`` table gives them); None: the documented defaults.
    wait : bool or None
        A serial port that does not exist when the runner opens: wait for it to appear
        (retried every 0.1 s, as after an unplug) instead of failing. None: the caller's
        default (``Runner``: fail; ``skinloc run``: wait unless ``--no-wait``).
    """

    model: Any
    source: Any = "sim"
    name: str = "skin"
    sinks: list[Any] = field(default_factory=list)
    config: PipelineConfig = field(default_factory=PipelineConfig)
    baud: int = 115200
    wire_format: str = "auto"
    n_tx: int | None = None
    n_rx: int | None = None
    tx_mask: str | None = None
    rx_mask: str | None = None
    realtime: bool = True
    loop: bool = False
    rate_hz: float = 100.0
    baseline: str | Path | None = None
    parent_frame: str | None = None
    translation: Sequence[float] = (0.0, 0.0, 0.0)
    rotation: Sequence[float] | None = None
    rpy: Sequence[float] | None = None
    up: Sequence[float] | None = None
    gestures: GestureConfig | dict[str, Any] | None = None
    wait: bool | None = None

    def __post_init__(self) -> None:
        _check_settings(self)
        self._mount = _mount_pose(self)
        if isinstance(self.gestures, dict):
            self.gestures = settings_from_dict(GestureConfig, self.gestures, "gestures")
        elif self.gestures is not None and not isinstance(self.gestures, GestureConfig):
            raise ValueError(f"gestures must be a table of thresholds, not {self.gestures!r}")
        self._kept = _kept_grid(self)
        if self.up is not None:
            u = _vector(self.up, 3, "up")
            if not any(u):
                raise ValueError("up must be a direction (3 numbers, not all 0)")
            self.up = u

    @property
    def mount(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """The skin frame's pose in ``parent_frame``: translation (m), quaternion ``xyzw``."""
        return self._mount

    @property
    def kept_grid(self) -> tuple[int | None, int | None]:
        """The grid the model sees: the lines the masks keep of ``n_tx x n_rx``.

        ``None`` where no grid is given: ``SkinCore`` completes it from the model's sensors.
        """
        return self._kept

    def source_options(self, core: SkinCore) -> SourceOptions:
        """The options of this skin's frame source (``source`` a name, not a ``FrameSource``).

        The grid is the one given, else the core's; the simulated skin's default keeps 8 TX
        lines and fits the RX lines to the model's sensors.
        """
        text = str(self.source)
        n_tx, n_rx = self.n_tx or core.n_tx, self.n_rx or core.n_rx
        if source_kind(text) is SourceKind.SIM:
            n_tx = self.n_tx or 8
            n_rx = self.n_rx or max(core.n_sensors // n_tx, 1)
        return SourceOptions(
            text,
            n_tx=n_tx,
            n_rx=n_rx,
            baud=self.baud,
            format=self.wire_format,
            tx_mask=self.tx_mask,
            rx_mask=self.rx_mask,
            rate_hz=self.rate_hz,
            realtime=self.realtime,
            loop=self.loop,
            skin=self.name,
        )


def _kept_grid(skin: SkinConfig) -> tuple[int | None, int | None]:
    """The device's grid completed from the masks' lengths, checked; returns the kept grid."""
    from skinloc.hardware.link import parse_line_mask

    kept: list[int | None] = []
    for axis in ("tx", "rx"):
        mask, n = getattr(skin, f"{axis}_mask"), getattr(skin, f"n_{axis}")
        if mask is None:
            kept.append(n)
            continue
        if n is None:
            n = len(mask.strip()) if isinstance(mask, str) else len(mask)
            setattr(skin, f"n_{axis}", n)
        kept.append(int(parse_line_mask(mask, n, f"{axis}_mask").sum()))
    return kept[0], kept[1]


#: Wire formats a serial port may be read in (``skinloc.hardware.framing``).
_WIRE_FORMATS = ("auto", "binary", "text")


def _check_settings(skin: SkinConfig) -> None:
    """Refuse a setting of the wrong type or range, naming it and its value (one line).

    A skins file's ``realtime = "no"`` must not read as true, nor ``baud = "fast"`` reach the
    port: TOML gives strings, numbers and booleans as written, and a dataclass checks none.
    """

    def need(name: str, ok: bool, allowed: str) -> None:
        if not ok:
            raise ValueError(f"{name} must be {allowed}, not {getattr(skin, name)!r}")

    def whole(v: Any) -> bool:
        return isinstance(v, numbers.Integral) and not isinstance(v, bool)

    need("name", isinstance(skin.name, str) and bool(skin.name.strip()), "a non-empty text")
    need(
        "source",
        isinstance(skin.source, FrameSource)
        or (isinstance(skin.source, str | Path) and bool(str(skin.source).strip())),
        "a serial port, a recording, sim, or a FrameSource",
    )
    need("baud", whole(skin.baud) and skin.baud >= 50, "a whole number of bits per second >= 50")
    need("wire_format", skin.wire_format in _WIRE_FORMATS, f"one of {', '.join(_WIRE_FORMATS)}")
    for name in ("n_tx", "n_rx"):
        v = getattr(skin, name)
        need(name, v is None or (whole(v) and v >= 1), "a whole number >= 1")
    for name in ("tx_mask", "rx_mask"):
        need(name, getattr(skin, name) is None or isinstance(getattr(skin, name), str), "a text")
    for name in ("realtime", "loop"):
        need(name, isinstance(getattr(skin, name), bool), "true or false")
    need("wait", skin.wait is None or isinstance(skin.wait, bool), "true or false")
    rate = skin.rate_hz
    ok = isinstance(rate, numbers.Real) and not isinstance(rate, bool)
    need("rate_hz", ok and math.isfinite(rate) and rate > 0, "a number of frames per second > 0")
    need(
        "baseline",
        skin.baseline is None or isinstance(skin.baseline, str | Path),
        "a recording's path",
    )
    need("sinks", isinstance(skin.sinks, list | tuple), "a list of sinks")
    need(
        "config",
        isinstance(skin.config, PipelineConfig),
        "a PipelineConfig (a skins file's pipeline table)",
    )


def _vector(value: Any, n: int, what: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be {n} numbers, not {value!r}") from None
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise ValueError(f"{what} must be {n} finite numbers, not {value!r}")
    return out


def _mount_pose(
    skin: SkinConfig,
) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """Check and normalise a skin's mounting pose (translation m, unit quaternion xyzw)."""
    return mount_pose(skin.parent_frame, skin.translation, skin.rotation, skin.rpy)


def mount_pose(
    parent_frame: str | None = None,
    translation: Sequence[float] = (0.0, 0.0, 0.0),
    rotation: Sequence[float] | None = None,
    rpy: Sequence[float] | None = None,
) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """A skin's mounting pose from a skins file's keys, checked: ``(translation m, xyzw)``.

    ``rotation`` is a unit quaternion ``x, y, z, w``, ``rpy`` fixed-axis roll, pitch, yaw in
    rad (one of them or neither: the identity). Raises ``ValueError`` naming the key.
    """
    if parent_frame is not None and (not isinstance(parent_frame, str) or not parent_frame.strip()):
        raise ValueError(f"parent_frame must be a frame name, not {parent_frame!r}")
    t = _vector(translation, 3, "translation")
    if rotation is not None and rpy is not None:
        raise ValueError("give rotation (quaternion x, y, z, w) or rpy (rad), not both")
    if rpy is not None:
        from skinloc.geometry.skin_frame import quaternion_from_rpy

        q = quaternion_from_rpy(*_vector(rpy, 3, "rpy"))
    elif rotation is not None:
        q = _vector(rotation, 4, "rotation (quaternion x, y, z, w)")
        norm = math.sqrt(sum(v * v for v in q))
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(f"rotation must be a unit quaternion x, y, z, w (norm {norm:.4g})")
        q = tuple(v / norm for v in q)
    else:
        q = (0.0, 0.0, 0.0, 1.0)
    return (t[0], t[1], t[2]), (q[0], q[1], q[2], q[3])


def skin_info(skin: SkinConfig, core: SkinCore) -> SkinInfo:
    """What the sinks learn of a skin: name, mesh (the model's), grid and pose on the robot."""
    translation, rotation = skin.mount
    return SkinInfo(
        skin.name,
        core.engine.spec.vertices,
        core.engine.spec.faces,
        n_tx=core.n_tx,
        n_rx=core.n_rx,
        parent_frame=skin.parent_frame,
        translation_m=translation,
        rotation_xyzw=rotation,
        max_contacts=core.max_contacts,
    )
