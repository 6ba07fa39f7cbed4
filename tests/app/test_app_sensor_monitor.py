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


def _line_flags(monitor: SensorMonitor, plan: list[tuple[int, float]]) -> list[bool]:
    """Feed ``monitor`` 100 Hz frames of an 8 x 8 skin by ``plan`` (frames, how far TX line 5
    wavers downwards, counts), a report a second: whether each report flags that line."""
    rng = np.random.default_rng(1)
    base = np.full(64, 1000.0)
    tx5 = np.arange(64) // 8 == 5
    flagged = []
    for k, dip in plan:
        for _ in range(k):
            f = base + rng.normal(0.0, 2.0, base.shape)
            f[tx5] -= dip * rng.uniform(0.0, 1.0, tx5.sum())  # never a rise, never a touch
            monitor.add(f, 0.01 * monitor.n_frames)
            if monitor.n_frames % 100 == 0:
                flagged.append(any(ln["index"] == 5 for ln in monitor.report()["tx_lines"]))
    return flagged


def test_a_line_flag_needs_reports_in_a_row_to_show_and_to_clear():
    """Issue 33: a line's flag came and went on the same touches. A window swayed for a moment
    (80 frames of a line wavering downwards, which the touch detector does not call a touch)
    flags the line in no report; a line noisy for seconds is flagged from its third report on,
    and clears on its third quiet report."""
    moment = [(300, 0.0), (80, 40.0), (420, 0.0)]
    assert sum(_line_flags(SensorMonitor(8, 8, steady=1), moment)) == 1  # each report as is
    assert not any(_line_flags(SensorMonitor(8, 8), moment))
    lasting = [(300, 0.0), (800, 40.0), (600, 0.0)]
    assert _line_flags(SensorMonitor(8, 8, steady=1), lasting)[3:11] == [True] * 8
    flagged = _line_flags(SensorMonitor(8, 8), lasting)
    assert flagged[3:5] == [False, False] and all(flagged[5:11]), flagged
    assert flagged[11:13] == [True, True] and not any(flagged[13:]), flagged  # 3rd quiet one
