"""The calibration session: baseline, targets, touches, point logs; free of any UI.

The session reads frames from any ``FrameSource`` and talks to the person (or a scripted
finger) through a ``Prober``. Its touches follow the one touch rule of
``calibration.capture`` (``TouchCapture``); its file is written by the one appender,
``data.appender.RecordingAppender``: the header after the baseline, then each point log as
it comes, so a crash loses at most the touch in progress, and ``resume`` carries on. The app
drives the same session frame by frame (``store_point_log``, ``drop_point_log``,
``save_plan_and_meta``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from skinloc._typing import Points
from skinloc.calibration.capture import (
    RELEASE_FRAMES,
    CapturedTouch,
    CapturePhase,
    TouchCapture,
    TouchDetector,
)
from skinloc.data.appender import RecordingAppender
from skinloc.data.recording import Recording, read_recording
from skinloc.errors import FrameTimeoutError, RecordingError
from skinloc.files import side_path, written_through_side
from skinloc.geometry.mesh import SamplingMode, sample_targets, surface_points
from skinloc.sources.base import FrameSource

log = logging.getLogger(__name__)

#: Sampling modes of a session: the planned ones and ``active`` (chosen touch by touch).
SESSION_MODES = (*(m.value for m in SamplingMode), "active")
#: Candidate targets an active session chooses from, per point log asked for (at least 64).
ACTIVE_POOL_PER_POINT = 3
#: Longest wait for each frame of a touch being captured, s (the source's clock).
CAPTURE_READ_TIMEOUT_S = 1.0

__all__ = [
    "SESSION_MODES",
    "CalibrationSession",
    "Prober",
    "ScriptedFinger",
    "SessionConfig",
    "TouchDetector",
    "simulate_session",
]


@dataclass
class SessionConfig:
    """Settings of a calibration session.

    Attributes
    ----------
    n_points : int
        Point logs to record.
    mode : str
        Target sampling: ``even``, ``random``, ``edge``, or ``active`` (the first
        ``active.N_START`` targets are spread evenly, then each next one is chosen
        after the touch before it, from the touches recorded so far; see ``calibration.active``).
    samples_per_touch : int
        Frames captured at each target (the paper: 50).
    n_baseline_frames : int
        No-touch frames captured first.
    threshold_sigma : float
        A sensor is touched when its delta exceeds this many baseline standard deviations.
    min_active : int
        Touched sensors needed for a frame to count as a touch.
    settle_frames : int
        Consecutive touch frames required before capture starts (lets the finger settle).
    touch_timeout_s : float
        Longest wait for a touch or a release, s.
    random_state : int
        Seed for the targets.
    description : str
        Free text stored with the recording.
    n_repeats : int
        Targets asked for a second time at the end of the session (spread over the first
        ``n_points``), to measure the probing repeatability (``skinloc.evaluation.repeatability``).
    """

    n_points: int = 80
    mode: str = "even"
    samples_per_touch: int = 50
    n_baseline_frames: int = 50
    threshold_sigma: float = 5.0
    min_active: int = 2
    settle_frames: int = 5
    touch_timeout_s: float = 60.0
    random_state: int = 0
    description: str = ""
    n_repeats: int = 0

    def __post_init__(self) -> None:
        if self.mode not in SESSION_MODES:
            raise ValueError(
                f"unknown sampling mode {self.mode!r}; choose one of: {', '.join(SESSION_MODES)}"
            )
        if not 0 <= self.n_repeats <= self.n_points:
            raise ValueError(
                f"SessionConfig.n_repeats must be in [0, n_points], got {self.n_repeats}"
            )
        for name in ("n_points", "samples_per_touch", "min_active", "settle_frames"):
            if getattr(self, name) < 1:
                raise ValueError(
                    f"SessionConfig.{name} must be at least 1, got {getattr(self, name)}"
                )
        if self.n_baseline_frames < 2:
            raise ValueError(
                f"SessionConfig.n_baseline_frames must be at least 2, got {self.n_baseline_frames}"
            )
        if self.threshold_sigma <= 0 or self.touch_timeout_s <= 0:
            raise ValueError("SessionConfig.threshold_sigma and touch_timeout_s must be positive")


class Prober(Protocol):
    """Who touches the skin: a person prompted by a UI, or a scripted finger."""

    def prompt(self, index: int, target: np.ndarray) -> None:
        """Ask for a touch at ``target (3,)`` m (point log ``index``)."""

    def captured(self, index: int) -> None:
        """The frames of point log ``index`` are stored: the finger may lift."""


class ScriptedFinger:
    """A prober for the simulated skin: touches near each target, lifts after capture.

    The contacts actually made (target plus probing error) are kept in ``contacts``.
    """

    def __init__(self, skin, random_state: int | None = None, move_time_s: float = 4.5) -> None:
        self.skin = skin
        self.rng = np.random.default_rng(random_state)
        self.move_time_s = move_time_s
        self.contacts: list[np.ndarray] = []

    def prompt(self, index: int, target: np.ndarray) -> None:
        """Move to ``target`` (the baselines drift meanwhile) and press near it."""
        # A person needs seconds per touch (the paper: 1-2 min per 20); the skin drifts meanwhile.
        self.skin.advance(self.move_time_s)
        self.contacts.append(np.asarray(self.skin.touch_near(target, rng=self.rng)))

    def captured(self, index: int) -> None:
        """Lift the simulated finger."""
        self.skin.release()


class CalibrationSession:
    """Record a calibration session to ``path``.

    Parameters
    ----------
    source : FrameSource
        Where frames come from (connected by the caller).
    mesh : trimesh.Trimesh
        The skin surface the targets lie on, m.
    path : str or Path
        Recording to write (HDF5): its header after the baseline (replacing any file there,
        atomically), then each point log appended as it comes (``RecordingAppender``).
    config : SessionConfig
        Session settings.
    targets : (n, 3) float, optional
        Targets to use instead of sampling them (e.g. a loaded list).
    incremental : bool
        Create ``path`` exclusively (never replacing a file: a side file that the caller
        renames when the session is complete) instead of replacing it.

    ``self.recording`` holds the whole recording (header and point logs) as in the file.
    """

    def __init__(
        self,
        source: FrameSource,
        mesh,
        path: str | Path,
        config: SessionConfig | None = None,
        targets: Points | None = None,
        source_name: str | None = None,
        incremental: bool = False,
    ) -> None:
        self.source = source
        self.incremental = incremental
        self._appender: RecordingAppender | None = None
        self.mesh = mesh
        self.path = Path(path)
        self.config = config or SessionConfig()
        self._pool: Points | None = None
        #: Targets the person skipped, ``(s, 3)`` m: an active session never asks them again.
        self.skipped: Points = np.zeros((0, 3))
        if targets is None:
            # An active session plans an even spread; all but its first targets are replaced
            # as the touches come in (``target_for``).
            plan_mode = "even" if self.config.mode == "active" else self.config.mode
            targets = sample_targets(
                mesh, self.config.n_points, plan_mode, random_state=self.config.random_state
            )
            if self.config.n_repeats:
                again = np.linspace(0, len(targets) - 1, self.config.n_repeats).round().astype(int)
                targets = np.concatenate([targets, targets[again]])
        # A copy: an active session replaces its targets as it goes.
        self.targets = np.array(targets, dtype=np.float64).reshape(-1, 3)
        self.source_name = source_name or source.name
        self.recording: Recording | None = None
        self.detector: TouchDetector | None = None

    # ------------------------------------------------------------ resuming
    @classmethod
    def resume(cls, source: FrameSource, path: str | Path) -> CalibrationSession:
        """Continue the unfinished session stored in ``path``."""
        rec = read_recording(path)
        if rec.planned_targets is None:
            raise RecordingError(f"{path} holds no planned targets: it cannot be resumed")
        if rec.n_sensors != source.n_sensors:
            raise RecordingError(
                f"{path} was recorded with {rec.n_sensors} sensors but the source has "
                f"{source.n_sensors}"
            )
        cfg_fields = SessionConfig.__dataclass_fields__
        cfg = SessionConfig(
            **{k: v for k, v in rec.meta.get("session", {}).items() if k in cfg_fields}
        )
        session = cls(source, rec.mesh, path, cfg, targets=rec.planned_targets)
        session.recording = rec
        # What was touched is what counts: an active session recomputes its next target
        # from these, whatever the plan in the file says.
        if cfg.mode == "active":
            n = min(rec.n_point_logs, len(session.targets))
            session.targets[:n] = rec.targets[:n]

        session.detector = TouchDetector(
            rec.baseline, rec.noise, cfg.threshold_sigma, cfg.min_active
        )
        return session

    @property
    def n_done(self) -> int:
        """Point logs recorded so far."""
        return 0 if self.recording is None else self.recording.n_point_logs

    @property
    def finished(self) -> bool:
        """Whether every target has its point log."""
        return self.n_done >= len(self.targets)

    # ------------------------------------------------------------ steps
    def capture_baseline(self) -> Recording:
        """Capture the no-touch frames and start the recording (written at once)."""
        cfg = self.config
        frames, _ = self.source.read_many(cfg.n_baseline_frames)
        n = self.source.n_sensors
        now = datetime.now(UTC).isoformat(timespec="seconds")
        self.recording = Recording(
            n_tx=self.source.n_tx,
            n_rx=self.source.n_rx,
            vertices=self.mesh.vertices,
            faces=self.mesh.faces,
            surface_points=surface_points(self.mesh),
            baseline_frames=frames,
            targets=np.zeros((0, 3)),
            frames=np.zeros((0, cfg.samples_per_touch, n), dtype=np.float32),
            planned_targets=self.targets.copy(),  # an active session changes its own
            meta={
                "sampling_mode": cfg.mode,
                "samples_per_touch": cfg.samples_per_touch,
                "description": cfg.description,
                "source": self.source_name,
                "created": now,
                "session": asdict(cfg),
            },
        )
        self.detector = TouchDetector(
            self.recording.baseline, self.recording.noise, cfg.threshold_sigma, cfg.min_active
        )
        self._appender = RecordingAppender(self.recording, self.path, replace=not self.incremental)
        return self.recording

    # ------------------------------------------------------------ the file
    @property
    def writer(self) -> RecordingAppender:
        """The appender of this session's file (a resumed file is opened on the first change)."""
        if self._appender is None:
            if self.recording is None:
                raise RecordingError("capture the baseline before recording point logs")
            # From the file, the truth of what is stored (the caller may have changed
            # ``self.recording`` already).
            self._appender = RecordingAppender.reopen(self.path)
        return self._appender

    def store_point_log(
        self,
        target: Points,
        frames: np.ndarray,
        times: np.ndarray,
        meta: dict[str, Any] | None = None,
    ) -> None:
        """Add a point log to the recording and append it to the file.

        ``target (3,)`` m, ``frames (s, n_sensors)`` raw counts, ``times (s,)`` s; ``meta``:
        keys merged into the recording's meta in the same write.
        """
        if self.recording is None:
            raise RecordingError("capture the baseline before recording point logs")
        self.writer.append(target, frames, times, meta=meta)
        self.recording.append(target, frames, times)
        self.recording.meta.update(meta or {})

    def drop_point_log(self, index: int) -> None:
        """Take point log ``index`` out of the file.

        The caller takes it out of ``self.recording``, with what else it keeps per touch
        (``app.workspace.state.pop_point_log``).
        """
        self.writer.remove(index)

    def save_plan_and_meta(self) -> None:
        """Write the recording's plan (``planned_targets``) and meta as they are now."""
        assert self.recording is not None
        self.writer.set_planned_targets(self.recording.planned_targets)
        self.writer.set_meta(self.recording.meta)

    def update_meta(self, **values: Any) -> None:
        """Merge ``values`` into the recording's meta, in memory and in the file."""
        assert self.recording is not None
        self.recording.meta.update(values)
        self.writer.update_meta(**values)

    # ------------------------------------------------------------ the touch rule
    def pull(self, capture: TouchCapture) -> CapturedTouch | None:
        """Feed ``capture`` frames from the source until its touch or its release.

        Returns the captured touch, or None when ``capture`` waited for a release.
        A wait for a touch or a release times out after ``touch_timeout_s`` on the source's
        clock (a simulated skin times out in simulated time); a frame being captured must come
        within ``CAPTURE_READ_TIMEOUT_S``.
        """
        timeout = self.config.touch_timeout_s
        waiting = capture.phase
        start = None
        while True:
            capturing = capture.phase is CapturePhase.CAPTURING
            frame = self.source.read(timeout_s=CAPTURE_READ_TIMEOUT_S if capturing else timeout)
            start = frame.timestamp_s if start is None else start
            touch = capture.feed(frame.values, frame.timestamp_s)
            if touch is not None or capture.phase is not waiting:
                if touch is not None or waiting is CapturePhase.WAIT_RELEASE:
                    return touch
                continue  # the touch settled: its frames are captured next
            if not capturing and frame.timestamp_s - start > timeout:
                what = "touch" if waiting is CapturePhase.WAIT_TOUCH else "release"
                raise FrameTimeoutError(
                    f"no {what} detected on {self.source_name} within {timeout:g} s"
                )

    def target_for(self, index: int) -> np.ndarray:
        """The target of point log ``index``, ``(3,)`` m (stored in ``self.targets``).

        Planned, except in an ``active`` session: after its first ``N_START`` (evenly spread)
        targets, each next one is the pool target that lowers the expected localisation
        error most given the touches recorded so far (``active.next_targets``; only
        their images are used), and the repeats at the end repeat recorded targets. The
        choice depends only on what is recorded, so a resumed session asks the same.
        """
        cfg = self.config
        if cfg.mode != "active":
            return self.targets[index]
        from skinloc.calibration.active import N_START, next_targets

        n_points = cfg.n_points
        done, images = self.touched()
        if index < min(N_START, n_points) or index > len(done):
            return self.targets[index]
        if index >= n_points:
            again = np.linspace(0, n_points - 1, cfg.n_repeats).round().astype(int)
            target = done[again[index - n_points]]
        else:
            pool = self.active_pool()
            # A target already touched (the repeats come at the end) or skipped is not asked
            # again.
            asked = np.concatenate([done, np.reshape(self.skipped, (-1, 3))])
            dist = np.linalg.norm(pool[:, None, :] - asked[None, :, :], axis=2).min(axis=1)
            left = pool[dist > 1e-6]
            assert self.recording is not None
            cands = self.recording.surface_points
            if cands is None:
                cands = surface_points(self.mesh)
            target = left[next_targets(done, images, left, cands)]
        self.targets[index] = target
        return self.targets[index]

    def touched(self) -> tuple[Points, np.ndarray]:
        """Targets ``(n, 3)`` m and mean baseline-subtracted images ``(n, k)`` of the touches.

        From the recording, whoever appended or removed its point logs (e.g. the app).
        """
        rec = self.recording
        if rec is None:
            return np.zeros((0, 3)), np.zeros((0, self.source.n_sensors))
        return np.asarray(rec.targets, dtype=np.float64), rec.touch_means.astype(np.float64)

    def active_pool(self) -> Points:
        """Candidate targets of an active session, ``(c, 3)`` m, evenly spread and seeded."""
        if self._pool is None:
            n = max(ACTIVE_POOL_PER_POINT * self.config.n_points, 64)
            self._pool = sample_targets(
                self.mesh, n, "even", random_state=self.config.random_state + 1
            )
        return self._pool

    def record_point(self, index: int, prober: Prober) -> None:
        """Prompt target ``index``, wait for a steady touch, capture and store its frames.

        The touch rule is ``TouchCapture``'s (the app's too): ``settle_frames`` touch frames
        in a row, then ``samples_per_touch`` frames captured, then, after the prober lifts,
        ``RELEASE_FRAMES`` no-touch frames in a row.
        """
        if self.recording is None or self.detector is None:
            raise RecordingError("capture the baseline before recording point logs")
        target = self.target_for(index)
        prober.prompt(index, target)
        cfg = self.config
        capture = TouchCapture(
            self.detector,
            cfg.samples_per_touch,
            settle_frames=cfg.settle_frames,
            release_frames=RELEASE_FRAMES,
        )
        touch = self.pull(capture)
        assert touch is not None
        self.store_point_log(target, touch.frames, touch.times)
        prober.captured(index)
        self.pull(capture)

    def run(self, prober: Prober, progress: Callable[[int, int], None] | None = None) -> Recording:
        """Record every remaining point log; returns the finished recording."""
        if self.recording is None:
            self.capture_baseline()
        while not self.finished:
            self.record_point(self.n_done, prober)
            if progress is not None:
                progress(self.n_done, len(self.targets))
        assert self.recording is not None
        return self.recording

    def close(self) -> None:
        """Sync the session's file to disk (a no-op if nothing was written)."""
        if self._appender is not None:
            self._appender.close()


