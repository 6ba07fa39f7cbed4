"""The response map's match, compiled: coarse cells by an exact pruned search, then the fine ones.

Prediction for baseline-subtracted counts ``x (k,)``::

    f = max(x, 0) / max(||max(x, 0)||_2, 1)         # (k,) float32; without clipping, x
    d(p) = |table[p]|^2 - 2 f . table[p] + |f|^2     # squared feature distance to candidate p
    coarse: the n_cells cells (every 16th candidate and the candidates nearest it) whose
            coarse point is nearest; fine: every candidate of those cells
    point = raw = the fine candidate of least d
    spread_mm = 1e3 * sqrt(sum_p w_p |c_p - point|^2 / sum_p w_p),
                w_p = exp(-(d(p) - d_min) / max(d_min, 2 noise)) over the fine candidates
                (a padded cell's coarse point counts once per pad)

The coarse stage finds the nearest cells exactly without measuring every coarse point (900 on
the paper's skin, against about 130 fine candidates). The engine groups the coarse points by
their features (k-means, about ``2 sqrt(C)`` groups) and keeps each group's centre ``mu`` and
each member's distance ``r`` to it. Since ``f . t <= f . mu + |f| r``, the coarse distance of a
member is at least ``|t|^2 - 2 f . mu - 2 |f| r``: the group of least bound is measured first,
then every group and member whose bound does not exceed the ``n_cells``-th best distance found
so far (the bounds are loosened by ``_EPS`` times the table's scale, far above float32
rounding, so nothing is passed over that could be chosen). A touched frame of the paper's skin
measures 60 centres and about 70 coarse points instead of 900.

One kernel per row does it all, for a single frame (``localise_into``) and for every row of a
batch (rows in parallel, both cores): a frame gets the same answer alone or in a batch, and the
answer of the search over every coarse point.
"""

from __future__ import annotations

import math

import numpy as np

from skinloc._jit import jit, prange
from skinloc.models.engine import clip_and_norm

#: Loosening of the coarse bounds, relative to the table's largest squared norm: features have
#: at most unit norm, so the float32 rounding of a distance or a bound is about 1e-6 of it.
_EPS = 1e-4
#: Rows per parallel task of a batch (each task allocates its scratch once).
ROWS = 256
#: Lloyd iterations that group the coarse points (the grouping only sets the speed).
_KMEANS_ITER = 10


@jit()
def _features(x: np.ndarray, clip: int, f: np.ndarray) -> float:  # pragma: no cover - compiled
    """Shape features of one image into ``f (k,)`` float32; returns ``|f|^2``."""
    inv = clip_and_norm(x, clip, 2, f)
    ff = 0.0
    for i in range(f.shape[0]):
        fv = np.float32(f[i] * inv)
        f[i] = fv
        ff += float(fv) * float(fv)
    return ff


@jit()
def _dot(f: np.ndarray, row: np.ndarray) -> float:  # pragma: no cover - compiled
    """``f . row`` in float32, summed in the one order every path uses (``row`` a row view)."""
    acc = np.float32(0.0)
    for i in range(f.shape[0]):
        acc += f[i] * row[i]
    return acc


@jit()
def _nearest_cells(
    f: np.ndarray, nf: float, fmu: np.ndarray, groups: tuple, scratch: tuple
) -> None:  # pragma: no cover - compiled
    """The ``n_cells`` coarse cells nearest ``f``, nearest first, into ``best_c``.

    ``groups`` = (mu (G, k) float32 centres, gmin (G,) least ``|t|^2`` of each group, gmax_r
    (G,) its largest ``r``, gtab (C, k) float32 coarse points in group order, gsq (C,) their
    ``|t|^2``, grad (C,) their ``r``, gcell (C,) their cell, goff (G + 1,) each group's rows,
    eps the bounds' loosening).
    ``nf`` is ``|f|`` and ``fmu (G,)`` float32 ``mu @ f`` (a loop, or a batch's matrix
    product: the bounds allow for either's rounding). ``scratch`` = (f, fmu, lb (G,), best_v
    (n_cells,), best_c (n_cells,), ...): ``best_v`` gets the chosen cells' distances (less
    ``|f|^2``), sorted, ties to the lower cell (so the cells kept do not depend on the order
    they come in). One function, no calls: this loop is the hot one, and numba's calls cost
    here.
    """
    mu, gmin, gmax_r, gtab, gsq, grad, gcell, goff, eps = groups
    lb, best_v, best_c = scratch[2], scratch[3], scratch[4]
    G = gmin.shape[0]
    k = f.shape[0]
    nb = best_v.shape[0]
    g0 = 0
    for g in range(G):  # each group's bound; g0 the least
        lb[g] = gmin[g] - 2.0 * fmu[g] - 2.0 * nf * gmax_r[g]
        if lb[g] < lb[g0]:
            g0 = g
    best_v[:] = np.inf
    best_c[:] = len(gcell)
    for t in range(G + 1):  # g0 first (it sets a tight bound at once), then the others
        g = g0 if t == 0 else t - 1
        if (t > 0 and g == g0) or lb[g] > best_v[nb - 1] + eps:
            continue
        for j in range(goff[g], goff[g + 1]):
            if gsq[j] - 2.0 * fmu[g] - 2.0 * nf * grad[j] > best_v[nb - 1] + eps:
                continue
            acc = np.float32(0.0)
            row = gtab[j]
            for i in range(k):
                acc += f[i] * row[i]
            v = float(gsq[j] - np.float32(2.0) * acc)
            c = gcell[j]
            u = nb - 1
            if v > best_v[u] or (v == best_v[u] and c >= best_c[u]):
                continue
            while u > 0 and (best_v[u - 1] > v or (best_v[u - 1] == v and best_c[u - 1] > c)):
                best_v[u] = best_v[u - 1]
                best_c[u] = best_c[u - 1]
                u -= 1
            best_v[u] = v
            best_c[u] = c


