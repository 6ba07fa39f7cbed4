"""The compiled multi-contact search (the method: ``skinloc.models.multi_contact``)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from skinloc._jit import jit
from skinloc.models.multi_contact.contacts import (
    N_COLS,
    PRM_MIN2,
    PRM_MISFIT,
    PRM_TAU2,
    PRM_TAU3,
    PRM_Z2_MIN,
    PRM_Z3_MIN,
    PRM_Z_ON,
    PRM_Z_POWER,
    CountRule,
    noise_weights,
)
from skinloc.models.multi_contact.pairs import PairTables, far_apart, seeds_and_pair

__all__ = [
    "MEM_FRAMES",
    "MEM_PAIR",
    "MEM_PEAK",
    "MEM_RESIDUAL",
    "MEM_ROW1",
    "MEM_VALID",
    "PEAK_GROWTH",
    "REFRESH_FRAMES",
    "RESIDUAL_GROWTH",
    "SAFE_SCORE",
    "STAT_G1",
    "STAT_G2",
    "STAT_G3",
    "STAT_ROW1",
    "STAT_ROWS",
    "STAT_XX",
    "STAT_Z2",
    "STAT_Z3",
    "SearchArrays",
    "SearchMemory",
    "SearchScratch",
    "SearchTables",
    "nnls",
    "nnls2",
    "nnls2_interior",
    "nnls3_interior",
    "polish",
    "recall_into",
    "relative_gain",
    "remember",
    "search_into",
    "search_remember",
    "single_into",
    "weakest_z",
    "whiten_into",
]

#: Coarse cells searched around each contact (its own and the nearest others).
N_NEIGHBOURS = 7
#: A stream's frames answered from its memory before the full search runs again.
REFRESH_FRAMES = 25
#: How far the one-contact residual (relative to the image's energy) may grow over the one
#: the full search saw before the full search runs again.
RESIDUAL_GROWTH = 1.15
#: How far the one-contact fit's largest residual (noise levels) may grow over the one at the
#: full search (a finger landing away from the first leaves its peak unexplained); below
#: half the rule's ``z2_min`` it may grow freely.
PEAK_GROWTH = 1.3
#: The largest count-rule score, as a share of the rule's threshold, of a frame a memory may
#: start from: a frame near the threshold is searched in full every time.
SAFE_SCORE = 0.3

# The search's statistics (``SearchScratch.stats``, (12,) float64), by slot: the gains of the
# one-, two- and three-contact fits (whitened counts^2), the weakest contact's peak z of the
# pair and of the triple, the image's energy ``|xw|^2``; the reported contacts' fine rows from
# ``STAT_ROWS`` (three slots, strongest first), and the one-contact fit's fine row.
STAT_G1, STAT_G2, STAT_G3, STAT_Z2, STAT_Z3, STAT_XX = 0, 1, 2, 3, 4, 5
STAT_ROWS = 8
STAT_ROW1 = 11

# A stream's memory (``SearchMemory.state``, (7,) float64), by slot: valid (1.0 or 0.0), the
# one-contact fit's fine row, its relative residual at the full search, frames answered since,
# the pair's two fine rows from ``MEM_PAIR`` (-1: none), the fit's largest residual (z).
MEM_VALID, MEM_ROW1, MEM_RESIDUAL, MEM_FRAMES, MEM_PAIR, MEM_PEAK = 0, 1, 2, 3, 4, 6


# --------------------------------------------------------------------------------------------
# the search tables


class SearchArrays(NamedTuple):
    """The compiled kernels' tables (a tuple, as numba takes it; read by name).

    ``C`` coarse candidates, ``P`` fine rows (candidates ordered cell by cell), ``k`` sensors;
    images are whitened (counts times ``w``).
    """

    w: np.ndarray  # (k,) float32, noise weights (1 / noise)
    Ct: np.ndarray  # (C, k) float32, the coarse candidates' unit images
    Cg: np.ndarray  # (C, C) float32, their Gram matrix
    Cd: np.ndarray  # (C,) float64, its diagonal
    Cpos: np.ndarray  # (C, 3) float64, the coarse candidates, m
    nbr: np.ndarray  # (C, n_nb) int64, each cell's nearest cells (itself first)
    Ft: np.ndarray  # (P, k) float32, the fine rows' unit images
    Fpos: np.ndarray  # (P, 3) float64, the fine rows' points, m
    Fpk: np.ndarray  # (P,) float64, each fine row's peak
    Fcell: np.ndarray  # (P,) int64, each fine row's cell
    off: np.ndarray  # (C + 1,) int64, each cell's first fine row
    cfine: np.ndarray  # (C,) int64, each coarse candidate's fine row
    Fn: np.ndarray  # (P,) float64, each fine row's ``_dot(row, row)``


class SearchScratch(NamedTuple):
    """The search's work arrays, allocated once per table (a tuple, as numba takes it)."""

    xw: np.ndarray  # (k,) float32, the whitened image
    bC: np.ndarray  # (C,) coarse correlations
    g1: np.ndarray  # (C,) one-contact gains (then suppressed)
    top: np.ndarray  # (n_top,) int64, seeds
    fi: np.ndarray  # (3,) int64, the contacts' fine rows
    keep: np.ndarray  # (3,) int64, the reported contacts' rows, kept while a third is tried
    gq: np.ndarray  # (widest,) gains of one contact's candidates
    qq: np.ndarray  # (widest,) int64, those candidates
    s: np.ndarray  # (3,) strengths
    spread: np.ndarray  # (3,) spreads, mm
    stats: np.ndarray  # (12,) the statistics, by the ``STAT_*`` slots

    def fresh(self) -> SearchScratch:
        """A scratch of the same shapes, of its own (zeros)."""
        return SearchScratch(*(np.zeros_like(a) for a in self))


