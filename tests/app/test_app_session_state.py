"""What belongs to a session stays with it; flagged touches are shown, left out, retaken.

Through the HTTP API with the simulated skin, as ``test_app_api``: a training result never
shows under another session, the scripted finger is off in a new session, a touch can be
retaken after "complete" (also in a session opened again), and training leaves out the
touches asked for and names the touch that raises the cross-validated error most.
"""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.calibration.touch_check import check_recording
from skinloc.data.recording import read_recording
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
        # The next touch (7th, or 8th when the finger pressed once more before it stopped on a
        # busy machine) made at the far side of the skin, the finger's other touches where asked.
        client.post("/api/finger", json={"on": False}, headers=A)
        client.post("/api/calibrate/start", headers=A)
        state = wait_for(
            client,
            lambda s: s["mode"] == "calibrate" and s["guided"]["phase"] == "wait_touch",
            "the prompt of touch 7",
        )
        k = state["guided"]["index"]
        assert k in (6, 7), state["guided"]
        target = np.asarray(state["guided"]["target"])
        skin = cone_skin().vertices  # its point farthest from the target: no other touch's image
        far = skin[np.argmax(np.linalg.norm(skin - target, axis=1))]
        client.post("/api/sim/touch", json={"point": far.tolist()}, headers=A)
        wait_for(client, lambda s: s["guided"]["index"] >= k + 1, "the touch elsewhere")
        client.post("/api/sim/touch", json={"point": None}, headers=A)
        calibrate(client)
        flags = client.get("/api/session").json()["calibration"]["flags"]
        assert "off_target" in flags[k], flags
        # The gate is skinloc check: the same words for every touch of the session's file.
        sid = client.get("/api/state").json()["session"]["id"]
        assert check_recording(read_recording(tmp_path / sid / "calibration.h5"))[0] == flags

        assert client.post("/api/train", headers=A).status_code == 200
        result = wait_for(client, trained, "training")["training"]["result"]
        assert result["n_recorded"] == 20 and result["left_out"] == []
        seventh = {"index": k, "number": k + 1, "attempt": 1, "flags": flags[k]}
        assert seventh in result["flagged_kept"] and seventh in result["went_in"]
        influence = result["influence"]
        assert len(influence["cv_errors_mm"]) == 20
        worst = influence["suspects"][0]
        assert worst["index"] == k and worst["gain_mm"] > 0
        assert worst["others_without_mm"] < worst["others_with_mm"]

        r = client.post("/api/train", json={"exclude": [k]}, headers=A)
        assert r.status_code == 200, r.text
        wait_for(client, lambda s: trained(s) and s["training"]["result"]["left_out"], "again")
        result = client.get("/api/state").json()["session"]["holdout"]
        assert result["left_out"] == [{**seventh, "why": "left out by hand"}]
        assert result["n_point_logs"] == 19 and k not in result["kept"]

        r = client.post("/api/train", json={"exclude": [40]}, headers=A)
        assert r.status_code == 400 and "no touch 41" in r.json()["detail"]


def _train(client) -> dict:
    r = client.post("/api/train", headers=A)
    assert r.status_code == 200, r.text
    wait_for(client, lambda s: s["training"] and s["training"].get("running"), "training start")
    return wait_for(client, trained, "training")["session"]["holdout"]


def test_a_touch_left_out_stays_out_until_put_back(tmp_path):
    with make_client(tmp_path) as client:
        client.app.state.workspace.config.influence_suspects = 0
        new_session(client, n_points=10)
        calibrate(client)
        # An unflagged touch left out by hand, then another: both stay out across trainings.
        assert client.post("/api/train/leave_out", json={"index": 2}, headers=A).status_code == 200
        assert [t["index"] for t in _train(client)["left_out"]] == [2]
        assert client.post("/api/train/leave_out", json={"index": 5}, headers=A).status_code == 200
        h = _train(client)
        assert [(t["index"], t["why"]) for t in h["left_out"]] == [
            (2, "left out by hand"),
            (5, "left out by hand"),
        ]
        assert h["n_point_logs"] == 8 and [t["index"] for t in h["went_in"]] == [
            0,
            1,
            3,
            4,
            6,
            7,
            8,
            9,
        ]
        detail = client.get("/api/session").json()["calibration"]
        assert detail["left_out"] == [i in (2, 5) for i in range(10)]
        # Stored with the recording: a session opened again keeps them out.
        sid = client.get("/api/state").json()["session"]["id"]
        client.post("/api/session/close", headers=A)
        client.post(f"/api/sessions/{sid}/open", headers=A)
        r = client.post("/api/train/leave_out", json={"index": 2, "out": False}, headers=A)
        assert r.status_code == 200 and "put back" in client.get("/api/state").json()["message"]
        assert [t["index"] for t in _train(client)["left_out"]] == [5]
        r = client.post("/api/train/leave_out", json={"index": 10}, headers=A)
        assert r.status_code == 400 and "no touch 11" in r.json()["detail"]


