"""Export (issue 22, section 4): the open session's files, validation CSV and error view.

One session is calibrated, trained and validated once (module fixture); every test downloads
from it. Every route is a GET: it needs no token, and reaches no file but the session's own.
"""

from __future__ import annotations

import csv
import io
import subprocess
import sys
import warnings

import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient  # noqa: E402

from skinloc.app.server import create_app  # noqa: E402
from skinloc.app.workspace import AppConfig  # noqa: E402
from skinloc.data.recording import read_recording  # noqa: E402
from skinloc.models.localizer import ContactLocalizer  # noqa: E402
from skinloc.sources.base import SourceOptions  # noqa: E402
from tests.app._app import run_as_printed  # noqa: E402
from tests.app._app import wait as _wait  # noqa: E402

A = {"X-Skinloc-Client": "tab-a"}


@pytest.fixture(scope="module")
def done(tmp_path_factory):
    """A client on a session with 8 touches, a model and 3 validation touches."""
    data = tmp_path_factory.mktemp("export")
    app = create_app(
        AppConfig(data_dir=data, finger_delay_s=0.05),
        SourceOptions(source="sim", rate_hz=400.0, seed=3),
    )
    with TestClient(app) as client:
        ws = app.state.workspace
        ws.create_session("export", n_points=8, samples=10, baseline_frames=20)
        ws.set_finger(True)
        ws.start_calibration()
        _wait(lambda: ws.message == "calibration complete", "calibration")
        ws.train()
        _wait(lambda: ws.training and not ws.training.get("running"), "training", 300)
        assert ws.active.model is not None, ws.training
        ws.start_validation(3)
        _wait(lambda: ws.active.info.get("validation") is not None, "validation")
        ws.stop()
        yield client, ws.active.folder


def test_the_session_files_are_listed_and_download_whole(done, tmp_path):
    client, folder = done
    listing = client.get("/api/export").json()
    names = {f["name"]: f for f in listing["files"]}
    assert {"calibration.h5", "validation.h5", "model.h5"} <= set(names)
    assert names["model.h5"]["kind"] == "trained model" and listing["validation"]
    assert listing["session"] == folder.id
    assert not any(n.startswith(".") for n in names)  # the lock file is not one

    for name in ("calibration.h5", "validation.h5", "model.h5"):
        r = client.get(f"/api/export/files/{name}")  # a GET: no token, no control needed
        assert r.status_code == 200, r.text
        assert r.headers["content-disposition"] == f'attachment; filename="{folder.id}-{name}"'
        assert r.content == (folder.path / name).read_bytes()
        (tmp_path / name).write_bytes(r.content)

    # Each downloaded file opens with skinloc: the recordings in Python and with `skinloc info`.
    cal = read_recording(tmp_path / "calibration.h5")
    assert cal.n_point_logs == 8
    assert read_recording(tmp_path / "validation.h5").n_point_logs == 3
    model = ContactLocalizer.load(tmp_path / "model.h5")
    assert model.predict(cal.touch_means).shape == (8, 3)
    out = subprocess.run(
        [sys.executable, "-m", "skinloc", "info", str(tmp_path / "calibration.h5"), "--json"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert '"n_point_logs": 8' in out.stdout


def test_every_command_the_page_prints_runs_as_printed(done, tmp_path):
    """Each file's "open with" command, run in the folder the files were downloaded to under
    their download names, exits 0; the skins file names the downloaded model and runs live."""
    client, folder = done
    files = client.get("/api/export").json()["files"]
    names = {f["name"] for f in files}
    assert {"calibration.h5", "validation.h5", "model.h5", "skins.toml"} <= names
    for f in files:
        r = client.get(f"/api/export/files/{f['name']}")
        assert r.status_code == 200, r.text
        assert r.headers["content-disposition"] == f'attachment; filename="{f["download"]}"'
        (tmp_path / f["download"]).write_bytes(r.content)
    skins = (tmp_path / f"{folder.id}-skins.toml").read_text()
    assert f'model = "{folder.id}-model.h5"' in skins
    assert not (folder.path / "skins.toml").exists()  # offered, not written, until saved
    commands = {f["name"]: f["command"] for f in files}
    assert commands["validation.h5"].startswith("skinloc evaluate ")
    assert commands["skins.toml"].startswith("skinloc run --config ")
    for command in commands.values():
        run_as_printed(command, tmp_path)


def test_validation_errors_as_csv(done):
    client, folder = done
    r = client.get("/api/export/validation.csv")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(r.text)))
    val = read_recording(folder.validation)
    assert len(rows) == val.n_point_logs == 3
    for i, row in enumerate(rows):
        assert row["status"] == "kept" and int(row["touch"]) == i + 1
        target = np.array([float(row[f"target_{c}_mm"]) for c in "xyz"])
        pred = np.array([float(row[f"predicted_{c}_mm"]) for c in "xyz"])
        np.testing.assert_allclose(target, 1e3 * val.targets[i], atol=1e-3)
        err = float(row["error_mm"])
        assert err == pytest.approx(val.meta["app"]["errors_mm"][i], abs=1e-3)
        assert err == pytest.approx(np.linalg.norm(pred - target), abs=1e-2)


