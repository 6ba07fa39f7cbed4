"""Simulate -> train -> evaluate on a small session, through the library and the CLI."""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from skinloc.calibration.session import SessionConfig, simulate_session
from skinloc.evaluation.scoring import evaluate, train_localizer
from skinloc.sim.skin import SimulatedSkin

runner = CliRunner()


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, cone):
    tmp = tmp_path_factory.mktemp("e2e")
    skin = SimulatedSkin(cone, random_state=0)
    with skin:
        cal = simulate_session(
            skin,
            cone,
            tmp / "cal.h5",
            SessionConfig(n_points=60, mode="even", samples_per_touch=10, random_state=0),
        )
        val = simulate_session(
            skin,
            cone,
            tmp / "val.h5",
            SessionConfig(n_points=15, mode="random", samples_per_touch=10, random_state=99),
        )
    return cal, val, tmp


@pytest.mark.slow  # two models, one a network
def test_default_beats_paper_on_simulated_skin(sessions):
    cal, val, _ = sessions
    default = evaluate(train_localizer([cal]), [val]).stats
    paper = evaluate(train_localizer([cal], arch="paper"), [val]).stats
    assert default.mean_mm < 12.0
    assert default.mean_mm < paper.mean_mm
    # a constant prediction (the mean target) is far worse
    centre = np.linalg.norm(val.targets - cal.targets.mean(0), axis=1).mean() * 1e3
    assert default.mean_mm < centre / 3


def test_cli_simulate_train_evaluate(tmp_path):
    def run(*a):
        res = runner.invoke(
            __import__("skinloc.cli.main", fromlist=["app"]).app, [str(x) for x in a]
        )
        assert res.exit_code == 0, res.output
        return res.output

    run(
        "simulate",
        "--points",
        "40",
        "--mode",
        "even",
        "--samples",
        "5",
        "--seed",
        "0",
        "--out",
        tmp_path / "cal.h5",
    )
    run(
        "simulate",
        "--points",
        "10",
        "--mode",
        "random",
        "--samples",
        "5",
        "--seed",
        "1",
        "--out",
        tmp_path / "val.mat",
    )
    run("train", tmp_path / "cal.h5", "--out", tmp_path / "m.h5")
    out = json.loads(run("evaluate", tmp_path / "m.h5", tmp_path / "val.mat", "--json"))
    assert out["n"] == 10 and out["mean_mm"] < 20.0
    info = json.loads(run("info", tmp_path / "cal.h5", "--json"))
    assert (info["n_point_logs"], info["n_frames"], info["tx"], info["rx"]) == (40, 200, 8, 8)


def test_same_skin_seed_same_wiring_different_noise(tmp_path):
    from skinloc.cli.main import app
    from skinloc.data.recording import read_recording

    for s in (0, 1):
        res = runner.invoke(
            app,
            [
                "simulate",
                "--points",
                "3",
                "--samples",
                "3",
                "--seed",
                str(s),
                "--out",
                str(tmp_path / f"{s}.h5"),
            ],
        )
        assert res.exit_code == 0, res.output
    a, b = read_recording(tmp_path / "0.h5"), read_recording(tmp_path / "1.h5")
    # same skin: baselines agree within noise; different sessions: frames differ
    assert np.abs(a.baseline - b.baseline).max() < 40
    assert not np.array_equal(a.baseline_frames, b.baseline_frames)


def test_simulated_recording_keeps_the_true_sensor_positions(tmp_path):
    from skinloc.cli.main import app
    from skinloc.sim.skin import SimulatedSkin

    out = tmp_path / "s.h5"
    args = ["simulate", "--points", "2", "--samples", "2", "--seed", "3", "--skin-seed", "5"]
    res = runner.invoke(app, [*args, "--out", str(out)])
    assert res.exit_code == 0, res.output
    info = json.loads(runner.invoke(app, ["info", str(out), "--json"]).output)
    pos = np.asarray(info["truth_sensor_positions_m"])
    assert pos.shape == (64, 3)
    # the skin seed's wiring, sensor k = TX k // 8, RX k % 8, not the session's
    # stored to 0.1 um: compare within 1 um
    assert np.allclose(pos, SimulatedSkin(random_state=5).sensor_positions, rtol=0, atol=1e-6)
    assert "truth_sensor_positions_m" not in info["meta"]
