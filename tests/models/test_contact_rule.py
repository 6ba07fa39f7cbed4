"""The count rule's misfit floor: the statistic, the kernel, the calibration, old rules."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from skinloc.models.contact_calibration import (
    count_statistics,
    rule_statistics,
    search_statistics,
    single_misfit,
)
from skinloc.models.contact_search import SearchTables, relative_gain
from skinloc.models.engine import load_engine
from skinloc.models.multi_contact import CountRule
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
    assert rule.calibrated
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


def test_the_kernel_counts_as_the_statistics_say(engine):
    """The compiled count and the calibration's statistic agree, floor included."""
    t = engine.search_tables()
    images = _images()
    for misfit in (0.0, engine.rule.misfit, 0.3):
        rule = replace(engine.rule, misfit=misfit, tau2=0.4, z2_min=10.0)
        tables = SearchTables(
            np.asarray(engine.spec.unit_table),
            engine.spec.surface_points,
            engine.spec.coarse,
            engine.spec.cells,
            engine.spec.sensor_noise,
            rule,
        )
        s = count_statistics(tables, images, 2)
        want = np.where(s[:, 4] < rule.z_on, 0, 1 + ((s[:, 0] >= 0.4) & (s[:, 2] >= 10.0)))
        engine._tables = tables
        try:
            got = np.array([len(engine.contacts(x, 2)) for x in images])
        finally:
            engine._tables = t
        np.testing.assert_array_equal(got, want)


def test_a_larger_floor_never_counts_more_contacts(engine):
    raw = search_statistics(engine.search_tables(), _images(), 3)
    rho = [rule_statistics(raw, m)[:, 0] for m in (0.0, 0.05, 0.2)]
    # a pair that explains more than one contact: the floor only shrinks its reduction
    found = np.isfinite(rho[0]) & (rho[0] >= 0)
    assert found.sum() > 20
    assert np.all(rho[1][found] <= rho[0][found] + 1e-12)
    assert np.all(rho[2][found] <= rho[1][found] + 1e-12)
