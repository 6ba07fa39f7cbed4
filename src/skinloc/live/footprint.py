"""A touch's footprint, frame by frame: whether its image is wider and fuller than a finger's.

``FootprintWatch`` reads, after each touched frame's contact search, the search's whitened
image and its one-contact fit's row (``SearchTables.scratch``), scores the image's footprint
against the model's own prediction for one finger there (``multi_contact.footprint``) and
keeps the mean score of the touch's strong frames. The gesture recogniser compares it with
the skin's calibrated levels (``CountRule.footprint_two`` and ``footprint_hold``) to tell a
tap from a two-finger tap whose fingers no contact search separated, as it does with the
landing change.
"""

from __future__ import annotations

import math

import numpy as np

from skinloc.models.multi_contact.contacts import CountRule
from skinloc.models.multi_contact.footprint import N_FEATURES, footprint_score
from skinloc.models.multi_contact.search import STAT_ROW1, STAT_XX, SearchTables

__all__ = ["FootprintWatch"]


#: Frames of a touch scored at most (its first moments: a tap lasts 5-20 frames at 100 Hz).
MAX_FRAMES = 32
#: Share of the touch's strongest frame's peak signal from which a frame's score counts: the
#: landing and lifting frames, weak and noisy, are not the touch's footprint (and the skin's
#: levels were calibrated on held touches).
STRONG = 0.7


class FootprintWatch:
    """The mean footprint score of one touch's strong frames so far.

    Parameters
    ----------
    tables : SearchTables
        The engine's search tables (``MapEngine.search_tables``): its scratch holds the last
        searched image and its one-contact fit.
    rule : CountRule
        The skin's rule (its ``footprint_weights``; frames under ``z_on`` are not scored).

    Attributes
    ----------
    mean : float
        The mean score of the touch's frames whose peak signal is at least ``STRONG`` of its
        strongest's (of its first ``MAX_FRAMES`` scored frames).
    n : int
        Frames scored so far.
    """

    def __init__(self, tables: SearchTables, rule: CountRule) -> None:
        if not rule.footprint_on:
            raise ValueError("the count rule has no footprint cue")
        self.tables = tables
        self.weights = np.asarray(rule.footprint_weights, dtype=np.float64)
        self._log_z_on = math.log(max(rule.z_on, 1e-9))
        self._f = np.zeros(N_FEATURES)
        self._scores = np.zeros(MAX_FRAMES)
        self._peaks = np.zeros(MAX_FRAMES)  # log peak signal, noise levels
        self.n = 0
        self.mean = 0.0

    def warm_up(self) -> FootprintWatch:
        """Compile the score now (numba caches it on disk), not on a touch's frames."""
        xw = self.tables.scratch.xw
        footprint_score(xw, self.tables.Ft[0], self.weights, self._f)
        self.tables.scratch.stats[STAT_XX] = 0.0  # the engine's warm-up image is no touch's
        return self

    def start(self) -> None:
        """A touch begins: forget the last one."""
        self.n = 0
        self.mean = 0.0

    def step(self) -> float:
        """Score the frame the search just answered; the touch's mean score so far.

        Call right after the frame's ``Engine.contacts`` (K >= 2): a frame under ``z_on``
        (nothing searched) is not scored. Marks the search's statistics read (``|xw|^2`` of
        its scratch set to 0; the next search sets it again).
        """
        S = self.tables.scratch
        st = S.stats
        if st[STAT_XX] <= 0.0 or self.n >= MAX_FRAMES:
            return self.mean
        f = self._f
        score = footprint_score(S.xw, self.tables.Ft[int(st[STAT_ROW1])], self.weights, f)
        # read once: a frame that was not searched (none at all, or a stand-in engine's)
        # finds no image here and is not scored again from the last one
        st[STAT_XX] = 0.0
        if score == score and f[7] >= self._log_z_on:
            n = self.n
            self._scores[n] = score
            self._peaks[n] = f[7]
            self.n = n + 1
            peaks = self._peaks[: n + 1]
            strong = peaks >= peaks.max() + math.log(STRONG)
            self.mean = float(self._scores[: n + 1][strong].mean())
        return self.mean
