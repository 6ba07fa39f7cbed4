import numpy as np
import pytest

from skinloc.calibration.session import (
    CalibrationSession,
    ScriptedFinger,
    SessionConfig,
    TouchDetector,
    simulate_session,
)
from skinloc.data.recording import read_recording
from skinloc.errors import FrameTimeoutError, RecordingError
from skinloc.geometry.mesh import nearest_on_surface
from skinloc.sim.skin import SimulatedSkin

SMALL = dict(n_points=6, samples_per_touch=5, n_baseline_frames=20)


def test_touch_detector():
    det = TouchDetector(np.full(4, 100.0), np.array([1.0, 1.0, 50.0, 0.0]), 5.0, 2)
    assert not det.is_touched(np.array([104.0, 104.0, 300.0, 100.0]))  # noisy sensor: 200 < 250
    assert det.is_touched(np.array([110.0, 106.0, 100.0, 100.0]))
    assert det.n_active(np.array([110.0, 106.0, 100.0, 106.0])) == 3  # floor of 1 count


def test_session_records_every_target(tmp_path, cone):
    skin = SimulatedSkin(cone, random_state=0)
    rec = simulate_session(skin, cone, tmp_path / "s.h5", SessionConfig(**SMALL, mode="edge"))
    assert rec.n_point_logs == 6 and rec.frames.shape == (6, 5, 64)
    back = read_recording(tmp_path / "s.h5")
    np.testing.assert_array_equal(back.frames, rec.frames)
    _, d, _ = nearest_on_surface(cone, back.targets)
    assert d.max() < 1e-9
    # true contacts are within a few mm of the targets (probing error), never identical
    miss = np.linalg.norm(np.array(back.meta["true_contacts"]) - back.targets, axis=1)
    assert 0 < miss.mean() < 0.01
    # every captured frame is a touch
    det = TouchDetector(back.baseline, back.noise)
    assert all(det.is_touched(f) for f in back.frames.reshape(-1, 64))
    assert back.meta["session"]["samples_per_touch"] == 5


class Crash(RuntimeError):
    pass


class CrashingFinger(ScriptedFinger):
    def __init__(self, skin, crash_at):
        super().__init__(skin, random_state=0)
        self.crash_at = crash_at

    def prompt(self, index, target):
        if index == self.crash_at:
            raise Crash
        super().prompt(index, target)


def test_crash_loses_nothing_and_resumes(tmp_path, cone):
    path = tmp_path / "s.h5"
    skin = SimulatedSkin(cone, random_state=1)
    with skin:
        session = CalibrationSession(skin, cone, path, SessionConfig(**SMALL))
        with pytest.raises(Crash):
            session.run(CrashingFinger(skin, crash_at=4))
        saved = read_recording(path)
        assert saved.n_point_logs == 4  # everything captured before the crash is on disk
        resumed = CalibrationSession.resume(skin, path)
        assert resumed.n_done == 4 and not resumed.finished
        rec = resumed.run(ScriptedFinger(skin, random_state=2))
    assert rec.n_point_logs == 6
    np.testing.assert_array_equal(rec.frames[:4], saved.frames)
    np.testing.assert_array_equal(rec.targets, session.targets)


def test_resume_needs_matching_source(tmp_path, cone):
    path = tmp_path / "s.h5"
    simulate_session(SimulatedSkin(cone, random_state=0), cone, path, SessionConfig(**SMALL))
    with pytest.raises(RecordingError, match="16"):
        CalibrationSession.resume(SimulatedSkin(cone, n_tx=4, n_rx=4), path)


class LazyFinger:
    """Never touches."""

    def prompt(self, index, target):
        pass

    def captured(self, index):
        pass


def test_no_touch_times_out_on_source_clock(tmp_path, cone):
    skin = SimulatedSkin(cone, random_state=0)
    with skin:
        session = CalibrationSession(
            skin, cone, tmp_path / "s.h5", SessionConfig(**SMALL, touch_timeout_s=2.0)
        )
        with pytest.raises(FrameTimeoutError, match="no touch"):
            session.run(LazyFinger())


def test_given_targets_are_used(tmp_path, cone):
    targets = cone.vertices[[0, 10, 100]]
    rec = simulate_session(
        SimulatedSkin(cone),
        cone,
        tmp_path / "s.h5",
        SessionConfig(**{**SMALL, "n_points": 3}),
        targets=targets,
    )
    np.testing.assert_array_equal(rec.targets, targets)


@pytest.mark.parametrize(
    "field,value",
    [("n_points", 0), ("mode", "grid"), ("n_baseline_frames", 1), ("threshold_sigma", 0)],
)
def test_bad_config(field, value):
    with pytest.raises(ValueError, match=field if field != "mode" else "grid"):
        SessionConfig(**{field: value})


def test_active_session_chooses_after_touches_and_repeats_recorded_targets(cone, tmp_path):
    """An incremental (header-only) active session still chooses from its touches."""
    from skinloc.calibration.active import N_START

    cfg = SessionConfig(**SMALL, mode="active", n_repeats=2)
    rec = simulate_session(SimulatedSkin(cone, random_state=0), cone, tmp_path / "s.h5", cfg)
    assert rec.n_point_logs == 8 and rec.meta["sampling_mode"] == "active"
    np.testing.assert_allclose(rec.targets[:N_START], rec.planned_targets[:N_START])
    chosen = rec.targets[N_START:6]
    assert np.linalg.norm(chosen - rec.planned_targets[N_START:6], axis=1).min() > 1e-6
    # The repeats ask again for recorded targets (the first and the last of the six).
    np.testing.assert_allclose(rec.targets[6:], rec.targets[[0, 5]])
