"""Train-page evidence (issue 22, section 4): each touch's error from a model that did not see it.

Training stores ``touch_errors`` with its result: every kept touch's cross-validated error and
its number (with or without the influence check); left-out touches never.
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


def test_without_the_influence_check_every_touch_is_still_cross_validated(tmp_path):
    # Never a figure from a few held-out touches: the error is over every kept touch.
    h = _trained(tmp_path, influence_suspects=0)
    te = h["touch_errors"]
    assert te["how"] == h["how"] == f"{h['n_folds']}-fold cross-validation"
    assert te["index"] == list(range(10)) and te["number"] == list(range(1, 11))
    assert np.mean(te["error_mm"]) == pytest.approx(h["mean_mm"], abs=0.02)
    low, high = h["ci95_mm"]
    assert low < h["mean_mm"] < high and "n_test" not in h
