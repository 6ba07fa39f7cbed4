"""recalibration_targets: which touches a later session is asked for."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.calibration.active import recalibration_targets
from skinloc.geometry.mesh import cone_skin, sample_targets, surface_points
from skinloc.models.response_map import ResponseMap


@pytest.fixture(scope="module")
def old_map() -> ResponseMap:
    mesh = cone_skin()
    rng = np.random.default_rng(0)
    pos = sample_targets(mesh, 30, "edge", rng)
    centres = sample_targets(mesh, 16, "edge", rng)
    # a smooth response per "sensor": a bump around its centre
    d = np.linalg.norm(pos[:, None, :] - centres[None, :, :], axis=2)
    F = np.exp(-0.5 * (d / 0.03) ** 2) + 0.01 * rng.normal(size=d.shape)
    return ResponseMap.fit(pos, F, surface_points(mesh, 600), prior=None)


@pytest.mark.parametrize("strategy", ["active", "random"])
def test_k_distinct_targets_of_the_pool(old_map, strategy):
    pool = old_map.candidates[::20]
    idx = recalibration_targets(old_map, 8, pool, strategy=strategy, random_state=3, n_eval=40)
    assert idx.shape == (8,)
    assert len(set(idx.tolist())) == 8
    assert ((idx >= 0) & (idx < len(pool))).all()
    # deterministic under a seed, and the seed matters
    again = recalibration_targets(old_map, 8, pool, strategy=strategy, random_state=3, n_eval=40)
    assert again.tolist() == idx.tolist()
    other = recalibration_targets(old_map, 8, pool, strategy=strategy, random_state=4, n_eval=40)
    assert other.tolist() != idx.tolist()


def test_default_pool_is_spread_surface_points_and_duplicates_count_once(old_map):
    idx = recalibration_targets(old_map, 5, n_eval=50)
    assert len(set(idx.tolist())) == 5 and idx.max() < 50
    pool = np.repeat(old_map.candidates[:6], 2, axis=0)  # every target twice: 6 distinct
    idx = recalibration_targets(old_map, 6, pool, n_eval=40)
    assert len({tuple(pool[i]) for i in idx}) == 6
    assert recalibration_targets(old_map, 0, pool).shape == (0,)


@pytest.mark.parametrize("k", [-1, 7, 2.5, True])
def test_bad_k_or_strategy_is_a_one_line_value_error(old_map, k):
    pool = old_map.candidates[:6]
    with pytest.raises(ValueError, match=r"^k must be an integer between 0 and 6") as e:
        recalibration_targets(old_map, k, pool)
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="strategy must be one of active, random"):
        recalibration_targets(old_map, 2, pool, strategy="even")


def test_random_needs_no_map_active_does(old_map):
    pool = old_map.candidates[:6]
    idx = recalibration_targets(None, 3, pool, strategy="random", random_state=2)
    assert (
        idx.tolist()
        == recalibration_targets(old_map, 3, pool, strategy="random", random_state=2).tolist()
    )
    with pytest.raises(ValueError, match="old_map is needed"):
        recalibration_targets(None, 3, pool)
