"""The change of a touch's image as it lands and lifts, frame by frame (a second finger in time).

``LandingWatch`` keeps a touch's last few whitened images and the largest change of shape so
far (``skinloc.models.multi_contact.landing``): about 1 noise level for one finger whatever its
pressure, more when a second finger lands or lifts beside it tens of milliseconds apart. The
gesture recogniser compares it with the skin's calibrated threshold
(``CountRule.landing_change``) to tell a tap from a two-finger tap whose second finger no
contact search separated.
"""

from __future__ import annotations

import numpy as np

from skinloc.models.multi_contact.landing import LAGS, frame_change

__all__ = ["LandingWatch"]


class LandingWatch:
    """The largest change of one touch's image so far.

    Parameters
    ----------
    weights : (n,) float
        ``1 / sensor noise`` (the model's; counts to noise levels).
    """

    def __init__(self, weights: np.ndarray) -> None:
        self.w = np.asarray(weights, dtype=np.float64)
        self._ring = np.zeros((max(LAGS) + 1, self.w.shape[0]))
        self.n = 0  # frames of this touch
        self.most = 0.0

    def warm_up(self) -> LandingWatch:
        """Compile the change now (numba caches it on disk), not on a touch's frames."""
        frame_change(self._ring[0], self._ring[1])
        return self

    def start(self) -> None:
        """A touch begins: forget the last one."""
        self.n = 0
        self.most = 0.0

    def step(self, delta: np.ndarray) -> float:
        """One frame of the touch (baseline-subtracted counts ``(n,)``); its change so far."""
        ring = self._ring
        m = ring.shape[0]
        i = self.n % m
        np.multiply(delta, self.w, out=ring[i])
        self.n += 1
        for lag in LAGS:
            if self.n > lag:
                e = frame_change(ring[i], ring[(i - lag) % m])
                if e > self.most:
                    self.most = e
        return self.most
