"""Tests of the hardware commands: ports, monitor, record, collect, virtual-skin."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.data.recording import read_recording
from skinloc.errors import RecordingError
from skinloc.sim.virtual_device import VirtualSkin
from skinloc.sources.replay import ReplaySource, read_stream
from tests._helpers import start_skinloc, wait_until

runner = CliRunner()
posix_only = pytest.mark.skipif(sys.platform == "win32", reason="needs a POSIX pty")


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def assert_one_line_error(res, *needles):
    assert res.exit_code != 0
    assert "Traceback" not in res.output
    err = res.output.strip()
    assert err.startswith("error:") and err.count("\n") == 0, err
    for n in needles:
        assert n in err


def test_help_lists_the_hardware_commands():
    res = run("--help")
    for cmd in ("ports", "monitor", "record", "collect", "virtual-skin"):
        assert cmd in res.output
        sub = run(cmd, "--help")
        assert sub.exit_code == 0 and "Example" in sub.output


def test_ports():
    # --no-ask: never write to the virtual skins of tests running beside this one (pytest -n);
    # asking a board is tests/firmware/test_host.py's
    assert run("ports", "--no-ask").exit_code == 0
    res = run("ports", "--json", "--no-ask")
    assert res.exit_code == 0 and isinstance(json.loads(res.output), list)


def test_monitor_sim():
    res = run("monitor", "--source", "sim", "--seconds", "0.3")
    assert res.exit_code == 0, res.output
    assert "TX" in res.output and "frame" in res.output


@pytest.mark.parametrize(
    "args, needles",
    [
        (["monitor"], ["--port", "--source sim"]),
        (["monitor", "--port", "/dev/skinloc-nope"], ["/dev/skinloc-nope"]),
        (["monitor", "--port", "loop://", "--source", "sim"], ["not both"]),
        (["monitor", "--port", "loop://", "--allow-url", "--tx-mask", "12"], ["tx_mask"]),
        (
            ["monitor", "--port", "loop://", "--allow-url", "--timeout", "0.05"],
            ["loop://", "no frame"],
        ),
        (["monitor", "--port", "loop://"], ["pyserial URL", "--allow-url", "'sim'"]),
        (["record", "--port", "socket://127.0.0.1:9", "--out", "x.h5"], ["pyserial URL"]),
        (["collect", "--port", "spy://loop://", "--out", "x.h5"], ["pyserial URL"]),
        (["monitor", "--port", "."], ["not a serial port"]),
        (["record", "--source", "sim", "--out", "x.csv"], [".h5"]),
        (["collect", "--port", "/dev/skinloc-nope", "--out", "x.h5"], ["/dev/skinloc-nope"]),
    ],
)
def test_bad_input_is_one_line(args, needles, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("skinloc.cli.hardware.FIRST_FRAME_S", 0.05)  # no board to wait for
    assert_one_line_error(run(*args), *needles)


def test_record_sim_and_replay(tmp_path):
    out = tmp_path / "stream.h5"
    res = run(
        "record", "--source", "sim", "--seconds", "1", "--baseline-frames", "10", "--out", out
    )
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_point_logs == 0 and len(rec.baseline_frames) == 10
    frames, times, index = read_stream(out)
    assert frames.shape == (100, 64) and times[-1] <= 1.0 and (np.diff(index) == 1).all()
    assert run("info", out).exit_code == 0
    info = json.loads(run("info", out, "--json").output)
    assert info["stream_frames"] == 100 and info["stream_lost_frames"] == 0
    assert info["stream_rate_hz"] == pytest.approx(100.0, rel=0.05)
    with ReplaySource(out) as src:
        assert src.read().values.tolist() == frames[0].tolist()
    with h5py.File(out, "a") as f:  # a damaged stream: one line, not a traceback
        del f["stream/times_s"]
    assert_one_line_error(run("info", out), "cannot read the stream")


def test_collect_sim_resumes(tmp_path):
    out = tmp_path / "cal.h5"
    common = [
        "collect",
        "--source",
        "sim",
        "--points",
        "3",
        "--samples",
        "5",
        "--baseline-frames",
        "10",
        "--out",
        out,
    ]
    res = run(*common, "--max-touches", "2")
    assert res.exit_code == 0, res.output
    assert "2/3" in res.output and read_recording(out).n_point_logs == 2
    res = run(*common)
    assert res.exit_code == 0, res.output
    assert "Resuming" in res.output and "3/3" in res.output
    assert read_recording(out).n_point_logs == 3
    assert_one_line_error(run(*common), "already complete")
    # Starting over would destroy the complete recording: --new alone is refused.
    assert_one_line_error(run(*common, "--new", "--points", "2"), "--force")
    assert read_recording(out).n_point_logs == 3
    res = run(*common, "--new", "--force", "--points", "2")
    assert res.exit_code == 0 and read_recording(out).n_point_logs == 2


@posix_only
def test_collect_on_virtual_skin_survives_a_crash(tmp_path):
    """Kill collect (SIGKILL) after its first saved touch; the rerun resumes and finishes."""
    out = tmp_path / "cal.h5"
    with VirtualSkin(fmt="binary", rate_hz=200) as dev:
        args = [
            "collect",
            "--port",
            dev.path,
            "--scripted-finger",
            "--points",
            "3",
            "--samples",
            "5",
            "--baseline-frames",
            "10",
            "--touch-timeout",
            "20",
            "--out",
            str(out),
        ]
        proc = start_skinloc(*args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)

        def n_done() -> int:
            try:
                return read_recording(out).n_point_logs if out.exists() else 0
            except RecordingError:  # caught mid-write
                return 0

        try:  # a fresh interpreter on a busy machine
            wait_until(n_done, "a first point log", 180.0, interval_s=0.05, proc=proc)
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
        res = run(*args)
        assert res.exit_code == 0, res.output
        assert "Resuming" in res.output and "3/3" in res.output
    rec = read_recording(out)
    assert rec.n_point_logs == 3 and rec.frames.shape == (3, 5, 64)
    assert not list(tmp_path.glob(".cal.h5.*"))  # no temporary files left behind


@posix_only
def test_virtual_skin_command_prints_the_port_first(tmp_path):
    truth = tmp_path / "truth.npz"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "skinloc",
            "virtual-skin",
            "--format",
            "text",
            "--rate",
            "50",
            "--faults",
            "--truth",
            str(truth),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # As when started in the background by a shell: SIGINT ignored, and it must still stop.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    try:
        port = proc.stdout.readline().strip()
        assert os.path.islink(port)
        res = run(
            "record",
            "--port",
            port,
            "--seconds",
            "0.5",
            "--baseline-frames",
            "5",
            "--timeout",
            "30",  # a frame may be late on a busy machine; a missing one still fails
            "--out",
            tmp_path / "s.h5",
        )
        assert res.exit_code == 0, res.output
    finally:
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "frames sent intact" in err and truth.exists()
    assert not os.path.exists(port)


def _active_args(out, *extra):
    return [
        "collect",
        "--mode",
        "active",
        "--points",
        "6",
        "--samples",
        "5",
        "--baseline-frames",
        "10",
        "--touch-timeout",
        "20",
        "--out",
        out,
        *extra,
    ]


def test_collect_active_sim_chooses_resumes_and_repeats(tmp_path):
    """Active targets: first few even, then chosen from the touches; same seed, same targets."""
    from skinloc.calibration.active import N_START
    from skinloc.calibration.session import CalibrationSession
    from skinloc.sim.skin import SimulatedSkin

    out, again = tmp_path / "a.h5", tmp_path / "b.h5"
    res = run(*_active_args(out, "--source", "sim", "--seed", "3", "--max-touches", "5"))
    assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_point_logs == 5 and rec.meta["sampling_mode"] == "active"
    np.testing.assert_allclose(rec.targets[:N_START], rec.planned_targets[:N_START])
    # The fifth was chosen after the touches, not taken from the plan.
    assert np.linalg.norm(rec.targets[N_START] - rec.planned_targets[N_START]) > 1e-6
    # The resumed session asks for what the recorded touches call for.
    with SimulatedSkin(n_tx=8, n_rx=8, random_state=3, mesh=rec.mesh) as skin:
        expected = CalibrationSession.resume(skin, out).target_for(5)
    res = run(*_active_args(out, "--source", "sim", "--seed", "3"))
    assert res.exit_code == 0, res.output
    assert "Resuming" in res.output and "6/6" in res.output
    rec = read_recording(out)
    np.testing.assert_allclose(rec.targets[5], expected)
    assert len(np.unique(np.round(rec.targets, 6), axis=0)) == 6  # no target asked twice
    res = run(*_active_args(again, "--source", "sim", "--seed", "3", "--max-touches", "5"))
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(read_recording(again).targets, rec.targets[:5])


def test_collect_active_rejects_a_bad_mode(tmp_path):
    from skinloc.calibration.session import SessionConfig

    res = run("collect", "--source", "sim", "--mode", "smart", "--out", tmp_path / "x.h5")
    assert res.exit_code != 0 and "Traceback" not in res.output
    assert "active" in res.output  # the valid choices are named
    assert not (tmp_path / "x.h5").exists()
    with pytest.raises(ValueError, match="active"):
        SessionConfig(mode="smart")


@posix_only
def test_collect_active_on_virtual_skin(tmp_path):
    """Active mode drives a virtual skin's scripted finger to each chosen target."""
    out = tmp_path / "cal.h5"
    with VirtualSkin(fmt="binary", rate_hz=200) as dev:
        res = run(*_active_args(out, "--port", dev.path, "--scripted-finger"))
        assert res.exit_code == 0, res.output
    rec = read_recording(out)
    assert rec.n_point_logs == 6 and rec.frames.shape == (6, 5, 64)
    assert np.linalg.norm(rec.targets[-1] - rec.planned_targets[-1]) > 1e-6
