"""The live landing watch: a touch's largest image change, frame by frame."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.live.landing import LandingWatch
from skinloc.models.multi_contact.landing import touch_change


def test_the_watch_after_each_frame_is_the_offline_change_of_the_touch_so_far():
    """``LandingWatch.step`` (one compiled call a frame) gives, after every frame, what
    ``touch_change`` computes over the touch's whitened frames so far; ``start`` forgets the
    last touch."""
    rng = np.random.default_rng(5)
    w = rng.uniform(0.1, 0.4, 64).astype(np.float32)
    watch = LandingWatch(w).warm_up()
    for touch in range(3):
        watch.start()
        frames = rng.normal(0.0, 1.0, (30, 64)).astype(np.float32) * 40.0
        frames[12:] += 300.0 * (np.arange(64) == 20 + touch)  # a second finger lands
        for n in range(1, len(frames) + 1):
            got = watch.step(frames[n - 1])
            want = touch_change(frames[:n].astype(np.float64) * w.astype(np.float64))
            assert got == pytest.approx(want, rel=1e-9, abs=1e-12)
        assert watch.n == len(frames) and watch.most > 1.0
