"""The One-Euro filter on its own: known step and ramp responses, the cutoff that follows the
speed, and the reset that starts a new touch.

With a fixed cutoff ``fc`` and sample interval ``dt`` it is the first-order low-pass
``y += a (x - y)``, ``a = 1 / (1 + 1 / (2 pi fc dt))``: after a unit step, ``1 - (1 - a)^n``;
on a ramp of speed ``v``, a steady lag of ``v / (2 pi fc)``. The speed raises the cutoff:
``fc = min_cutoff + beta |speed|``, the speed being its own low-passed estimate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from skinloc.live.one_euro import one_euro, one_euro_onto

DT = 0.01  # s: a 100 Hz skin


def run(points: np.ndarray, min_cutoff_hz: float, beta: float, d_cutoff_hz: float = 1.0):
    """Filter ``points (n, 3)`` m sampled every ``DT``; the outputs ``(n, 3)`` and the state."""
    state, out = np.zeros(8), np.zeros(3)
    prm = np.array([min_cutoff_hz, beta, d_cutoff_hz])
    got = np.empty_like(points)
    for i, p in enumerate(points):
        one_euro(state, p[0], p[1], p[2], i * DT, prm, out)
        got[i] = out
    return got, state


def alpha(cutoff_hz: float) -> float:
    return 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff_hz * DT))


def test_the_first_point_passes_unchanged():
    got, state = run(np.array([[0.01, -0.02, 0.03]]), 1.0, 0.0)
    assert got[0].tolist() == [0.01, -0.02, 0.03] and state[0] == 1.0


def test_a_step_is_the_first_order_response_of_the_minimum_cutoff():
    # beta = 0: the cutoff never moves, whatever the speed
    points = np.zeros((60, 3))
    points[1:] = [0.01, 0.0, -0.02]  # a 10 mm / -20 mm jump after the first sample
    got, _ = run(points, min_cutoff_hz=2.0, beta=0.0)
    n = np.arange(60)
    expected = 1.0 - (1.0 - alpha(2.0)) ** n
    assert got[:, 0] == pytest.approx(0.01 * expected, abs=1e-12)
    assert got[:, 2] == pytest.approx(-0.02 * expected, abs=1e-12)
    assert np.all(got[:, 1] == 0.0)  # an axis that did not move stays put


def test_a_ramp_lags_by_its_speed_over_two_pi_cutoff():
    v = 0.05  # m/s along x
    points = np.zeros((400, 3))
    points[:, 0] = v * DT * np.arange(400)
    got, _ = run(points, min_cutoff_hz=1.5, beta=0.0)
    lag = points[-1, 0] - got[-1, 0]
    assert lag == pytest.approx(v / (2 * math.pi * 1.5), rel=1e-6)


def test_the_cutoff_rises_with_the_speed():
    """A fast finger lags less, for its speed, than a slow one; without beta, the same."""

    def relative_lag(v: float, beta: float) -> tuple[float, np.ndarray]:
        points = np.zeros((600, 3))
        points[:, 1] = v * DT * np.arange(600)
        got, state = run(points, min_cutoff_hz=1.0, beta=beta)
        return (points[-1, 1] - got[-1, 1]) / v, state

    slow, _ = relative_lag(0.01, beta=0.0)
    fast, _ = relative_lag(0.5, beta=0.0)
    assert fast == pytest.approx(slow, rel=1e-6)  # a fixed cutoff: lag proportional to speed
    slow, _ = relative_lag(0.01, beta=20.0)
    fast, state = relative_lag(0.5, beta=20.0)
    assert fast < 0.5 * slow
    # the steady lag is that of the cutoff the filter chose from its speed estimate
    speed = float(np.linalg.norm(state[5:8]))
    # measured against the previous filtered point, the estimate includes the lag: v + lag / dt
    assert speed == pytest.approx(0.5 + 0.5 * fast / DT, rel=1e-6)
    assert fast == pytest.approx(1.0 / (2 * math.pi * (1.0 + 20.0 * speed)), rel=1e-6)


def test_a_reset_starts_afresh_at_the_next_point():
    state, out = np.zeros(8), np.zeros(3)
    prm = np.array([1.0, 0.5, 1.0])
    for i in range(50):
        one_euro(state, 0.02, 0.0, 0.0, i * DT, prm, out)
    state[0] = 0.0  # what the pipeline does when a touch ends
    one_euro(state, -0.03, 0.01, 0.0, 50 * DT, prm, out)
    assert out.tolist() == [-0.03, 0.01, 0.0]  # no memory of the earlier touch
    assert state[5:8].tolist() == [0.0, 0.0, 0.0]  # nor of its speed
    # and the time of the reset is the new start: the next interval is measured from it
    one_euro(state, -0.03, 0.01, 0.0, 51 * DT, prm, out)
    assert out == pytest.approx([-0.03, 0.01, 0.0], abs=1e-15)


def test_a_repeated_timestamp_does_not_divide_by_zero():
    state, out = np.zeros(8), np.zeros(3)
    prm = np.array([1.0, 0.5, 1.0])
    one_euro(state, 0.0, 0.0, 0.0, 1.0, prm, out)
    one_euro(state, 0.01, 0.0, 0.0, 1.0, prm, out)  # same time: treated as 1 ms later
    assert np.all(np.isfinite(out)) and 0.0 < out[0] < 0.01


def test_the_filter_onto_the_surface_is_the_filter_then_the_constraint():
    """``one_euro_onto`` (one compiled call a track) writes what ``one_euro`` followed by the
    surface's ``constrain_into`` writes, with the same filter state, for every constraint."""
    from skinloc.geometry.mesh import cone_skin
    from skinloc.geometry.snap import Surface

    mesh = cone_skin()
    rng = np.random.default_rng(3)
    prm = np.array([1.0, 0.05, 1.0])
    for mode in ("none", "snap", "project"):
        v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        surface = Surface(mode, v[::7], v, f)
        s1, s2, tmp1, tmp2 = np.zeros(8), np.zeros(8), np.zeros(3), np.zeros(3)
        for i, p in enumerate(v[:40] + rng.normal(0.0, 2e-3, (40, 3))):
            want, got = np.zeros(3), np.zeros(3)
            one_euro(s1, p[0], p[1], p[2], i * DT, prm, tmp1)
            surface.constrain_into(tmp1[0], tmp1[1], tmp1[2], want)
            one_euro_onto(s2, p[0], p[1], p[2], i * DT, prm, tmp2, surface.mode, surface.args, got)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
            np.testing.assert_allclose(s2, s1, rtol=0, atol=1e-12)
