"""The one recalibration entry point: the model, what was kept, before and after in mm."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.errors import RecordingError
from skinloc.evaluation.recalibration import FEW_TOUCHES, recalibrate
from skinloc.evaluation.scoring import evaluate, train_localizer
from tests.conftest import make_recording


@pytest.fixture(scope="module")
def old():
    return train_localizer([make_recording(12, 4, random_state=0)])


def test_a_later_session_is_recalibrated_and_reported(old):
    later = make_recording(6, 4, random_state=7)
    done = recalibrate(old, [later])
    r = done.report
    assert r.n_touches == 6 and r.method == done.model.recalibration_["method"]
    assert "cross-validation over 6 new touches" in r.summary
    # before: the old model untouched on the new touches, as `skinloc evaluate` scores it
    assert r.before_mm == pytest.approx(evaluate(old, [later]).stats.mean_mm)
    # after: the chosen candidate's cross-validated error, one of those it was chosen among
    assert r.after_mm == pytest.approx(r.cv_error_mm[r.method], abs=0.01)
    assert r.after_mm == min(r.cv_error_mm.values())
    assert 6 < FEW_TOUCHES and "6 touches only" in r.caveat
    text = "\n".join(r.lines())
    assert f"old model untouched {r.before_mm:.1f} mm" in text and "cross-validated" in text
    meta = done.model.training_meta_
    assert meta["report"] == r.as_dict() and meta["n_point_logs"] == 6
    assert done.model is not old


def test_a_baseline_capture_alone_keeps_the_model(old):
    capture = make_recording(2, 4, random_state=8).subset(np.array([], dtype=int))
    done = recalibrate(old, [capture])
    r = done.report
    assert r.n_touches == 0 and r.before_mm is None and r.after_mm is None
    assert r.method == "old map" and "no new touch" in r.caveat
    X = make_recording(4, 4, random_state=9).touch_means
    np.testing.assert_allclose(done.model.predict(X), old.predict(X))


def test_a_session_of_another_skin_is_refused(old):
    with pytest.raises(RecordingError, match="16 sensors"):
        recalibrate(old, [make_recording(3, 3, n_tx=4, n_rx=4)])
    with pytest.raises(RecordingError, match="no recordings"):
        recalibrate(old, [])
