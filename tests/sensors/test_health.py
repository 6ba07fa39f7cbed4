"""The one dead/weak/noisy rule (skinloc.sensors.health): lines of a no-touch baseline."""

from __future__ import annotations

import numpy as np

from skinloc.sensors.health import line_health


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
