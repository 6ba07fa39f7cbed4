"""The skinloc ROS 2 node seen by a real rclpy (the Jazzy wheels) in another process.

Skipped, with the reason, where the wheels are not installed (``pip install '.[ros2]'``;
``make test`` installs them).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests._helpers import (
    Lines,
    popen_foreground,
    scaled,
    start_skinloc,
    stop_and_wait,
    wait_until,
)

try:
    import rclpy  # noqa: F401
    import std_srvs.srv  # noqa: F401
    from diagnostic_msgs.msg import DiagnosticArray  # noqa: F401

    _WHY = ""
except ImportError as exc:  # the banner pytest shows for every skipped test
    _WHY = f"the ROS 2 Jazzy wheels are not installed ({exc}); pip install '.[ros2]'"

pytestmark = [pytest.mark.slow, pytest.mark.skipif(bool(_WHY), reason=_WHY)]

PROBE = Path(__file__).with_name("rclpy_probe.py")


@pytest.fixture
def ros_domain(ros_domain, monkeypatch):
    """The conftest's domain of this test alone, served by rclpy."""
    monkeypatch.setenv("SKINLOC_ROS2_BACKEND", "rclpy")
    return ros_domain


def test_a_real_node_with_parameters_tare_diagnostics_and_tf(tmp_path, ros_domain):
    from tests._live import model_path

    cfg = tmp_path / "robot.toml"
    model = model_path("map")
    cfg.write_text(
        f'[defaults]\nmodel = "{model}"\nsource = "sim"\n'
        '[[skin]]\nname = "arm"\n'
        '[[skin]]\nname = "leg"\nsource = "sim:1"\nparent_frame = "fr3_link5"\n'
    )
    proc = start_skinloc(
        "run", "--config", cfg, "--sink", "ros2", "--duration", "900",
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    err = Lines(proc.stderr)
    try:
        err.wait_for("running", "skinloc run to start", 180.0)
        probe = subprocess.run(
            [sys.executable, str(PROBE), "arm,leg", str(scaled(240.0))],
            capture_output=True,
            text=True,
            timeout=scaled(300.0),
            env=dict(os.environ),
        )
        assert probe.returncode == 0, probe.stderr[-3000:]
        seen = json.loads(probe.stdout.strip().splitlines()[-1])
        stop_and_wait(proc, signal.SIGINT, "skinloc run --sink ros2")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.rest()
    assert proc.returncode == 0 and "Traceback" not in text, text[-2000:]
    # the node in the graph, publishing every topic with ROS 2's own type hashes
    assert "/skinloc" in seen["nodes"], seen["nodes"]
    for topic, info in seen["topics"].items():
        assert info["publishers"] == ["skinloc"], (topic, info)
        assert info["equal"], (topic, info)
    for skin in ("arm", "leg"):
        assert f"/skinloc/{skin}/tare" in seen["services"]
        assert f"/skinloc/{skin}/reset_tracks" in seen["services"]
    # /tf_static: both skins (arm under base_link by default), through the DDS writer
    assert seen["tf_static"]["types"] == ["tf2_msgs/msg/TFMessage"]
    assert seen["tf_static"]["publishers"] >= 1
    # parameters: listed, read, set live, a bad value refused with the settings' own reason
    assert "arm.pipeline.touch_on_z" in seen["param_names"]
    assert "leg.gestures.tap_max_s" in seen["param_names"]
    assert seen["param_get"] == pytest.approx(8.0)
    assert seen["param_set_good"][0] is True, seen["param_set_good"]
    assert seen["param_after_good"] == pytest.approx(9.0)
    ok, reason = seen["param_set_bad"]
    assert ok is False and "touch_off_z" in reason and "touch_on_z" in reason, reason
    assert seen["param_after_bad"] == pytest.approx(4.0)
    # tare: refused while touched, done (with what changed) while not
    assert any("touched" in m for _, m in seen["tare_refused"]), seen["tare_refused"]
    assert seen["tare_ok"] and "counts" in seen["tare_ok"][0][1], seen["tare_ok"]
    # diagnostics: one status per skin, named for it, with the maintainer's values
    names = [d["name"] for d in seen["diagnostics"]]
    assert any("arm" in n for n in names) and any("leg" in n for n in names), names
    arm = next(d for d in seen["diagnostics"] if "arm" in d["name"])
    assert arm["hardware_id"] == "sim"
    for key in ("frame_rate_hz", "expected_rate_hz", "link", "dead_lines", "latency_p99_us",
                "baseline_drift_mean_counts", "errors", "publisher_queue_bytes"):  # fmt: skip
        assert key in arm["values"], (key, arm["values"])
    assert arm["level"] in (0, 1, 2)


def test_plain_dds_says_once_what_it_cannot_do(tmp_path, monkeypatch, ros_domain):
    from cyclonedds.domain import DomainParticipant  # noqa: F401 - the plain path's own

    from tests._live import model_path

    monkeypatch.setenv("SKINLOC_ROS2_BACKEND", "dds")  # over the module's rclpy
    proc = start_skinloc(
        "run", "--model", model_path("map"), "--source", "sim", "--name", "arm", "--sink", "ros2",
        "--duration", "900", stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    err = Lines(proc.stderr)
    try:
        err.wait_for("running", "skinloc run to start", 180.0)
        wait_until(lambda: "no parameters" in err.text, lambda: err.text[-2000:], 60.0)
        time.sleep(0.5)  # a second warning would come with the next sweeps
        stop_and_wait(proc, signal.SIGINT, "skinloc run --sink ros2")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.rest()
    assert text.count("no parameters") == 1, text[-2000:]
    assert "no node in the ROS graph" in text and "tare" in text


def test_the_loop_survives_a_model_that_raises_once_and_a_sink_that_always_raises(
    tmp_path, ros_domain
):
    """Through the real node: contacts keep reaching an rclpy subscriber after both faults,
    and the counts show in ``/diagnostics`` and ``--stats``."""
    from tests._live import model_path

    launcher = Path(__file__).with_name("faulty_run.py")
    probe = Path(__file__).with_name("faults_probe.py")
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[4])  # the checkout: tests._live and skinloc
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    proc = popen_foreground(  # SIGINT at its default even when pytest ignores it
        [sys.executable, str(launcher), "run", "--model", str(model_path("map")),
         "--source", "sim", "--name", "arm", "--sink", "ros2", "--sink", "failing",
         "--duration", "900", "--stats"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        env={**env, "PYTHONFAULTHANDLER": "1"},  # its threads' stacks if it hangs (stop_and_wait)
    )  # fmt: skip
    err = Lines(proc.stderr)
    try:
        err.wait_for("running", "the faulty skinloc run to start", 180.0)
        res = subprocess.run(
            [sys.executable, str(probe), "arm", str(scaled(240.0))],
            capture_output=True,
            text=True,
            timeout=scaled(300.0),
            env=env,
        )
        assert res.returncode == 0, res.stderr[-3000:]
        seen = json.loads(res.stdout.strip().splitlines()[-1])
        stop_and_wait(proc, signal.SIGINT, "the faulty skinloc run", output=err)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.rest()
    assert proc.returncode == 0, text[-3000:]
    # /diagnostics: the dropped frame and the failing sink, counted, as a warning at least
    assert seen["faults_seen"], seen
    values = seen["first_status"]["values"]
    assert int(values["errors"]) == 1 and int(values["sink_errors"]) >= 1, values
    assert int(seen["last_status"]["values"]["errors"]) == 1, seen["last_status"]
    # contacts kept reaching the subscriber after both faults
    assert seen["contacts_after"] >= 10, seen
    # logged once each, with the traceback; --stats has the same counts
    assert text.count("FloatingPointError: the model blew up on this frame") >= 1
    assert text.count("Traceback") == 2, text[-3000:]  # one per fault, not one per frame
    stats = json.loads(text.strip().splitlines()[-1])
    (arm,) = stats
    assert arm["errors"] == 1 and "the model blew up" in arm["last_error"], arm
    routes = {s["sink"]: s for s in arm["sinks"]}
    assert routes["failing"]["errors"] >= 2 and routes["failing"]["skipped"] > 0, routes
    assert routes["ros2"]["errors"] == 0, routes
    assert arm["sink_errors"] == routes["failing"]["errors"]


def test_workers_each_serve_their_skins_from_a_node_of_their_own(tmp_path, ros_domain):
    from tests._live import model_path

    cfg = tmp_path / "robot.toml"
    cfg.write_text(
        f'[defaults]\nmodel = "{model_path("map")}"\nsource = "sim"\n'
        '[[skin]]\nname = "arm"\n[[skin]]\nname = "leg"\nsource = "sim:1"\n'
    )
    proc = start_skinloc(
        "run", "--config", cfg, "--workers", "2", "--sink", "ros2", "--duration", "900",
        "--stats", stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    err = Lines(proc.stderr)
    try:
        err.wait_for("ROS 2 node skinloc_1", "the second worker's node", 240.0)
        probe = subprocess.run(
            [sys.executable, str(PROBE.with_name("workers_probe.py")), "skinloc_0,skinloc_1",
             "arm,leg", str(scaled(240.0))],
            capture_output=True, text=True, timeout=scaled(300.0), env=dict(os.environ),
        )  # fmt: skip
        assert probe.returncode == 0, probe.stderr[-3000:]
        seen = json.loads(probe.stdout.strip().splitlines()[-1])
        stop_and_wait(proc, signal.SIGINT, "skinloc run --workers 2 --sink ros2")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.rest()
    assert proc.returncode == 0 and "Traceback" not in text, text[-3000:]
    assert {"skinloc_0", "skinloc_1"} <= set(seen["nodes"]), seen["nodes"]
    # each node holds the parameters of its own worker's skin only
    assert seen["params"] == {"skinloc_0": ["arm"], "skinloc_1": ["leg"]}, seen["params"]
    assert seen["tf_static_publishers"] >= 2  # each worker's skins' transforms
    for skin in ("arm", "leg"):
        assert f"/skinloc/{skin}/tare" in seen["services"]
        assert any(skin in d for d in seen["diagnostics"]), seen["diagnostics"]
        assert seen["tares"].get(skin), seen["tares"]  # answered (done or refused: touched)
    stats = json.loads(text.strip().splitlines()[-1])
    assert [(d["skin"], d["worker"]) for d in stats] == [("arm", 0), ("leg", 1)]
