"""Train-page evidence (issue 22, section 4): each touch's error from a model that did not see it.

Training stores ``touch_errors`` with its result: every kept touch's cross-validated error when
the influence check runs, else the held-out check's touches only; left-out touches never.
"""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.app.hub import Hub
from skinloc.app.workspace import AppConfig, Workspace
from skinloc.sources.base import SourceOptions
from tests._helpers import wait_until


def _trained(tmp_path, exclude=None, **config) -> dict:
    ws = Workspace(AppConfig(data_dir=tmp_path, finger_delay_s=0.05, **config), Hub())
    try:
        ws.connect(SourceOptions(source="sim", rate_hz=400.0, seed=3))
        ws.create_session("evidence", n_points=10, samples=10, baseline_frames=20)
        ws.set_finger(True)
        ws.start_calibration()
        wait_until(lambda: ws.message == "calibration complete", "calibration", 180, 0.05)
        ws.train(exclude)
        wait_until(lambda: not ws.training.get("running"), "training", 300, 0.05)
        result = ws.training.get("result")
        assert result is not None, ws.training
        assert ws.snapshot()["session"]["holdout"]["touch_errors"] == result["touch_errors"]
        return result
    finally:
        ws.shutdown()


def test_every_kept_touch_is_scored_by_cross_validation(tmp_path):
    h = _trained(tmp_path, exclude=[3])
    te = h["touch_errors"]
    assert te["how"].endswith("-fold cross-validation")
    assert te["index"] == [i for i in range(10) if i != 3]
    errors = np.asarray(te["error_mm"])
    assert errors.shape == (9,) and np.all(np.isfinite(errors)) and np.all(errors >= 0)
    assert np.mean(errors) == pytest.approx(h["influence"]["cv_mean_mm"], abs=0.02)


def test_without_the_cross_validation_the_held_out_touches_are_shown(tmp_path):
    h = _trained(tmp_path, influence_suspects=0)
    te = h["touch_errors"]
    assert te["how"] == "held out" and len(te["index"]) == h["n_test"] == 2
    assert np.mean(te["error_mm"]) == pytest.approx(h["mean_mm"], abs=0.02)
    assert set(te["index"]) <= set(range(10))