@jit()
def _exp_neg(e: float) -> float:  # pragma: no cover - compiled
    """``exp(-e)`` for ``0 <= e <= 50`` to about 1e-9 relative, in arithmetic a loop vectorises.

    ``exp(-e) = exp(-e / 128) ** 128``: a degree-9 Taylor series, squared seven times.
    """
    y = -e * (1.0 / 128.0)
    p = 1.0 + y * (
        1.0
        + y
        * (1.0 / 2.0)
        * (
            1.0
            + y
            * (1.0 / 3.0)
            * (
                1.0
                + y
                * (1.0 / 4.0)
                * (
                    1.0
                    + y
                    * (1.0 / 5.0)
                    * (
                        1.0
                        + y
                        * (1.0 / 6.0)
                        * (
                            1.0
                            + y * (1.0 / 7.0) * (1.0 + y * (1.0 / 8.0) * (1.0 + y * (1.0 / 9.0)))
                        )
                    )
                )
            )
        )
    )
    for _ in range(7):
        p = p * p
    return p


@jit()
def _fine(
    f: np.ndarray, ff: float, best_c: np.ndarray, fine: tuple, d: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """The chosen cells in full, into ``out (7,)`` = [point (3), point (3), spread_mm].

    ``fine`` = (tt, sqp, cand, off, pad_n, pad_pos, noise): ``tt (P, k)`` is the table with
    the candidates grouped by coarse cell (cell c is rows ``off[c]:off[c+1]``, each candidate
    once), ``sqp`` their squared norms, ``cand (3, P)`` their points (m). ``pad_n`` and
    ``pad_pos`` give the padding of each cell (its coarse point repeated), which weighs in the
    spread. ``d (2, n)`` is scratch: the candidates' distances, then their weights. A map's raw
    output lies on the surface.
    """
    tt, sqp, cand, off, pad_n, pad_pos, noise = fine
    nb = best_c.shape[0]
    dist = d[0]
    w = d[1]
    dmin = np.inf
    best = -1
    j = 0
    for b in range(nb):
        c = best_c[b]
        for p in range(off[c], off[c + 1]):
            dv = max(float(sqp[p] - np.float32(2.0) * _dot(f, tt[p])) + ff, 0.0)
            dist[j] = dv
            if dv < dmin:
                dmin = dv
                best = p
            j += 1
    n = j
    inv_scale = 1.0 / max(dmin, 2.0 * noise)
    for j in range(n):
        e = (dist[j] - dmin) * inv_scale
        w[j] = _exp_neg(e) if e <= 50.0 else 0.0  # beyond: below 2e-22, nothing to add
    j = 0
    for b in range(nb):  # a padded cell's coarse point counts once per pad
        c = best_c[b]
        if pad_pos[c] >= 0:
            w[j + pad_pos[c]] *= 1.0 + pad_n[c]
        j += off[c + 1] - off[c]
    bx, by, bz = cand[0, best], cand[1, best], cand[2, best]
    cx, cy, cz = cand[0], cand[1], cand[2]
    wsum = 0.0
    acc2 = 0.0
    j = 0
    for b in range(nb):
        c = best_c[b]
        j0 = j - off[c]
        for p in range(off[c], off[c + 1]):
            wp = w[j0 + p]
            wsum += wp
            acc2 += wp * ((cx[p] - bx) ** 2 + (cy[p] - by) ** 2 + (cz[p] - bz) ** 2)
        j += off[c + 1] - off[c]
    out[0] = bx
    out[1] = by
    out[2] = bz
    out[3] = bx
    out[4] = by
    out[5] = bz
    out[6] = 1e3 * math.sqrt(acc2 / wsum)


@jit()
def new_scratch(k: int, n_groups: int, n_best: int, n_fine: int) -> tuple:  # pragma: no cover
    """Scratch of one row at a time: (f, fmu, lb, best_v, best_c, d)."""
    return (
        np.zeros(k, dtype=np.float32),
        np.zeros(n_groups, dtype=np.float32),
        np.zeros(n_groups),
        np.zeros(n_best),
        np.zeros(n_best, dtype=np.int64),
        np.zeros((2, n_fine)),
    )


@jit()
def match_one(
    x: np.ndarray, clip: int, groups: tuple, fine: tuple, scratch: tuple, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """One image ``x (k,)`` into ``out (7,)``: features, nearest cells, fine search."""
    f, fmu = scratch[0], scratch[1]
    ff = _features(x, clip, f)
    mu = groups[0]
    for g in range(mu.shape[0]):
        fmu[g] = _dot(f, mu[g])
    _nearest_cells(f, math.sqrt(ff), fmu, groups, scratch)
    _fine(f, ff, scratch[4], fine, scratch[5], out)


@jit()
def match_rows(
    X: np.ndarray, clip: int, groups: tuple, fine: tuple, sizes: tuple, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """``match_one`` over the rows of ``X (n, k)`` into ``out (n, 7)``, on this thread."""
    scratch = new_scratch(sizes[0], sizes[1], sizes[2], sizes[3])
    for r in range(X.shape[0]):
        match_one(X[r], clip, groups, fine, scratch, out[r])


@jit(parallel=True)
def match_many(
    X: np.ndarray,
    clip: int,
    groups: tuple,
    mu_t: np.ndarray,
    fine: tuple,
    sizes: tuple,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``match_one`` over the rows of ``X (n, k)`` into ``out (n, 7)``, in parallel tasks.

    Each task's products with the group centres are one float32 matrix product (BLAS, one
    thread per task: see ``MapEngine._predict_rows``); ``mu_t (k, G)`` is ``mu`` transposed.
    """
    n = X.shape[0]
    for task in prange((n + ROWS - 1) // ROWS):
        r0 = task * ROWS
        rows = min(n, r0 + ROWS) - r0
        scratch = new_scratch(sizes[0], sizes[1], sizes[2], sizes[3])
        F = np.empty((rows, X.shape[1]), dtype=np.float32)
        ff = np.empty(rows)
        for r in range(rows):
            ff[r] = _features(X[r0 + r], clip, F[r])
        FMU = np.dot(F, mu_t)  # (rows, G)
        for r in range(rows):
            _nearest_cells(F[r], math.sqrt(ff[r]), FMU[r], groups, scratch)
            _fine(F[r], ff[r], scratch[4], fine, scratch[5], out[r0 + r])


def _group_coarse(ct: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group the coarse points ``ct (C, k)`` by feature (k-means, about ``2 sqrt(C)`` groups).

    Deterministic (farthest-point start, then Lloyd iterations). Returns ``(label (C,) int,
    centres (G, k) float32)`` with no empty group; the centres are the members' means.
    """
    X = ct.astype(np.float64)
    n_groups = max(1, min(len(X), round(2.0 * math.sqrt(len(X)))))
    seeds = [0]
    d2 = ((X - X[0]) ** 2).sum(axis=1)
    for _ in range(n_groups - 1):
        seeds.append(int(np.argmax(d2)))
        d2 = np.minimum(d2, ((X - X[seeds[-1]]) ** 2).sum(axis=1))
    centres = X[seeds]
    for _ in range(_KMEANS_ITER + 1):  # the last pass only labels, by the final centres
        label = np.argmin((centres**2).sum(1)[None, :] - 2.0 * X @ centres.T, axis=1)
        used, label = np.unique(label, return_inverse=True)  # drop emptied groups
        member = np.arange(len(used))[:, None] == label[None, :]  # (G, C)
        centres = (member @ X) / member.sum(axis=1, keepdims=True)
    return label, centres.astype(np.float32)


def coarse_groups(ct: np.ndarray, csq: np.ndarray) -> tuple:
    """The coarse points as ``_nearest_cells`` takes them: grouped, with the bounds' radii.

    ``ct (C, k)`` float32 are the coarse points' features and ``csq (C,)`` their ``|t|^2``.
    """
    label, centres = _group_coarse(ct)
    order = np.argsort(label, kind="stable")
    goff = np.concatenate([[0], np.cumsum(np.bincount(label))]).astype(np.int64)
    # radii from the float32 values the kernels use, rounded up: the bounds must hold exactly
    r = np.sqrt(((ct[order].astype(np.float64) - centres[label[order]]) ** 2).sum(axis=1))
    r = r * (1.0 + 1e-6) + 1e-9
    gsq = csq[order].astype(np.float32)
    gmin = np.array([gsq[a:b].min() for a, b in zip(goff[:-1], goff[1:], strict=True)], float)
    gmax_r = np.array([r[a:b].max() for a, b in zip(goff[:-1], goff[1:], strict=True)])
    return (
        centres,
        gmin,
        gmax_r,
        np.ascontiguousarray(ct[order]),
        gsq,
        r,
        order.astype(np.int64),
        goff,
        _EPS * max(1.0, float(csq.max())),
    )
