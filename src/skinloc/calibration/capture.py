"""The calibration touch rule: when a touch starts, is held and ends, and which frames it keeps.

One rule for every calibration capture: ``skinloc collect`` and ``skinloc simulate`` pull
frames through it (``CalibrationSession.record_point``), the app pushes its reader thread's
frames through it (guided capture), and both store each finished touch with
``data.appender.RecordingAppender`` (a point log appended as it comes).

- ``TouchDetector`` says whether one frame is a touch: at least ``min_active`` sensors rise
  more than ``threshold_sigma`` no-touch standard deviations (floored at 1 count) above the
  session's fixed baseline.
- ``TouchCapture`` is the dwell of one point log: ``settle_frames`` touch frames in a row
  start it, the next ``samples`` frames are its point log whatever they show (a finger that
  lifts early is counted in ``CapturedTouch.n_untouched``, and the app flags it ``short``),
  then ``release_frames`` no-touch frames in a row end it before the next touch may start.

The live pipeline's touch detection (``live.core.SkinCore``) is a different rule on purpose,
not a second copy of this one: it follows a moving finger on a baseline that tracks drift,
starts and ends a contact by hysteresis on the largest z-score of the frame (on above
``touch_on_z``, off below ``touch_off_z`` or a fraction of the touch's level) with
debouncing, and runs compiled per frame. A calibration touch is a held press at one place on
a fixed baseline, judged by how many sensors it moves, and keeps a fixed number of frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

__all__ = [
    "RELEASE_FRAMES",
    "CapturePhase",
    "CapturedTouch",
    "TouchCapture",
    "TouchDetector",
]

#: No-touch frames in a row that end a touch in a session pulled by ``CalibrationSession``.
RELEASE_FRAMES = 2


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


class CapturePhase(StrEnum):
    """Where a capture stands."""

    WAIT_TOUCH = "wait_touch"  # waiting for a steady touch
    CAPTURING = "capturing"  # storing frames
    WAIT_RELEASE = "wait_release"  # the finger must lift before the next touch


@dataclass
class CapturedTouch:
    """The frames of one touch.

    Attributes
    ----------
    frames : (s, n_sensors) float32
        Raw counts.
    times : (s,) float
        Frame timestamps, s.
    n_untouched : int
        Captured frames the detector did not see as a touch (the finger lifted early).
    forced : bool
        Started by the key, not by the detector.
    """

    frames: np.ndarray
    times: np.ndarray
    n_untouched: int
    forced: bool


@dataclass
class TouchCapture:
    """The touch rule, one frame at a time: wait for a steady touch, capture, wait for release.

    Parameters
    ----------
    detector : TouchDetector
        Decides whether a frame is a touch.
    samples : int
        Frames to capture per touch.
    settle_frames : int
        Consecutive touch frames before capture starts (not captured themselves).
    release_frames : int
        Consecutive no-touch frames that count as a release: the app's guided capture keeps
        the default (3), a session pulling from a source ``RELEASE_FRAMES`` (2), as each
        did before they shared this rule.
    """

    detector: TouchDetector
    samples: int
    settle_frames: int = 5
    release_frames: int = 3
    phase: CapturePhase = CapturePhase.WAIT_TOUCH
    run: int = 0
    _frames: list[np.ndarray] = field(default_factory=list)
    _times: list[float] = field(default_factory=list)
    _untouched: int = 0
    _forced: bool = False

    @property
    def n_captured(self) -> int:
        """Frames stored so far in the current capture."""
        return len(self._frames)

    def restart(self, touched_now: bool = True) -> None:
        """Drop a capture in progress; wait for a release first when ``touched_now``."""
        self._frames, self._times, self._untouched, self._forced = [], [], 0, False
        self.run = 0
        self.phase = CapturePhase.WAIT_RELEASE if touched_now else CapturePhase.WAIT_TOUCH

    def force(self) -> None:
        """Start capturing with the next frame, touch detected or not (the key fallback)."""
        if self.phase is not CapturePhase.CAPTURING:
            self._frames, self._times, self._untouched = [], [], 0
            self._forced = True
            self.phase = CapturePhase.CAPTURING

    def feed(self, values: np.ndarray, timestamp_s: float) -> CapturedTouch | None:
        """Advance by one frame of raw counts; returns the touch when its capture completes.

        The touch's last frame moves the capture to ``WAIT_RELEASE``.
        """
        touched = self.detector.is_touched(values)
        if self.phase is CapturePhase.WAIT_RELEASE:
            self.run = self.run + 1 if not touched else 0
            if self.run >= self.release_frames:
                self.phase, self.run = CapturePhase.WAIT_TOUCH, 0
            return None
        if self.phase is CapturePhase.WAIT_TOUCH:
            self.run = self.run + 1 if touched else 0
            if self.run >= self.settle_frames:
                self._frames, self._times, self._untouched, self._forced = [], [], 0, False
                self.phase = CapturePhase.CAPTURING
            return None
        self._frames.append(np.asarray(values, dtype=np.float32))
        self._times.append(float(timestamp_s))
        self._untouched += not touched
        if len(self._frames) < self.samples:
            return None
        touch = CapturedTouch(
            np.stack(self._frames), np.asarray(self._times), self._untouched, self._forced
        )
        self.restart(touched_now=True)
        return touch
