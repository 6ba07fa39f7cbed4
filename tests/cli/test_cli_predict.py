"""``skinloc predict``: JSON lines of contacts per row; bad input is one clear line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.models.localizer import ContactLocalizer
from tests._live import calibration, model_path

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def lines(text: str) -> list[dict]:
    return [json.loads(s) for s in text.splitlines() if s.strip()]


@pytest.fixture(scope="module")
def images():
    """Two touches alone, the two together (far apart), and nothing."""
    cal = calibration()
    X, y = cal.touch_means, cal.targets
    d = np.linalg.norm(y[:, None] - y[None], axis=2)
    a, b = np.unravel_index(np.argmax(d), d.shape)
    return np.stack([X[a], X[b], X[a] + X[b], np.zeros(64)]).astype(np.float32)


def test_predict_npy_writes_one_json_line_per_row(tmp_path, images):
    np.save(tmp_path / "x.npy", images)
    res = run("predict", model_path("map"), tmp_path / "x.npy")
    assert res.exit_code == 0, res.output
    out = lines(res.stdout)
    assert [len(o["contacts"]) for o in out] == [1, 1, 2, 0]
    c = out[2]["contacts"]
    assert c[0]["strength"] >= c[1]["strength"] > 0
    assert set(c[0]) == {"position_m", "uncertainty_mm", "strength"}
    assert len(c[0]["position_m"]) == 3


def test_max_contacts_one_is_the_single_contact_answer(tmp_path, images):
    np.save(tmp_path / "x.npy", images)
    res = run("predict", model_path("map"), tmp_path / "x.npy", "--max-contacts", "1")
    assert res.exit_code == 0, res.output
    out = lines(res.stdout)
    assert [len(o["contacts"]) for o in out] == [1, 1, 1, 0]
    want = ContactLocalizer.load(model_path("map")).predict(images[:3])
    got = np.array([o["contacts"][0]["position_m"] for o in out[:3]])
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_predict_csv_with_a_header_and_out_file(tmp_path, images):
    csv = tmp_path / "x.csv"
    header = ",".join(f"s{i}" for i in range(64))
    np.savetxt(csv, images, delimiter=",", header=header, comments="")
    out = tmp_path / "c.jsonl"
    res = run("predict", model_path("map"), csv, "--out", out)
    assert res.exit_code == 0, res.output
    assert [len(o["contacts"]) for o in lines(out.read_text())] == [1, 1, 2, 0]
    # an existing --out is kept without --force, replaced with it
    res = run("predict", model_path("map"), csv, "--out", out)
    assert res.exit_code == 1 and "--force" in res.output
    assert run("predict", model_path("map"), csv, "--out", out, "--force").exit_code == 0


def test_predict_a_recordings_frames(tmp_path):
    cal = calibration()
    path = tmp_path / "cal.h5"
    from skinloc.data.recording import write_recording

    write_recording(cal, path)
    res = run("predict", model_path("map"), path, "--max-contacts", "2")
    assert res.exit_code == 0, res.output
    out = lines(res.stdout)
    assert len(out) == cal.n_point_logs * cal.samples_per_touch
    assert np.mean([len(o["contacts"]) == 1 for o in out]) > 0.8


def test_out_never_overwrites_an_input(tmp_path, images):
    x = tmp_path / "x.npy"
    np.save(x, images)
    before = x.read_bytes()
    for target in (x, model_path("map")):
        res = run("predict", model_path("map"), x, "--out", target, "--force")
        assert res.exit_code == 1 and "also an input" in res.output
    assert x.read_bytes() == before


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda p: np.save(p / "in.npy", np.zeros((3, 63))), "rows of 64 sensors"),
        (lambda p: np.save(p / "in.npy", np.zeros((2, 2, 64))), "rows of 64 sensors"),
        (lambda p: (p / "in.csv").write_text("a,b\nc,d\n"), "comma-separated numbers"),
        (lambda p: (p / "in.txt").write_text("1,2"), "cannot tell what"),
        (lambda p: np.save(p / "in.npy", np.full((2, 64), np.nan)), "row 0 holds NaN"),
        (lambda p: None, "input not found"),
    ],
)
def test_bad_input_is_one_clear_line(tmp_path, make, match):
    make(tmp_path)
    found = [p for p in tmp_path.iterdir() if p.name.startswith("in.")]
    path = found[0] if found else tmp_path / "in.npy"
    res = run("predict", model_path("map"), path)
    assert res.exit_code == 1, res.output
    assert match in res.output and "Traceback" not in res.output
    assert len(res.output.strip().splitlines()) == 1


def test_not_a_model_and_missing_model(tmp_path, images):
    x = tmp_path / "x.npy"
    np.save(x, images)
    res = run("predict", x, x)
    assert res.exit_code == 1 and "Traceback" not in res.output
    res = run("predict", tmp_path / "none.h5", x)
    assert res.exit_code == 1 and "not found" in res.output
    res = run("predict", model_path("map"), x, "--max-contacts", "4")
    assert res.exit_code == 2  # a usage error: 1..3
