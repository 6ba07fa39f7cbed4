"""The landing change: one finger keeps its image's shape, a second finger landing does not."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.models.multi_contact.landing import calibrate_landing, frame_change, touch_change

N = 64  # sensors on a line, 1 noise level each


def blob(centre: float, strength: float = 60.0) -> np.ndarray:
    return strength * np.exp(-0.5 * ((np.arange(N) - centre) / 2.0) ** 2)


def test_one_finger_changes_by_the_noise_alone_whatever_its_strength():
    rng = np.random.default_rng(0)
    e = [
        frame_change(a * blob(20) + rng.standard_normal(N), blob(20) + rng.standard_normal(N))
        for a in rng.uniform(0.3, 3.0, 400)
    ]
    assert 0.8 < np.median(e) < 1.2 and max(e) < 1.7


def test_a_second_finger_landing_changes_the_shape():
    rng = np.random.default_rng(1)
    before = blob(20) + rng.standard_normal(N)
    after = blob(20) + 0.5 * blob(24) + rng.standard_normal(N)  # 4 sensors away, half as strong
    assert frame_change(after, before) > 3.0
    assert frame_change(before, np.zeros(N)) == 0.0  # nothing before: no change


def test_touch_change_is_the_largest_over_frames_and_lags():
    rng = np.random.default_rng(2)
    ramp = np.array([0.25, 0.5, 0.75] + [1.0] * 8 + [0.75, 0.5, 0.25])
    one = np.array([r * blob(20) + rng.standard_normal(N) for r in ramp])
    two = one + np.array([r * blob(26) for r in np.r_[0.0, 0.0, ramp[:-2]]])
    assert touch_change(one) < 2.0 < touch_change(two)
    assert touch_change(one[:2]) == 0.0  # shorter than the lags


def _touches(rng, n_touches, n_frames=50):
    centres = rng.uniform(5, N - 5, n_touches)
    frames = [blob(c, rng.uniform(40, 120)) + rng.standard_normal((n_frames, N)) for c in centres]
    positions = np.c_[centres * 0.01, np.zeros((n_touches, 2))]  # 10 mm a sensor
    return frames, positions


def test_calibration_calls_few_singles_two_and_finds_shifted_pairs():
    rng = np.random.default_rng(3)
    frames, positions = _touches(rng, 40)
    thr, rep = calibrate_landing(frames, np.ones(N), positions, rate=0.01, hold_rate=0.1)
    assert 1.0 < rep["single_p50"] < rep["hold"] <= thr < rep["pair_p50"]
    assert rep["singles"] == rep["pairs"] == 160
    assert rep["pairs_found"] >= 0.9
    # the threshold holds on fresh single fingers of the same skin
    more, _ = _touches(rng, 40)
    ramp = np.array([0.25, 0.5, 0.75] + [1.0] * 8 + [0.75, 0.5, 0.25])
    fresh = [touch_change(ramp[:, None] * F.mean(0) + F[: len(ramp)] - F.mean(0)) for F in more]
    assert np.mean(np.asarray(fresh) >= thr) <= 0.05


def test_too_few_touches_turn_the_cue_off():
    rng = np.random.default_rng(4)
    frames, positions = _touches(rng, 5)
    thr, rep = calibrate_landing(frames, np.ones(N), positions)
    assert thr == 0.0 and rep["hold"] == 0.0


@pytest.mark.parametrize("scale", [0.5, 4.0])
def test_the_change_is_in_noise_levels(scale):
    """Weights that whiten: the same images in other units give the same change."""
    rng = np.random.default_rng(5)
    frames, positions = _touches(rng, 20)
    a, _ = calibrate_landing(frames, np.ones(N), positions, random_state=1)
    b, _ = calibrate_landing([scale * F for F in frames], np.ones(N) / scale, positions,
                             random_state=1)  # fmt: skip
    assert a == pytest.approx(b, rel=1e-6)
