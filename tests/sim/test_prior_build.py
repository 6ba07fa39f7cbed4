"""Building the map prior from simulated skins (skinloc.sim.prior_build)."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.sim.prior_build import build_prior, simulate_calibration


def test_a_skin_follows_its_seed_alone():
    a_t, a_x = simulate_calibration(7, 5)
    b_t, b_x = simulate_calibration(7, 5)
    np.testing.assert_allclose(a_t, b_t)
    np.testing.assert_allclose(a_x, b_x)
    c_t, c_x = simulate_calibration(8, 5)
    assert not np.allclose(a_x, c_x)
    assert a_x.shape == (5, 64) and a_t.shape == (5, 3)
    assert np.all(a_x.max(axis=1) > 20.0)  # every touch is felt


@pytest.fixture(scope="module")
def small():
    return build_prior(n_skins=2, n_eval_skins=1, n_touches=40, n_jobs=1)


def test_a_small_build(small):
    p = small.prior
    assert p.provenance["skins"] == 3
    assert p.provenance["command"] == (
        "skinloc prior build --skins 2 --eval-skins 1 --touches 40 --seed 1000"
    )
    assert set(small.curve) == {"none", "prior"}
    assert list(small.curve["none"]) == [5, 10, 15, 20]  # 40 touches: 20 pool, 20 test
    assert p.max_touches in (0, 5, 10, 15, 20)
    assert small.skins_per_minute > 0
    assert all(np.isfinite(v) for v in small.by_candidate.values())


@pytest.mark.slow  # a second build
def test_the_same_build_on_another_joblib_backend(small):
    from joblib import parallel_config

    with parallel_config(backend="threading"):
        again = build_prior(n_skins=2, n_eval_skins=1, n_touches=40, n_jobs=2)
    np.testing.assert_allclose(again.prior.log_mean, small.prior.log_mean, rtol=1e-6)
    assert again.prior.max_touches == small.prior.max_touches


def test_too_small_a_build_is_refused():
    with pytest.raises(ValueError, match="at least"):
        build_prior(n_skins=1)


def test_active_scores_are_made_with_the_prior_where_it_applies():
    from skinloc.calibration.active import active_scores
    from skinloc.geometry.mesh import cone_skin, surface_points

    targets, means = simulate_calibration(3, 14)
    cands = surface_points(cone_skin(), 1500)
    args = (targets[:6], means[:6], targets[6:], cands[::10], cands)
    with_prior = active_scores(*args)
    without = active_scores(*args, prior="none")
    assert with_prior.shape == without.shape == (8,)
    assert np.all(np.isfinite(with_prior)) and not np.allclose(with_prior, without)


def test_the_shipped_prior_was_built_by_the_documented_defaults():
    import inspect

    from skinloc.models.map_prior import load_prior

    d = {k: p.default for k, p in inspect.signature(build_prior).parameters.items()}
    want = (
        f"skinloc prior build --skins {d['n_skins']} --eval-skins {d['n_eval_skins']} "
        f"--touches {d['n_touches']} --seed {d['seed']}"
    )
    assert load_prior().provenance["command"] == want
