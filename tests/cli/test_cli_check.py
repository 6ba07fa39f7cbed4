"""``skinloc check``: every touch's flags, as the app's gate gives them."""

from __future__ import annotations

import json

import numpy as np
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.data.recording import read_recording, write_recording
from skinloc.geometry.mesh import surface_points
from tests._helpers import one_line_error

runner = CliRunner()


def _moved(targets, surface, j, d_mm):
    dist = 1e3 * np.linalg.norm(surface - targets[j], axis=1)
    return surface[int(np.argmin(np.abs(dist - d_mm)))]


def test_check_flags_two_mispressed_touches_and_a_short_one(tmp_path):
    cal = tmp_path / "cal.h5"
    args = ["simulate", "--points", "30", "--samples", "10", "--seed", "4", "--out", str(cal)]
    assert runner.invoke(app, args).exit_code == 0
    rec = read_recording(cal)
    surface = surface_points(rec.mesh, 2000)
    rec.targets[3] = _moved(rec.targets, surface, 3, 60.0)  # pressed 60 mm from its target
    rec.targets[11] = _moved(rec.targets, surface, 11, 90.0)
    rec.frames[20][5:] = rec.baseline_frames[:5]  # the finger lifted half way through
    bad = tmp_path / "bad.h5"
    write_recording(rec, bad)
    res = runner.invoke(app, ["check", str(bad), "--json"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.output)
    assert out["n_touches"] == 30 and len(out["touches"]) == 30
    assert [t["index"] for t in out["touches"]] == list(range(30))
    flagged = {t["index"]: t["flags"] for t in out["touches"] if t["flags"]}
    assert "off_target" in flagged[3] and "off_target" in flagged[11], flagged
    assert "short" in flagged[20], flagged
    assert len(flagged) <= 4, flagged  # at most one good touch flagged with them
    # the clean session: at most one touch flagged (the false-flag rate is about 1 %)
    res = runner.invoke(app, ["check", str(cal), "--json"])
    clean = json.loads(res.output)
    assert sum(bool(t["flags"]) for t in clean["touches"]) <= 1
    res = runner.invoke(app, ["check", str(bad)])  # the table
    assert res.exit_code == 0 and "off_target" in res.output


def test_check_refuses_what_is_not_a_recording(tmp_path):
    text = tmp_path / "notes.h5"
    text.write_text("not a recording\n")
    one_line_error(runner.invoke(app, ["check", str(text)]))
    one_line_error(runner.invoke(app, ["check", str(tmp_path / "missing.h5")]))
