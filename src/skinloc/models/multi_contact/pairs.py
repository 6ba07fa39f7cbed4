"""The seed and pair stages of the multi-contact search, pruned without changing its answer.

``skinloc.models.multi_contact.search`` picks ``n_top`` seeds among the coarse candidates (the best
one-contact gains, each at least half the minimum separation from the others) and tries every
seed with every coarse candidate as a pair (2 x 2 NNLS). Two things make that cheap here:

* the seeds' suppression uses each coarse candidate's precomputed list of near candidates, and
  the running maximum is kept per block of ``BLOCK`` candidates, so a seed costs a few blocks
  instead of two passes over all candidates;
* a pair is skipped when an exact upper bound on its gain cannot beat the best pair so far. For
  columns of cosine ``rho`` and one-contact gains ``g_a``, ``g_c`` the pair's least-squares gain
  with both strengths positive is ``(g_a + g_c - 2 rho sqrt(g_a g_c)) / (1 - rho^2)``, at most
  ``g_a + g_c`` when ``rho >= 0`` and at most ``(g_a + g_c) / (1 - |rho|)`` otherwise; so
  ``(g_a + g_c) * kappa_a`` bounds every pair of seed ``a`` (``kappa_a = 1 / (1 - max(0,
  -min_c rho_ac))``, with a margin for rounding). A skipped pair is one the plain loop would
  not have kept (it keeps a pair only when its gain beats the best so far), so the chosen pair
  is the same.
"""

from __future__ import annotations

import numpy as np

from skinloc._jit import jit

__all__ = ["BLOCK", "PairTables", "far_apart", "seeds_and_pair"]

#: Coarse candidates per block of the seeds' running maximum.
BLOCK = 32
#: Relative margin of the gain bound (the gains are computed in float64 from float32 tables).
BOUND_MARGIN = 1e-6


@jit()
def far_apart(p: np.ndarray, q: np.ndarray, min2: float) -> bool:  # pragma: no cover - compiled
    """Whether points ``p``, ``q`` (3,) m are at least ``sqrt(min2)`` m apart."""
    d = 0.0
    for t in range(3):
        d += (p[t] - q[t]) ** 2
    return d >= min2


@jit()
def _near_lists(Cpos: np.ndarray, min2: float) -> tuple:  # pragma: no cover - compiled
    """Each coarse candidate's near ones (``not far_apart``, itself included), CSR: (off, idx)."""
    C = Cpos.shape[0]
    off = np.zeros(C + 1, dtype=np.int64)
    for a in range(C):
        n = 0
        for c in range(C):
            # the search's own test, argument order included: the same booleans
            if not far_apart(Cpos[c], Cpos[a], min2):
                n += 1
        off[a + 1] = off[a] + n
    idx = np.empty(off[C], dtype=np.int64)
    for a in range(C):
        n = off[a]
        for c in range(C):
            if not far_apart(Cpos[c], Cpos[a], min2):
                idx[n] = c
                n += 1
    return off, idx


