"""One output, one writer; a model scored only on its own skin; meshes the simulator can wire."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest
import trimesh
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.data.recording import read_recording
from skinloc.files import claim_output
from tests._helpers import one_line_error, start_skinloc

runner = CliRunner()


def test_two_simulates_of_one_output_started_together_leave_one_good_file(tmp_path):
    out = tmp_path / "x.h5"
    args = ("simulate", "--points", "6", "--samples", "4", "--seed", "0", "--out", out)
    procs = [
        start_skinloc(*args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for _ in range(2)
    ]
    results = [p.communicate(timeout=300) for p in procs]
    codes = sorted(p.returncode for p in procs)
    errors = " ".join(err for _, err in results)
    # Either the second was refused while the first wrote, or it started after the first
    # finished and found the file there: never both "Wrote", never a lost side file.
    assert codes == [0, 1], results
    assert "is writing" in errors or "exists: pass --force" in errors, errors
    assert "Traceback" not in errors
    assert read_recording(out).n_point_logs == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.h5"]


def test_a_train_to_an_output_another_process_writes_is_refused(tmp_path, golden_recording):
    out = tmp_path / "m.h5"
    claim = claim_output(out)  # as another skinloc process would hold it
    try:
        res = runner.invoke(app, ["train", str(golden_recording), "--out", str(out)])
    finally:
        claim.release()
    one_line_error(res, "is writing", str(out))
    assert not out.exists()


@pytest.fixture(scope="module")
def golden_recording(tmp_path_factory):
    out = tmp_path_factory.mktemp("outputs") / "cal.h5"
    res = runner.invoke(
        app, ["simulate", "--points", "20", "--samples", "5", "--seed", "3", "--out", str(out)]
    )
    assert res.exit_code == 0, res.output
    return out


def _mesh_file(tmp_path, name, mesh):
    path = tmp_path / name
    mesh.export(path)
    return path


def test_a_closed_sphere_is_refused_in_one_line_and_a_hemisphere_simulates(tmp_path):
    sphere = trimesh.creation.uv_sphere(radius=0.06)
    path = _mesh_file(tmp_path, "sphere.stl", sphere)
    res = runner.invoke(
        app, ["simulate", "--mesh", str(path), "--points", "8", "--out", str(tmp_path / "s.h5")]
    )
    one_line_error(res, "cover only", "open shell")
    dome = trimesh.creation.icosphere(subdivisions=3, radius=0.06)
    dome.update_faces(dome.face_normals[:, 2] > 0)
    dome.remove_unreferenced_vertices()
    path = _mesh_file(tmp_path, "dome.stl", dome)
    out = tmp_path / "d.h5"
    args = ["simulate", "--mesh", str(path), "--points", "8", "--samples", "4", "--out", str(out)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    assert read_recording(out).n_point_logs == 8


def test_evaluate_and_recalibrate_refuse_a_recording_of_another_mesh(tmp_path, golden_recording):
    model = tmp_path / "m.h5"
    assert runner.invoke(app, ["train", str(golden_recording), "--out", str(model)]).exit_code == 0
    plate = trimesh.creation.box(extents=(0.15, 0.1, 0.01))
    path = _mesh_file(tmp_path, "plate.stl", plate)
    other = tmp_path / "plate.h5"
    args = ["simulate", "--mesh", str(path), "--points", "8", "--samples", "4", "--out", str(other)]
    assert runner.invoke(app, args).exit_code == 0
    one_line_error(runner.invoke(app, ["evaluate", str(model), str(other)]), "another mesh")
    res = runner.invoke(
        app, ["train", str(other), "--init", str(model), "--out", str(tmp_path / "r.h5")]
    )
    one_line_error(res, "another mesh")
    # its own skin is scored as before
    res = runner.invoke(app, ["evaluate", str(model), str(golden_recording), "--json"])
    assert res.exit_code == 0, res.output
    assert np.isfinite(__import__("json").loads(res.output)["mean_mm"])


def test_simulate_records_a_later_session_of_the_same_skin(tmp_path):
    first, later = tmp_path / "first.h5", tmp_path / "later.h5"
    common = ["simulate", "--points", "6", "--samples", "4", "--skin-seed", "2"]
    assert runner.invoke(app, [*common, "--out", str(first)]).exit_code == 0
    res = runner.invoke(
        app, [*common, "--session-change", "real", "--change-seed", "1", "--out", str(later)]
    )
    assert res.exit_code == 0, res.output
    a, b = read_recording(first), read_recording(later)
    assert "later session (real change, seed 1)" in b.meta["description"]
    np.testing.assert_allclose(a.targets, b.targets)  # the same session seed: the same targets
    assert np.median(np.abs(a.baseline - b.baseline)) > 100  # the baselines moved
    res = runner.invoke(app, [*common, "--session-change", "huge", "--out", str(tmp_path / "x")])
    assert res.exit_code != 0 and "Traceback" not in res.output
    res = runner.invoke(
        app, ["simulate", "--gestures", "2", "--session-change", "real", "--out", str(later)]
    )
    one_line_error(res, "--session-change")
