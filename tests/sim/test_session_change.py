"""The session-change model: sizes, determinism by seed, no change is the identity, bad sizes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from skinloc.sim.session_change import SESSION_CHANGES, SessionChange, later_session
from skinloc.sim.skin import SimulatedSkin, sensor_image


@pytest.fixture(scope="module")
def skin() -> SimulatedSkin:
    return SimulatedSkin(random_state=4)


def _moves_mm(a: SimulatedSkin, b: SimulatedSkin) -> np.ndarray:
    return 1e3 * np.linalg.norm(a.sensor_positions - b.sensor_positions, axis=1)


def test_no_change_is_the_same_skin(skin):
    later = later_session(skin, "none", seed=3)
    assert SessionChange.preset("none").is_identity
    assert later is not skin and later.layout is skin.layout
    assert later.params == skin.params
    point = skin.sensor_positions[10]
    np.testing.assert_allclose(
        sensor_image(later.layout, later.params, point, 1.0, 0.008),
        sensor_image(skin.layout, skin.params, point, 1.0, 0.008),
    )


def test_the_real_change_has_the_real_sizes(skin):
    change = SessionChange.preset("real")
    later = later_session(skin, change, seed=1)
    base = np.abs(later.layout.baselines_counts - skin.layout.baselines_counts)
    assert 200 < np.median(base) < 450  # 312 counts on the real skin
    log_gain = np.log(later.layout.gains / skin.layout.gains)
    outside = np.mean((log_gain < np.log(0.67)) | (log_gain > np.log(1.5)))
    assert 0.2 < outside < 0.8
    moves = _moves_mm(skin, later)
    assert 35 < np.median(moves) < 90  # each crossing's own move on top of the rigid one
    assert later.params.finger_radius_m == pytest.approx(0.9 * skin.params.finger_radius_m)
    assert later.params.silicone_thickness_m == pytest.approx(
        0.9 * skin.params.silicone_thickness_m
    )
    # the crossings stay on the shell
    dist = trimesh.proximity.closest_point(skin.mesh, later.sensor_positions)[1]
    assert dist.max() < 1e-6
    # the mild change is much smaller than the real one
    mild = later_session(skin, "mild", seed=1)
    assert np.median(_moves_mm(skin, mild)) < 10
    assert np.exp(np.std(np.log(mild.layout.gains / skin.layout.gains))) < 1.3


def test_a_rigid_move_alone_moves_every_crossing_alike(skin):
    change = SessionChange(rotation_deg=0.0, shift_mm=5.0)
    moves = _moves_mm(skin, later_session(skin, change, seed=2))
    assert np.median(moves) == pytest.approx(5.0, abs=1.5)
    np.testing.assert_allclose(later_session(skin, change, seed=2).layout.gains, skin.layout.gains)


def test_the_seed_decides_the_change(skin):
    a = later_session(skin, "real", seed=5)
    b = later_session(skin, "real", seed=5)
    c = later_session(skin, "real", seed=6)
    np.testing.assert_array_equal(a.layout.gains, b.layout.gains)
    np.testing.assert_array_equal(a.sensor_positions, b.sensor_positions)
    assert not np.allclose(a.layout.gains, c.layout.gains)
    # the first session's skin is left as it was
    assert np.array_equal(skin.layout.gains, SimulatedSkin(random_state=4).layout.gains)


def test_bad_sizes_and_names_are_refused_naming_them(skin):
    with pytest.raises(ValueError, match="displacement_mm"):
        SessionChange(displacement_mm=-1.0)
    with pytest.raises(ValueError, match="footprint_factor"):
        SessionChange(footprint_factor=0.0)
    with pytest.raises(ValueError, match="one of none, mild, real|one of real, mild, none"):
        SessionChange.preset("huge")
    with pytest.raises(ValueError, match="seed"):
        later_session(skin, "mild", seed=-1)
    assert set(SESSION_CHANGES) == {"none", "mild", "real"}
    assert dataclasses.replace(SESSION_CHANGES["real"]) == SessionChange.preset("real")