class PairTables:
    """The pruned stages' tables and scratch, built once per engine (a few ms).

    Parameters
    ----------
    Cg : (C, C) float32
        Gram matrix of the whitened coarse unit images.
    Cpos : (C, 3) float64
        Coarse candidates, m.
    min2 : float
        Minimum separation of two contacts, squared, m^2.

    Attributes
    ----------
    arrays : tuple
        ``(near_off (C + 1,) int, near_idx (n,) int, kappa (C,) float64)``: each candidate's
        near candidates (within half the separation) and its bound factor.
    scratch : tuple
        ``(g1 (C,) float64, block max (nb,) float64, block argmax (nb,) int, list (C,) int,
        one seed's partners (C,) int)``.
    """

    def __init__(self, Cg: np.ndarray, Cpos: np.ndarray, min2: float) -> None:
        C = Cg.shape[0]
        off, idx = _near_lists(np.ascontiguousarray(Cpos, dtype=np.float64), 0.25 * float(min2))
        g = np.asarray(Cg, dtype=np.float64)
        d = np.sqrt(np.maximum(np.diag(g), 0.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = g / np.outer(d, d)
        rho = np.where(np.isfinite(rho), rho, 0.0)
        neg = np.clip(-rho.min(axis=1), 0.0, 1.0) if C else np.zeros(0)
        with np.errstate(divide="ignore"):
            kappa = (1.0 + BOUND_MARGIN) / (1.0 - neg)  # inf (no pruning) at rho = -1
        nb = (C + BLOCK - 1) // BLOCK
        self.arrays = (off, idx, np.ascontiguousarray(kappa, dtype=np.float64))
        self.scratch = (
            np.zeros(C),
            np.zeros(nb),
            np.zeros(nb, dtype=np.int64),
            np.zeros(C, dtype=np.int64),
            np.zeros(C, dtype=np.int64),
        )
        #: ``search_into``'s last two arguments
        self.kernel_args = (self.arrays, self.scratch)


@jit()
def _block_max(
    g1: np.ndarray, b: int, bmax: np.ndarray, barg: np.ndarray
) -> None:  # pragma: no cover
    """Block ``b``'s first strict maximum above -1 (``barg`` -1 if none)."""
    best = -1.0
    bi = -1
    for c in range(b * BLOCK, min((b + 1) * BLOCK, g1.shape[0])):
        if g1[c] > best:
            best = g1[c]
            bi = c
    bmax[b] = best
    barg[b] = bi


@jit()
def _pair_terms(
    gaa: float, ba: float, gab: float, gbb: float, bb: float
) -> tuple:  # pragma: no cover - compiled
    """A seed and a partner's pair: ``(num, det, ok)``, its gain ``num / det``.

    ``ok``: the partner correlates with the image, the pair is not degenerate and both
    strengths are positive (then ``det > 0``); computed without branches and without
    divisions (``s_a``, ``s_b`` and the gain over ``det``).
    """
    det = gaa * gbb - gab * gab
    na = gbb * ba - gab * bb
    nb_ = gaa * bb - gab * ba
    ok = (bb > 0.0) & (det > 1e-12 * gaa * gbb) & (na > 0.0) & (nb_ > 0.0)
    return na * ba + nb_ * bb, det, ok


@jit()
def seeds_and_pair(
    bC: np.ndarray,
    g1: np.ndarray,
    Cg: np.ndarray,
    Cd: np.ndarray,
    Cpos: np.ndarray,
    min2: float,
    top: np.ndarray,
    pair: tuple,
    pair_s: tuple,
) -> tuple:  # pragma: no cover - compiled
    """The seeds, then the best pair of a seed and a coarse candidate: ``(n_seeds, a, c)``.

    ``bC (C,)`` are the coarse correlations with the whitened image, ``g1 (C,)`` the one-contact
    gains (suppressed to -1 in place as the seeds are taken, as the plain search does);
    ``top (n_top,)`` receives the seeds. ``a``, ``c`` are -1 when no pair has two positive
    strengths at least ``sqrt(min2)`` m apart. The answer is the plain loops' (module
    docstring): every seed with every candidate, the first strictly best pair kept.
    """
    near_off, near_idx, kappa = pair
    g1o, bmax, barg, lst, cand = pair_s
    C = g1.shape[0]
    nb = bmax.shape[0]
    for c in range(C):
        g1o[c] = g1[c]
    for b in range(nb):
        _block_max(g1, b, bmax, barg)
    n_seeds = 0
    for t in range(top.shape[0]):
        best = -1.0
        bi = -1
        for b in range(nb):  # the first block holding the maximum: its first maximum
            if bmax[b] > best:
                best = bmax[b]
                bi = barg[b]
        if bi < 0:
            break
        top[t] = bi
        n_seeds += 1
        last = -1
        for r in range(near_off[bi], near_off[bi + 1]):
            c = near_idx[r]
            g1[c] = -1.0
        for r in range(near_off[bi], near_off[bi + 1]):
            b = near_idx[r] // BLOCK
            if b != last:
                _block_max(g1, b, bmax, barg)
                last = b
    bestg = -1.0
    pa = -1
    pb = -1
    # the best pair of two seeds first (the loop's own test, the earlier seed first, as the
    # loop meets them): its gain prunes from the first seed on. The loop below still visits,
    # in its order, every pair that could beat it, so it ends on the pair the plain loop keeps
    for t in range(n_seeds):
        a = top[t]
        gaa = float(Cg[a, a])
        ba = bC[a]
        for u in range(t + 1, n_seeds):
            c = top[u]
            num, det, ok = _pair_terms(gaa, ba, float(Cg[a, c]), Cd[c], bC[c])
            if ok and num > bestg * det and far_apart(Cpos[a], Cpos[c], min2):
                bestg = num / det
                pa = a
                pb = c
    # a partner the image does not correlate with cannot take a positive strength (rows are
    # mostly non-negative): the list holds the others only. The compactions below are
    # branch-free: their tests pass about one time in three, unpredictably, and mispredicted
    # branches were most of this stage's time
    n_list = 0
    for c in range(C):
        lst[n_list] = c
        n_list += 1 if bC[c] > 0.0 else 0
    for t in range(n_seeds):
        a = top[t]
        gaa = float(Cg[a, a])
        ba = bC[a]
        ga_row = Cg[a]
        g1a = g1o[a]
        ka = kappa[a]
        # the partners whose pair could beat the best so far (the exact bound, with the best
        # as this seed starts: a later best only skips more of them)
        n_cand = 0
        for r in range(n_list):
            c = lst[r]
            cand[n_cand] = c
            n_cand += 0 if (g1a + g1o[c]) * ka < bestg else 1
        for r in range(n_cand):
            c = cand[r]
            num, det, ok = _pair_terms(gaa, ba, float(ga_row[c]), Cd[c], bC[c])
            # the tests all at once: each passes unpredictably, a branch apiece cost more than
            # the arithmetic; only a pair that beats the best branches
            if ok & (c != a) & (num > bestg * det) and far_apart(Cpos[a], Cpos[c], min2):
                bestg = num / det
                pa = a
                pb = c
        if t + 1 < n_seeds:
            # the later seeds' gains are at most the next one's, their factors at most the
            # largest of theirs: keep the candidates that could still make a better pair
            g1n = g1o[top[t + 1]]
            kn = 0.0
            for u in range(t + 1, n_seeds):
                kn = max(kn, kappa[top[u]])
            n = 0
            for r in range(n_list):
                c = lst[r]
                lst[n] = c
                n += 0 if (g1n + g1o[c]) * kn < bestg else 1
            n_list = n
    return n_seeds, pa, pb
