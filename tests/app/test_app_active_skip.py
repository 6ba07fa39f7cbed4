"""An active session's next target after a skip: chosen from the touches, never the plan's."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("fastapi")
pytest.importorskip("httpx")

from skinloc.calibration.active import N_START  # noqa: E402
from skinloc.calibration.session import CalibrationSession  # noqa: E402
from skinloc.data.recording import read_recording  # noqa: E402
from skinloc.geometry.mesh import cone_skin  # noqa: E402
from skinloc.sim.skin import SimulatedSkin  # noqa: E402
from tests.app.test_app_api import A, calibrate, make_client, new_session, wait_for  # noqa: E402


def _expected_next(path, n: int) -> np.ndarray:
    """What the active strategy asks for touch ``n`` given the file's touches and skips."""
    rec = read_recording(path)
    with SimulatedSkin(cone_skin(), random_state=3) as skin:
        sess = CalibrationSession.resume(skin, path)
        sess.skipped = np.asarray(rec.meta["app"]["skipped"]).reshape(-1, 3)
        return sess.target_for(n)


def test_after_a_skip_the_next_target_is_chosen_from_the_touches(tmp_path):
    with make_client(tmp_path) as client:
        # room for two skips after a scripted finger that may press a touch or two past `until`
        sid = new_session(client, n_points=10, mode="active")
        plan = np.asarray(client.get("/api/session").json()["calibration"]["planned"])
        calibrate(client, until=N_START + 1)
        path = tmp_path / sid / "calibration.h5"
        assert client.post("/api/finger", json={"on": False}, headers=A).status_code == 200
        assert client.post("/api/calibrate/start", headers=A).status_code == 200
        state = wait_for(client, lambda s: s["guided"] is not None, "guided capture")
        n = state["guided"]["index"]
        assert n >= N_START + 1
        skipped = np.asarray(state["guided"]["target"])

        assert client.post("/api/capture/skip", headers=A).status_code == 200
        state = client.get("/api/state").json()
        assert state["guided"]["index"] == n
        after = np.asarray(state["guided"]["target"])
        # Not what the even plan had left next (the bug), nor the skipped target again.
        left_over = plan[n + 1]
        assert np.linalg.norm(after - left_over) > 1e-6
        assert np.linalg.norm(after - skipped) > 1e-6
        np.testing.assert_allclose(after, _expected_next(path, n), atol=1e-9)
        rec = read_recording(path)
        assert len(rec.planned_targets) == 9
        np.testing.assert_allclose(rec.planned_targets[n], after, atol=1e-9)
        np.testing.assert_allclose(rec.meta["app"]["skipped"][0], skipped)

        # A second skip in a row leaves out both skipped targets.
        assert client.post("/api/capture/skip", headers=A).status_code == 200
        again = np.asarray(client.get("/api/state").json()["guided"]["target"])
        assert min(np.linalg.norm(again - after), np.linalg.norm(again - skipped)) > 1e-6
        np.testing.assert_allclose(again, _expected_next(path, n), atol=1e-9)

        # Reopened, the session asks the same (it knows what was skipped).
        assert client.post("/api/session/close", headers=A).status_code == 200
        assert client.post(f"/api/sessions/{sid}/open", headers=A).status_code == 200
        assert client.post("/api/calibrate/start", headers=A).status_code == 200
        state = wait_for(client, lambda s: s["guided"] is not None, "the resumed calibration")
        np.testing.assert_allclose(state["guided"]["target"], again, atol=1e-9)
