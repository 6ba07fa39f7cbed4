"""``skinloc collect --probe sim``: a session pressed by a simulated robot's probe."""

from __future__ import annotations

import json
import signal
import subprocess

import numpy as np
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.data.recording import read_recording
from skinloc.geometry.mesh import nearest_on_surface
from tests._helpers import one_line_error, start_skinloc, stop_and_wait, wait_until

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def _args(out, *extra):
    return [
        "collect",
        "--probe",
        "sim",
        "--points",
        "6",
        "--samples",
        "5",
        "--baseline-frames",
        "10",
        "--skin-seed",
        "11",
        "--touch-timeout",
        "20",
        "--out",
        out,
        *extra,
    ]


def test_a_probed_session_end_to_end_then_info(tmp_path):
    out = tmp_path / "cal.h5"
    res = run(*_args(out, "--probe-error-mm", "0.5"))
    assert res.exit_code == 0, res.output
    assert "Plan: 6 of 6 targets" in res.output and "6/6 probed point logs (complete)" in res.output
    rec = read_recording(out)
    assert rec.n_point_logs == 6 and rec.frames.shape == (6, 5, 64)
    probe = rec.meta["probe"]
    assert probe["skin_seed"] == 11 and probe["error_m"] == 0.0005
    assert probe["n_asked"] == 6 and probe["n_drawn"] >= 6 + len(probe["skipped_m"])
    assert len(probe["skipped_m"]) == len(probe["skipped_reasons"])
    assert set(probe["skipped_reasons"]) <= {"rim", "tilt"}
    # the reported tip lies the press depth under each stored target, which is on the surface
    tips = np.array(rec.meta["probe_tips_m"])
    assert np.allclose(nearest_on_surface(rec.mesh, tips)[1], 0.002, atol=1e-6)
    assert nearest_on_surface(rec.mesh, rec.targets)[1].max() < 1e-9
    assert rec.meta["probe_depths_m"] == [0.002] * 6
    # the simulated truth: within a few probe errors of the targets, never on them
    miss = np.linalg.norm(np.array(rec.meta["true_contacts"]) - rec.targets, axis=1)
    assert 0 < miss.max() < 0.004
    # the same skin as `skinloc simulate --skin-seed 11` (its true crossings)
    sim = tmp_path / "sim.h5"
    res = run("simulate", "--points", "1", "--samples", "5", "--skin-seed", "11", "--out", sim)
    assert res.exit_code == 0, res.output
    np.testing.assert_allclose(
        read_recording(sim).meta["truth_sensor_positions_m"],
        rec.meta["truth_sensor_positions_m"],
    )
    res = run("info", out)
    assert res.exit_code == 0, res.output
    assert "6 with the probe's reported tip, depth 2 mm" in res.output
    res = run("info", out, "--json")
    info = json.loads(res.output)
    assert len(info["probe_touches"]) == 6 and info["probe_touches"][0]["depth_mm"] == 2.0
    np.testing.assert_allclose(info["probe_touches"][0]["tip_mm"], 1e3 * tips[0], atol=1e-3)
    assert "probe_tips_m" not in info["meta"] and info["meta"]["probe"]["kind"] == "sim"


def test_each_target_pressed_at_several_depths_then_resumed(tmp_path):
    out = tmp_path / "cal.h5"
    args = _args(out, "--press-depth-mm", "1,2,3")
    args[args.index("--points") + 1] = "3"
    res = run(*args, "--max-touches", "4")
    assert res.exit_code == 0, res.output
    assert "each pressed at 3 levels (1, 2, 3 mm), 9 touches" in res.output
    assert read_recording(out).n_point_logs == 4
    res = run(*args)  # resumed with the file's levels
    assert res.exit_code == 0 and "Resuming" in res.output, res.output
    rec = read_recording(out)
    assert rec.n_point_logs == 9
    assert rec.meta["probe_depths_m"] == [0.001, 0.002, 0.003] * 3
    assert [p["depth_m"] for p in rec.meta["probe"]["presses"]] == [0.001, 0.002, 0.003]
    # each press is its own touch at the target, pressed once per depth, one after the other
    np.testing.assert_array_equal(rec.planned_targets[0::3], rec.planned_targets[1::3])
    np.testing.assert_array_equal(rec.planned_targets[0::3], rec.planned_targets[2::3])
    assert len(np.unique(rec.planned_targets, axis=0)) == 3
    # a deeper press gives a stronger touch at the same target
    peaks = rec.deltas.mean(axis=1).max(axis=1).reshape(3, 3)
    assert np.all(np.diff(peaks, axis=1) > 0)
    res = run("info", out)
    assert "9 with the probe's reported tip, depth 1-3 mm" in res.output
    info = json.loads(run("info", out, "--json").output)
    assert [t["depth_mm"] for t in info["probe_touches"][:3]] == [1.0, 2.0, 3.0]


def test_several_forces_are_recorded(tmp_path):
    out = tmp_path / "cal.h5"
    res = run(*_args(out, "--press-force-n", "2,3", "--max-touches", "2"))
    assert res.exit_code == 0, res.output
    assert "each pressed at 2 levels (2, 3 N), 12 touches" in res.output
    rec = read_recording(out)
    assert rec.meta["probe_forces_n"] == [2.0, 3.0] and rec.meta["probe_depths_m"] == [None] * 2


