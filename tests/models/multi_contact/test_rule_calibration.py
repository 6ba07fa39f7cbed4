"""The count rule's misfit floor: the statistic, the kernel, the calibration, old rules."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skinloc.models.engine import load_engine
from skinloc.models.localizer import ContactLocalizer
from skinloc.models.multi_contact.contacts import CountRule
from skinloc.models.multi_contact.rule_calibration import (
    calibrate_count_rule,
    count_statistics,
    rule_statistics,
    search_statistics,
    single_misfit,
)
from skinloc.models.multi_contact.search import SearchTables, relative_gain
from tests._live import calibration, model_path


@pytest.fixture(scope="module")
def engine():
    return load_engine(model_path("map")).warm_up()


def _images():
    cal = calibration()
    X = cal.touch_means.astype(np.float32)
    n = len(X)
    pairs = [X[a] + X[b] for a in range(0, n // 2, 2) for b in range(n // 2, n, 2)]
    return np.concatenate([X, np.asarray(pairs, dtype=np.float32)])


def test_relative_gain_is_the_reduction_over_the_floored_residual():
    assert relative_gain(10.0, 4.0, 0.0) == pytest.approx(1.5)
    assert relative_gain(10.0, 4.0, 2.0) == pytest.approx(1.0)
    raw = np.array([[90.0, 96.0, 0.0, 12.0, 0.0, 100.0, 20.0]])  # g1, g2, g3, z2, z3, xx, zmax
    no_floor, floor = rule_statistics(raw, 0.0)[0], rule_statistics(raw, 0.06)[0]
    assert no_floor[0] == pytest.approx((10.0 - 4.0) / 4.0)  # the rule saved before it
    assert floor[0] == pytest.approx((10.0 - 4.0) / (4.0 + 6.0))
    assert no_floor[1] == -np.inf and no_floor[2] == 12.0  # no third contact found


def test_rules_saved_before_the_floor_load_with_none():
    old = {"z_on": 8.0, "tau2": 0.5, "tau3": 0.6, "z2_min": 12.0, "calibrated": True}
    rule = CountRule.from_dict(old)
    assert rule.misfit == 0.0 and rule.params()[7] == 0.0
    assert CountRule.from_dict(rule.as_dict()) == rule


def test_the_calibrated_rule_measures_the_misfit(engine):
    rule = engine.rule
    assert rule.calibrated and rule.z_power == 1.0
    # the default model's held-out touch means leave a few to a few tens of percent
    assert 0.005 < rule.misfit < 0.5


def test_single_misfit_is_the_median_share_one_contact_leaves():
    raw = np.zeros((4, 7))
    raw[:, 5] = 100.0
    raw[:, 0] = [95.0, 90.0, 80.0, 10.0]
    raw[:, 6] = [20.0, 20.0, 20.0, 2.0]  # the last is no contact at all: left out
    assert single_misfit(raw, 8.0) == pytest.approx(0.1)
    raw[:, 6] = 0.0
    assert single_misfit(raw, 8.0) == 0.0


def _tables(engine, rule):
    s = engine.spec
    return SearchTables(
        np.asarray(s.unit_table), s.surface_points, s.coarse, s.cells, s.sensor_noise, rule
    )


def test_the_kernel_counts_as_the_statistics_say(engine):
    """The compiled count and the calibration's statistic agree, floor and factor included."""
    t = engine.search_tables()
    images = _images()
    for misfit, z_power in ((0.0, 0.0), (engine.rule.misfit, 1.0), (0.3, 1.0), (0.05, 2.0)):
        rule = replace(engine.rule, misfit=misfit, z_power=z_power, z2_min=10.0)
        s = count_statistics(_tables(engine, rule), images, 2)
        # a threshold inside the statistic's range, so that both counts occur
        tau = float(np.median(s[np.isfinite(s[:, 0]) & (s[:, 2] >= 10.0), 0]))
        want = np.where(s[:, 4] < rule.z_on, 0, 1 + ((s[:, 0] >= tau) & (s[:, 2] >= 10.0)))
        assert {1, 2} <= set(want.tolist())
        engine._tables = _tables(engine, replace(rule, tau2=tau))
        try:
            got = np.array([len(engine.contacts(x, 2)) for x in images])
        finally:
            engine._tables = t
        np.testing.assert_array_equal(got, want)


def test_calibration_without_floor_and_factor_is_the_rule_before():
    model = ContactLocalizer.load(model_path("map"))
    m = model.map_
    coarse, cells = m.search_cells()
    cal = calibration()
    base = m.layers[0]
    args = (cal.touch_means, cal.targets, m.candidates, coarse, cells, base.length_scale_mm)
    old, rep_old = calibrate_count_rule(
        *args, base.noise, model.sensor_noise_, misfit_floor=False, z_power=0.0
    )
    new, rep_new = calibrate_count_rule(*args, base.noise, model.sensor_noise_)
    assert old.calibrated and new.calibrated
    assert old.misfit == 0.0 and old.z_power == 0.0 and rep_old["misfit"] == 0.0
    assert new.misfit > 0.0 and new.z_power == 1.0 and rep_new["misfit"] == new.misfit
    # the same searches: only the statistic differs, so the rules' thresholds do
    assert new.tau2 != old.tau2


def test_a_larger_floor_never_counts_more_contacts(engine):
    raw = search_statistics(engine.search_tables(), _images(), 3)
    rho = [rule_statistics(raw, m)[:, 0] for m in (0.0, 0.05, 0.2)]
    # a pair that explains more than one contact: the floor only shrinks its reduction
    found = np.isfinite(rho[0]) & (rho[0] >= 0)
    assert found.sum() > 20
    assert np.all(rho[1][found] <= rho[0][found] + 1e-12)
    assert np.all(rho[2][found] <= rho[1][found] + 1e-12)