def truth_layout(skin) -> dict[str, Any]:
    """A simulated skin's true wire crossings, for a recording's meta (models never read them).

    ``{"truth_sensor_positions_m": (n_sensors, 3) m}``, sensor k = TX ``k // n_rx``, RX
    ``k % n_rx``; ``skinloc info --json`` prints it and ``skinloc sensors`` scores against it.
    Empty for a skin without a known layout.
    """
    layout = getattr(skin, "layout", None)
    if layout is None:
        return {}
    return {"truth_sensor_positions_m": np.round(layout.sensor_positions, 7).tolist()}


def simulate_session(
    skin,
    mesh,
    path: str | Path,
    config: SessionConfig,
    targets: Points | None = None,
    progress: Callable[[int, int], None] | None = None,
    partial: str | Path | None = None,
) -> Recording:
    """Record a whole session from a simulated skin with a scripted finger.

    ``skin`` is a ``SimulatedSkin`` (connected or not); the true contacts (targets plus probing
    error) are kept in ``meta["true_contacts"]`` and the wire crossings, ``(n_sensors, 3)`` m,
    in ``meta["truth_sensor_positions_m"]``, for diagnosis; models never see them.

    Point logs are appended to a side file (``partial``, default ``NAME.partial.h5`` next to
    ``path``, or the next free name) that is renamed over ``path`` only when the session is
    complete, so an existing ``path`` is never half replaced. On ``KeyboardInterrupt`` the side
    file keeps the complete point logs (a valid recording) and ``Interrupted`` is raised with a
    message naming it; on any other error it is removed.
    """
    path = Path(path)
    side = side_path(partial if partial is not None else path, "partial")
    finger = ScriptedFinger(skin, random_state=config.random_state + 1)
    was_connected = skin.is_connected
    if not was_connected:
        skin.connect()
    session = CalibrationSession(
        skin, mesh, side, config, targets=targets, source_name="sim", incremental=True
    )

    def kept() -> tuple[int, int]:
        return session.n_done, len(session.targets)

    with written_through_side(side, path, kept, "point logs", "point log"):
        try:
            session.run(finger, progress)
        finally:
            if not was_connected:
                skin.disconnect()
            if session._appender is not None:
                contacts = np.asarray(finger.contacts[: session.n_done]).tolist()
                session.update_meta(true_contacts=contacts, **truth_layout(skin))
            session.close()
    return read_recording(path)
