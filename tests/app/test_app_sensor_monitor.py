"""The Connect page's sensor statistics: noise measured on untouched frames only."""

from __future__ import annotations

import numpy as np

from skinloc.app.device import SensorMonitor


def test_a_finger_held_down_does_not_make_its_sensors_noisy():
    rng = np.random.default_rng(0)
    n_tx, n_rx = 8, 8
    base = np.full(n_tx * n_rx, 1000.0)
    mon = SensorMonitor(n_tx, n_rx)
    t = 0.0

    def feed(k: int, touch: np.ndarray | None = None) -> None:
        nonlocal t
        for _ in range(k):
            f = base + rng.normal(0.0, 2.0, base.shape)
            if touch is not None:
                f = f + touch * rng.uniform(0.6, 1.0)  # a finger presses harder and softer
            mon.add(f, t)
            t += 0.01

    feed(60)
    quiet = mon.noise().copy()
    finger = np.zeros_like(base)
    finger[[18, 19, 26, 27, 28]] = 250.0
    feed(150, finger)  # held down for longer than the window
    report = mon.report()
    assert report["status"].count("noisy") == 0, report["status"]
    assert not report["tx_lines"] and not report["rx_lines"]
    assert np.allclose(mon.noise(), quiet)
    feed(5)  # just lifted: the settling frames are not noise either
    assert np.allclose(mon.noise(), quiet)
    feed(40)
    assert np.nanmax(mon.noise()) < 5.0
    assert mon.peak.max() > 100  # the touch still counts for the SNR
