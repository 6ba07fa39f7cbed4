"""A two-contact fit anchored at a known finger: whether there is a second one, and where.

The multi-contact search (``skinloc.models.multi_contact.search``) decides each frame on its own
whether an image holds one finger or two. A tracker knows more: where a finger already is. This
module answers, for one frame, the question the tracker can ask with that knowledge: with one
contact placed at (near) ``anchor``, how much better do two contacts explain the image than
one, and where is the second? The live pipeline (``skinloc.live.pair_prior``) weighs the answer
over several frames.

The fit is the search's (noise-whitened image, non-negative strengths, the same candidate
tables and refinement): the anchor's nearest coarse candidate refined alone (the one-contact
fit, gain ``g1``); every coarse candidate at least ``min_separation_mm`` from it tried as the
second (2 x 2 NNLS; the correlations by two matrix-vector products); the best pair refined
once, one contact at a time. Returned: the relative residual reduction ``(R1 - R2) / R2``
(``R_m = |xw|^2 - g_m``, floored at 1), the weaker contact's peak in noise levels (``z2``)
and both places.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skinloc._jit import compiled_entry, jit
from skinloc.models.multi_contact.contacts import PRM_MIN2
from skinloc.models.multi_contact.pairs import far_apart
from skinloc.models.multi_contact.search import (
    SearchArrays,
    SearchScratch,
    nnls2_interior,
    polish,
    weakest_z,
    whiten_into,
)

__all__ = ["AnchoredPair", "PairRefit"]


@dataclass(frozen=True)
class AnchoredPair:
    """The two-contact fit of one frame around an anchor.

    Attributes
    ----------
    ratio : float
        ``(R1 - R2) / R2``: how much the second contact reduces the residual, relatively.
    z2 : float
        Peak of the weaker contact's fitted image, noise levels.
    first_m : (3,) float
        The anchored contact, m.
    second_m : (3,) float
        The second contact, m.
    """

    ratio: float
    z2: float
    first_m: np.ndarray
    second_m: np.ndarray


@jit()
def _anchored_pair(
    x: np.ndarray,
    anchor: np.ndarray,
    arrays: SearchArrays,
    min2: float,
    S: SearchScratch,
    out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """The fit into ``out (3,)``: ratio, z2, found (1.0) or not; rows of ``S.fi[:2]``."""
    w, Ct, Cg, Cd, Cpos, nbr, Ft, Fpos, Fpk, Fcell, off, cfine, _ = arrays
    xw, fi, s = S.xw, S.fi, S.s
    xx, _ = whiten_into(x, w, xw)
    C = Ct.shape[0]
    best = np.inf
    ca = 0
    for c in range(C):
        d = 0.0
        for t in range(3):
            d += (Cpos[c, t] - anchor[t]) ** 2
        if d < best:
            best = d
            ca = c
    fi[0] = cfine[ca]
    g1 = polish(1, fi, xw, xx, arrays, 0.0, S, 1, False)
    # every coarse candidate against the image and against the anchored contact: two
    # matrix-vector products (BLAS), then a 2 x 2 NNLS per candidate far enough
    ra = Ft[fi[0]]
    gaa = float(np.dot(ra, ra))
    ba = float(np.dot(ra, xw))
    bc = np.dot(Ct, xw)
    gc = np.dot(Ct, ra)
    bestg = -1.0
    cb = -1
    for c in range(C):
        bb = float(bc[c])
        # only two positive strengths count: NNLS's interior answer (its others have a zero);
        # the tests at once, one branch for a better pair (each test passes unpredictably)
        g, s1, s2 = nnls2_interior(gaa, float(gc[c]), Cd[c], ba, bb)
        if (bb > 0.0) & far_apart(Cpos[c], Fpos[fi[0]], min2) & (g > bestg):
            bestg = g
            cb = c
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    if cb < 0:
        return 0
    fi[1] = cfine[cb]
    g2 = polish(2, fi, xw, xx, arrays, min2, S, 1, False)
    r1 = max(xx - g1, 1.0)
    r2 = max(xx - g2, 1.0)
    out[0] = (r1 - r2) / r2
    out[1] = weakest_z(2, fi, s, Fpk)
    out[2] = 1.0
    return 1


class PairRefit:
    """Anchored two-contact fits on one engine's search tables.

    Parameters
    ----------
    engine : Engine
        A model engine with the multi-contact search (``search_tables``).
    """

    def __init__(self, engine: object) -> None:
        tables = engine.search_tables()  # type: ignore[attr-defined]
        self._arrays = tables.arrays
        self._min2 = float(tables.prm[PRM_MIN2])
        # scratch of our own: the engine's is the live search's
        self._S = tables.scratch.fresh()
        self._out = np.zeros(3)
        self._anchor = np.zeros(3)
        self._fit = None  # _anchored_pair compiled for these tables (``compiled_entry``)

    def warm_up(self) -> PairRefit:
        """Compile the fit now (numba caches it on disk) rather than on a touch's frames.

        The live pipeline fits in a touch's first frames: compiled there, the fit held up the
        loop for seconds (up to 3 s on a cold cache), and the frames read after it all carried
        one late arrival time.
        """
        x = np.zeros(self._arrays.w.shape[0], dtype=np.float32)  # one weight per sensor
        self.fit(x, self._arrays.Fpos[0])
        return self

    def fit(self, x: np.ndarray, anchor_m: np.ndarray) -> AnchoredPair | None:
        """The anchored pair of image ``x (n_features,)`` counts; None if no pair fits.

        Parameters
        ----------
        x : (n_features,) float32
            Baseline-subtracted counts.
        anchor_m : (3,) float
            Where one finger is known to be, m.
        """
        xs = x if x.dtype == np.float32 else x.astype(np.float32)
        self._anchor[:] = anchor_m
        args = (self._anchor, self._arrays, self._min2, self._S, self._out)
        if self._fit is None:
            self._fit = compiled_entry(_anchored_pair, np.zeros_like(xs), *args)
        fit = self._fit if xs.flags.c_contiguous and xs.ndim == 1 else _anchored_pair
        if not fit(xs, *args):
            return None
        fpos = self._arrays.Fpos
        fi = self._S.fi
        ratio, z2 = float(self._out[0]), float(self._out[1])
        if not (math.isfinite(ratio) and math.isfinite(z2)):
            return None
        return AnchoredPair(ratio, z2, fpos[fi[0]].copy(), fpos[fi[1]].copy())
