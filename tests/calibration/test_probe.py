import math

import numpy as np
import pytest

from skinloc.calibration.probe import (
    ProbeError,
    ProbeLinkError,
    ProbeSafetyError,
    ProbeSettings,
    SimulatedProbe,
    check_press,
    probe_dry_run,
    record_probe_point,
)
from skinloc.calibration.probe_plan import SkinPose, plan_probing
from skinloc.calibration.session import CalibrationSession, SessionConfig
from skinloc.data.recording import read_recording
from skinloc.geometry.mesh import nearest_on_surface
from skinloc.geometry.skin_frame import quaternion_from_rpy
from skinloc.sim.skin import SimulatedSkin

SMALL = dict(n_points=4, samples_per_touch=5, n_baseline_frames=20, touch_timeout_s=5.0)
POSE = SkinPose((0.4, -0.1, 0.2), quaternion_from_rpy(0.3, -0.2, 1.0), "base_link")


def _session(tmp_path, cone, skin, n=4):
    plan = plan_probing(cone, n, "even", max_tilt_deg=180, rim_clearance_m=0, pose=POSE)
    cfg = SessionConfig(**{**SMALL, "n_points": len(plan)})
    session = CalibrationSession(skin, cone, tmp_path / "p.h5", cfg, targets=plan.targets_m)
    skin.connect()
    session.capture_baseline()
    return session, plan


class Spy:
    """A probe that wraps another and can fail on the n-th press."""

    def __init__(self, inner, fail=None, at=0):
        self.inner, self.fail, self.at, self.presses, self.stops = inner, fail, at, 0, 0

    def move_above(self, approach_m, press_direction):
        self.inner.move_above(approach_m, press_direction)

    def press(self, target_m, press_direction, depth_m=None, force_n=None):
        if self.fail is not None and self.presses == self.at:
            raise self.fail
        self.presses += 1
        return self.inner.press(target_m, press_direction, depth_m, force_n)

    def lift(self):
        self.inner.lift()

    def stop(self):
        self.stops += 1
        self.inner.stop()

    def close(self):
        pass


def test_check_press_refuses_beyond_the_limits():
    check_press(ProbeSettings(depth_m=0.003, max_depth_m=0.005))
    check_press(ProbeSettings(depth_m=None, force_n=3.0))
    with pytest.raises(ProbeSafetyError, match="press depth 6 mm is beyond the limit of 5 mm"):
        check_press(ProbeSettings(depth_m=0.006, max_depth_m=0.005))
    with pytest.raises(ProbeSafetyError, match="press force 12 N is beyond the limit of 10 N"):
        check_press(ProbeSettings(depth_m=None, force_n=12.0))
    with pytest.raises(ValueError, match="depth_m or force_n"):
        check_press(ProbeSettings(depth_m=0.001, force_n=1.0))
    with pytest.raises(ValueError, match="depth_m must be > 0"):
        check_press(ProbeSettings(depth_m=-0.001))
    with pytest.raises(ValueError, match="clearance_m"):
        check_press(ProbeSettings(clearance_m=0.0))


def test_simulated_probe_presses_the_skin_where_it_was_sent(cone):
    skin = SimulatedSkin(cone, random_state=0)
    probe = SimulatedProbe(skin, pose=POSE, position_error_m=0.0005, random_state=1)
    target = POSE.points_to_base(cone.vertices[[40]])[0]
    down = POSE.directions_to_base(-cone.vertex_normals[[40]])[0]
    probe.move_above(target - 0.01 * down, down)
    t0 = skin.time_s
    report = probe.press(target, down, depth_m=0.002)
    assert skin.time_s > t0  # travel and dwell take simulated time
    np.testing.assert_allclose(report.tip_m, target + 0.002 * down)
    assert report.depth_m == 0.002 and math.isnan(report.force_n)
    # the skin's finger is down within a few errors of the target, in the mesh frame
    assert skin.contact is not None
    assert 0 < np.linalg.norm(skin.contact - cone.vertices[40]) < 0.003
    np.testing.assert_allclose(probe.contacts[-1], skin.contact)
    probe.lift()
    assert skin.contact is None
    # a force press; the probe's own limits
    assert probe.press(target, down, force_n=2.0).force_n == 2.0
    probe.lift()
    with pytest.raises(ProbeSafetyError, match="beyond the probe's limit"):
        probe.press(target, down, depth_m=0.01)
    with pytest.raises(ProbeSafetyError, match="beyond the probe's limit"):
        probe.press(target, down, force_n=50.0)
    probe.press(target, down, depth_m=0.002)
    probe.stop()
    assert skin.contact is None and probe.stopped
    with pytest.raises(ProbeError, match="stopped"):
        probe.move_above(target, down)
    with pytest.raises(ValueError, match="position_error_m"):
        SimulatedProbe(skin, position_error_m=-1.0)


def test_a_deeper_press_is_stronger_and_wider(cone):
    skin = SimulatedSkin(cone, random_state=0)
    probe = SimulatedProbe(skin, position_error_m=0.0, random_state=1)
    target, down = cone.vertices[40], -cone.vertex_normals[40]
    pressed, press = {}, skin.press

    def seen_press(point, *, pressure, finger_radius_m):  # what the probe asks of the skin
        pressed[depth] = (pressure, finger_radius_m)
        press(point, pressure=pressure, finger_radius_m=finger_radius_m)

    skin.press = seen_press
    for depth in (0.001, 0.002, 0.004):
        probe.move_above(target - 0.01 * down, down)
        probe.press(target, down, depth_m=depth)
        probe.lift()
    # pressure depth / 2 mm; the contact widens as the simulator's finger does (P ** 1/3)
    assert [pressed[d][0] for d in (0.001, 0.002, 0.004)] == [0.5, 1.0, 2.0]
    exponent = skin.params.radius_pressure_exponent
    assert pressed[0.002][1] == pytest.approx(skin.params.finger_radius_m)
    assert pressed[0.004][1] == pytest.approx(skin.params.finger_radius_m * 2.0**exponent)
    assert pressed[0.001][1] < pressed[0.002][1] < pressed[0.004][1]


