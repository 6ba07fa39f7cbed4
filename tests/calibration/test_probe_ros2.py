"""The ROS 2 probe against a stand-in arm written with the real rclpy, in another process.

Skipped, with the reason, where the Jazzy wheels are not installed (``pip install '.[ros2]'``).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skinloc.calibration.probe import (
    ProbeError,
    ProbeLinkError,
    ProbeSettings,
    SimulatedProbe,
    record_probe_point,
)
from skinloc.calibration.probe_plan import SkinPose, plan_probing
from skinloc.calibration.session import CalibrationSession, SessionConfig
from skinloc.data.recording import read_recording
from skinloc.geometry.skin_frame import quaternion_from_rpy
from skinloc.sim.skin import SimulatedSkin
from tests._helpers import scaled, wait_until

try:
    import rclpy  # noqa: F401
    import std_msgs.msg  # noqa: F401
    from geometry_msgs.msg import PoseStamped  # noqa: F401

    _WHY = ""
except ImportError as exc:  # the banner pytest shows for every skipped test
    _WHY = f"the ROS 2 Jazzy wheels are not installed ({exc}); pip install '.[ros2]'"

ARM = Path(__file__).with_name("ros2_arm.py")
TIP_OFFSET_M = np.array([0.0003, -0.0002, 0.0001])  # ros2_arm.py's
FORCE_SHORT_M = 0.001  # ros2_arm.py's: a press to a force stops this short of the press pose
POSE = SkinPose((0.4, -0.1, 0.2), quaternion_from_rpy(0.3, -0.2, 1.0), "base_link")
SMALL = dict(samples_per_touch=5, n_baseline_frames=20, touch_timeout_s=5.0)
needs_rclpy = pytest.mark.skipif(bool(_WHY), reason=_WHY)


class Arm:
    """The stand-in arm process and what it heard."""

    def __init__(self, tmp_path: Path, mode: str, port: str | None = None) -> None:
        self.log = tmp_path / f"arm-{mode}.jsonl"
        self.log.touch()
        self.proc = subprocess.Popen(
            [sys.executable, str(ARM), str(self.log), mode, str(scaled(300.0))]
            + ([port] if port else []),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=dict(os.environ),
        )
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        assert line.strip() == "ready", self.proc.stderr.read() if self.proc.stderr else line

    def heard(self) -> list[dict]:
        return [json.loads(x) for x in self.log.read_text().splitlines() if x.strip()]

    def kinds(self) -> list[str]:
        return [r["kind"] for r in self.heard()]

    def end(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=scaled(20.0))
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


@pytest.fixture
def arm(tmp_path, ros_domain, request):
    a = Arm(tmp_path, getattr(request, "param", "ok"))
    yield a
    a.end()


class ArmOnSimSkin:
    """The ROS 2 probe, with the stand-in arm's presses felt by a simulated skin.

    The arm process cannot reach the test's simulated skin, so this puts the skin's finger where
    the ROS 2 exchange sent the tip (a ``SimulatedProbe`` with no position error) after each
    answered move: the exchange itself is the real rclpy one.
    """

    def __init__(self, ros, sim) -> None:
        self.ros, self.sim, self.stops = ros, sim, 0

    def move_above(self, approach_m, press_direction):
        self.ros.move_above(approach_m, press_direction)
        self.sim.move_above(approach_m, press_direction)

    def press(self, target_m, press_direction, depth_m=None, force_n=None):
        report = self.ros.press(target_m, press_direction, depth_m, force_n)
        self.sim.press(target_m, press_direction, depth_m, force_n)
        return report

    def lift(self):
        self.ros.lift()
        self.sim.lift()

    def stop(self):
        self.stops += 1
        self.ros.stop()
        self.sim.stop()

    def close(self):
        self.ros.close()


def _session(tmp_path, cone, n=2):
    skin = SimulatedSkin(cone, n_tx=8, n_rx=8, random_state=3)
    plan = plan_probing(cone, n, "even", max_tilt_deg=180, rim_clearance_m=0, pose=POSE)
    cfg = SessionConfig(n_points=len(plan), **SMALL)
    session = CalibrationSession(skin, cone, tmp_path / "p.h5", cfg, targets=plan.targets_m)
    skin.connect()
    session.capture_baseline()
    return session, skin


def _probe(**kw):
    from skinloc.calibration.probe_ros2 import Ros2Probe

    return Ros2Probe("base_link", connect_timeout_s=scaled(60.0), **kw)


@needs_rclpy
def test_orientation_turns_the_tool_z_onto_the_press_direction():
    from scipy.spatial.transform import Rotation

    from skinloc.calibration.probe_ros2 import tool_orientation

    for d in ([0, 0, -1], [0, 0, 1], [1, 2, -3], [-1, 0, 0]):
        u = np.asarray(d, float) / np.linalg.norm(d)
        z = Rotation.from_quat(tool_orientation(np.asarray(d, float))).apply([0, 0, 1])
        assert np.allclose(z, u, atol=1e-9), d
    with pytest.raises(ValueError, match="press_direction"):
        tool_orientation(np.zeros(3))


@needs_rclpy
def test_a_probed_session_through_a_stand_in_arm(tmp_path, cone, arm):
    session, skin = _session(tmp_path, cone)
    settings = ProbeSettings(depth_m=0.002)
    ros = _probe(timeout_s=scaled(30.0))
    probe = ArmOnSimSkin(ros, SimulatedProbe(skin, pose=POSE, position_error_m=0.0))
    reports = []
    try:
        for i in range(len(session.targets)):
            reports.append(record_probe_point(session, i, probe, settings, POSE))
    finally:
        probe.close()
        session.close()
        skin.disconnect()
    assert probe.stops == 0
    heard = arm.heard()
    assert [r["kind"] for r in heard] == ["approach", "press", "lift"] * 2
    assert all(r["frame"] == "base_link" for r in heard)
    presses = [r for r in heard if r["kind"] == "press"]
    for press, report in zip(presses, reports, strict=True):
        # the arm's measured tip is what the report (and the recording) keeps
        assert np.allclose(report.tip_m, np.add(press["position"], TIP_OFFSET_M), atol=1e-12)
        assert report.depth_m == 0.002
    # the press pose is the depth past the surface along the tool's z, from the approach
    approach, press = heard[0], heard[1]
    from scipy.spatial.transform import Rotation

    z = Rotation.from_quat(press["orientation"]).apply([0, 0, 1])
    step = np.subtract(press["position"], approach["position"])
    assert np.allclose(step / np.linalg.norm(step), z, atol=1e-9)
    assert np.isclose(np.linalg.norm(step), settings.clearance_m + 0.002, atol=1e-9)
    assert heard[2]["position"] == approach["position"]
    rec = read_recording(tmp_path / "p.h5")
    tips = np.asarray(rec.meta["probe_tips_m"])
    want = POSE.points_to_skin(np.stack([r.tip_m for r in reports]))
    assert np.allclose(tips, want, atol=1e-6)
    assert rec.meta["probe_depths_m"] == [0.002, 0.002]


@needs_rclpy
@pytest.mark.parametrize(
    ("arm", "error", "needle"),
    [("mute", ProbeLinkError, "did not say 'pressed'"), ("refuse", ProbeError, "joint limit")],
    indirect=["arm"],
)
def test_a_lost_or_refusing_arm_stops_the_session(tmp_path, cone, arm, error, needle):
    session, skin = _session(tmp_path, cone, n=1)
    # the approach's answer may come late on a busy machine; only the press waits briefly
    ros = _probe(timeout_s=scaled(60.0))

    class BriefPress:
        def __getattr__(self, name):
            return getattr(ros, name)

        def press(self, *a, **k):
            ros.timeout_s = scaled(3.0)
            return ros.press(*a, **k)

    try:
        with pytest.raises(error, match=needle) as info:
            record_probe_point(session, 0, BriefPress(), ProbeSettings(depth_m=0.002), POSE)
    finally:
        ros.close()
        session.close()
        skin.disconnect()
    assert str(info.value).count("\n") == 0
    # the stop reached the arm: the session published it before raising
    wait_until(lambda: "stop" in arm.kinds(), "the arm to hear the stop", 30.0)
    assert arm.kinds()[:2] == ["approach", "press"]
    assert session.n_done == 0


@needs_rclpy
def test_ctrl_c_stops_the_arm(tmp_path, cone, arm):
    session, skin = _session(tmp_path, cone, n=1)
    ros = _probe(timeout_s=scaled(30.0))

    class CtrlC:  # Ctrl-C lands while the arm is pressing
        def __getattr__(self, name):
            return getattr(ros, name)

        def press(self, *a, **k):
            ros.press(*a, **k)
            raise KeyboardInterrupt

    try:
        with pytest.raises(KeyboardInterrupt):
            record_probe_point(session, 0, CtrlC(), ProbeSettings(depth_m=0.002), POSE)
    finally:
        ros.close()
        session.close()
        skin.disconnect()
    wait_until(lambda: "stop" in arm.kinds(), "the arm to hear the stop", 30.0)
    assert arm.kinds() == ["approach", "press", "stop"]


@needs_rclpy
def test_no_arm_is_a_one_line_link_error(ros_domain):
    from skinloc.calibration.probe_ros2 import Ros2Probe

    with pytest.raises(ProbeLinkError, match="no arm answers on /skinloc/probe") as info:
        Ros2Probe("base_link", connect_timeout_s=1.0)
    assert str(info.value).count("\n") == 0


@needs_rclpy
def test_a_too_strong_or_too_deep_press_is_refused_before_anything_moves(arm):
    from skinloc.calibration.probe import ProbeSafetyError

    ros = _probe(max_depth_m=0.003, max_force_n=5.0)
    target, down = np.array([0.4, 0.0, 0.29]), np.array([0.0, 0.0, -1.0])
    try:
        ros.move_above(np.array([0.4, 0.0, 0.3]), down)
        with pytest.raises(ProbeSafetyError, match="press force 6 N is beyond the probe's limit"):
            ros.press(target, down, force_n=6.0)
        with pytest.raises(ProbeSafetyError, match="beyond the probe's limit"):
            ros.press(target, down, depth_m=0.004)
        with pytest.raises(ValueError, match="one of them"):
            ros.press(target, down, depth_m=0.002, force_n=2.0)
    finally:
        ros.close()
    assert arm.kinds() == ["approach"]


@needs_rclpy
@pytest.mark.parametrize("arm", ["lose-first-answer"], indirect=True)
def test_an_approach_whose_answer_is_lost_is_sent_again(arm):
    """The arm's first ``above`` never reaches skinloc (as when its publisher had not matched
    skinloc's subscriber yet): the approach goes again, the same goal, and is answered."""
    ros = _probe(timeout_s=scaled(30.0))
    try:
        ros.move_above(np.array([0.4, 0.0, 0.3]), np.array([0.0, 0.0, -1.0]))
    finally:
        ros.close()
    assert arm.kinds() == ["approach"]  # the same stamp: one goal


