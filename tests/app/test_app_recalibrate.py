"""The Recalibrate page's API: a model brought to today's skin with k guided touches.

The simulated skin streams at 400 Hz and the scripted finger presses each target, as for
calibration (one capture path); the old model is never written over.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import train_localizer
from skinloc.models.localizer import ContactLocalizer
from tests.app.test_app_api import (
    A,
    TestClient,
    calibrate,
    make_client,
    new_session,
    wait_for,
)
from tests.conftest import make_recording

pytestmark = pytest.mark.slow  # a session calibrated and trained, touches captured


def _status(client: TestClient) -> dict:
    return client.get("/api/recalibrate").json()


def _result(client: TestClient, what: str) -> dict:
    def done(_state: dict) -> bool:
        job = _status(client)["job"]
        return job is not None and not job.get("running") and job.get("planned") is None

    wait_for(client, done, what)
    st = _status(client)
    assert "error" not in st["job"], st["job"]
    return st["result"]


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_recalibrate_a_trained_model_with_k_touches_then_with_none(tmp_path):
    with make_client(tmp_path) as client:
        sid = new_session(client, n_points=8)
        # no model yet: refused, naming why
        r = client.post("/api/recalibrate/start", json={"k": 3}, headers=A)
        assert r.status_code == 400 and "no trained model" in r.json()["detail"]
        calibrate(client)
        assert client.post("/api/train", headers=A).status_code == 200
        wait_for(client, lambda s: s["training"] and not s["training"].get("running"), "training")
        old_file = tmp_path / sid / "model.h5"
        before = _digest(old_file)
        assert {"kind": "session", "id": sid} in [
            {k: m[k] for k in ("kind", "id")} for m in _status(client)["models"]
        ]

        r = client.post("/api/recalibrate/start", json={"session": sid, "k": 4}, headers=A)
        assert r.status_code == 200, r.text
        result = _result(client, "the recalibration")
        assert result["n_touches"] == 4 and result["from"] == f"session {sid}"
        assert result["strategy"] == "active"
        assert np.isfinite(result["before_mm"]) and len(result["before_per_touch_mm"]) == 4
        assert result["before_mm"] == pytest.approx(np.mean(result["before_per_touch_mm"]), 0.01)
        # after: the chosen candidate's cross-validated error; the caveat of few touches
        assert result["after_mm"] == result["cv_error_mm"][result["method"]]
        assert "4 touches only" in result["caveat"]
        rec = read_recording(tmp_path / sid / "recalibration.h5")
        assert rec.n_point_logs == 4  # captured by the guided capture, in the session
        saved = tmp_path / sid / result["model_file"]
        assert saved.name.startswith("model-recalibrated-") and saved.is_file()
        model = ContactLocalizer.load(saved)
        assert model.meta_["training"]["recalibration"]["n_touches"] == 4
        assert _digest(old_file) == before  # the old model untouched
        state = client.get("/api/state").json()
        assert "recalibrated" in state["message"] and result["model_file"] in state["message"]

        # k = 0: a fresh baseline only, the model kept as it is (saved as a new file)
        r = client.post("/api/recalibrate/start", json={"k": 0}, headers=A)
        assert r.status_code == 200, r.text
        again = _result(client, "the baseline-only recalibration")
        assert again["n_touches"] == 0 and again["before_mm"] is None
        assert again["method"] == "old map" and again["model_file"] != result["model_file"]
        X = rec.touch_means
        np.testing.assert_allclose(
            ContactLocalizer.load(tmp_path / sid / again["model_file"]).predict(X),
            ContactLocalizer.load(old_file).predict(X),
        )
        # the earlier recalibration's touches are kept, renamed
        assert len(list((tmp_path / sid).glob("recalibration-*.h5"))) == 1
        assert _digest(old_file) == before


def test_recalibration_refuses_what_it_cannot_do(tmp_path):
    with make_client(tmp_path) as client:
        r = client.post("/api/recalibrate/start", json={"k": 3}, headers=A)
        assert r.status_code == 400 and "open a session" in r.json()["detail"]
        new_session(client, n_points=4)
        for k in (-1, 51):  # k out of range: the field named
            r = client.post("/api/recalibrate/start", json={"k": k}, headers=A)
            assert r.status_code == 422 and "k" in r.json()["detail"]
        # a model of another skin (16 sensors, not 64): uploaded, then refused
        small = tmp_path / "small.h5"
        train_localizer([make_recording(6, 3, n_tx=4, n_rx=4)]).save(small)
        r = client.post(
            "/api/recalibrate/models?filename=small.h5", content=small.read_bytes(), headers=A
        )
        assert r.status_code == 200 and r.json()["n_sensors"] == 16
        r = client.post("/api/recalibrate/start", json={"file": "small.h5", "k": 3}, headers=A)
        assert r.status_code == 400
        assert "expects 16 sensors but the skin has 64" in r.json()["detail"]
        r = client.post("/api/recalibrate/start", json={"file": "none.h5", "k": 3}, headers=A)
        assert r.status_code == 400 and "no uploaded model file" in r.json()["detail"]
        junk = client.post("/api/recalibrate/models?filename=junk.h5", content=b"x", headers=A)
        assert junk.status_code == 400 and "not a skinloc model" in junk.json()["detail"]
        assert [m["id"] for m in _status(client)["models"]] == ["small.h5"]
        assert client.get("/api/state").json()["mode"] == "idle"
        # without the page's token: refused, nothing started
        stranger = TestClient(client.app)
        r = stranger.post("/api/recalibrate/start", json={"k": 3}, headers=A)
        assert r.status_code == 403
        r = stranger.post("/api/recalibrate/models?filename=x.h5", content=b"x", headers=A)
        assert r.status_code == 403 and not (tmp_path / "models" / "x.h5").exists()
