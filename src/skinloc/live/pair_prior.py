"""A second finger the per-frame count misses: the two-contact fit weighed over frames.

The multi-contact search decides one frame at a time whether an image holds one finger or two,
and on the simulated two-finger taps it sees one in about half of them (docs/multitouch.md).
The tracker knows where the first finger is. ``PairPrior`` asks, while a touch has one track
and the search reports one contact, for the two-contact fit anchored at that contact
(``skinloc.models.multi_contact.refit``), and:

* **starts** a second finger when, within ``window_s`` of the first finger's landing, over
  the last ``start_frames`` frames the fit has been better than one contact by ``start_ratio``
  on average (relative residual reduction) with its weaker contact at ``start_z`` noise
  levels on average, its second contact staying within ``consistent_mm`` from frame to frame
  (a finger stays put; the second contact of a single finger's fit wanders), or the pair
  staying put either way round, or, while the fingers land (``mirror_s``), the second contact
  on the other side of an unmoved first, as far along the same line (two fingers closer than
  about 30 mm: their fit swaps which one is anchored, or puts the second beyond either finger,
  side to side from frame to frame); a frame in which
  the search itself reports two contacts counts as one at the thresholds, with its contact
  farthest from the track as the second (the search sees some fingers in some frames only);
* **keeps** two fingers, once there are two tracks and the search is back to one contact,
  while the anchored fit stays better than one by the lower ``keep_ratio`` and ``keep_z``
  (hysteresis: the evidence that started a finger need not be repeated each frame), up to
  ``keep_s`` after the first landing (a tap's length: after it, a finger only the prior saw
  ends, and the recogniser takes such a brief second touch within a long one as a piece of
  the long one's image). The frames that started a finger are spent once it is kept: if its
  track ends, another start needs ``start_frames`` new frames.

Only the touch's first moments are searched: that is when the second finger of a two-finger
tap lands, and it keeps the cost (a fit of about 30-40 us) off long touches. ``max_fits``
(30, the 0.30 s of ``keep_s`` at the skin's 100 Hz) caps the fits of one touch whatever the
frame rate or the timestamps (a replay as fast as it goes, stamped with arrival times, fits
a whole touch in 0.25 s). The thresholds were
set on simulated gesture streams of skin seeds 1-5 (docs/multitouch.md).

Units: metres, seconds; ``consistent_mm`` in mm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["PairPrior", "PairRule", "pair_prior"]


@dataclass(frozen=True)
class PairRule:
    """Thresholds of ``PairPrior`` (see the module's docstring)."""

    window_s: float = 0.25
    keep_s: float = 0.30
    start_ratio: float = 0.15
    start_z: float = 5.0
    start_frames: int = 3
    consistent_mm: float = 15.0
    mirror_s: float = 0.10
    keep_ratio: float = 0.08
    keep_z: float = 3.0
    max_fits: int = 30


class PairPrior:
    """The anchored pair of each frame, weighed over frames.

    Parameters
    ----------
    refit : PairRefit
        The model's anchored two-contact fit (``skinloc.models.multi_contact.refit``).
    image : (n_features,) float32
        The buffer holding the current frame's baseline-subtracted counts (read each frame).
    rule : PairRule, optional
        Thresholds.
    """

    def __init__(self, refit: Any, image: np.ndarray, rule: PairRule | None = None) -> None:
        self.refit = refit
        self.image = image
        self.rule = PairRule() if rule is None else rule
        self.run = 0
        self.fits = 0  # anchored fits asked in this touch
        self._last = np.zeros(3)  # the last frame's second contact, m
        self._last_first = np.zeros(3)  # and its anchored one
        n = max(int(self.rule.start_frames), 1)
        self._ratio = np.zeros(n)
        self._z = np.zeros(n)

    def reset(self) -> None:
        """Forget the evidence gathered so far."""
        self.run = 0

    def end_touch(self) -> None:
        """The touch ended: forget the evidence and the fits counted."""
        self.run = 0
        self.fits = 0

    def _window(self, ts: float, live: Sequence[Any]) -> bool:
        r = self.rule
        n = len(live)
        if n == 0 or n > 2:
            return False
        first_s = min(t.start_s for t in live)
        return ts - first_s <= (r.window_s if n == 1 else r.keep_s)

    def _push(
        self,
        second_m: np.ndarray,
        ratio: float,
        z2: float,
        first_m: np.ndarray | None = None,
        landing: bool = False,
    ) -> bool:
        """One frame's evidence; whether the window's means reach the start thresholds."""
        r = self.rule
        tol = r.consistent_mm * 1e-3
        if self.run and math.dist(second_m, self._last) > tol:
            # two close fingers: their fit may swap which one is anchored, or put the second
            # on the other side of an unmoved first, as far along the same line (the mirror)
            last1 = self._last_first
            if first_m is None or not (
                math.dist(first_m, self._last) <= tol
                and math.dist(second_m, last1) <= tol
                or landing
                and math.dist(first_m, last1) <= tol
                and math.dist(second_m, 2.0 * first_m - self._last) <= tol
            ):
                self.run = 0
        i = self.run % len(self._ratio)
        self._ratio[i], self._z[i] = ratio, z2
        self.run += 1
        self._last[:] = second_m
        if first_m is not None:
            self._last_first[:] = first_m
        return (
            self.run >= len(self._ratio)
            and float(self._ratio.mean()) >= r.start_ratio
            and float(self._z.mean()) >= r.start_z
        )

    def saw(self, ts: float, live: Sequence[Any], positions: np.ndarray) -> None:
        """The search itself reported several contacts while one track is live.

        Its contact farthest from the track counts as one frame of evidence at the start
        thresholds (the search's own rule is stricter), so that a second finger the search
        sees in some frames and the anchored fit in the others adds up.
        """
        if len(live) != 1 or not self._window(ts, live):
            self.run = 0
            return
        d = np.linalg.norm(positions - live[0].last_m, axis=1)
        far = positions[int(np.argmax(d))]
        self._push(far, self.rule.start_ratio, self.rule.start_z, live[0].last_m)

    def step(self, ts: float, live: Sequence[Any], contact_m: np.ndarray) -> np.ndarray | None:
        """Two contacts ``(2, 3)`` m for this frame instead of ``contact_m``, or None.

        ``live``: the live tracks (``start_s``); ``contact_m``: the search's one contact.
        """
        r = self.rule
        if self.fits >= r.max_fits or not self._window(ts, live):  # the cheap test first
            self.run = 0
            return None
        self.fits += 1
        fit = self.refit.fit(self.image, contact_m)
        if fit is None:
            self.run = 0
            return None
        if len(live) == 2:
            # the evidence that started the second finger is spent: should its track end, a
            # new one needs start_frames fresh frames (the old ones, still in the window,
            # restarted it on the next frame however weak that frame was)
            self.run = 0
            if fit.ratio >= r.keep_ratio and fit.z2 >= r.keep_z:
                return np.array([fit.first_m, fit.second_m])
            return None
        landing = ts - live[0].start_s <= r.mirror_s
        if self._push(fit.second_m, fit.ratio, fit.z2, fit.first_m, landing):
            return np.array([fit.first_m, fit.second_m])
        return None


def pair_prior(engine: Any, image: np.ndarray, rule: PairRule | None = None) -> PairPrior | None:
    """The prior for ``engine``, or None if its model has no multi-contact search."""
    if engine.search_tables() is None:  # built once here, and kept, for the refit below
        return None
    from skinloc.models.multi_contact.refit import PairRefit

    return PairPrior(PairRefit(engine), image, rule)