@needs_rclpy
def test_a_press_to_a_force_through_a_stand_in_arm(tmp_path, cone, arm):
    session, skin = _session(tmp_path, cone)
    settings = ProbeSettings(depth_m=None, force_n=3.0, max_depth_m=0.004, max_force_n=5.0)
    ros = _probe(timeout_s=scaled(30.0), max_depth_m=0.004, max_force_n=5.0)
    probe = ArmOnSimSkin(ros, SimulatedProbe(skin, pose=POSE, position_error_m=0.0))
    reports = []
    try:
        for i in range(len(session.targets)):
            reports.append(record_probe_point(session, i, probe, settings, POSE))
    finally:
        probe.close()
        session.close()
        skin.disconnect()
    heard = arm.heard()
    assert [r["kind"] for r in heard] == ["approach", "press_force", "press", "lift"] * 2
    approach, goal, press = heard[0], heard[1], heard[2]
    # the goal: 3 N along the press direction, in the base frame
    step = np.subtract(press["position"], approach["position"])
    down = step / np.linalg.norm(step)
    assert goal["frame"] == "base_link" and np.allclose(goal["force"], 3.0 * down, atol=1e-9)
    # the press pose is the depth limit: the arm may stop short of it, never pass it
    assert np.isclose(np.linalg.norm(step), settings.clearance_m + 0.004, atol=1e-9)
    for i, report in enumerate(reports):  # the measured force; the measured tip's depth
        step = np.subtract(heard[4 * i + 2]["position"], heard[4 * i]["position"])
        down = step / np.linalg.norm(step)
        assert report.force_n == pytest.approx(3.0)
        assert report.depth_m == pytest.approx(0.004 - FORCE_SHORT_M + TIP_OFFSET_M @ down)
    rec = read_recording(tmp_path / "p.h5")
    assert rec.meta["probe_forces_n"] == pytest.approx([3.0, 3.0])
    assert rec.meta["probe_depths_m"] == pytest.approx([r.depth_m for r in reports])