class SearchTables:
    """The arrays of the search, built once per engine.

    Parameters
    ----------
    unit : (P, k) float
        Unit image at every candidate (counts per count of strength).
    candidates : (P, 3) float
        Candidate surface points, m.
    coarse : (C,) int
        Coarse candidates.
    cells : (C, m) int
        Each coarse candidate's cell (padded by repeating the coarse candidate).
    sensor_noise : (k,) float or None
        Noise per sensor, counts (``None``: ``DEFAULT_NOISE_COUNTS``).
    rule : CountRule
        The count rule.

    Attributes
    ----------
    arrays : SearchArrays
        The kernels' tables.
    pair : PairTables
        The pruned seed and pair stages' tables (``skinloc.models.multi_contact.pairs``).
    scratch : SearchScratch
        The search's work arrays; ``scratch.stats`` its statistics (``STAT_*`` slots).
    """

    def __init__(
        self,
        unit: np.ndarray,
        candidates: np.ndarray,
        coarse: np.ndarray,
        cells: np.ndarray,
        sensor_noise: np.ndarray | None,
        rule: CountRule,
    ) -> None:
        from scipy.spatial import cKDTree

        k = unit.shape[1]
        self.w = noise_weights(sensor_noise, k)
        self.rule = rule
        self.prm = rule.params()
        coarse = np.asarray(coarse, dtype=np.int64)
        perm, off, fcell, cfine = [], [0], [], []
        for c, row in enumerate(np.asarray(cells, dtype=np.int64)):
            members = list(dict.fromkeys(row.tolist()))
            cfine.append(len(perm) + members.index(int(coarse[c])))
            perm += members
            fcell += [c] * len(members)
            off.append(len(perm))
        perm_a = np.asarray(perm, dtype=np.int64)
        uw = np.asarray(unit, dtype=np.float64) * self.w.astype(np.float64)
        self.Ft = np.ascontiguousarray(uw[perm_a], dtype=np.float32)
        self.Fpos = np.ascontiguousarray(np.asarray(candidates, dtype=np.float64)[perm_a])
        self.Fpk = np.maximum(self.Ft.max(axis=1), 0.0).astype(np.float64)
        self.Fcell = np.asarray(fcell, dtype=np.int64)
        self.off = np.asarray(off, dtype=np.int64)
        self.cfine = np.asarray(cfine, dtype=np.int64)
        self.Ct = np.ascontiguousarray(self.Ft[self.cfine])
        self.Cg = np.ascontiguousarray(self.Ct @ self.Ct.T, dtype=np.float32)
        self.Cpos = np.ascontiguousarray(self.Fpos[self.cfine])
        n_nb = min(N_NEIGHBOURS, len(coarse))
        self.nbr = cKDTree(self.Cpos).query(self.Cpos, k=n_nb)[1].reshape(len(coarse), n_nb)
        self.nbr = np.ascontiguousarray(self.nbr, dtype=np.int64)
        # the pruned seed and pair stages' tables (``skinloc.models.multi_contact.pairs``)
        self.pair = PairTables(self.Cg, self.Cpos, float(self.prm[1]))
        widest = int(np.diff(self.off).max()) * n_nb
        n_top = max(1, min(int(rule.n_top), len(coarse)))
        self.arrays = SearchArrays(
            self.w,
            self.Ct,
            self.Cg,
            np.ascontiguousarray(np.diag(self.Cg), dtype=np.float64),
            self.Cpos,
            self.nbr,
            self.Ft,
            self.Fpos,
            self.Fpk,
            self.Fcell,
            self.off,
            self.cfine,
            _row_norms(self.Ft),
        )
        self.scratch = SearchScratch(
            xw=np.zeros(k, dtype=np.float32),
            bC=np.zeros(len(coarse)),
            g1=np.zeros(len(coarse)),
            top=np.zeros(n_top, dtype=np.int64),
            fi=np.zeros(3, dtype=np.int64),
            keep=np.zeros(3, dtype=np.int64),
            gq=np.zeros(widest),
            qq=np.zeros(widest, dtype=np.int64),
            s=np.zeros(3),
            spread=np.zeros(3),
            stats=np.zeros(12),
        )