@pytest.mark.parametrize("fmt", ["png", "svg"])
def test_error_view_as_png_and_svg(done, fmt):
    client, folder = done
    r = client.get(f"/api/export/errors.{fmt}")
    assert r.status_code == 200, r.text
    assert r.headers["content-disposition"].endswith(f'-validation-errors.{fmt}"')
    if fmt == "png":
        assert r.content.startswith(b"\x89PNG\r\n\x1a\n")
    else:
        assert b"<svg" in r.content[:2000] and r.content.rstrip().endswith(b"</svg>")


@pytest.mark.parametrize(
    "path",
    [
        "/api/export/files/..%2Fsession.json",
        "/api/export/files/..%2F..%2F..%2Fetc%2Fpasswd",
        "/api/export/files/%2Fetc%2Fpasswd",
        "/api/export/files/session.json",
        "/api/export/files/plan.npz",
        "/api/export/files/.lock",
        "/api/export/files/calibration.h5%00.txt",
        "/api/export/files/%2e%2e",
        "/api/export/files/" + "a" * 300 + ".h5",
        "/api/export/files/live-20260101-000000.h5",  # a name that fits, but no such file
    ],
)
def test_no_file_outside_the_exportable_ones(done, path):
    client, _ = done
    r = client.get(path)
    assert r.status_code in (404, 400), (path, r.status_code)
    detail = r.json()["detail"]
    assert "\n" not in detail and len(detail) <= 300
    assert "root:" not in r.text


def test_a_symlink_in_the_session_folder_is_not_followed(done, tmp_path):
    client, folder = done
    secret = tmp_path / "secret.h5"
    secret.write_bytes(b"not the session's")
    link = folder.path / "validation-20260101-000000.h5"
    link.symlink_to(secret)
    try:
        assert link.name not in {f["name"] for f in client.get("/api/export").json()["files"]}
        assert client.get(f"/api/export/files/{link.name}").status_code == 404
    finally:
        link.unlink()


def test_bad_formats_and_no_session_say_so_in_one_line(tmp_path):
    app = create_app(AppConfig(data_dir=tmp_path))
    with TestClient(app) as client:
        for path in (
            "/api/export",
            "/api/export/files/model.h5",
            "/api/export/validation.csv",
            "/api/export/errors.png",
        ):
            r = client.get(path)
            assert r.status_code == 400, path
            assert r.json()["detail"].startswith("no session open")
        client.headers.update({"X-Skinloc-Token": app.state.token})
        assert client.post("/api/sessions", json={"n_points": 3}, headers=A).status_code == 200
        r = client.get("/api/export/errors.gif")
        assert r.status_code == 400 and "png or svg" in r.json()["detail"]
        for path in ("/api/export/validation.csv", "/api/export/errors.svg"):
            r = client.get(path)
            assert r.status_code == 400 and r.json()["detail"].startswith("validate first")
        assert client.get("/api/export").json()["files"] == []


def test_downloads_change_nothing_and_refuse_other_methods(done):
    client, folder = done
    before = {p.name: p.stat().st_mtime_ns for p in folder.path.iterdir()}
    client.get("/api/export/files/model.h5")
    client.get("/api/export/validation.csv")
    assert {p.name: p.stat().st_mtime_ns for p in folder.path.iterdir()} == before
    # No route writes under /api/export: other methods are refused (by the token guard first).
    r = client.post("/api/export/files/model.h5")
    assert r.status_code in (403, 405)