@needs_rclpy
@pytest.mark.parametrize(
    ("arm", "needle"),
    [
        ("overforce", "measured 6 N on /skinloc/probe/force, over the limit of 5 N"),
        ("noforce", "sent no force on /skinloc/probe/force"),
    ],
    indirect=["arm"],
)
def test_a_force_over_the_limit_or_unmeasured_stops_the_arm(tmp_path, cone, arm, needle):
    session, skin = _session(tmp_path, cone, n=1)
    ros = _probe(timeout_s=scaled(10.0), max_force_n=5.0)
    settings = ProbeSettings(depth_m=None, force_n=3.0, max_force_n=5.0)
    try:
        with pytest.raises(ProbeError, match=needle) as info:
            record_probe_point(session, 0, ros, settings, POSE)
    finally:
        ros.close()
        session.close()
        skin.disconnect()
    assert str(info.value).count("\n") == 0
    wait_until(lambda: "stop" in arm.kinds(), "the arm to hear the stop", 30.0)
    assert arm.kinds()[:3] == ["approach", "press_force", "press"]
    assert session.n_done == 0


def test_without_rclpy_the_error_names_the_extra(monkeypatch):
    import builtins

    from skinloc.calibration.probe_ros2 import Ros2Probe

    real = builtins.__import__

    def no_rclpy(name, *a, **k):
        if name == "rclpy" or name.startswith("rclpy."):
            raise ImportError(f"No module named {name!r}")
        return real(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_rclpy)
    with pytest.raises(ProbeError, match=r"pip install 'skinloc\[ros2\]'") as info:
        Ros2Probe("base_link")
    assert str(info.value).count("\n") == 0