def test_a_probed_session_resumes(tmp_path):
    out = tmp_path / "cal.h5"
    res = run(*_args(out, "--max-touches", "2"))
    assert res.exit_code == 0, res.output
    assert "2/6" in res.output and read_recording(out).n_point_logs == 2
    first = read_recording(out)
    res = run(*_args(out))
    assert res.exit_code == 0, res.output
    assert "Resuming" in res.output and "6/6" in res.output
    rec = read_recording(out)
    assert rec.n_point_logs == 6 and len(rec.meta["probe_tips_m"]) == 6
    assert len(rec.meta["true_contacts"]) == 6
    np.testing.assert_array_equal(rec.targets[:2], first.targets)
    np.testing.assert_array_equal(rec.planned_targets, first.planned_targets)
    one_line_error(run(*_args(out)), "already complete")
    # a recording made without a probe is not resumed with one
    plain = tmp_path / "plain.h5"
    assert run("simulate", "--points", "2", "--samples", "5", "--out", plain).exit_code == 0
    one_line_error(run(*_args(plain)), "not recorded with a probe")


def test_an_over_deep_press_is_refused_and_nothing_is_written(tmp_path):
    out = tmp_path / "cal.h5"
    one_line_error(
        run(*_args(out, "--press-depth-mm", "6")), "press depth 6 mm", "limit of 5 mm", "refused"
    )
    one_line_error(
        run(*_args(out, "--press-force-n", "12")), "press force 12 N", "limit of 10 N", "refused"
    )
    assert not out.exists()
    # a deeper limit lets it through
    res = run(*_args(out, "--press-depth-mm", "3", "--max-depth-mm", "4", "--max-touches", "1"))
    assert res.exit_code == 0, res.output
    assert read_recording(out).meta["probe_depths_m"] == [0.003]


def test_bad_probe_options_are_one_line(tmp_path):
    out = tmp_path / "cal.h5"
    one_line_error(run(*_args(out, "--mode", "edge")), "--mode must be even or random")
    one_line_error(run(*_args(out, "--source", "sim")), "drop --port, --source")
    one_line_error(run(*_args(out, "--arm-direction", "0,0")), "--arm-direction")
    one_line_error(run(*_args(out, "--arm-direction", "0,0,1")), "no target is reachable")
    one_line_error(run(*_args(out, "--skin", "a")), "--skins FILE")
    one_line_error(run(*_args(out, "--skins", tmp_path / "none.toml")), "skins file not found")
    for bad in ("", "1,,2", "a", "0", "-1", "nan", "1,1"):
        one_line_error(run(*_args(out, "--press-depth-mm", bad)), "--press-depth-mm")
    one_line_error(run(*_args(out, "--press-force-n", "2,x")), "--press-force-n")
    one_line_error(run(*_args(out, "--press-depth-mm", "1,6")), "press depth 6 mm", "refused")
    assert not out.exists()


def test_the_pose_comes_from_the_skins_file(tmp_path):
    skins = tmp_path / "skins.toml"
    # the skin upside down under the arm: a probe pointing down reaches nothing
    skins.write_text('[[skin]]\nname = "arm"\nparent_frame = "base"\nrpy = [3.14159, 0, 0]\n')
    out = tmp_path / "cal.h5"
    one_line_error(run(*_args(out, "--skins", skins, "--skin", "arm")), "no target is reachable")
    # ... pointing up reaches it
    res = run(*_args(out, "--skins", skins, "--arm-direction", "0,0,1", "--max-touches", "1"))
    assert res.exit_code == 0, res.output
    pose = read_recording(out).meta["probe"]["pose"]
    assert pose["parent_frame"] == "base" and abs(pose["rotation_xyzw"][0]) > 0.99


def test_dry_run_moves_above_and_writes_nothing(tmp_path):
    out = tmp_path / "cal.h5"
    res = run(*_args(out, "--dry-run"))
    assert res.exit_code == 0, res.output
    assert "Dry run: moved above 6 targets, pressed none; nothing written" in res.output
    assert not out.exists()


def test_ctrl_c_stops_the_probe_and_keeps_the_touches(tmp_path, monkeypatch):
    from skinloc.calibration import probe as probe_mod

    stops = []
    press = probe_mod.SimulatedProbe.press
    stop = probe_mod.SimulatedProbe.stop

    def press_then_ctrl_c(self, *a, **k):
        if len(self.contacts) == 3:
            raise KeyboardInterrupt
        return press(self, *a, **k)

    def counted_stop(self):
        stops.append(self)
        stop(self)

    monkeypatch.setattr(probe_mod.SimulatedProbe, "press", press_then_ctrl_c)
    monkeypatch.setattr(probe_mod.SimulatedProbe, "stop", counted_stop)
    out = tmp_path / "cal.h5"
    res = run(*_args(out))
    assert res.exit_code != 0
    assert len(stops) == 1 and stops[0].stopped and stops[0].skin.contact is None
    assert read_recording(out).n_point_logs == 3
    monkeypatch.undo()
    res = run(*_args(out))
    assert res.exit_code == 0 and "Resuming" in res.output
    assert read_recording(out).n_point_logs == 6


def test_a_real_ctrl_c_stops_a_running_session(tmp_path):
    out = tmp_path / "cal.h5"
    args = _args(out)
    args[args.index("--points") + 1] = "150"
    args[args.index("--samples") + 1] = "400"
    proc = start_skinloc(*args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def touched() -> bool:
        try:
            return read_recording(out).n_point_logs >= 1
        except Exception:
            return False

    try:
        wait_until(touched, "a first probed touch", timeout_s=120, proc=proc)
    finally:
        stop_and_wait(proc, signal.SIGINT, "collect --probe sim")
    _, err = proc.communicate()
    assert proc.returncode == 130, err
    assert "probe stopped" in err and "rerun the same command to resume" in err
    n = read_recording(out).n_point_logs
    assert 1 <= n < 150