class SearchMemory:
    """What one stream's last full search found, so that its next frames can skip it.

    A touch held on a skin is one finger frame after frame; the full search (seeds, every
    pair) asks each frame afresh whether a second finger arrived. The memory lets a frame
    answer "one contact" from the last full search's one-contact fit instead (``recall_into``)
    while (a) that search counted one contact, with its rule's score at most ``SAFE_SCORE``
    of the threshold (``remember``); (b) the one-contact fit, refined from where it was, leaves
    a relative residual at most ``RESIDUAL_GROWTH`` times the one the full search left (a
    second finger landing leaves its image unexplained); (c) fewer than ``REFRESH_FRAMES``
    frames were answered so since. Anything else runs the full search. One memory per stream
    (an engine serves several skins); ``reset`` at a touch's start.

    Attributes
    ----------
    state : (7,) float64
        By the ``MEM_*`` slots: valid (1.0 or 0.0), the one-contact fit's fine row, its
        relative residual ``R_1 / |xw|^2`` at the full search, frames answered since, the pair's
        two fine rows (-1: no pair), the fit's largest whitened residual at the full search
        (noise levels).
    """

    __slots__ = ("state",)

    def __init__(self) -> None:
        self.state = np.zeros(7)

    def reset(self) -> None:
        """Forget: the next frame is searched in full."""
        self.state[:] = 0.0


# --------------------------------------------------------------------------------------------
# compiled kernels


@jit()
def _dot(a: np.ndarray, b: np.ndarray) -> float:  # pragma: no cover - compiled
    acc = np.float32(0.0)
    for i in range(a.shape[0]):
        acc += a[i] * b[i]
    return float(acc)


