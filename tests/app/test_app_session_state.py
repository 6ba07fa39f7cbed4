"""What belongs to a session stays with it; flagged touches are shown, left out, retaken.

Through the HTTP API with the simulated skin, as ``test_app_api``: a training result never
shows under another session, the scripted finger is off in a new session, a touch can be
retaken after "complete" (also in a session opened again), and training leaves out the
touches asked for and names the touch that raises the cross-validated error most.
"""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.geometry.mesh import cone_skin
from tests.app.test_app_api import A, calibrate, make_client, new_session, wait_for


def trained(state: dict) -> bool:
    t = state["training"]
    return bool(t) and not t.get("running")


def test_a_training_result_stays_with_its_session(tmp_path):
    with make_client(tmp_path) as client:
        first = new_session(client, n_points=8)
        calibrate(client)
        assert client.post("/api/train", headers=A).status_code == 200
        wait_for(client, lambda s: s["training"] is not None, "training to start")
        # A new session while the first one trains: nothing of that training shows with it.
        second = new_session(client, n_points=8)
        state = client.get("/api/state").json()
        assert state["session"]["id"] == second and state["training"] is None
        time_out = wait_for(
            client,
            lambda s: s["training"] is None and (tmp_path / first / "model.h5").is_file(),
            "the first session's model",
        )
        assert not time_out["session"]["has_model"]
        # Its own result again once it is opened.
        assert client.post(f"/api/sessions/{first}/open", headers=A).status_code == 200
        state = client.get("/api/state").json()
        assert state["session"]["has_model"] and state["session"]["holdout"]["n_point_logs"] == 8
        assert state["session"]["holdout"]["map_prior"]  # 8 touches: the map prior's range


def test_the_scripted_finger_is_off_in_a_new_session(tmp_path):
    with make_client(tmp_path) as client:
        new_session(client, n_points=4)
        assert client.post("/api/finger", json={"on": True}, headers=A).status_code == 200
        assert client.get("/api/state").json()["finger"]
        new_session(client, n_points=4)
        assert not client.get("/api/state").json()["finger"]


def test_retake_after_complete_and_in_a_reopened_session(tmp_path):
    with make_client(tmp_path) as client:
        sid = new_session(client, n_points=6)
        calibrate(client)
        client.post("/api/finger", json={"on": False}, headers=A)
        r = client.post("/api/capture/retake", json={"index": 2}, headers=A)
        assert r.status_code == 200, r.text
        state = client.get("/api/state").json()
        assert state["mode"] == "calibrate" and state["guided"]["index"] == 5
        assert "again" in state["message"]
        client.post("/api/finger", json={"on": True}, headers=A)
        wait_for(client, lambda s: s["message"] == "calibration complete", "the retaken touch")
        # Closed and opened again: the calibration is resumed from its file for the retake.
        client.post("/api/session/close", headers=A)
        client.post(f"/api/sessions/{sid}/open", headers=A)
        r = client.post("/api/capture/retake", json={"index": 5}, headers=A)
        assert r.status_code == 200, r.text
        state = client.get("/api/state").json()
        assert state["mode"] == "calibrate" and not state["finger"]  # off in a reopened session
        client.post("/api/finger", json={"on": True}, headers=A)
        wait_for(client, lambda s: s["message"] == "calibration complete", "the second retake")
        assert len(client.get("/api/session").json()["calibration"]["done"]) == 6


@pytest.mark.slow  # a 20-touch session trained twice
def test_training_leaves_out_touches_and_names_the_one_that_hurts(tmp_path):
    with make_client(tmp_path) as client:
        client.app.state.workspace.config.influence_suspects = 2
        new_session(client, n_points=20)
        calibrate(client, until=6)
        # Touch 7 made at the far side of the skin, the finger's other touches where asked.
        client.post("/api/finger", json={"on": False}, headers=A)
        client.post("/api/calibrate/start", headers=A)
        state = wait_for(
            client,
            lambda s: s["mode"] == "calibrate" and s["guided"]["phase"] == "wait_touch",
            "the prompt of touch 7",
        )
        target = np.asarray(state["guided"]["target"])
        skin = cone_skin().vertices  # its point farthest from the target: no other touch's image
        far = skin[np.argmax(np.linalg.norm(skin - target, axis=1))]
        client.post("/api/sim/touch", json={"point": far.tolist()}, headers=A)
        wait_for(client, lambda s: s["guided"]["index"] >= 7, "the touch elsewhere")
        client.post("/api/sim/touch", json={"point": None}, headers=A)
        calibrate(client)
        flags = client.get("/api/session").json()["calibration"]["flags"]
        assert "off-target" in flags[6], flags

        assert client.post("/api/train", headers=A).status_code == 200
        result = wait_for(client, trained, "training")["training"]["result"]
        assert result["n_recorded"] == 20 and result["left_out"] == []
        assert {"index": 6, "flags": flags[6]} in result["flagged_kept"]
        influence = result["influence"]
        assert len(influence["cv_errors_mm"]) == 20
        worst = influence["suspects"][0]
        assert worst["index"] == 6 and worst["gain_mm"] > 0
        assert worst["others_without_mm"] < worst["others_with_mm"]

        r = client.post("/api/train", json={"exclude": [6]}, headers=A)
        assert r.status_code == 200, r.text
        wait_for(client, lambda s: trained(s) and s["training"]["result"]["left_out"], "again")
        result = client.get("/api/state").json()["session"]["holdout"]
        assert result["left_out"] == [{"index": 6, "flags": flags[6]}]
        assert result["n_point_logs"] == 19 and 6 not in result["kept"]

        r = client.post("/api/train", json={"exclude": [40]}, headers=A)
        assert r.status_code == 400 and "no touch 41" in r.json()["detail"]


@pytest.mark.parametrize("path", ["/api/live/start", "/api/validate/start"])
def test_live_and_validate_without_a_model_say_so(tmp_path, path):
    with make_client(tmp_path) as client:
        new_session(client, n_points=4)
        r = client.post(path, json={}, headers=A)
        assert r.status_code == 400 and "train a model first" in r.json()["detail"]
