"""``skinloc simulate --gestures``: the stream, its truth in ``info --json``, the same skin."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from skinloc.data.recording import read_recording
from skinloc.sim.gestures import GESTURE_KINDS
from skinloc.sources.replay import read_stream
from tests._helpers import one_line_error

runner = CliRunner()


def run(*args: object):
    from skinloc.cli.main import app

    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def gestures(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("g") / "g.h5"
    res = run("simulate", "--gestures", 5, "--seed", 2, "--skin-seed", 4, "--out", out)
    assert res.exit_code == 0, res.output
    assert "5 gestures and 2 other touches" in res.output
    return out


def test_info_json_prints_the_truth(gestures: Path) -> None:
    res = run("info", gestures, "--json")
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    truth = info["truth_gestures"]
    assert len(truth) == 5 and {g["kind"] for g in truth} == set(GESTURE_KINDS)
    for g in truth + info["truth_touches"]:
        assert {"kind", "direction", "start_s", "end_s"} <= set(g)
        assert 0 <= g["start_s"] < g["end_s"] <= info["stream_seconds"]
        assert (g["direction"] is None) == (g["kind"] != "swipe")
        # every finger's landing point: two for a two-finger tap (and a double tap's two taps)
        two = g["kind"] in ("two_finger_tap", "double_tap")
        assert np.shape(g["fingers_m"]) == ((2, 3) if two else (1, 3))
        assert g["fingers_m"][0] == g["position_m"]
        if g["kind"] == "two_finger_tap":
            sep = np.linalg.norm(np.subtract(*g["fingers_m"]))
            assert sep == pytest.approx(g["separation_m"]) and 0.019 <= sep <= 0.061
    assert {g["kind"] for g in info["truth_touches"]} == {"rest", "drag"}
    assert info["stream_frames"] > 0 and info["n_baseline_frames"] == 50
    assert info["meta"]["gesture_script"]["skin_seed"] == 4
    # the table form names them too
    table = run("info", gestures)
    assert table.exit_code == 0 and "truth_gestures" in table.output


def test_same_skin_as_a_session_with_the_same_skin_seed(gestures: Path, tmp_path: Path) -> None:
    cal = tmp_path / "cal.h5"
    res = run(
        "simulate", "--points", 3, "--samples", 5, "--seed", 9, "--skin-seed", 4, "--out", cal
    )
    assert res.exit_code == 0, res.output
    a, b = read_recording(gestures), read_recording(cal)
    np.testing.assert_array_equal(
        a.meta["truth_sensor_positions_m"], b.meta["truth_sensor_positions_m"]
    )
    # the same electronics: baselines agree to within noise and drift
    assert np.abs(a.baseline - b.baseline).max() < 40
    other = tmp_path / "other.h5"
    res = run("simulate", "--gestures", 1, "--other-touches", 0, "--skin-seed", 5, "--out", other)
    assert res.exit_code == 0, res.output
    assert np.abs(read_recording(other).baseline - b.baseline).max() > 200
    frames, times, _ = read_stream(other)
    assert len(frames) == len(times) > 0


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--gestures", 0], "--gestures must be >= 1"),
        (["--gestures", -3], "--gestures must be >= 1"),
        (["--gestures", 2, "--other-touches", -1], "--other-touches must be >= 0"),
        (["--other-touches", 2], "--other-touches needs --gestures"),
    ],
)
def test_bad_options_are_one_line_errors(tmp_path: Path, args: list, needle: str) -> None:
    out = tmp_path / "g.h5"
    one_line_error(run("simulate", *args, "--out", out), needle)
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_refuses_mat_and_an_existing_file(tmp_path: Path) -> None:
    one_line_error(
        run("simulate", "--gestures", 2, "--out", tmp_path / "g.mat"), "must name an .h5"
    )
    out = tmp_path / "g.h5"
    out.write_bytes(b"precious")
    digest = hashlib.sha256(out.read_bytes()).hexdigest()
    one_line_error(run("simulate", "--gestures", 2, "--out", out), str(out))
    assert hashlib.sha256(out.read_bytes()).hexdigest() == digest


def test_refuses_a_stream_too_large(tmp_path: Path) -> None:
    one_line_error(run("simulate", "--gestures", 10**7, "--out", tmp_path / "g.h5"), "GiB")
    assert list(tmp_path.iterdir()) == []