@jit()
def _dot2(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple:  # pragma: no cover - compiled
    """``(_dot(a, b), _dot(a, c))`` in one pass over ``a``: the same sums, bit for bit.

    Each accumulator is reduced as ``_dot`` reduces its own; ``a`` is read once (the
    refinement's candidates cost about half as much).
    """
    ab = np.float32(0.0)
    ac = np.float32(0.0)
    for i in range(a.shape[0]):
        ab += a[i] * b[i]
        ac += a[i] * c[i]
    return float(ab), float(ac)


@jit()
def whiten_into(x: np.ndarray, w: np.ndarray, xw: np.ndarray) -> tuple:  # pragma: no cover
    """``xw = x * w`` (float32, whitened counts); returns ``(|xw|^2, max(0, max xw))``."""
    xx = 0.0
    zmax = 0.0
    for j in range(x.shape[0]):
        v = np.float32(x[j] * w[j])
        xw[j] = v
        xx += float(v) * float(v)
        zmax = max(zmax, float(v))
    return xx, zmax


@jit()
def _row_norms(Ft: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """``_dot(row, row)`` of every row of ``Ft (P, k)``: ``(P,)`` float64 (the search's own)."""
    n = np.empty(Ft.shape[0])
    for q in range(Ft.shape[0]):
        n[q] = _dot(Ft[q], Ft[q])
    return n


@jit()
def nnls2_interior(
    g11: float, g12: float, g22: float, b1: float, b2: float
) -> tuple:  # pragma: no cover - compiled
    """``nnls2``'s ``(gain, s1, s2)`` if both its strengths are positive, else ``(-1, 0, 0)``.

    The same arithmetic as ``nnls2``'s interior solution (its other answers have a zero
    strength). Without branches (the scans that call it per candidate pass its tests
    unpredictably): a degenerate pair divides by 1 and is refused.
    """
    det = g11 * g22 - g12 * g12
    ok = det > 1e-12 * g11 * g22
    d = det if ok else 1.0
    s1 = (g22 * b1 - g12 * b2) / d
    s2 = (g11 * b2 - g12 * b1) / d
    g = s1 * b1 + s2 * b2
    ok = ok & (s1 > 0.0) & (s2 > 0.0)
    return (g if ok else -1.0), (s1 if ok else 0.0), (s2 if ok else 0.0)


@jit()
def nnls2(
    g11: float, g12: float, g22: float, b1: float, b2: float
) -> tuple:  # pragma: no cover - compiled
    """NNLS of two columns: ``(gain, s1, s2)``."""
    det = g11 * g22 - g12 * g12
    if det > 1e-12 * g11 * g22:
        s1 = (g22 * b1 - g12 * b2) / det
        s2 = (g11 * b2 - g12 * b1) / det
        if s1 >= 0.0 and s2 >= 0.0:
            return s1 * b1 + s2 * b2, s1, s2
    ga = b1 * b1 / g11 if b1 > 0.0 else 0.0
    gb = b2 * b2 / g22 if b2 > 0.0 else 0.0
    if ga >= gb:
        return ga, (b1 / g11 if b1 > 0.0 else 0.0), 0.0
    return gb, 0.0, b2 / g22


@jit()
def _solve3(G: np.ndarray, b: np.ndarray) -> tuple:  # pragma: no cover - compiled
    """Least squares of three columns from their Gram ``G`` and ``b``, by cofactors.

    Returns ``(ok, s0, s1, s2)``: ``ok`` False (and zeros) for a degenerate ``G``; the
    strengths may be negative (``nnls`` and ``nnls3_interior`` decide what to keep).
    """
    a, bb, c = G[0, 0], G[0, 1], G[0, 2]
    d, e, f = G[1, 1], G[1, 2], G[2, 2]
    c00 = d * f - e * e
    c01 = c * e - bb * f
    c02 = bb * e - c * d
    det = a * c00 + bb * c01 + c * c02
    if not det > 1e-12 * a * d * f:
        return False, 0.0, 0.0, 0.0
    c11 = a * f - c * c
    c12 = bb * c - a * e
    c22 = a * d - bb * bb
    s0 = (c00 * b[0] + c01 * b[1] + c02 * b[2]) / det
    s1 = (c01 * b[0] + c11 * b[1] + c12 * b[2]) / det
    s2 = (c02 * b[0] + c12 * b[1] + c22 * b[2]) / det
    return True, s0, s1, s2


@jit()
def nnls(G: np.ndarray, b: np.ndarray, m: int, s: np.ndarray) -> float:  # pragma: no cover
    """Non-negative least squares of ``m <= 3`` columns from their Gram ``G`` and ``b``.

    Returns the gain ``s . b`` (the residual's reduction), the strengths in ``s[:m]``. For three
    columns: the unconstrained solution if it is feasible, else the best of the three pairs
    (the optimum then lies on a face).
    """
    if m == 1:
        s[0] = b[0] / G[0, 0] if b[0] > 0.0 else 0.0
        return s[0] * b[0]
    if m == 2:
        g, s[0], s[1] = nnls2(G[0, 0], G[0, 1], G[1, 1], b[0], b[1])
        return g
    ok, s0, s1, s2 = _solve3(G, b)
    if ok and s0 >= 0.0 and s1 >= 0.0 and s2 >= 0.0:
        s[0], s[1], s[2] = s0, s1, s2
        return s0 * b[0] + s1 * b[1] + s2 * b[2]
    a, bb, c = G[0, 0], G[0, 1], G[0, 2]
    d, e, f = G[1, 1], G[1, 2], G[2, 2]
    g01, p0, p1 = nnls2(a, bb, d, b[0], b[1])
    g02, q0, q2 = nnls2(a, c, f, b[0], b[2])
    g12, r1, r2 = nnls2(d, e, f, b[1], b[2])
    if g01 >= g02 and g01 >= g12:
        s[0], s[1], s[2] = p0, p1, 0.0
        return g01
    if g02 >= g12:
        s[0], s[1], s[2] = q0, 0.0, q2
        return g02
    s[0], s[1], s[2] = 0.0, r1, r2
    return g12


@jit()
def nnls3_interior(G: np.ndarray, b: np.ndarray, s: np.ndarray) -> float:  # pragma: no cover
    """``nnls(G, b, 3, s)``'s gain if its answer has three positive strengths, else -1.

    ``nnls``'s interior solution (``_solve3``); ``s`` is written only when kept.
    """
    ok, s0, s1, s2 = _solve3(G, b)
    if not (ok and s0 > 0.0 and s1 > 0.0 and s2 > 0.0):
        return -1.0
    s[0], s[1], s[2] = s0, s1, s2
    return s0 * b[0] + s1 * b[1] + s2 * b[2]


@jit()
def _refine(
    i: int,
    m: int,
    fi: np.ndarray,
    xw: np.ndarray,
    xx: float,
    arrays: SearchArrays,
    min2: float,
    gq: np.ndarray,
    qq: np.ndarray,
    s_out: np.ndarray,
    spread_on: bool = True,
) -> tuple:  # pragma: no cover - compiled
    """Move contact ``i`` of ``m`` (fine rows ``fi``) to its best candidate, the others fixed.

    Returns ``(gain, spread_mm)`` (spread nan unless ``spread_on``); ``fi[i]`` and the
    strengths ``s_out[:m]`` are updated.
    """
    w, Ct, Cg, Cd, Cpos, nbr, Ft, Fpos, Fpk, Fcell, off, cfine, Fn = arrays
    G = np.empty((3, 3))  # once per call, not per candidate
    b = np.empty(3)
    s = np.empty(3)
    for j in range(m):
        b[j] = _dot(Ft[fi[j]], xw)
        for t in range(j, m):
            G[j, t] = G[t, j] = _dot(Ft[fi[j]], Ft[fi[t]])
    home = Fcell[fi[i]]
    n = 0
    best = -1.0
    best_q = fi[i]
    for a in range(nbr.shape[1]):
        cell = nbr[home, a]
        for q in range(off[cell], off[cell + 1]):
            ok = True
            for j in range(m):
                if j != i and not far_apart(Fpos[q], Fpos[fi[j]], min2):
                    ok = False
            if not ok:
                continue
            row = Ft[q]
            if m == 1:
                b[i] = _dot(row, xw)
            else:
                # the image and the first other contact in one pass over the row
                j0 = 1 if i == 0 else 0
                b[i], g0 = _dot2(row, xw, Ft[fi[j0]])
                G[i, j0] = G[j0, i] = g0
                for j in range(j0 + 1, m):
                    if j != i:
                        G[i, j] = G[j, i] = _dot(row, Ft[fi[j]])
            G[i, i] = Fn[q]  # _dot(row, row), once per model
            g = nnls(G, b, m, s)
            gq[n] = g
            qq[n] = q
            n += 1
            if g > best:
                best = g
                best_q = q
                for j in range(m):
                    s_out[j] = s[j]
    if n == 0:  # nowhere to go: keep the contact
        return -1.0, math.nan
    fi[i] = best_q
    if not spread_on:
        return best, math.nan
    rmin = max(xx - best, 0.0)
    k = xw.shape[0]
    scale = 2.0 * max(rmin / max(k - 4 * m, 1), 1.0)
    wsum = 0.0
    acc = 0.0
    for r in range(n):
        e = (best - gq[r]) / scale
        if e > 50.0:
            continue
        wt = math.exp(-e)
        wsum += wt
        acc += wt * (
            (Fpos[qq[r], 0] - Fpos[best_q, 0]) ** 2
            + (Fpos[qq[r], 1] - Fpos[best_q, 1]) ** 2
            + (Fpos[qq[r], 2] - Fpos[best_q, 2]) ** 2
        )
    return best, 1e3 * math.sqrt(acc / wsum)


@jit()
def polish(
    m: int,
    fi: np.ndarray,
    xw: np.ndarray,
    xx: float,
    arrays: SearchArrays,
    min2: float,
    S: SearchScratch,
    rounds: int = 2,
    spread_on: bool = True,
) -> float:  # pragma: no cover - compiled
    """``rounds`` rounds of ``_refine`` over the ``m`` contacts; returns the gain.

    A round that moves no contact ends the polish: the next would repeat it exactly. The
    contacts' spreads (``S.spread``) only with ``spread_on`` (the reported contacts need them; a
    fit that only weighs the count does not).
    """
    return _rounds(m, fi, xw, xx, arrays, min2, S, rounds, spread_on)[0]


@jit()
def _rounds(
    m: int,
    fi: np.ndarray,
    xw: np.ndarray,
    xx: float,
    arrays: SearchArrays,
    min2: float,
    S: SearchScratch,
    rounds: int,
    spread_on: bool,
) -> tuple:  # pragma: no cover - compiled
    """``polish``'s rounds: ``(gain, settled)``.

    Settled: its last round moved no contact and every contact had somewhere to go (one more
    round then repeats it exactly).
    """
    gq, qq, s, spread = S.gq, S.qq, S.s, S.spread
    g = 0.0
    settled = False
    for _ in range(rounds):
        moved = False
        stuck = False
        for i in range(m):
            before = fi[i]
            gi, sp = _refine(i, m, fi, xw, xx, arrays, min2, gq, qq, s, spread_on)
            if gi >= 0.0:
                g = gi
                spread[i] = sp
            else:
                stuck = True
            moved = moved or fi[i] != before
        settled = not moved and not stuck
        if not moved:
            break
    return g, settled


@jit()
def relative_gain(r_prev: float, r_next: float, floor: float) -> float:  # pragma: no cover
    """What one more contact brings: ``(r_prev - r_next) / (r_next + floor)``.

    ``floor`` (whitened counts^2) is the residual the model leaves on a touch it explains
    (``CountRule.misfit`` times the image's energy; 0: the residual alone).
    """
    return (r_prev - r_next) / (r_next + floor)


@jit()
def weakest_z(m: int, fi: np.ndarray, s: np.ndarray, Fpk: np.ndarray) -> float:  # pragma: no cover
    """The weakest of ``m`` contacts' peak signals, noise levels (strength times peak)."""
    z = np.inf
    for j in range(m):
        z = min(z, s[j] * Fpk[fi[j]])
    return z


@jit()
def search_into(
    x: np.ndarray,
    K: int,
    arrays: SearchArrays,
    prm: np.ndarray,
    S: SearchScratch,
    calib: bool,
    out: np.ndarray,
    pair: tuple,
    pair_s: tuple,
) -> int:  # pragma: no cover - compiled
    """The contacts of one image ``x (k,)`` float32 counts into ``out (K, 5)``; returns their count.

    ``arrays``, ``prm``, ``S``: ``SearchTables.arrays``, ``.prm`` (the ``PRM_*`` slots of
    ``CountRule.params``), ``.scratch``; ``pair``,
    ``pair_s``: ``SearchTables.pair.arrays`` and ``.scratch`` (the pruned seed and pair stages).

    A count of 1 leaves ``out`` to the caller (the model's single-contact answer). With
    ``calib`` every stage up to ``K`` runs whatever the rule says (for its calibration); the
    statistics go to ``S.stats`` (the ``STAT_*`` slots).
    """
    w, Ct, Cg, Cd, Cpos, nbr, Ft, Fpos, Fpk, Fcell, off, cfine, Fn = arrays
    xw, bC, g1, top, fi, keep, gq, qq, s, spread, st = S
    z_on, min2, tau2, tau3 = prm[PRM_Z_ON], prm[PRM_MIN2], prm[PRM_TAU2], prm[PRM_TAU3]
    z2_min, z3_min = prm[PRM_Z2_MIN], prm[PRM_Z3_MIN]
    xx, zmax = whiten_into(x, w, xw)
    st[:] = 0.0
    st[STAT_XX] = xx
    # the model's typical misfit of one touch: a reduction within it is no second finger
    floor = prm[PRM_MISFIT] * xx
    if zmax < z_on and not calib:
        return 0
    if K <= 1:
        return 1
    C = Ct.shape[0]
    for c in range(C):
        bc = _dot(Ct[c], xw)
        bC[c] = bc
        g1[c] = bc * bc / Cd[c] if bc > 0.0 else 0.0
    # seeds: the best one-contact candidates, each at least half the separation from the rest;
    # then every seed with every coarse candidate far enough from it (pruned: multi_contact.pairs)
    n_seeds, pa, pb = seeds_and_pair(bC, g1, Cg, Cd, Cpos, min2, top, pair, pair_s)
    # one contact, refined (its residual is what a second must improve on; its spread is
    # never reported: one contact is the model's single-contact answer)
    fi[0] = cfine[top[0]]
    gain1 = polish(1, fi, xw, xx, arrays, 0.0, S, 2, False)
    st[STAT_G1] = gain1
    st[STAT_ROW1] = fi[0]
    if pa < 0:
        return 1
    fi[0] = cfine[pa]
    fi[1] = cfine[pb]
    # the pair's spreads only matter if it is reported: polished without them first
    gain2, settled = _rounds(2, fi, xw, xx, arrays, min2, S, 2, False)
    z2 = weakest_z(2, fi, s, Fpk)
    st[STAT_G2] = gain2
    st[STAT_Z2] = z2
    r1 = max(xx - gain1, 1.0)
    r2 = max(xx - gain2, 1.0)
    zp = prm[PRM_Z_POWER]
    two = relative_gain(r1, r2, floor) * max(z2, 0.0) ** zp >= tau2 and z2 >= z2_min
    if not two and not calib:
        return 1
    count = 2 if two else 1
    if settled:
        # a round that moves nothing, as the polish with spreads would have ended
        polish(2, fi, xw, xx, arrays, min2, S, 1, True)
    else:
        fi[0] = cfine[pa]
        fi[1] = cfine[pb]
        polish(2, fi, xw, xx, arrays, min2, S)
    for j in range(2):
        keep[j] = fi[j]
        out[j, 3] = s[j]
        out[j, 4] = spread[j]
    if K >= 3:
        best3 = -1.0
        pc = -1
        G = np.empty((3, 3))
        b = np.empty(3)
        for j in range(2):
            b[j] = _dot(Ft[fi[j]], xw)
            for t in range(2):
                G[j, t] = _dot(Ft[fi[j]], Ft[fi[t]])
        r0, r1_ = Ft[fi[0]], Ft[fi[1]]
        for c in range(C):
            far = far_apart(Cpos[c], Fpos[fi[0]], min2)
            if not (far and far_apart(Cpos[c], Fpos[fi[1]], min2)):
                continue
            b[2] = bC[c]
            if b[2] <= 0.0:
                continue
            G[2, 2] = Cd[c]
            g20, g21 = _dot2(Ct[c], r0, r1_)
            G[2, 0] = G[0, 2] = g20
            G[2, 1] = G[1, 2] = g21
            # only a solution with three positive strengths is kept: that is NNLS's
            # interior one (its faces have a zero strength), so the faces are not solved
            g = nnls3_interior(G, b, s)
            if g > best3:
                best3 = g
                pc = c
        if pc >= 0:
            fi[2] = cfine[pc]
            gain3 = polish(3, fi, xw, xx, arrays, min2, S)
            z3 = weakest_z(3, fi, s, Fpk)
            st[STAT_G3] = gain3
            st[STAT_Z3] = z3
            r3 = max(xx - gain3, 1.0)
            rho3 = relative_gain(r2, r3, floor) * max(z3, 0.0) ** zp
            if two and rho3 >= tau3 and z3 >= z3_min:
                count = 3
                for j in range(3):
                    keep[j] = fi[j]
                    out[j, 3] = s[j]
                    out[j, 4] = spread[j]
    if count == 1:
        return 1
    for j in range(count):
        st[STAT_ROWS + j] = keep[j]  # the contacts' fine rows, for the caller's polish
        for t in range(3):
            out[j, t] = Fpos[keep[j], t]
    # strongest first (at most 3 rows: insertion sort)
    for j in range(1, count):
        t = j
        while t > 0 and out[t, 3] > out[t - 1, 3]:
            for col in range(N_COLS):
                out[t, col], out[t - 1, col] = out[t - 1, col], out[t, col]
            a, b_ = STAT_ROWS + t, STAT_ROWS + t - 1
            st[a], st[b_] = st[b_], st[a]
            t -= 1
    return count


@jit()
def single_into(
    x: np.ndarray, w: np.ndarray, z_on: float, out7: np.ndarray, out: np.ndarray
) -> int:  # pragma: no cover - compiled
    """The detection rule and the strength of one contact; returns 0 (nothing) or 1.

    ``out7`` is the single-contact answer (``Engine.localise_into``'s layout); the contact
    goes to ``out[0]`` (5 columns).
    """
    zmax = 0.0
    nrm = 0.0
    for j in range(x.shape[0]):
        v = float(x[j])
        zmax = max(zmax, v * w[j])
        if v > 0.0:
            nrm += v * v
    if zmax < z_on:
        return 0
    for t in range(3):
        out[0, t] = out7[3 + t]
    out[0, 3] = math.sqrt(nrm)
    out[0, 4] = out7[6]
    return 1


@jit()
def _residual_peak(xw: np.ndarray, row: int, arrays: SearchArrays) -> float:  # pragma: no cover
    """The largest whitened residual of the one-contact fit at fine row ``row`` (noise levels)."""
    Ft, Fn = arrays.Ft, arrays.Fn
    b = _dot(Ft[row], xw)
    sc = b / Fn[row] if b > 0.0 and Fn[row] > 0.0 else 0.0
    e = -np.inf
    for j in range(xw.shape[0]):
        e = max(e, float(xw[j]) - sc * float(Ft[row, j]))
    return e


@jit()
def _score(
    xx: float, g1: float, g2: float, z2: float, prm: np.ndarray
) -> float:  # pragma: no cover - compiled
    """The count rule's score of two contacts over one, as a share of ``tau2`` (0: no pair)."""
    if g2 <= 0.0:
        return 0.0
    r1 = max(xx - g1, 1.0)
    r2 = max(xx - g2, 1.0)
    rho = relative_gain(r1, r2, prm[PRM_MISFIT] * xx) * max(z2, 0.0) ** prm[PRM_Z_POWER]
    if prm[PRM_TAU2] <= 0.0:
        # tau2 0: no held-out single touch reached z2_min at calibration (a small session), so
        # any pair counts; its share of tau2 is unbounded, never safe
        return math.inf if rho > 0.0 else 0.0
    return rho / prm[PRM_TAU2]


@jit()
def remember(
    K: int, n: int, arrays: SearchArrays, prm: np.ndarray, S: SearchScratch, mem: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Record a full search's answer ``n`` (scratch ``S``, ``SearchTables.scratch``) in ``mem``.

    Only a count of one whose rule score is at most ``SAFE_SCORE`` of ``tau2`` starts a
    memory (``SearchMemory``): its one-contact fit's row and the pair's rows (-1: none).
    """
    st, fi = S.stats, S.fi
    mem[MEM_VALID] = 0.0
    xx = st[STAT_XX]
    g1, g2 = st[STAT_G1], st[STAT_G2]
    if K <= 1 or n != 1 or xx <= 0.0 or _score(xx, g1, g2, st[STAT_Z2], prm) > SAFE_SCORE:
        return
    mem[MEM_VALID] = 1.0
    mem[MEM_ROW1] = st[STAT_ROW1]
    mem[MEM_RESIDUAL] = max(xx - g1, 1.0) / xx
    mem[MEM_FRAMES] = 0.0
    # a count of one leaves the polished pair in fi
    mem[MEM_PAIR] = fi[0] if g2 > 0.0 else -1.0
    mem[MEM_PAIR + 1] = fi[1] if g2 > 0.0 else -1.0
    mem[MEM_PEAK] = _residual_peak(S.xw, int(st[STAT_ROW1]), arrays)


@jit()
def recall_into(
    x: np.ndarray, arrays: SearchArrays, prm: np.ndarray, S: SearchScratch, mem: np.ndarray
) -> int:  # pragma: no cover - compiled
    """One frame answered from a stream's memory: -1 (search in full), 0 or 1 contacts.

    0 is the full search's own first test (no sensor at ``z_on``); 1 leaves ``out`` to the
    caller, as the full search does. The one-contact fit is refined from the memory's row as
    the full search refines its best seed (``polish``, two rounds), the pair from the
    memory's pair (one round); their rule score must stay at most ``SAFE_SCORE`` of ``tau2``
    and the one-contact residual within ``RESIDUAL_GROWTH`` of the remembered one. The
    statistics go to ``S.stats`` as the full search's (g1, g2, weakest z of 2, ``|xw|^2``).
    """
    if mem[MEM_VALID] == 0.0 or mem[MEM_FRAMES] >= REFRESH_FRAMES:
        return -1
    w = arrays.w
    xw, fi, s, st = S.xw, S.fi, S.s, S.stats
    xx, zmax = whiten_into(x, w, xw)
    st[:] = 0.0
    st[STAT_XX] = xx
    if zmax < prm[PRM_Z_ON]:
        mem[MEM_VALID] = 0.0
        return 0
    fi[0] = int(mem[MEM_ROW1])
    gain1 = polish(1, fi, xw, xx, arrays, 0.0, S, 2, False)
    if max(xx - gain1, 1.0) > RESIDUAL_GROWTH * mem[MEM_RESIDUAL] * xx:
        return -1
    peak = _residual_peak(xw, fi[0], arrays)
    if peak > PEAK_GROWTH * mem[MEM_PEAK] and peak > 0.5 * prm[PRM_Z2_MIN]:
        return -2
    st[STAT_G1] = gain1
    st[STAT_ROW1] = fi[0]
    row1 = fi[0]
    if mem[MEM_PAIR] >= 0.0:
        fi[0] = int(mem[MEM_PAIR])
        fi[1] = int(mem[MEM_PAIR + 1])
        gain2 = polish(2, fi, xw, xx, arrays, prm[PRM_MIN2], S, 1, False)
        z2 = weakest_z(2, fi, s, arrays.Fpk)
        if _score(xx, gain1, gain2, z2, prm) > SAFE_SCORE:
            return -3
        st[STAT_G2] = gain2
        st[STAT_Z2] = z2
        mem[MEM_PAIR] = fi[0]
        mem[MEM_PAIR + 1] = fi[1]
    mem[MEM_ROW1] = row1
    mem[MEM_FRAMES] += 1.0
    return 1


@jit()
def search_remember(
    x: np.ndarray,
    K: int,
    arrays: SearchArrays,
    prm: np.ndarray,
    S: SearchScratch,
    out: np.ndarray,
    pair: tuple,
    pair_s: tuple,
    mem: np.ndarray,
    use_memory: bool,
) -> int:  # pragma: no cover - compiled
    """``search_into``, then (``use_memory``) ``remember`` in ``mem``, in one call.

    Each compiled call unboxes every table again (1-2 µs): a frame the memory could not
    answer pays for ``recall_into``'s and this one's only.
    """
    n = search_into(x, K, arrays, prm, S, False, out, pair, pair_s)
    if use_memory:
        remember(K, n, arrays, prm, S, mem)
    return n
