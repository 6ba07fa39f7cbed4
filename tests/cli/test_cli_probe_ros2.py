"""``skinloc collect --probe ros2`` against a stand-in arm written with rclpy, in another process.

Whole sessions: the stand-in arm presses ``skinloc virtual-skin`` (a pseudo-terminal) at the tip
it reports, and collect reads that port. Failure paths on ``--source sim``, which the arm cannot
press (a press it answers is never felt): the timeouts, and that every stop reaches the arm.
Skipped, with the reason, without the Jazzy wheels.
"""

from __future__ import annotations

import os
import signal
import subprocess

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.data.recording import read_recording
from tests._helpers import (
    Lines,
    one_line_error,
    scaled,
    start_skinloc,
    stop_and_wait,
    wait_until,
)
from tests.calibration.test_probe_ros2 import _WHY, Arm

pytestmark = pytest.mark.skipif(bool(_WHY), reason=_WHY)
runner = CliRunner()


@pytest.fixture
def arm(tmp_path, ros_domain, request):
    a = Arm(tmp_path, getattr(request, "param", "ok"))
    yield a
    a.end()


def last_line_error(res, *needles: str) -> str:
    """A failed run whose progress lines end in one line ``error: ...`` holding every needle."""
    assert res.exit_code not in (0, None), res.output
    assert "Traceback" not in res.output, res.output
    err = res.output.strip().splitlines()[-1]
    assert err.startswith("error:"), res.output
    for n in needles:
        assert n in err, err
    return err


def _args(out, *extra):
    return [
        "collect", "--probe", "ros2", "--source", "sim", "--points", "3", "--samples", "5",
        "--baseline-frames", "10", "--out", str(out), *(str(e) for e in extra),
    ]  # fmt: skip


def test_no_arm_is_a_one_line_error(tmp_path, ros_domain):
    res = runner.invoke(app, _args(tmp_path / "cal.h5", "--probe-timeout", "1"))
    one_line_error(res, "no arm answers on /skinloc/probe", "ROS_DOMAIN_ID")


@pytest.mark.parametrize("arm", ["mute"], indirect=True)
def test_a_lost_arm_stops_the_session(tmp_path, arm):
    out = tmp_path / "cal.h5"
    # the timeout is also how long the arm's node may take to be discovered: longer when busy
    res = runner.invoke(app, _args(out, "--probe-timeout", f"{scaled(5.0):.1f}"))
    last_line_error(res, "did not say 'pressed'", "lost link")
    wait_until(lambda: "stop" in arm.kinds(), "the arm to hear the stop", 30.0)
    assert arm.kinds() == ["approach", "press", "stop"]
    heard = arm.heard()
    assert all(r["frame"] == "base_link" for r in heard if "frame" in r)
    # the baseline and the plan are kept: the session resumes from there
    rec = read_recording(out)
    assert rec.n_point_logs == 0 and rec.meta["probe"]["kind"] == "ros2"
    assert rec.meta["probe"]["error_m"] is None
    # resumed with another probe: refused in one line
    one_line_error(
        runner.invoke(app, ["collect", "--probe", "sim", "--out", str(out)]),
        "probed with --probe ros2",
    )


def test_a_press_the_skin_does_not_feel_stops_the_arm(tmp_path, arm):
    res = runner.invoke(app, _args(tmp_path / "cal.h5", "--touch-timeout", "1"))
    last_line_error(res, "no touch detected")
    wait_until(lambda: "stop" in arm.kinds(), "the arm to hear the stop", 30.0)
    assert arm.kinds()[:2] == ["approach", "press"] and arm.kinds()[-1] == "stop"


def test_the_frame_comes_from_the_skins_file(tmp_path, arm):
    skins = tmp_path / "skins.toml"
    skins.write_text(
        '[[skin]]\nname = "arm"\nparent_frame = "fr3_link0"\ntranslation = [0.4, 0.0, 0.1]\n'
    )
    res = runner.invoke(
        app, _args(tmp_path / "cal.h5", "--skins", skins, "--skin", "arm", "--dry-run")
    )
    assert res.exit_code == 0, res.output
    assert "Dry run: moved above 3 targets, pressed none" in res.output
    heard = arm.heard()
    assert [r["kind"] for r in heard] == ["approach"] * 3
    assert {r["frame"] for r in heard} == {"fr3_link0"}


@pytest.mark.parametrize("arm", ["mute"], indirect=True)
def test_a_real_ctrl_c_stops_the_arm(tmp_path, arm):
    out = tmp_path / "cal.h5"
    proc = start_skinloc(
        *_args(out, "--probe-timeout", "600"),
        env={"PYTHONFAULTHANDLER": "1"},  # a hang shows every thread's stack (stop_and_wait)
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines = Lines(proc.stderr)  # read as it comes: a full pipe would block the run
    try:
        wait_until(lambda: "press" in arm.kinds(), "the arm to be sent a press", 120.0)
        stop_and_wait(proc, signal.SIGINT, "collect --probe ros2", output=lines)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = lines.rest()
    assert proc.returncode != 0 and "Traceback" not in err, err
    assert "probe stopped" in err, err
    wait_until(lambda: "stop" in arm.kinds(), "the arm to hear the stop", 30.0)
    assert arm.kinds() == ["approach", "press", "stop"]


@pytest.mark.skipif(os.name != "posix", reason="the virtual skin is a pseudo-terminal")
def test_an_arm_presses_the_virtual_skin_end_to_end(tmp_path, ros_domain):
    """The stand-in arm presses ``skinloc virtual-skin`` at its measured tip; collect reads it."""
    import numpy as np

    from tests.calibration.test_probe_ros2 import TIP_OFFSET_M

    skin = start_skinloc(
        "virtual-skin", "--format", "binary", "--rate", "100",
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    arm = None
    try:
        assert skin.stdout is not None
        port = skin.stdout.readline().strip()
        assert port, skin.stderr.read() if skin.stderr else ""
        arm = Arm(tmp_path, "skin", port)
        out = tmp_path / "cal.h5"
        args = [
            "collect", "--probe", "ros2", "--port", port, "--points", "3", "--samples", "5",
            "--baseline-frames", "10", "--touch-timeout", "30", "--out", str(out),
        ]  # fmt: skip
        res = runner.invoke(app, [*args, "--max-touches", "2"])
        assert res.exit_code == 0, res.output
        assert "2/3 probed point logs (saved; rerun" in res.output
        res = runner.invoke(app, args)  # the same command resumes, with the file's settings
        assert res.exit_code == 0, res.output
        assert "Resuming" in res.output and "3/3 probed point logs (complete)" in res.output
    finally:
        if arm is not None:
            arm.end()
        skin.send_signal(signal.SIGINT)
        skin.communicate(timeout=scaled(120.0))
    assert arm.kinds() == ["approach", "press", "lift"] * 3
    rec = read_recording(out)
    assert rec.n_point_logs == 3 and rec.meta["probe"]["kind"] == "ros2"
    presses = [r["position"] for r in arm.heard() if r["kind"] == "press"]
    # the recording keeps the arm's measured tips (base frame = mesh frame here)
    np.testing.assert_allclose(rec.meta["probe_tips_m"], np.add(presses, TIP_OFFSET_M), atol=1e-6)
    assert rec.meta["probe_depths_m"] == [0.002] * 3
    res = runner.invoke(app, ["info", str(out)])
    assert res.exit_code == 0 and "3 with the probe's reported tip, depth 2 mm" in res.output
