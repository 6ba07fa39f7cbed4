"""The response-map engine: an image's shape matched against the map at every candidate point.

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

import functools
import math
import threading
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from skinloc._jit import jit, prange
from skinloc._typing import Points
from skinloc.models.contact_search import SearchTables, search_into, single_into
from skinloc.models.engine import Engine, ModelSpec, clip_and_norm

__all__ = ["MapEngine", "MapSpec"]

#: Loosening of the coarse bounds, relative to the table's largest squared norm: features have
#: at most unit norm, so the float32 rounding of a distance or a bound is about 1e-6 of it.
_EPS = 1e-4
#: Rows per parallel task of a batch (each task allocates its scratch once).
_ROWS = 256
#: Lloyd iterations that group the coarse points (the grouping only sets the speed).
_KMEANS_ITER = 10


@dataclass(kw_only=True)
class MapSpec(ModelSpec):
    """A response map as arrays (see the module's docstring for the arithmetic).

    ``surface_points`` are the candidates (required); the constraint is always ``snap``.

    Attributes
    ----------
    table : (P, k) float32
        The map's predicted features at every candidate.
    coarse : (C,) int
        Candidates of the coarse level.
    cells : (C, m) int
        Each coarse candidate's cell, padded by repeating the coarse candidate.
    noise : float
        Residual feature variance of the map (per feature).
    n_cells : int
        Coarse cells searched in full.
    unit_table : (P, k) float32 or None
        The amplitude map's unit image at every candidate (counts per count of strength), for
        ``Engine.contacts``; ``None`` (maps saved before it): the shape table stands in.
    """

    kind: ClassVar[str] = "map"

    table: np.ndarray
    coarse: np.ndarray
    cells: np.ndarray
    noise: float
    n_cells: int = 8
    unit_table: np.ndarray | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.surface_points is None or len(self.surface_points) != len(self.table):
            raise ValueError("a MapSpec needs one surface point (candidate) per table row")
        if self.cells.ndim != 2 or len(self.cells) != len(self.coarse):
            raise ValueError("a MapSpec needs one cell row per coarse candidate")
        if self.unit_table is not None and np.shape(self.unit_table) != np.shape(self.table):
            raise ValueError("a MapSpec's unit table must have the shape of its table")

    def engine(self, constraint: str | None = None) -> MapEngine:
        """The compiled engine of this map."""
        return MapEngine(self)


# --------------------------------------------------------------------------------------------
# compiled kernels


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
def _new_scratch(k: int, n_groups: int, n_best: int, n_fine: int) -> tuple:  # pragma: no cover
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
def _match_one(
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
def _match_rows(
    X: np.ndarray, clip: int, groups: tuple, fine: tuple, sizes: tuple, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """``_match_one`` over the rows of ``X (n, k)`` into ``out (n, 7)``, on this thread."""
    scratch = _new_scratch(sizes[0], sizes[1], sizes[2], sizes[3])
    for r in range(X.shape[0]):
        _match_one(X[r], clip, groups, fine, scratch, out[r])


@jit(parallel=True)
def _match_many(
    X: np.ndarray,
    clip: int,
    groups: tuple,
    mu_t: np.ndarray,
    fine: tuple,
    sizes: tuple,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``_match_one`` over the rows of ``X (n, k)`` into ``out (n, 7)``, in parallel tasks.

    Each task's products with the group centres are one float32 matrix product (BLAS, one
    thread per task: see ``MapEngine._predict_rows``); ``mu_t (k, G)`` is ``mu`` transposed.
    """
    n = X.shape[0]
    for task in prange((n + _ROWS - 1) // _ROWS):
        r0 = task * _ROWS
        rows = min(n, r0 + _ROWS) - r0
        scratch = _new_scratch(sizes[0], sizes[1], sizes[2], sizes[3])
        F = np.empty((rows, X.shape[1]), dtype=np.float32)
        ff = np.empty(rows)
        for r in range(rows):
            ff[r] = _features(X[r0 + r], clip, F[r])
        FMU = np.dot(F, mu_t)  # (rows, G)
        for r in range(rows):
            _nearest_cells(F[r], math.sqrt(ff[r]), FMU[r], groups, scratch)
            _fine(F[r], ff[r], scratch[4], fine, scratch[5], out[r0 + r])


@jit()
def _contact_one(
    x: np.ndarray,
    clip: int,
    groups: tuple,
    fine: tuple,
    scratch: tuple,
    out7: np.ndarray,
    w: np.ndarray,
    z_on: float,
    out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """``_match_one`` and the detection rule in one call: the single contact (0 or 1)."""
    _match_one(x, clip, groups, fine, scratch, out7)
    return single_into(x, w, z_on, out7, out)


@jit()
def _peel(
    x: np.ndarray,
    n: int,
    rows: np.ndarray,
    arrays: tuple,
    min2: float,
    clip: int,
    groups: tuple,
    fine: tuple,
    scratch: tuple,
    out7: np.ndarray,
    z: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Each of ``n`` contacts placed by this map's single-contact match on its own image.

    Contact ``i``'s image is ``x`` less the others' fitted images (strength times the unit
    image at their rows ``rows``); the single-contact match is the map's best-tuned answer, so
    each finger is placed as precisely as a finger alone, with that answer's spread (mm) as
    its uncertainty. A place within the minimum separation of another contact keeps the
    search's own place and spread.
    """
    w, Ft = arrays[0], arrays[6]
    for i in range(n):
        for j in range(x.shape[0]):
            v = float(x[j])
            for o in range(n):
                if o != i:
                    v -= out[o, 3] * Ft[int(rows[o]), j] / w[j]
            z[j] = v
        _match_one(z, clip, groups, fine, scratch, out7)
        ok = True
        for o in range(n):
            d = 0.0
            for t in range(3):
                d += (out7[3 + t] - out[o, t]) ** 2
            if o != i and d < min2:
                ok = False
        if ok:  # the single-contact answer's place and spread, as for a finger alone
            out[i, 0], out[i, 1], out[i, 2] = out7[3], out7[4], out7[5]
            out[i, 4] = out7[6]


# --------------------------------------------------------------------------------------------
# the engine


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


def _coarse_groups(ct: np.ndarray, csq: np.ndarray) -> tuple:
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


class MapEngine(Engine):
    """The compiled coarse-to-fine matcher of a ``MapSpec``."""

    kind: ClassVar[str] = "map"

    def __init__(self, spec: MapSpec, constraint: str | None = None) -> None:
        # the constraint of the pipeline's filtered points: the map's own candidates
        super().__init__(spec, "snap")
        table = np.asarray(spec.table, dtype=np.float32)
        sq = (table**2).sum(axis=1)
        coarse = np.asarray(spec.coarse, dtype=np.int64)
        perm, off, pad_n, pad_pos = [], [0], [], []
        for c, row in enumerate(np.asarray(spec.cells, dtype=np.int64)):
            members = list(dict.fromkeys(row.tolist()))  # unique, in order
            pad_n.append(len(row) - len(members))
            pad_pos.append(members.index(int(coarse[c])) if coarse[c] in members else -1)
            if pad_n[-1] and pad_pos[-1] < 0:
                raise ValueError("response-map cell padding without its coarse point")
            perm += members
            off.append(len(perm))
        perm_a = np.asarray(perm, dtype=np.int64)
        self._clip = int(spec.clip_negative)
        # small products: BLAS's threads would cost more to wake than the work (30 ms a
        # product on a loaded machine)
        with _BLAS_LOCK, _blas_controller().limit(limits=1, user_api="blas"):
            self._groups = _coarse_groups(table[coarse], sq[coarse])
        self._mu_t = np.ascontiguousarray(self._groups[0].T)
        n_best = min(int(spec.n_cells), len(coarse))
        self._fine = (
            np.ascontiguousarray(table[perm_a]),  # (P', k), grouped by cell
            sq[perm_a],
            np.ascontiguousarray(np.asarray(spec.surface_points, dtype=np.float64)[perm_a].T),
            np.asarray(off, dtype=np.int64),
            np.asarray(pad_n, dtype=np.int64),
            np.asarray(pad_pos, dtype=np.int64),
            float(spec.noise),
        )
        widest = np.sort(np.diff(off))[::-1][:n_best].sum()  # the most fine candidates a row has
        self._sizes = (self.n_features, len(self._groups[0]), n_best, int(widest))
        self._scratch = _new_scratch(*self._sizes)
        self._tables: SearchTables | None = None
        self._z_on = float(self.rule.z_on)
        self._z = np.zeros(self.n_features, dtype=np.float32)

    def localise_into(self, x: np.ndarray, out: np.ndarray) -> None:
        """One image ``x (n_features,)`` float32 counts into ``out (7,)`` (see ``Engine``)."""
        _match_one(x, self._clip, self._groups, self._fine, self._scratch, out)

    def contacts_into(self, x: np.ndarray, max_contacts: int, out: np.ndarray) -> int:
        """Up to ``max_contacts`` contacts of ``x`` into ``out`` (see ``Engine.contacts_into``).

        The multi-contact search (``skinloc.models.multi_contact``) on the amplitude map; one
        contact is this map's own single-contact answer.
        """
        if max_contacts > 1:
            t = self._tables if self._tables is not None else self.search_tables()
            n = search_into(x, max_contacts, t.arrays, t.prm, t.scratch, False, out)
            if n > 1:
                _peel(
                    x,
                    n,
                    t.scratch[-1][8:],
                    t.arrays,
                    t.prm[1],
                    self._clip,
                    self._groups,
                    self._fine,
                    self._scratch,
                    self._out,
                    self._z,
                    out,
                )
            if n != 1:
                return n
        return _contact_one(
            x,
            self._clip,
            self._groups,
            self._fine,
            self._scratch,
            self._out,
            self._w,
            self._z_on,
            out,
        )

    def search_tables(self) -> SearchTables:
        """The multi-contact search's arrays (built on first use)."""
        if self._tables is None:
            s = self.spec
            unit = s.table if s.unit_table is None else s.unit_table
            self._tables = SearchTables(
                np.asarray(unit), s.surface_points, s.coarse, s.cells, s.sensor_noise, self.rule
            )
        return self._tables

    def _predict_rows(self, X: np.ndarray) -> tuple[Points, Points, np.ndarray]:
        out = np.empty((len(X), 7))
        # a few frames (the app's, per frame) on the caller's thread; callers may be threads,
        # so every call has its own scratch
        if len(X) < _ROWS:
            _match_rows(X, self._clip, self._groups, self._fine, self._sizes, out)
        else:
            # BLAS's own threads would fight numba's for the cores (and spin after each
            # product): each task's product runs on the thread that handles the task.
            # The limit is process-wide: one batch at a time sets and restores it.
            with _BLAS_LOCK, _blas_controller().limit(limits=1, user_api="blas"):
                _match_many(X, self._clip, self._groups, self._mu_t, self._fine, self._sizes, out)
        return out[:, 3:6].copy(), out[:, :3].copy(), out[:, 6].copy()


_BLAS_LOCK = threading.Lock()


@functools.cache
def _blas_controller() -> Any:
    """The process's ``threadpoolctl`` controller (inspecting the libraries takes a while)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()
