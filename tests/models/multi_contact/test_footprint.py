"""The footprint cue: its features, its calibration, its place in the count rule and the model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from skinloc.models.multi_contact.contacts import CountRule
from skinloc.models.multi_contact.footprint import (
    FEATURES,
    N_FEATURES,
    calibrate_footprint,
    features_of,
    footprint_score,
)

GRID = 10  # 10 x 10 sensors, one pitch apart


def _blob(cx: float, cy: float, width: float = 0.9) -> np.ndarray:
    """A finger's whitened unit image at ``(cx, cy)`` (sensor pitches), ``(GRID * GRID,)``."""
    i, j = np.meshgrid(np.arange(GRID), np.arange(GRID), indexing="ij")
    return np.exp(-((i - cx) ** 2 + (j - cy) ** 2) / (2 * width**2)).reshape(-1)


def _features(z: np.ndarray, u: np.ndarray) -> dict[str, float]:
    return dict(zip(FEATURES, features_of(z[None], u[None])[0], strict=True))


def test_one_finger_matches_its_own_prediction_whatever_its_strength():
    rng = np.random.default_rng(0)
    u = _blob(4.5, 4.5)
    for strength in (30.0, 80.0):
        f = _features(strength * u + rng.standard_normal(u.shape), u)
        for name in ("total_over_peak", "participation", "lit", "flank_over_core"):
            assert abs(f[name]) < 0.25, (name, f[name])  # logs of ratios near 1
        assert f["misfit"] < 0.06 and f["outside"] < 0.05  # the noise alone
        assert f["peak"] == pytest.approx(np.log(strength * u.max()), abs=0.15)


def test_two_fingers_two_pitches_apart_are_wider_and_fuller_than_one():
    rng = np.random.default_rng(1)
    u = _blob(4.5, 4.5)  # the one-contact fit lands between the fingers
    one = 40.0 * u + rng.standard_normal(u.shape)
    two = 40.0 * (_blob(3.5, 4.5) + _blob(5.5, 4.5)) + rng.standard_normal(u.shape)
    f1, f2 = _features(one, u), _features(two, u)
    for name in ("total_over_peak", "lit", "flank_over_core", "misfit", "residual_outside_core"):
        assert f2[name] > f1[name] + 0.05, (name, f1[name], f2[name])
    assert f2["peak"] > f1["peak"]


def test_the_score_is_the_features_weighted_and_nan_without_signal():
    u = _blob(4.5, 4.5)
    z = 30.0 * u
    w = np.arange(1.0, N_FEATURES + 1)
    f = np.zeros(N_FEATURES)
    got = footprint_score(z.astype(np.float32), u.astype(np.float32), w, f)
    assert got == pytest.approx(float(features_of(z[None], u[None])[0] @ w))
    assert np.isnan(footprint_score(np.zeros(u.shape, np.float32), u.astype(np.float32), w, f))
    assert np.all(np.isnan(features_of(-z[None], u[None])))


def test_calibration_calls_at_most_two_percent_of_each_single_set_two():
    rng = np.random.default_rng(2)
    means = rng.standard_normal((400, N_FEATURES))
    frames = 1.5 * rng.standard_normal((500, N_FEATURES))
    pairs = rng.standard_normal((300, N_FEATURES)) + 3.0 * (np.arange(N_FEATURES) == 0)
    w, two, hold, rep = calibrate_footprint([means, frames], pairs)
    assert w.shape == (N_FEATURES,) and np.argmax(np.abs(w)) == 0  # the feature that differs
    assert hold <= two
    for s in (means, frames):
        assert np.mean(s @ w >= two) <= 0.02
        assert np.mean(s @ w >= hold) <= 0.05 + 1e-9
    assert rep["single_called_two"] <= 0.02 and rep["pairs_found"] > 0.3
    assert rep["pairs_found"] == pytest.approx(np.mean(pairs @ w >= two))


def test_too_few_sets_turn_the_cue_off():
    rng = np.random.default_rng(3)
    w, two, hold, rep = calibrate_footprint(
        [rng.standard_normal((300, N_FEATURES))], rng.standard_normal((10, N_FEATURES))
    )
    assert w.size == 0 and two == 0.0 and hold == 0.0 and rep["pairs"] == 10


def test_the_rule_keeps_the_cue_through_json_and_older_rules_load_without_it():
    rule = CountRule(footprint_weights=(1.0, -2.0), footprint_two=3.5, footprint_hold=3.0)
    back = CountRule.from_dict(json.loads(json.dumps(rule.as_dict())))
    assert back == rule and back.footprint_on and isinstance(back.footprint_weights, tuple)
    old = {"z_on": 8.0, "tau2": 0.5, "calibrated": True, "landing_change": 4.0}
    assert not CountRule.from_dict(old).footprint_on
    hash(back)  # still a frozen, hashable rule


def test_fit_calibrates_and_saves_the_cue():
    from skinloc.models.localizer import ContactLocalizer
    from tests._live import model_path

    model = ContactLocalizer.load(model_path("map"))
    rule = CountRule.from_dict(model.contact_rule_)
    assert rule.footprint_on and len(rule.footprint_weights) == N_FEATURES
    assert rule.footprint_hold <= rule.footprint_two
    rep = model.contact_rule_["cv"]["footprint"]
    assert rep["single_called_two"] <= 0.02 + 1e-9 and rep["pairs"] >= 40
