"""The response map's prior (skinloc.models.map_prior) and its use by the default model."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from skinloc.models.localizer import ContactLocalizer
from skinloc.models.map_prior import PRIOR_FORMAT_VERSION, MapPrior, load_prior
from skinloc.models.response_map import ResponseMap, fit_gp


@pytest.fixture(scope="module")
def prior() -> MapPrior:
    return load_prior()


def test_the_package_prior_is_small_versioned_and_says_how_it_was_built(prior):
    from importlib import resources

    text = resources.files("skinloc.models").joinpath("map_prior.json").read_text()
    assert len(text) < 4096
    assert prior.version == PRIOR_FORMAT_VERSION
    assert prior.provenance["command"].startswith("skinloc prior build")
    assert prior.provenance["skins"] >= 10
    # a footprint-sized length scale, as on the real skin (20-26 mm by maximum likelihood)
    assert 10.0 < prior.typical["length_scale_mm"] < 50.0
    # max_touches is the build's own measure: the most touches up to which the prior lowered
    # the simulated error at every size of its curve (and it does help somewhere)
    curve = prior.provenance["simulated_error_mm"]
    sizes = sorted(int(n) for n in curve["none"])
    helps = 0
    for n in sizes:
        if curve["prior"][str(n)] >= curve["none"][str(n)]:
            break
        helps = n
    assert prior.max_touches == helps > 0, curve


def test_the_package_prior_lowers_the_error_of_a_small_calibration(prior):
    """The prior's values, not only its bookkeeping: on 12 simulated skins it was not built on,
    a 5-touch map with the shipped prior places held-out touches better than one without, and
    better than the same prior with a wrong length scale or noise level."""
    from skinloc.geometry.mesh import cone_skin, farthest_point_sampling, surface_points
    from skinloc.models.response_map import shape_features
    from skinloc.sim.prior_build import errors_mm, simulate_calibration

    a, ell, noise = prior.log_mean
    priors = {
        "none": None,
        "shipped": prior,
        "short": dataclasses.replace(prior, log_mean=(a, ell - 1.0, noise)),
        "noisy": dataclasses.replace(prior, log_mean=(a, ell, noise + 3.0)),
    }
    cands = surface_points(cone_skin(), 2000)
    mm: dict[str, list[float]] = {key: [] for key in priors}
    for seed in range(5000, 5012):  # the build's skins are seeds 1000-1063
        y, means = simulate_calibration(seed, 40)
        F = shape_features(means)
        pool, test = np.arange(20), np.arange(20, 40)
        idx = pool[farthest_point_sampling(y[pool], 5, 0)]
        for key, p in priors.items():
            rmap = ResponseMap.fit(y[idx], F[idx], cands, prior=p)
            mm[key].append(float(errors_mm(rmap, F[test], y[test]).mean()))
    mean = {key: float(np.mean(v)) for key, v in mm.items()}
    # measured: none 42.6, shipped 35.1, short 45.6, noisy 38.5 mm
    assert mean["shipped"] < 0.92 * mean["none"], mean
    assert mean["shipped"] < min(mean["short"], mean["noisy"]), mean


def test_save_and_load_round_trip(prior, tmp_path):
    path = tmp_path / "p.json"
    prior.save(path)
    again = load_prior(path)
    assert again.max_touches == prior.max_touches
    np.testing.assert_allclose(again.log_mean, prior.log_mean)
    np.testing.assert_allclose(again.log_std, prior.log_std)


@pytest.mark.parametrize(
    "content,match",
    [
        ("not json", "cannot read"),
        ('{"version": 99}', "version 99"),
        ('{"version": 1}', "cannot read"),
        ("[1]", "cannot read"),
    ],
)
def test_a_bad_prior_file_is_one_line(tmp_path, content, match):
    path = tmp_path / "p.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=match) as info:
        load_prior(path)
    assert "\n" not in str(info.value)


def test_bad_values_are_refused(prior):
    with pytest.raises(ValueError):
        dataclasses.replace(prior, log_std=(0.1, 0.0, 0.1))
    with pytest.raises(ValueError):
        dataclasses.replace(prior, mean_pseudo_touches=-1.0)


def test_the_mean_is_shrunk_towards_the_common_level(prior):
    F = np.zeros((3, 64))
    F[:, 0] = 1.0
    m = prior.mean(F)
    w = prior.mean_pseudo_touches
    assert m[0] == pytest.approx((3 + w * prior.common_feature) / (3 + w))
    assert m[1] == pytest.approx(w * prior.common_feature / (3 + w))
    many = np.repeat(F, 1000, axis=0)
    assert prior.mean(many)[0] == pytest.approx(1.0, abs=0.01)


def _bumps(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` touches on a plane (m) and noisy unit-norm features of 16 Gaussian bumps."""
    rng = np.random.default_rng(seed)
    pts = np.c_[rng.uniform(0, 0.1, (n, 2)), np.zeros(n)]
    sensors = np.c_[rng.uniform(0, 0.1, (16, 2)), np.zeros(16)]
    d2 = ((pts[:, None] - sensors[None]) ** 2).sum(-1)
    F = np.exp(-0.5 * d2 / 0.015**2) + 0.02 * rng.standard_normal((n, 16))
    return pts, F / np.linalg.norm(F, axis=1, keepdims=True)


