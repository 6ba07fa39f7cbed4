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

from skinloc._jit import jit
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
        _step(np.zeros(self.w.shape[0], dtype=np.float32), self.w, self._ring.copy(), 0, 0.0)
        return self

    def start(self) -> None:
        """A touch begins: forget the last one."""
        self.n = 0
        self.most = 0.0

    def step(self, delta: np.ndarray) -> float:
        """One frame of the touch (baseline-subtracted counts ``(n,)``); its change so far."""
        self.most = _step(delta, self.w, self._ring, self.n, self.most)
        self.n += 1
        return self.most


@jit()
def _step(
    delta: np.ndarray, w: np.ndarray, ring: np.ndarray, n: int, most: float
) -> float:  # pragma: no cover - compiled
    """Frame ``n`` of a touch whitened into ``ring``; the largest change over ``LAGS`` so far.

    One compiled call a frame: 0.6 us, where the multiply and the two changes took 1.9 in Python.
    """
    m = ring.shape[0]
    i = n % m
    for j in range(delta.shape[0]):
        ring[i, j] = delta[j] * w[j]
    for lag in LAGS:
        if n + 1 > lag:
            e = frame_change(ring[i], ring[(i - lag) % m])
            if e > most:
                most = e
    return most
