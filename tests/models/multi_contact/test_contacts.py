"""Multi-contact localisation: Engine.contacts, the amplitude map, the count rule, the file."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import nnls

from skinloc.models.engine import load_engine
from skinloc.models.localizer import ContactLocalizer
from skinloc.models.multi_contact.contacts import ContactSet, CountRule, noise_weights
from skinloc.models.multi_contact.rule_calibration import (
    calibrate_count_rule,
    choose_thresholds,
    sensor_noise_from_frames,
)
from skinloc.models.multi_contact.search import nnls as search_nnls
from tests._live import calibration, model_path

GOLDEN = Path(__file__).parents[2] / "golden"


@pytest.fixture(scope="module")
def engine():
    return load_engine(model_path("map"))


@pytest.fixture(scope="module")
def touches():
    cal = calibration()
    return cal.touch_means.astype(np.float32), cal.targets


def _far_pairs(targets, min_mm):
    return [
        (a, b)
        for a, b in itertools.combinations(range(len(targets)), 2)
        if 1e3 * np.linalg.norm(targets[a] - targets[b]) > min_mm
    ]


def _errors_mm(cs: ContactSet, true: np.ndarray) -> np.ndarray:
    from scipy.optimize import linear_sum_assignment

    D = 1e3 * np.linalg.norm(cs.positions_m[:, None] - true[None], axis=2)
    r, c = linear_sum_assignment(D)
    return D[r, c]


def test_two_fingers_far_apart_are_two_contacts_where_they_touch(engine, touches):
    X, y = touches
    pairs = _far_pairs(y, 60.0)
    assert len(pairs) > 50
    counts, good = [], []
    for a, b in pairs:
        cs = engine.contacts(X[a] + X[b], 3)
        counts.append(len(cs))
        good.append(len(cs) == 2 and np.all(_errors_mm(cs, y[[a, b]]) <= 15.0))
        assert np.all(np.diff(cs.strength) <= 0)  # strongest first
        assert np.all(cs.strength > 0) and np.all(np.isfinite(cs.uncertainty_mm))
    assert np.mean(np.array(counts) == 2) >= 0.9
    assert np.mean(good) >= 0.8


def test_single_touches_are_one_contact(engine, touches):
    X, y = touches
    counts = [len(engine.contacts(x, 3)) for x in X]
    assert np.mean(np.array(counts) == 1) >= 0.9


def test_max_contacts_caps_the_count(engine, touches):
    X, y = touches
    a, b = _far_pairs(y, 60.0)[0]
    assert len(engine.contacts(X[a] + X[b], 1)) == 1
    assert len(engine.contacts(X[a] + X[b], 2)) <= 2


def test_one_contact_is_todays_single_contact_answer(engine, touches):
    X, _ = touches
    for x in X[:10]:
        cs = engine.contacts(x, 1)
        point, _, spread = engine.predict_one(x)
        np.testing.assert_array_equal(cs.positions_m[0], point)
        assert np.isclose(cs.uncertainty_mm[0], spread)
        assert np.isclose(cs.strength[0], np.linalg.norm(np.maximum(x, 0)), rtol=1e-5)


def test_nothing_touching_is_no_contact(engine):
    rng = np.random.default_rng(0)
    assert len(engine.contacts(np.zeros(64, np.float32), 3)) == 0
    noise = (5.0 * rng.standard_normal((50, 64))).astype(np.float32)
    assert all(len(engine.contacts(x, 3)) == 0 for x in noise)
    cs = engine.contacts(np.zeros(64, np.float32), 3)
    assert cs.positions_m.shape == (0, 3) and cs.to_json() == []


def test_contacts_refuses_bad_input(engine):
    with pytest.raises(ValueError, match="shape \\(64,\\)"):
        engine.contacts(np.zeros(63, np.float32))
    with pytest.raises(ValueError, match="max_contacts"):
        engine.contacts(np.zeros(64, np.float32), 0)
    with pytest.raises(ValueError, match="max_contacts"):
        engine.contacts(np.zeros(64, np.float32), 4)
    # float64 and lists are converted, not refused
    assert len(engine.contacts([0.0] * 64)) == 0


def test_a_network_reports_at_most_one_contact(touches):
    X, y = touches
    net = load_engine(model_path("mlp"))
    a, b = _far_pairs(y, 60.0)[0]
    cs = net.contacts(X[a] + X[b], 3)
    assert len(cs) == 1
    point, _, _ = net.predict_one(X[a] + X[b])
    np.testing.assert_array_equal(cs.positions_m[0], point)
    assert len(net.contacts(np.zeros(64, np.float32), 3)) == 0


def test_the_model_file_keeps_the_amplitude_map_and_the_rule(tmp_path, touches):
    model = ContactLocalizer.load(model_path("map"))
    assert model.map_.amplitude is not None
    rule = CountRule.from_dict(model.contact_rule_)
    assert rule.calibrated and model.contact_rule_["cv"]["calibrated"]
    assert model.sensor_noise_.shape == (64,)
    model.save(tmp_path / "again.h5")
    again = ContactLocalizer.load(tmp_path / "again.h5")
    X, y = touches
    a, b = _far_pairs(y, 60.0)[0]
    for x in (X[a], X[a] + X[b]):
        one, two = model.engine().contacts(x), again.engine().contacts(x)
        np.testing.assert_array_equal(one.positions_m, two.positions_m)
        np.testing.assert_allclose(one.strength, two.strength)


def test_model_files_written_by_main_give_contacts():
    model = ContactLocalizer.load(GOLDEN / "model_main_default.h5")
    assert model.map_.amplitude is None and model.contact_rule_ is None
    engine = model.engine().warm_up()
    assert engine.rule == CountRule()  # the defaults
    frames = np.load(GOLDEN / "model_main_predictions.npz")["frames"].astype(np.float32)
    for x in frames[:20]:
        cs = engine.contacts(x, 3)
        assert 0 <= len(cs) <= 3
        one = engine.contacts(x, 1)
        if len(one):
            np.testing.assert_array_equal(one.positions_m[0], engine.predict_one(x)[0])


def test_nnls_kernel_is_scipys_nnls():
    rng = np.random.default_rng(1)
    s = np.zeros(3)
    for _ in range(300):
        m = int(rng.integers(1, 4))
        A = rng.random((20, m)) + 0.2 * rng.standard_normal((20, m))
        b = A @ rng.standard_normal(m) + 0.3 * rng.standard_normal(20)
        G, ab = A.T @ A, A.T @ b
        gain = search_nnls(G, ab, m, s)
        ref, rnorm = nnls(A, b)
        np.testing.assert_allclose(gain, b @ b - rnorm**2, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(s[:m], ref, atol=1e-6)


def test_sensor_noise_is_the_frames_scatter_away_from_the_finger():
    rng = np.random.default_rng(2)
    sigma = np.linspace(3.0, 9.0, 64)
    X = sigma * rng.standard_normal((30 * 20, 64))
    groups = np.repeat(np.arange(30), 20)
    X[groups == 0, 5] += 80 * rng.random(20)  # a finger pressing harder and softer
    noise = sensor_noise_from_frames(X, groups)
    np.testing.assert_allclose(noise, sigma, rtol=0.15)
    assert sensor_noise_from_frames(X, None) is None
    assert sensor_noise_from_frames(X[:3], np.arange(3)) is None  # one frame per touch


def test_noise_weights_floor_quiet_sensors_and_check_the_shape():
    w = noise_weights(np.array([1.0, 5.0, 5.0, 50.0]), 4)
    np.testing.assert_allclose(w, [0.2, 0.2, 0.2, 0.02])
    with pytest.raises(ValueError, match="shape \\(4,\\)"):
        noise_weights(np.ones(3), 4)


def test_few_point_logs_keep_the_default_rule():
    model = ContactLocalizer.load(model_path("map"))
    m = model.map_
    coarse, cells = m.search_cells()
    X = calibration().touch_means[:6]
    rule, report = calibrate_count_rule(
        X, calibration().targets[:6], m.candidates, coarse, cells, 20.0, 1e-3, None
    )
    assert rule == CountRule() and report["calibrated"] is False


def test_thresholds_keep_the_false_rate_on_every_negative_set():
    rng = np.random.default_rng(3)
    neg_a = np.column_stack([rng.random(400), 8 + 10 * rng.random(400)])
    neg_b = np.column_stack([2 * rng.random(400), 8 + 4 * rng.random(400)])
    pos = np.column_stack([1.5 + rng.random(400), 8 + 20 * rng.random(400)])
    z, tau, det, false = choose_thresholds([neg_a, neg_b], pos, 8.0, 0.02)
    for v in (neg_a, neg_b):
        assert np.mean((v[:, 0] >= tau) & (v[:, 1] >= z)) <= 0.02
    assert det > 0.5 and false <= 0.02


def test_contact_set_json():
    rows = np.array([[0.1, 0.2, 0.3, 120.0, 4.5], [0.0, 0.0, 0.1, 50.0, np.nan]])
    cs = ContactSet(rows)
    assert len(cs) == 2
    assert cs.to_json() == [
        {"position_m": [0.1, 0.2, 0.3], "uncertainty_mm": 4.5, "strength": 120.0},
        {"position_m": [0.0, 0.0, 0.1], "uncertainty_mm": None, "strength": 50.0},
    ]


def test_each_of_two_contacts_has_a_single_contacts_uncertainty(engine, touches):
    # each finger of a pair is placed by the single-contact match on its own image, and
    # reports that match's spread: the same scale as a finger alone
    X, y = touches
    alone = np.median([engine.predict_one(x)[2] for x in X])
    two = [
        u
        for a, b in _far_pairs(y, 60.0)
        for cs in [engine.contacts(X[a] + X[b], 2)]
        if len(cs) == 2
        for u in cs.uncertainty_mm
    ]
    assert 1 / 2.5 < np.median(two) / alone < 2.5
