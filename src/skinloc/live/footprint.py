"""A touch's footprint, frame by frame: whether its image is wider and fuller than a finger's.

``FootprintWatch`` reads, after each touched frame's contact search, the search's whitened
image and its one-contact fit's row (``SearchTables.scratch``), scores the image's footprint
against the model's own prediction for one finger there (``multi_contact.footprint``) and
keeps the touch's mean score. The gesture recogniser compares it with the skin's calibrated
levels (``CountRule.footprint_two`` and ``footprint_hold``) to tell a tap from a two-finger
tap whose fingers no contact search separated, as it does with the landing change.
"""

from __future__ import annotations

import math

import numpy as np

from skinloc.models.multi_contact.contacts import CountRule
from skinloc.models.multi_contact.footprint import N_FEATURES, footprint_score
from skinloc.models.multi_contact.search import SearchTables

__all__ = ["FootprintWatch"]


class FootprintWatch:
    """The mean footprint score of one touch's frames so far.

    Parameters
    ----------
    tables : SearchTables
        The engine's search tables (``MapEngine.search_tables``): its scratch holds the last
        searched image and its one-contact fit.
    rule : CountRule
        The skin's rule (its ``footprint_weights``; frames under ``z_on`` are not scored).
    """

    def __init__(self, tables: SearchTables, rule: CountRule) -> None:
        if not rule.footprint_on:
            raise ValueError("the count rule has no footprint cue")
        self.tables = tables
        self.weights = np.asarray(rule.footprint_weights, dtype=np.float64)
        self._log_z_on = math.log(max(rule.z_on, 1e-9))
        self._f = np.zeros(N_FEATURES)
        self.n = 0  # frames scored
        self._sum = 0.0
        self.mean = 0.0

    def warm_up(self) -> FootprintWatch:
        """Compile the score now (numba caches it on disk), not on a touch's frames."""
        xw = self.tables.scratch[0]
        footprint_score(xw, self.tables.Ft[0], self.weights, self._f)
        return self

    def start(self) -> None:
        """A touch begins: forget the last one."""
        self.n = 0
        self._sum = 0.0
        self.mean = 0.0

    def step(self) -> float:
        """Score the frame the search just answered; the touch's mean score so far.

        Call right after the frame's ``Engine.contacts`` (K >= 2): a frame under ``z_on``
        (nothing searched) is not scored.
        """
        S = self.tables.scratch
        st = S[-1]
        if st[5] <= 0.0:
            return self.mean
        f = self._f
        score = footprint_score(S[0], self.tables.Ft[int(st[11])], self.weights, f)
        if score == score and f[7] >= self._log_z_on:
            self.n += 1
            self._sum += score
            self.mean = self._sum / self.n
        return self.mean
