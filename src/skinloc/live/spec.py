"""One skin of a runner and the frame source it names.

``SkinSpec``: model, source, sinks, settings and pose on the robot; ``open_source``: the
``FrameSource`` of a spec that the runner's loop does not read itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from skinloc.errors import SkinlocError
from skinloc.live.config import PipelineConfig, settings_from_dict
from skinloc.live.gestures import GestureConfig
from skinloc.live.scripted import ScriptedFinger
from skinloc.live.sinks.base import SkinInfo
from skinloc.sources.base import FrameSource

if TYPE_CHECKING:
    import numpy as np

    from skinloc.live.contact import Contact
    from skinloc.live.core import SkinCore
    from skinloc.live.sinks.base import Sink

__all__ = ["SkinSpec", "open_source", "record_frames", "skin_info"]

_RECORDING_SUFFIXES = (".h5", ".hdf5", ".mat", ".mcap")


@dataclass
class SkinSpec:
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
        Grid the device sends (default: 8 x 8 for a 64-input model).
    tx_mask, rx_mask : str or None
        Lines to keep, as for ``SerialSourceConfig``.
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
        self._mount = _mount_pose(self)
        if self.wait is not None and not isinstance(self.wait, bool):
            raise ValueError(f"wait must be true or false, not {self.wait!r}")
        if isinstance(self.gestures, dict):
            self.gestures = settings_from_dict(GestureConfig, self.gestures, "gestures")
        elif self.gestures is not None and not isinstance(self.gestures, GestureConfig):
            raise ValueError(f"gestures must be a table of thresholds, not {self.gestures!r}")
        if self.up is not None:
            u = _vector(self.up, 3, "up")
            if not any(u):
                raise ValueError("up must be a direction (3 numbers, not all 0)")
            self.up = u

    @property
    def mount(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """The skin frame's pose in ``parent_frame``: translation (m), quaternion ``xyzw``."""
        return self._mount


def _vector(value: Any, n: int, what: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be {n} numbers, not {value!r}") from None
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise ValueError(f"{what} must be {n} finite numbers, not {value!r}")
    return out


def _mount_pose(
    spec: SkinSpec,
) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """Check and normalise a spec's mounting pose (translation m, unit quaternion xyzw)."""
    if spec.parent_frame is not None and (
        not isinstance(spec.parent_frame, str) or not spec.parent_frame.strip()
    ):
        raise ValueError(f"parent_frame must be a frame name, not {spec.parent_frame!r}")
    t = _vector(spec.translation, 3, "translation")
    if spec.rotation is not None and spec.rpy is not None:
        raise ValueError("give rotation (quaternion x, y, z, w) or rpy (rad), not both")
    if spec.rpy is not None:
        from skinloc.live.sinks.ros2.sink import quaternion_from_rpy

        q = quaternion_from_rpy(*_vector(spec.rpy, 3, "rpy"))
    elif spec.rotation is not None:
        q = _vector(spec.rotation, 4, "rotation (quaternion x, y, z, w)")
        norm = math.sqrt(sum(v * v for v in q))
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(f"rotation must be a unit quaternion x, y, z, w (norm {norm:.4g})")
        q = tuple(v / norm for v in q)
    else:
        q = (0.0, 0.0, 0.0, 1.0)
    return (t[0], t[1], t[2]), (q[0], q[1], q[2], q[3])


def _is_recording(source: str) -> bool:
    p = Path(source)
    return p.suffix.lower() in _RECORDING_SUFFIXES


def open_source(spec: SkinSpec, n_sensors: int) -> FrameSource:
    """The ``FrameSource`` for a spec whose source is not read through the selector loop."""
    src = spec.source
    if isinstance(src, FrameSource):
        return src
    text = str(src)
    if text == "sim" or text.startswith("sim:"):
        from skinloc.sim.skin import SimulatedSkin

        seed = int(text.partition(":")[2] or 0) if text != "sim" else 0
        n_tx, n_rx = spec.n_tx or 8, spec.n_rx or max(n_sensors // (spec.n_tx or 8), 1)
        skin = SimulatedSkin(
            n_tx=n_tx, n_rx=n_rx, random_state=seed, rate_hz=spec.rate_hz, realtime=spec.realtime
        )
        return ScriptedFinger(skin, random_state=seed)
    if _is_recording(text):
        if not Path(text).is_file():
            raise SkinlocError(f"recording not found: {text}")
        if Path(text).suffix.lower() == ".mcap":
            from skinloc.sources.mcap_ros2 import McapReplaySource

            return McapReplaySource(text, skin=spec.name, loop=spec.loop)
        from skinloc.sources.replay import ReplaySource

        return ReplaySource(text, loop=spec.loop)
    from skinloc.hardware.serial import SerialSource, SerialSourceConfig

    return SerialSource(
        SerialSourceConfig(
            text,
            baud=spec.baud,
            n_tx=spec.n_tx or 8,
            n_rx=spec.n_rx or 8,
            tx_mask=spec.tx_mask,
            rx_mask=spec.rx_mask,
            format=spec.wire_format,
        )
    )


def skin_info(spec: SkinSpec, core: SkinCore) -> SkinInfo:
    """What the sinks learn of a skin: name, mesh (the model's), grid and pose on the robot."""
    translation, rotation = spec.mount
    return SkinInfo(
        spec.name,
        core.fast.spec.vertices,
        core.fast.spec.faces,
        n_tx=core.n_tx,
        n_rx=core.n_rx,
        parent_frame=spec.parent_frame,
        translation_m=translation,
        rotation_xyzw=rotation,
        max_contacts=core.max_contacts,
    )


def record_frames(core: SkinCore, sinks: Sequence[Sink]) -> None:
    """Hand every raw frame of ``core`` to ``sinks`` (``emit_frame``) before processing.

    The instance's ``process_frame`` is wrapped, so frames parsed from a serial port's
    bytes (``SkinCore.feed``) are recorded as well as frames from thread-fed sources;
    skins without a recording sink keep the unwrapped method.
    """
    process = core.process_frame
    name = core.name

    def recording_process(
        values: np.ndarray, timestamp_s: float, index: int = -1, t_in: float | None = None
    ) -> Sequence[Contact]:
        for sink in sinks:
            sink.emit_frame(name, values, timestamp_s, index)
        return process(values, timestamp_s, index, t_in)

    core.process_frame = recording_process  # type: ignore[method-assign]
