"""Recalibration by cross-validation: keeps the old map when the new touches agree with it,
replaces it when it is badly off, keeps it with no touch; the blend of two maps."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.models.recalibration import (
    RecalibrationChoice,
    blend_maps,
    choose_recalibration,
)
from skinloc.models.response_map import ResponseMap

GRID = np.linspace(0.0, 0.1, 21)
CANDIDATES = np.array([[x, y, 0.0] for x in GRID for y in GRID])  # a 100 mm square, m


def _features(p: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Eight smooth bumps (30 mm wide) over the square, normalised like shape features."""
    d2 = ((p[:, None, :] - centres[None]) ** 2).sum(-1)
    F = np.exp(-d2 / (2 * 0.03**2))
    return F / np.linalg.norm(F, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def setting():
    rng = np.random.default_rng(0)
    centres = np.c_[rng.uniform(0, 0.1, (8, 2)), np.zeros(8)]
    old_touches = CANDIDATES[rng.choice(len(CANDIDATES), 40, replace=False)]
    old = ResponseMap.fit(old_touches, _features(old_touches, centres), CANDIDATES)
    new_touches = CANDIDATES[rng.choice(len(CANDIDATES), 12, replace=False)]
    return old, centres, new_touches


def test_new_touches_that_agree_with_the_old_map_keep_it(setting):
    old, _, _ = setting
    picks = np.arange(3, len(CANDIDATES), 37)[:12]
    q, F = CANDIDATES[picks], old.table[picks].astype(np.float64)  # just as the map says
    chosen, choice = choose_recalibration(old, q, F)
    assert choice.method == "old map" and chosen is old
    assert choice.n_touches == 12 and choice.n_folds == 5
    assert set(choice.cv_error_mm) >= {"old map", "old map + correction", "new touches alone"}
    assert "chose old map by 5-fold cross-validation over 12 new touches" in choice.summary()


def test_an_old_map_badly_off_is_replaced_by_the_new_touches(setting):
    old, centres, q = setting
    moved = centres[::-1]  # every feature now peaks where another did
    _, mixed = choose_recalibration(old, q, _features(q, moved))
    assert mixed.method in ("blend 0.75", "new touches alone")  # mostly the new map
    chosen, choice = choose_recalibration(old, q, _features(q, moved), blend_weights=())
    assert choice.method == "new touches alone" and "blend 0.5" not in choice.cv_error_mm
    cv = choice.cv_error_mm
    assert cv["old map"] > 3 * cv["new touches alone"]
    # the chosen map localises the later session far better than the old one
    test = CANDIDATES[::7]
    F = _features(test, moved)

    def err(m):
        return (1e3 * np.linalg.norm(m.nearest(F) - test, axis=1)).mean()

    assert err(chosen) < 0.5 * err(old)


def test_no_touch_or_one_keeps_the_old_map(setting):
    old, centres, q = setting
    for k in (0, 1):
        chosen, choice = choose_recalibration(old, q[:k], _features(q[:k], centres[::-1]))
        assert chosen is old and choice.method == "old map" and choice.cv_error_mm == {}
    assert "no new touch" in RecalibrationChoice("old map", 0).summary()
    meta = choice.as_meta()
    assert meta["method"] == "old map" and meta["n_touches"] == 1 and "summary" in meta


def test_a_blend_is_the_weighted_mean_of_the_two_maps(setting):
    old, centres, q = setting
    new = ResponseMap.fit(q, _features(q, centres[::-1]), CANDIDATES)
    mixed = blend_maps(old, new, 0.25)
    np.testing.assert_allclose(mixed.table, 0.75 * old.table + 0.25 * new.table, atol=1e-5)
    with pytest.raises(ValueError, match="w must be"):
        blend_maps(old, new, 1.5)


def test_features_of_the_wrong_shape_are_refused(setting):
    old, _, q = setting
    with pytest.raises(ValueError, match="F must have shape"):
        choose_recalibration(old, q, np.zeros((len(q), 3)))
