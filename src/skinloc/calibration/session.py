"""The calibration session: baseline, targets, touches, point logs; free of any UI.

The session reads frames from any ``FrameSource`` and talks to the person (or a scripted
finger) through a ``Prober``. The recording is written atomically after the baseline and after
every point log, so a crash loses at most the touch in progress, and ``resume`` carries on.
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
from skinloc.data.appender import RecordingAppender
from skinloc.data.recording import Recording, read_recording, write_recording
from skinloc.errors import FrameTimeoutError, RecordingError
from skinloc.files import side_path, written_through_side
from skinloc.geometry.mesh import SamplingMode, sample_targets, surface_points
from skinloc.sources.base import FrameSource

log = logging.getLogger(__name__)

#: Sampling modes of a session: the planned ones and ``active`` (chosen touch by touch).
SESSION_MODES = (*(m.value for m in SamplingMode), "active")
#: Candidate targets an active session chooses from, per point log asked for (at least 64).
ACTIVE_POOL_PER_POINT = 3

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


class TouchDetector:
    """Decide from one frame whether the skin is touched.

    Parameters
    ----------
    baseline : (n_sensors,) float
        No-touch mean, counts.
    noise : (n_sensors,) float
        No-touch standard deviation, counts.
    threshold_sigma, min_active :
        See ``SessionConfig``.
    """

    def __init__(
        self,
        baseline: np.ndarray,
        noise: np.ndarray,
        threshold_sigma: float = 5.0,
        min_active: int = 2,
    ) -> None:
        self.baseline = np.asarray(baseline, dtype=np.float64)
        # A floor of 1 count keeps a perfectly quiet sensor from triggering on quantisation.
        self.threshold = threshold_sigma * np.maximum(np.asarray(noise, dtype=np.float64), 1.0)
        self.min_active = min_active

    def n_active(self, values: np.ndarray) -> int:
        """Sensors above threshold in ``values (n_sensors,)`` raw counts."""
        return int(np.count_nonzero(np.asarray(values) - self.baseline > self.threshold))

    def is_touched(self, values: np.ndarray) -> bool:
        """Whether ``values (n_sensors,)`` raw counts look like a touch."""
        return self.n_active(values) >= self.min_active


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
        Recording to write (HDF5), rewritten atomically after every point log.
    config : SessionConfig
        Session settings.
    targets : (n, 3) float, optional
        Targets to use instead of sampling them (e.g. a loaded list).
    incremental : bool
        Create ``path`` (never replacing a file) and append each point log to it, instead of
        rewriting it atomically after each one (time linear, not quadratic, in the session's
        length); ``self.recording`` then holds the header only. ``close`` closes the file.
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
        # Targets and mean images of the touches made, for the active choice (kept here
        # because an incremental session's recording holds its header only).
        self._done_targets: list[np.ndarray] = []
        self._done_images: list[np.ndarray] = []
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
        if self._appender is not None:
            return self._appender.n_point_logs
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
        if self.incremental:
            self._appender = RecordingAppender(self.recording, self.path)
        else:
            write_recording(self.recording, self.path)
        return self.recording

    def _wait(self, touched: bool, n_consecutive: int) -> None:
        """Read frames until ``n_consecutive`` in a row are (or are not) touches.

        The timeout runs on the source's clock, so a simulated skin times out in simulated time.
        """
        assert self.detector is not None
        run, start = 0, None
        while run < n_consecutive:
            frame = self.source.read(timeout_s=self.config.touch_timeout_s)
            start = frame.timestamp_s if start is None else start
            run = run + 1 if self.detector.is_touched(frame.values) == touched else 0
            if run < n_consecutive and frame.timestamp_s - start > self.config.touch_timeout_s:
                what = "touch" if touched else "release"
                raise FrameTimeoutError(
                    f"no {what} detected on {self.source_name} within "
                    f"{self.config.touch_timeout_s:g} s"
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

        From the recording when it holds them (whoever appended or removed point logs, e.g.
        the app), else (an incremental session) from those this session recorded.
        """
        rec = self.recording
        if self._appender is None and rec is not None:
            return np.asarray(rec.targets, dtype=np.float64), rec.touch_means.astype(np.float64)
        k = self.source.n_sensors if rec is None else rec.n_sensors
        if not self._done_targets:
            return np.zeros((0, 3)), np.zeros((0, k))
        return np.asarray(self._done_targets), np.asarray(self._done_images)

    def active_pool(self) -> Points:
        """Candidate targets of an active session, ``(c, 3)`` m, evenly spread and seeded."""
        if self._pool is None:
            n = max(ACTIVE_POOL_PER_POINT * self.config.n_points, 64)
            self._pool = sample_targets(
                self.mesh, n, "even", random_state=self.config.random_state + 1
            )
        return self._pool

    def record_point(self, index: int, prober: Prober) -> None:
        """Prompt target ``index``, wait for a steady touch, capture and store its frames."""
        if self.recording is None:
            raise RecordingError("capture the baseline before recording point logs")
        target = self.target_for(index)
        prober.prompt(index, target)
        self._wait(touched=True, n_consecutive=self.config.settle_frames)
        frames, times = self.source.read_many(self.config.samples_per_touch)
        self._done_targets.append(np.array(target, dtype=np.float64))
        # Computed as ``Recording.touch_means`` does, so a resumed session sees the same.
        delta = np.asarray(frames, dtype=np.float32) - self.recording.baseline.astype(np.float32)
        self._done_images.append(delta[None].mean(axis=1)[0].astype(np.float64))
        if self._appender is not None:
            self._appender.append(target, frames, times)
        else:
            self.recording.append(target, frames, times)
            write_recording(self.recording, self.path)
        prober.captured(index)
        self._wait(touched=False, n_consecutive=2)

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
        """Close the file of an incremental session (a no-op otherwise)."""
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
                session._appender.update_meta(true_contacts=contacts, **truth_layout(skin))
            session.close()
    return read_recording(path)