def test_a_probe_session_stores_the_reported_tip(tmp_path, cone):
    skin = SimulatedSkin(cone, random_state=0)
    session, plan = _session(tmp_path, cone, skin)
    probe = SimulatedProbe(skin, pose=POSE, position_error_m=0.0005, random_state=2)
    settings = ProbeSettings(depth_m=0.002)
    for i in range(len(plan)):
        record_probe_point(session, i, probe, settings, POSE)
    session.close()
    rec = read_recording(tmp_path / "p.h5")
    assert rec.n_point_logs == len(plan) == 4
    # the target stored is the reported tip put on the surface: the planned target, here
    np.testing.assert_allclose(rec.targets, plan.targets_m, atol=1e-6)
    tips = np.array(rec.meta["probe_tips_m"])
    # the reported tip lies the press depth below the surface
    _, depth, _ = nearest_on_surface(cone, tips)
    np.testing.assert_allclose(depth, 0.002, atol=1e-6)
    assert rec.meta["probe_depths_m"] == [0.002] * 4 and rec.meta["probe_forces_n"] == [None] * 4
    miss = np.linalg.norm(np.array(rec.meta["true_contacts"]) - rec.targets, axis=1)
    assert 0 < miss.max() < 0.003
    assert skin.contact is None


def test_an_over_deep_press_is_refused_before_anything_moves(tmp_path, cone):
    skin = SimulatedSkin(cone, random_state=0)
    session, _ = _session(tmp_path, cone, skin)
    probe = Spy(SimulatedProbe(skin, pose=POSE))
    with pytest.raises(ProbeSafetyError, match="plan refused"):
        record_probe_point(session, 0, probe, ProbeSettings(depth_m=0.008), POSE)
    assert probe.presses == 0 and probe.inner.position is None and session.n_done == 0


@pytest.mark.parametrize(
    ("fail", "kind"),
    [
        (ProbeLinkError("link to the arm lost"), ProbeLinkError),
        (KeyboardInterrupt(), KeyboardInterrupt),
    ],
)
def test_a_lost_link_or_ctrl_c_stops_the_probe_and_keeps_the_touches(tmp_path, cone, fail, kind):
    skin = SimulatedSkin(cone, random_state=0)
    session, _ = _session(tmp_path, cone, skin)
    probe = Spy(SimulatedProbe(skin, pose=POSE), fail=fail, at=2)
    record_probe_point(session, 0, probe, ProbeSettings(), POSE)
    record_probe_point(session, 1, probe, ProbeSettings(), POSE)
    with pytest.raises(kind):
        record_probe_point(session, 2, probe, ProbeSettings(), POSE)
    assert probe.stops == 1 and probe.inner.stopped and skin.contact is None
    rec = read_recording(tmp_path / "p.h5")
    assert rec.n_point_logs == 2 and len(rec.meta["probe_tips_m"]) == 2


def test_a_touch_where_none_is_planned_stops_the_probe(tmp_path, cone):
    skin = SimulatedSkin(cone, random_state=0)
    session, plan = _session(tmp_path, cone, skin)
    probe = Spy(SimulatedProbe(skin, pose=POSE))
    skin.press(plan.targets_m[-1], pressure=1.0)  # someone's hand on the skin
    with pytest.raises(ProbeSafetyError, match="feels a touch with the probe above target 1"):
        record_probe_point(session, 0, probe, ProbeSettings(), POSE)
    assert probe.presses == 0 and probe.stops == 1 and session.n_done == 0


def test_dry_run_only_moves_above(tmp_path, cone):
    skin = SimulatedSkin(cone, random_state=0)
    session, plan = _session(tmp_path, cone, skin)
    probe = Spy(SimulatedProbe(skin, pose=POSE))
    assert probe_dry_run(session, probe, ProbeSettings(), POSE) == len(plan)
    assert probe.presses == 0 and session.n_done == 0
    np.testing.assert_allclose(probe.inner.position, POSE.points_to_base(plan.approach_m[-1:])[0])
    skin.press(plan.targets_m[0], pressure=1.0)
    with pytest.raises(ProbeSafetyError, match="dry run"):
        probe_dry_run(session, probe, ProbeSettings(), POSE)
    assert probe.stops == 1


def test_a_press_the_skin_does_not_feel_stops_the_probe(tmp_path, cone):
    from skinloc.errors import FrameTimeoutError

    skin = SimulatedSkin(cone, random_state=0)
    session, _ = _session(tmp_path, cone, skin)
    # a typical touch needs 1000 mm here: 2 mm barely dents the skin, which feels nothing
    probe = Spy(SimulatedProbe(skin, pose=POSE, nominal_depth_m=1.0))
    with pytest.raises(FrameTimeoutError, match="no touch detected"):
        record_probe_point(session, 0, probe, ProbeSettings(), POSE)
    assert probe.presses == 1 and probe.stops == 1 and skin.contact is None
    assert session.n_done == 0
