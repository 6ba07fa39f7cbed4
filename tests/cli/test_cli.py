import json

import numpy as np
import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.data.recording import write_recording
from skinloc.models.localizer import ContactLocalizer
from tests._helpers import one_line_error
from tests.conftest import make_recording

runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture
def rec_path(tmp_path):
    p = tmp_path / "rec.h5"
    write_recording(make_recording(12, 4), p)
    return p


def test_help_everywhere():
    res = run("--help")
    assert res.exit_code == 0
    for cmd in ("demo", "simulate", "train", "evaluate", "snr", "info", "convert", "bench"):
        assert cmd in res.output
        sub = run(cmd, "--help")
        assert sub.exit_code == 0, cmd
        assert "Example" in sub.output or "Usage" in sub.output


def test_info_json(rec_path):
    res = run("info", rec_path, "--json")
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert (info["n_point_logs"], info["n_frames"], info["tx"], info["rx"]) == (12, 48, 8, 8)
    assert run("info", rec_path).exit_code == 0


def test_snr_json(rec_path):
    res = run("snr", rec_path, "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert len(out["per_sensor_db"]) == 64 and out["mean_snr_db"] > 0
    assert run("snr", rec_path).exit_code == 0


def test_convert_both_ways(rec_path, tmp_path):
    assert run("convert", rec_path, tmp_path / "a.mat").exit_code == 0
    assert run("convert", tmp_path / "a.mat", tmp_path / "b.h5").exit_code == 0
    a = json.loads(run("info", rec_path, "--json").output)
    b = json.loads(run("info", tmp_path / "b.h5", "--json").output)
    assert a["n_frames"] == b["n_frames"]
    res = run("convert", rec_path, tmp_path / "a.csv")
    assert res.exit_code == 1 and ".mat or .h5" in res.output


@pytest.mark.slow  # models trained and evaluated
def test_train_and_evaluate(rec_path, tmp_path):
    model = tmp_path / "m.h5"
    res = run("train", rec_path, "--out", model, "--arch", "paper", "--epochs", "30")
    assert res.exit_code == 0, res.output
    res = run("evaluate", model, rec_path, "--json")
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert {"n", "mean_mm", "std_mm", "median_mm", "p95_mm"} <= set(out)
    assert out["n"] == 12
    per_frame = json.loads(run("evaluate", model, rec_path, "--json", "--per-frame").output)
    assert per_frame["n"] == 48
    assert run("evaluate", model, rec_path).exit_code == 0


def test_default_train_then_recalibrate(rec_path, tmp_path):
    model, new = tmp_path / "m.h5", tmp_path / "new.h5"
    assert run("train", rec_path, "--out", model).exit_code == 0
    later = tmp_path / "later.h5"
    write_recording(make_recording(5, 4, random_state=7), later)
    res = run("train", later, "--init", model, "--out", new)
    assert res.exit_code == 0, res.output
    assert "Recalibrated" in res.output
    # what it did, in one line and in the model file
    line = next(x for x in res.output.splitlines() if x.startswith("Recalibration: "))
    assert "cross-validation over 5 new touches" in line
    done = ContactLocalizer.load(new).meta_["training"]["recalibration"]
    assert done["n_touches"] == 5 and done["method"] in line and done["summary"] in line
    # a baseline capture alone (no touch): the old model, unchanged
    capture = tmp_path / "capture.h5"
    write_recording(make_recording(2, 4, random_state=8).subset(np.array([], dtype=int)), capture)
    kept = tmp_path / "kept.h5"
    res = run("train", capture, "--init", model, "--out", kept)
    assert res.exit_code == 0, res.output
    assert "Recalibration: kept the old model (no new touch to judge it by)" in res.output
    X = make_recording(4, 4, random_state=9).touch_means
    np.testing.assert_allclose(
        ContactLocalizer.load(kept).predict(X), ContactLocalizer.load(model).predict(X)
    )
    res = run("train", capture, "--out", tmp_path / "none.h5")  # without --init: no model
    assert res.exit_code == 1 and "without point logs" in res.output
    out = json.loads(run("evaluate", new, later, "--json").output)
    assert out["n"] == 5 and "uncertainty_spearman" in out
    small = tmp_path / "small.h5"
    write_recording(make_recording(3, 3, n_tx=4, n_rx=4), small)
    res = run("train", small, "--init", model, "--out", tmp_path / "x.h5")
    assert res.exit_code == 1 and "16 sensors" in res.output
    assert not (tmp_path / "x.h5").exists()


def test_recalibrate_on_the_touches_the_old_map_asks_for(rec_path, tmp_path):
    model, new = tmp_path / "m.h5", tmp_path / "new.h5"
    assert run("train", rec_path, "--out", model).exit_code == 0
    later = tmp_path / "later.h5"
    write_recording(make_recording(8, 4, random_state=7), later)
    res = run("train", later, "--init", model, "--select", "4", "--out", new)
    assert res.exit_code == 0, res.output
    assert "Chose 4 point logs (active for recalibration, seed 0)" in res.output
    assert "cross-validation over 4 new touches" in res.output
    # a bad --select or a strategy recalibration does not have: one line, no output
    bad = tmp_path / "bad.h5"
    res = run("train", later, "--init", model, "--select", "9", "--out", bad)
    one_line_error(res, "--select", "between 0 and 8")
    res = run("train", later, "--init", model, "--select", "3", "--strategy", "even", "--out", bad)
    one_line_error(res, "strategy must be one of active, random")
    assert not bad.exists()


def test_option_of_another_model_kind(rec_path, tmp_path):
    res = run("train", rec_path, "--out", tmp_path / "m.h5", "--epochs", "5")
    assert res.exit_code == 1 and "does not apply" in res.output and "Traceback" not in res.output


@pytest.mark.parametrize(
    "args,match",
    [
        (["info", "missing.h5"], "not found"),
        (["train", "missing.h5", "--out", "m.h5"], "not found"),
        (["evaluate", "missing_model.h5", "missing.h5"], "not found"),
        (["bench", "--sizes", "a,b"], "comma-separated"),
    ],
)
def test_errors_are_one_line(tmp_path, monkeypatch, args, match):
    monkeypatch.chdir(tmp_path)
    res = run(*args)
    assert res.exit_code == 1
    assert match in res.output
    assert "Traceback" not in res.output


def test_sensor_count_mismatch(tmp_path):
    model = tmp_path / "m.h5"
    a, b = tmp_path / "a.h5", tmp_path / "b.h5"
    write_recording(make_recording(6, 3), a)
    write_recording(make_recording(6, 3, n_tx=4, n_rx=4), b)
    assert run("train", a, "--out", model, "--arch", "paper", "--epochs", "5").exit_code == 0
    res = run("evaluate", model, b)
    assert res.exit_code == 1 and "16 sensors" in res.output and "64" in res.output
    res = run("train", a, b, "--out", model, "--force")
    assert res.exit_code == 1 and "different sensor counts" in res.output


def test_empty_and_nan_files(tmp_path):
    empty = tmp_path / "empty.h5"
    empty.write_bytes(b"")
    res = run("info", empty)
    assert res.exit_code == 1 and "empty" in res.output
    rec = make_recording(3, 2)
    rec.frames[0, 0, 0] = np.nan
    import h5py

    good = tmp_path / "good.h5"
    write_recording(make_recording(3, 2), good)
    with h5py.File(good, "r+") as f:
        f["point_logs/frames"][0, 0, 0] = np.nan
    res = run("evaluate", good, good)
    assert res.exit_code == 1


def test_bad_option_value_is_usage_error(rec_path, tmp_path):
    res = run("train", rec_path, "--out", tmp_path / "m.h5", "--arch", "huge")
    assert res.exit_code == 2
    assert "huge" in res.output


def test_bad_mesh(tmp_path):
    bad = tmp_path / "skin.obj"
    bad.write_text("garbage\n")
    res = run("simulate", "--out", tmp_path / "x.h5", "--mesh", bad, "--points", "2")
    assert res.exit_code == 1 and "mesh" in res.output


def test_info_describes_an_app_sessions_history(tmp_path):
    """The Export page offers history.h5: ``info`` lists what was taken back, as a table and as
    JSON; an HDF5 file that is neither a recording nor a history is still a one-line error."""
    import h5py

    from skinloc.app.store import SessionFolder
    from skinloc.errors import RecordingError

    folder = SessionFolder(tmp_path)
    frames = np.ones((5, 64), dtype=np.float32)
    target = np.array([0.01, -0.02, 0.05])
    folder.archive("touch", {"target": target, "frames": frames}, {"reason": "retake", "index": 3})
    folder.archive("baseline", {"frames": frames}, {"reason": "new baseline"})
    res = run("info", str(folder.history), "--json")
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["format"] == "skinloc-history"
    first, second = info["entries"]
    assert (first["kind"], first["reason"], first["index"], first["n_frames"]) == (
        "touch",
        "retake",
        3,
        5,
    )
    assert first["target_mm"] == pytest.approx([10.0, -20.0, 50.0])
    assert second["kind"] == "baseline" and "target_mm" not in second
    res = run("info", str(folder.history))
    assert res.exit_code == 0 and "retake" in res.output
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.zeros(3)
    res = run("info", str(other))
    assert res.exit_code != 0 and "Traceback" not in res.output
    # a history.h5 that is something else is never written over by the app
    other.replace(folder.history)
    with pytest.raises(RecordingError, match="not a session history"):
        folder.archive("touch", {"frames": frames}, {})
    with h5py.File(folder.history, "r") as f:
        assert list(f) == ["x"]
