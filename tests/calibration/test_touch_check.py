"""The off-target check on the square-root map (``touch_check.off_target``, ``LeaveOneOutMap``)."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.calibration.touch_check import off_target
from skinloc.data.recording import read_recording
from skinloc.evaluation.influence import LeaveOneOutMap
from skinloc.geometry.mesh import load_mesh, surface_points
from skinloc.models.response_map import shape_features


def moved(targets: np.ndarray, surface: np.ndarray, j: int, d_mm: float) -> np.ndarray:
    """``targets`` with target ``j`` replaced by the surface point nearest ``d_mm`` from it."""
    dist = 1e3 * np.linalg.norm(surface - targets[j], axis=1)
    out = targets.copy()
    out[j] = surface[int(np.argmin(np.abs(dist - d_mm)))]
    return out


@pytest.fixture(scope="module")
def real_20(real_dir):
    """One of the recordings the check was chosen on (20 touches) and its surface points."""
    rec = read_recording(real_dir / "ConeSkinData_RND_20PL_1.mat")
    return rec, surface_points(load_mesh(real_dir / "Color_Cone.obj"), 2000)


def test_each_target_of_a_real_20_touch_session_moved_80mm_is_flagged(real_20):
    rec, surface = real_20
    # the clean session flags nothing (the raw-image map flagged touch 13)
    assert not off_target(rec.targets, rec.touch_means, surface).flags.any()
    # each target moved 80 mm along the surface in turn: 19 of 20 flagged, 18 alone (the
    # raw-image map with the previous thresholds: 16, and a good touch with 2 of them)
    hit = alone = 0
    for j in range(rec.n_point_logs):
        flags = off_target(moved(rec.targets, surface, j, 80.0), rec.touch_means, surface).flags
        hit += bool(flags[j])
        alone += bool(flags[j] and flags.sum() == 1)
    assert hit >= 18 and alone >= 17, (hit, alone)


def test_the_previous_check_is_one_call_away(real_20):
    # power 1, k 2.5, 20 mm: the check of bench/results/off_target_eval-2026-11-29
    rec, surface = real_20
    old = off_target(rec.targets, rec.touch_means, surface, power=1.0, k=2.5, floor_mm=20.0)
    assert np.flatnonzero(old.flags).tolist() == [13]


def test_the_map_takes_the_square_root_of_the_positive_counts():
    rng = np.random.default_rng(0)
    q = rng.uniform(-0.05, 0.05, (12, 3))
    X = rng.normal(0.0, 5.0, (12, 16))
    X[:, :3] += 200.0
    raw = LeaveOneOutMap.fit(q, X)
    assert np.allclose(raw.F, shape_features(X))
    root = LeaveOneOutMap.fit(q, X, power=0.5)
    assert np.allclose(root.F, shape_features(np.sqrt(np.maximum(X, 0.0))))
    assert np.all(np.isfinite(root.residuals()))


@pytest.mark.parametrize("power", [0.0, -0.5, 1.5, float("nan")])
def test_a_power_outside_0_1_is_refused(power):
    q = np.zeros((8, 3))
    with pytest.raises(ValueError, match="power"):
        LeaveOneOutMap.fit(q, np.ones((8, 4)), power=power)
    with pytest.raises(ValueError, match="power"):
        off_target(q, np.ones((8, 4)), np.zeros((5, 3)), power=power)
