"""The one dead/weak/noisy rule (skinloc.sensors.health): lines of a no-touch baseline."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.sensors.health import (
    WEAK_CLEAR_FRACTION,
    WEAK_FRACTION,
    SteadyHealth,
    classify_sensors,
    line_health,
)


def test_line_health_finds_a_dead_and_a_noisy_line():
    rng = np.random.default_rng(0)
    base = rng.uniform(4000, 12000, 64)
    f = base + rng.normal(0, 3, (100, 64))
    f = f.reshape(100, 8, 8)
    f[:, :, 3] = 0  # RX 3: a broken wire
    f[:, 5, :] += rng.normal(0, 40, (100, 8))  # TX 5: noisy
    h = line_health(f.reshape(100, 64), 8, 8)
    assert (h.dead_tx, h.dead_rx, h.noisy_tx, h.noisy_rx) == ([], [3], [5], [])
    assert not h.healthy
    assert line_health((base + rng.normal(0, 3, (50, 64))), 8, 8).healthy


def _gains(rx3: float) -> np.ndarray:
    """Gains of an 8 x 8 grid, every crossing 1 but RX 3's at ``rx3``."""
    g = np.ones((8, 8))
    g[:, 3] = rx3
    return g.ravel()


def test_steady_health_changes_a_state_only_once_said_in_a_row():
    ok = classify_sensors(8, 8, gain=_gains(1.0))
    weak = classify_sensors(8, 8, gain=_gains(0.3))
    assert weak.lines["rx"][3] == "weak" and ok.lines["rx"][3] == "ok"
    steady = SteadyHealth(3)
    assert steady.lines is None
    shown = [steady.update(h).lines["rx"][3] for h in (ok, weak, ok, weak, weak, weak, ok, ok)]
    # the first is shown as it is; one or two weak windows are not enough, three in a row are;
    # and two good ones do not clear it
    assert shown == ["ok", "ok", "ok", "ok", "ok", "weak", "weak", "weak"]
    assert steady.update(ok).lines["rx"][3] == "ok"  # the third good one in a row
    # the sensors follow the same rule as the lines
    assert steady.update(weak).status[3] == "ok"
    # another grid starts afresh
    assert SteadyHealth(3).update(classify_sensors(4, 4)).lines["rx"] == ["ok"] * 4
    assert steady.update(classify_sensors(4, 4, gain=np.r_[np.ones(15), 0.01])).status[15] == "dead"
    assert SteadyHealth(1).update(weak).lines["rx"][3] == "weak"
    for bad in (0, 1.5, -2):
        with pytest.raises(ValueError, match="n_confirm"):
            SteadyHealth(bad)


def test_a_line_shown_weak_clears_only_well_above_the_weak_limit():
    assert WEAK_FRACTION < 0.6 < WEAK_CLEAR_FRACTION < 0.7
    assert classify_sensors(8, 8, gain=_gains(0.6)).lines["rx"][3] == "ok"
    was_weak = {"tx": ["ok"] * 8, "rx": ["ok", "ok", "ok", "weak", "ok", "ok", "ok", "ok"]}
    assert classify_sensors(8, 8, gain=_gains(0.6), shown=was_weak).lines["rx"][3] == "weak"
    assert classify_sensors(8, 8, gain=_gains(0.7), shown=was_weak).lines["rx"][3] == "ok"
    # a line shown ok is flagged at the usual limit
    assert classify_sensors(8, 8, gain=_gains(0.5), shown=None).lines["rx"][3] == "weak"
