"""One touch rule and one appender for every calibration capture."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.calibration.capture import RELEASE_FRAMES, CapturePhase, TouchCapture
from skinloc.calibration.session import CalibrationSession, ScriptedFinger, SessionConfig
from skinloc.data.recording import read_recording
from skinloc.errors import FrameTimeoutError
from skinloc.sim.skin import SimulatedSkin

SMALL = dict(n_points=4, samples_per_touch=5, n_baseline_frames=20)


def test_the_session_pulls_frames_through_the_rule_the_app_feeds(tmp_path, cone):
    """Every frame the session read, pushed through a ``TouchCapture`` as the app pushes its
    reader's frames, gives the same point logs."""
    skin = SimulatedSkin(cone, random_state=2)
    read = skin.read
    seen: list = []

    def logged(timeout_s: float = 1.0):
        frame = read(timeout_s)
        seen.append(frame)
        return frame

    skin.read = logged
    with skin:
        session = CalibrationSession(skin, cone, tmp_path / "s.h5", SessionConfig(**SMALL))
        session.capture_baseline()
        n_baseline = len(seen)
        session.run(ScriptedFinger(skin, random_state=3))
    cfg = session.config
    capture = TouchCapture(
        session.detector, cfg.samples_per_touch, cfg.settle_frames, RELEASE_FRAMES
    )
    touches = [capture.feed(f.values, f.timestamp_s) for f in seen[n_baseline:]]
    touches = [t for t in touches if t is not None]
    rec = read_recording(tmp_path / "s.h5")
    assert len(touches) == rec.n_point_logs == 4
    np.testing.assert_array_equal(np.stack([t.frames for t in touches]), rec.frames)
    np.testing.assert_array_equal(np.stack([t.times for t in touches]), rec.frame_times)
    assert capture.phase is CapturePhase.WAIT_TOUCH  # the last release was waited for


def test_a_session_appends_its_touches_to_its_file_in_place(tmp_path, cone):
    path = tmp_path / "s.h5"
    path.write_bytes(b"replaced by the header, as collect --new --force does")
    with SimulatedSkin(cone, random_state=0) as skin:
        session = CalibrationSession(skin, cone, path, SessionConfig(**SMALL))
        session.capture_baseline()
        inode = path.stat().st_ino
        finger = ScriptedFinger(skin, random_state=1)
        for i in range(2):
            session.record_point(i, finger)
            assert read_recording(path).n_point_logs == i + 1
        resumed = CalibrationSession.resume(skin, path)
        resumed.run(finger)
    assert path.stat().st_ino == inode  # never a whole new file
    assert read_recording(path).n_point_logs == 4


class StuckFinger(ScriptedFinger):
    """Presses, and never lifts."""

    def captured(self, index: int) -> None:
        pass


def test_a_finger_that_stays_down_times_out_on_the_source_clock(tmp_path, cone):
    with SimulatedSkin(cone, random_state=0) as skin:
        cfg = SessionConfig(**SMALL, touch_timeout_s=2.0)
        session = CalibrationSession(skin, cone, tmp_path / "s.h5", cfg)
        session.capture_baseline()
        with pytest.raises(FrameTimeoutError, match="no release detected .* within 2 s"):
            session.record_point(0, StuckFinger(skin, random_state=1))
    assert read_recording(tmp_path / "s.h5").n_point_logs == 1  # the touch itself is kept