def test_a_touch_keeps_its_number_and_a_retake_is_its_next_attempt(tmp_path):
    with make_client(tmp_path) as client:
        sid = new_session(client, n_points=6)
        calibrate(client, until=3)
        client.post("/api/finger", json={"on": False}, headers=A)
        n = len(client.get("/api/session").json()["calibration"]["done"])
        # Retake the second touch: target 2 is asked again as its 2nd attempt; the later
        # touches keep their numbers, and the targets not touched yet come after.
        r = client.post("/api/capture/retake", json={"index": 1}, headers=A)
        assert r.status_code == 200, r.text
        state = client.get("/api/state").json()
        assert (state["guided"]["number"], state["guided"]["attempt"]) == (2, 2)
        assert "#2 again (2nd attempt)" in state["message"]
        client.post("/api/finger", json={"on": True}, headers=A)
        wait_for(client, lambda s: s["message"] == "calibration complete", "the rest")
        numbers = client.get("/api/session").json()["calibration"]["numbers"]
        later = [[k, 1] for k in range(3, n + 1)]
        assert numbers == [[1, 1], *later, [2, 2], *([k, 1] for k in range(n + 1, 7))]
        # A session opened again: the numbers are in the file, a retake goes on counting.
        client.post("/api/session/close", headers=A)
        client.post(f"/api/sessions/{sid}/open", headers=A)
        second = numbers.index([2, 2])
        r = client.post("/api/capture/retake", json={"index": second}, headers=A)
        assert r.status_code == 200, r.text
        state = client.get("/api/state").json()
        assert (state["guided"]["number"], state["guided"]["attempt"]) == (2, 3)
        client.post("/api/finger", json={"on": True}, headers=A)
        wait_for(client, lambda s: s["message"] == "calibration complete", "the 3rd attempt")
        rec = read_recording(tmp_path / sid / "calibration.h5")
        moved = [k for k, _ in numbers if k != 2]
        assert rec.meta["app"]["target_numbers"] == [*moved, 2]
        assert rec.meta["app"]["attempts"] == [1, 1, 1, 1, 1, 3]


def test_a_validation_belongs_to_the_model_it_scored(tmp_path):
    with make_client(tmp_path) as client:
        client.app.state.workspace.config.influence_suspects = 0
        new_session(client, n_points=8)
        calibrate(client)
        first = _train(client)
        r = client.post("/api/validate/start", json={"n_points": 3}, headers=A)
        assert r.status_code == 200, r.text
        state = wait_for(client, lambda s: s["session"]["validation"] is not None, "validation")
        assert state["session"]["validation"]["model_id"] == first["model_id"]
        # Trained again: no validation of the new model until it is validated.
        second = _train(client)
        assert second["model_id"] != first["model_id"]
        state = client.get("/api/state").json()
        assert state["session"]["validation"] is None
        assert state["session"]["validation_previous"]["earlier_model"]
        listed = client.get("/api/sessions").json()["sessions"][0]
        assert listed["validation"] is None
        # Validating again scores the new model in a new run (the old one kept).
        r = client.post("/api/validate/start", json={"n_points": 3}, headers=A)
        assert r.status_code == 200, r.text
        state = wait_for(client, lambda s: s["session"]["validation"] is not None, "again")
        assert state["session"]["validation"]["model_id"] == second["model_id"]
        assert state["session"]["validation"]["n"] == 3


@pytest.mark.parametrize("path", ["/api/live/start", "/api/validate/start"])
def test_live_and_validate_without_a_model_say_so(tmp_path, path):
    with make_client(tmp_path) as client:
        new_session(client, n_points=4)
        r = client.post(path, json={}, headers=A)
        assert r.status_code == 400 and "train a model first" in r.json()["detail"]
