"""The app's settings and the state its actions share: modes, the open session, touch metadata.

``WorkspaceState`` declares the state that more than one part of ``Workspace`` reads or changes;
what one part keeps for itself it declares in its own class (``tests/app/test_app_state.py``
checks that every attribute a part uses is declared in one of the two, and that no part uses
another's private state).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from skinloc.app.capture import TouchCapture
from skinloc.app.device import DeviceLink
from skinloc.app.hub import Hub
from skinloc.app.store import SessionFolder, SessionStore
from skinloc.calibration.session import CalibrationSession, TouchDetector
from skinloc.data.recording import PER_TOUCH_META, Recording
from skinloc.errors import SkinlocError
from skinloc.geometry.mesh import cone_skin

__all__ = [
    "ActiveSession",
    "AppConfig",
    "CAPTURED",
    "GUIDED_MODES",
    "BusyError",
    "Mode",
    "WorkspaceState",
    "fill_per_touch",
    "left_out_touches",
    "ordinal",
    "touch_numbers",
]


class BusyError(SkinlocError):
    """Another tab (or process) has control of the skin."""


class Mode(StrEnum):
    """What the frames are used for."""

    IDLE = "idle"
    BASELINE = "baseline"  # a baseline capture is running
    CALIBRATE = "calibrate"
    VALIDATE = "validate"
    RECALIBRATE = "recalibrate"
    LIVE = "live"


#: The modes of guided capture (a touch at each planned target, ``workspace.guided``).
GUIDED_MODES = (Mode.CALIBRATE, Mode.VALIDATE, Mode.RECALIBRATE)
#: What each mode of guided capture records.
CAPTURED = {
    Mode.CALIBRATE: "calibration",
    Mode.VALIDATE: "validation",
    Mode.RECALIBRATE: "recalibration",
}


@dataclass
class AppConfig:
    """Settings of one app process.

    Attributes
    ----------
    data_dir : Path
        Folder of sessions and recordings.
    mesh : trimesh.Trimesh or None
        Skin of new sessions; the paper's semi-cone when None.
    mesh_name : str
        How the UI names that mesh.
    train_options : dict
        Overrides passed to ``train_localizer`` (none: its defaults).
    finger_delay_s : float
        Pause of the scripted finger before each touch, s.
    frame_push_hz : float
        Heat-map updates sent to the tabs per second.
    cv_folds : int
        Folds of the cross-validation that measures the error when training (at most one
        touch a fold: leave-one-out).
    influence_suspects : int
        Touches examined after training for how much they raise the cross-validated error
        of the others (``skinloc.evaluation.influence``); 0: none.
    """

    data_dir: Path = Path("skinloc-sessions")
    mesh: Any = None
    mesh_name: str = "paper semi-cone (built in)"
    train_options: dict[str, Any] = field(default_factory=dict)
    finger_delay_s: float = 0.4
    frame_push_hz: float = 25.0
    cv_folds: int = 5
    influence_suspects: int = 2


@dataclass
class ActiveSession:
    """The open session."""

    folder: SessionFolder
    lock_fd: int
    info: dict[str, Any]
    mesh: trimesh.Trimesh
    targets: np.ndarray
    cal: CalibrationSession | None = None
    val: CalibrationSession | None = None
    model: Any = None
    #: the Recalibrate page's touches, and the model they recalibrate (``model``, ``path``,
    #: ``name``, ``strategy``)
    recal: CalibrationSession | None = None
    recal_from: dict[str, Any] | None = None


class WorkspaceState:
    """The state the parts of ``Workspace`` share, declared in one place.

    Every part (``link``, ``sessions``, ``guided``, ...) is a subclass, so what it may touch is
    this class's attributes, its own class's, and the public attributes and the methods of the
    other parts. The reader thread and the HTTP handlers change them only under ``_lock``.

    Parameters
    ----------
    config : AppConfig
        Settings.
    hub : Hub
        Where messages to the tabs go.

    Attributes
    ----------
    config : AppConfig
        Settings of this app process.
    hub : Hub
        Where messages to the tabs go.
    store : SessionStore
        The session folders under ``config.data_dir``.
    default_mesh : trimesh.Trimesh
        Skin of new sessions (``config.mesh``, else the paper's semi-cone).
    device : DeviceLink or None
        The connected skin.
    active : ActiveSession or None
        The open session.
    mode : Mode
        What the frames are used for.
    capture : TouchCapture or None
        The guided capture's per-frame state machine (calibration, validation).
    detector : TouchDetector or None
        Touched or not, against the running capture's or the live view's baseline.
    message : str
        The line the tabs show.
    _lock : threading.RLock
        Held by every action and by the reader thread for each frame.
    _finger, _finger_due, _finger_down
        The scripted finger (``finger``) as guided capture drives it: the finger (or None),
        when it presses next (monotonic s, or None), whether it is down.
    _live_base : numpy.ndarray or None
        The live view's baseline, ``(n_sensors,)`` counts (what its heat map counts above).
    """

    config: AppConfig
    hub: Hub
    store: SessionStore
    default_mesh: trimesh.Trimesh
    device: DeviceLink | None
    active: ActiveSession | None
    mode: Mode
    capture: TouchCapture | None
    detector: TouchDetector | None
    message: str
    _lock: threading.RLock
    _finger: Any
    _finger_due: float | None
    _finger_down: bool
    _live_base: np.ndarray | None

    def __init__(self, config: AppConfig, hub: Hub) -> None:
        self.config = config
        self.hub = hub
        self.store = SessionStore(config.data_dir)
        self.default_mesh = config.mesh if config.mesh is not None else cone_skin()
        self._lock = threading.RLock()
        self.device = None
        self.active = None
        self.mode = Mode.IDLE
        self.capture = None
        self.detector = None
        self.message = ""
        self._finger = None
        self._finger_due = None
        self._finger_down = False
        self._live_base = None


def app_meta(rec: Recording) -> dict[str, Any]:
    """The app's own metadata in a recording (``meta["app"]``), created when missing."""
    return rec.meta.setdefault("app", {})


#: Per-touch lists in ``meta["app"]``, one entry per point log.
PER_POINT = (
    "touch_flags",
    "flags",
    "peaks",
    "predicted",
    "uncertainty_mm",
    "errors_mm",
    "left_out",
    "target_numbers",
    "attempts",
)


def touch_numbers(rec: Recording) -> list[tuple[int, int]]:
    """Each touch's target number (1-based, kept for life) and attempt (1: the first).

    A retake or an undo is its target's next attempt under the same number; a recording
    without the numbers (older, or written elsewhere) numbers its touches by position.
    """
    meta = app_meta(rec)
    nums, tries = meta.get("target_numbers", []), meta.get("attempts", [])
    return [
        (int(nums[i]) if i < len(nums) else i + 1, int(tries[i]) if i < len(tries) else 1)
        for i in range(rec.n_point_logs)
    ]


def ordinal(k: int) -> str:
    """``1st``, ``2nd``, ``3rd``, ``4th``, ... ``11th``, ``21st``."""
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def left_out_touches(rec: Recording) -> list[bool]:
    """Whether each touch is left out of training by hand (until put back)."""
    out = app_meta(rec).get("left_out", [])
    return [bool(out[i]) if i < len(out) else False for i in range(rec.n_point_logs)]


def fill_per_touch(rec: Recording) -> None:
    """Give every touch its entries in ``touch_flags``, ``left_out`` and the numbers.

    Touches recorded elsewhere (``skinloc collect`` on the same file, an older recording)
    have none of their own: no flags of the capture, not left out, numbered by position.
    """
    meta = app_meta(rec)
    numbers = touch_numbers(rec)
    n = rec.n_point_logs
    for key, default in (
        ("touch_flags", lambda i: []),
        ("left_out", lambda i: False),
        ("target_numbers", lambda i: numbers[i][0]),
        ("attempts", lambda i: numbers[i][1]),
    ):
        own = meta.setdefault(key, [])
        own.extend(default(i) for i in range(len(own), n))
        del own[n:]


def pop_point_log(rec: Recording, i: int) -> dict[str, Any]:
    """Remove point log ``i`` (and its per-touch metadata); returns what was removed."""
    keep = np.arange(rec.n_point_logs) != i
    removed = {
        "target": rec.targets[i].copy(),
        "frames": rec.frames[i].copy(),
        "times": None if rec.frame_times is None else rec.frame_times[i].copy(),
    }
    rec.targets, rec.frames = rec.targets[keep], rec.frames[keep]
    if rec.frame_times is not None:
        rec.frame_times = rec.frame_times[keep]
    meta = app_meta(rec)
    removed["meta"] = {}
    for key in PER_POINT:
        if key in meta and len(meta[key]) > i:
            removed["meta"][key] = meta[key].pop(i)
    for key in PER_TOUCH_META:  # a probed session's tips, a simulated one's true contacts
        values = rec.meta.get(key)
        if isinstance(values, list) and len(values) > i:
            removed["meta"][key] = values.pop(i)
    return removed


def same_mesh(a: Any, b: Any) -> bool:
    """Whether two meshes (or None) have the same vertices."""
    if a is None or b is None:
        return a is b
    return a.vertices.shape == b.vertices.shape and np.allclose(a.vertices, b.vertices)