def test_a_posteriori_hyperparameters_stay_near_the_prior_with_few_touches(prior):
    pts, F = _bumps(5, 0)
    R = F - F.mean(axis=0)
    ml = fit_gp(1e3 * pts, R, 20.0, (2.0, 300.0), None).kernel_.theta
    mp = fit_gp(1e3 * pts, R, 20.0, (2.0, 300.0), None, prior).kernel_.theta
    z_ml = np.abs(ml - prior.log_mean) / prior.log_std
    z_mp = np.abs(mp - prior.log_mean) / prior.log_std
    assert z_mp.sum() < z_ml.sum()
    # and the map is the usual one: a posterior mean through the touches
    rmap = ResponseMap.fit(pts, F, pts, prior=prior)
    assert np.abs(rmap.table - F).max() < 0.5


def test_many_touches_outweigh_the_prior(prior):
    pts, F = _bumps(150, 1)
    R = F - F.mean(axis=0)
    ml = fit_gp(1e3 * pts, R, 20.0, (2.0, 300.0), None).kernel_.theta
    mp = fit_gp(1e3 * pts, R, 20.0, (2.0, 300.0), None, prior).kernel_.theta
    # the length scale: from the data's (15 mm bumps), not pinned to the prior's
    assert abs(mp[1] - ml[1]) < abs(prior.log_mean[1] - ml[1])


def _fit(n: int, **kw) -> ContactLocalizer:
    from skinloc.geometry.mesh import cone_skin, sample_targets, surface_points

    mesh = cone_skin()
    y = sample_targets(mesh, n, "even", random_state=0)
    rng = np.random.default_rng(0)
    X = 5.0 * rng.standard_normal((n, 64))
    X[np.arange(n), rng.integers(64, size=n)] += 150.0
    return ContactLocalizer(**kw).fit(X, y, surface_points=surface_points(mesh, 2000))


def test_the_default_uses_the_prior_only_where_it_helps(prior):
    if prior.max_touches >= 4:
        assert _fit(4).prior_used_
    assert not _fit(prior.max_touches + 1).prior_used_
    assert not _fit(4, prior="none").prior_used_
    assert ContactLocalizer().get_config()["prior"] == "package"


def test_a_prior_file_and_a_bad_one(prior, tmp_path):
    path = tmp_path / "p.json"
    dataclasses.replace(prior, max_touches=1000).save(path)
    assert _fit(30, prior=str(path)).prior_used_
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"version": 1}))
    with pytest.raises(ValueError, match="cannot read"):
        _fit(4, prior=str(bad))
