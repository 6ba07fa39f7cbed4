"""Which touch hurts the cross-validated error most (``skinloc.evaluation.influence``)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from skinloc.calibration.session import SessionConfig, simulate_session
from skinloc.evaluation.influence import touch_influence
from skinloc.geometry.mesh import cone_skin
from skinloc.sim.skin import SimulatedSkin


class NearestImages:
    """A small stand-in localiser: the mean target of the 3 most alike training images."""

    def __init__(self, rec) -> None:
        Z = np.maximum(rec.touch_means, 0.0)
        self.Z = Z / np.linalg.norm(Z, axis=1, keepdims=True)
        self.y = rec.targets
        self.n_features_in_ = rec.n_sensors

    def predict_full(self, X: np.ndarray) -> SimpleNamespace:
        Z = np.maximum(X, 0.0)
        Z = Z / np.linalg.norm(Z, axis=1, keepdims=True)
        near = np.argsort(-(Z @ self.Z.T), axis=1)[:, :3]
        return SimpleNamespace(
            points=self.y[near].mean(axis=1), uncertainty_mm=1.0 + np.arange(len(X))
        )


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    mesh = cone_skin()
    path = tmp_path_factory.mktemp("infl") / "s.h5"
    rec = simulate_session(
        SimulatedSkin(mesh, random_state=1),
        mesh,
        path,
        SessionConfig(n_points=24, samples_per_touch=5),
    )
    return rec


def test_a_mislabelled_touch_hurts_most_and_a_good_one_does_not(recording):
    rec = recording.subset(slice(None))
    far = int(np.argmax(np.linalg.norm(rec.targets - rec.targets[5], axis=1)))
    rec.targets = rec.targets.copy()
    rec.targets[5] = rec.targets[far]  # touch 5 recorded under another target's label
    calls = []
    out = touch_influence(
        rec, NearestImages, suspects=[11], max_suspects=3, progress=lambda d, t: calls.append(d)
    )
    by_index = {s["index"]: s for s in out.suspects}
    assert out.suspects[0]["index"] == 5 and out.suspects[0]["gain_mm"] > 1.0
    assert 11 in by_index  # asked for, examined whatever its error
    assert by_index[11]["gain_mm"] < out.suspects[0]["gain_mm"]
    assert out.errors_mm.shape == (24,) and np.isfinite(out.errors_mm).all()
    assert calls == list(range(1, len(calls) + 1)) and len(calls) == out.n_folds + 3 * (
        out.n_folds - 1
    )
    d = out.as_dict()
    assert d["cv_mean_mm"] == pytest.approx(out.errors_mm.mean(), abs=0.01)
