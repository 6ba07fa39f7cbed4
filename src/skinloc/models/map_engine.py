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

The coarse stage is the bulk of the arithmetic (900 coarse candidates against about 130 fine
ones on the paper's skin). For a single frame it is a compiled loop; for a batch, one float32
matrix product (BLAS) per chunk of 128 rows, chunks in parallel. A product's rounding differs
from the loop's, so the cells whose coarse distance lies within a rounding bound of the
``n_cells``-th best get their distance again by the loop's own sum: a frame chooses the same
cells, and gets the same answer to the bit, alone or in a batch.
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

#: Rows per coarse matrix product in a batch (their distances: 128 x 900 floats in cache).
_CHUNK = 128
#: Bound on the float32 rounding of a coarse distance by the matrix product (squared
#: feature units; features have unit norm, so the rounding is about 1e-6).
_EPS = 1e-4


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
def _coarse_into(
    f: np.ndarray, ct: np.ndarray, csq: np.ndarray, dc: np.ndarray
) -> None:  # pragma: no cover
    """Coarse distances (less ``|f|^2``) of one image, ``dc (C,)`` = ``csq - 2 ct @ f``."""
    for c in range(ct.shape[0]):
        acc = np.float32(0.0)
        row = ct[c]
        for i in range(f.shape[0]):
            acc += f[i] * row[i]
        dc[c] = csq[c] - np.float32(2.0) * acc


@jit()
def _best_cells(
    f: np.ndarray,
    dc: np.ndarray,
    ct: np.ndarray,
    csq: np.ndarray,
    best_v: np.ndarray,
    best_c: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """The ``len(best_c)`` coarse cells nearest ``f``, nearest first, into ``best_c``.

    ``dc (C,)`` are the coarse distances up to ``_EPS`` (a matrix product's rounding); the
    cells within ``2 _EPS`` of the ``nb``-th smallest get their distance again here, by one
    fixed sum, so that every path that gets here chooses the same cells. ``best_v (nb,)`` is
    scratch. Ties go to the lower cell.
    """
    C = dc.shape[0]
    nb = best_c.shape[0]
    best_v[:] = np.inf
    worst = np.inf  # best_v[nb - 1], in a register: the scan is one compare per cell
    for c in range(C):  # the nb-th smallest of dc
        v = dc[c]
        if v < worst:
            t = nb - 1
            while t > 0 and best_v[t - 1] > v:
                best_v[t] = best_v[t - 1]
                t -= 1
            best_v[t] = v
            worst = best_v[nb - 1]
    thr = worst + 2.0 * _EPS
    best_v[:] = np.inf
    best_c[:] = 0
    for c in range(C):
        if dc[c] > thr:
            continue
        acc = np.float32(0.0)
        row = ct[c]
        for i in range(f.shape[0]):
            acc += f[i] * row[i]
        v = csq[c] - 2.0 * acc
        if v < best_v[nb - 1]:
            t = nb - 1
            while t > 0 and best_v[t - 1] > v:
                best_v[t] = best_v[t - 1]
                best_c[t] = best_c[t - 1]
                t -= 1
            best_v[t] = v
            best_c[t] = c


@jit()
def _fine(
    f: np.ndarray, ff: float, best_c: np.ndarray, fine: tuple, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """The chosen cells in full, into ``out (7,)`` = [point (3), point (3), spread_mm].

    ``fine`` = (tt, sqp, candp, off, pad_n, pad_pos, noise): ``tt (P, k)`` is the table with
    the candidates grouped by coarse cell (cell c is rows ``off[c]:off[c+1]``, each candidate
    once), ``sqp`` their squared norms, ``candp`` their points (m). ``pad_n`` and ``pad_pos``
    give the padding of each cell (its coarse point repeated), which weighs in the spread.
    A map's raw output already lies on the surface.
    """
    tt, sqp, candp, off, pad_n, pad_pos, noise = fine
    k = f.shape[0]
    nb = best_c.shape[0]
    total = 0
    for b in range(nb):
        total += off[best_c[b] + 1] - off[best_c[b]]
    d = np.empty(total, dtype=np.float64)
    idx = np.empty(total, dtype=np.int64)
    dmin = np.inf
    best = -1
    j = 0
    for b in range(nb):
        c = best_c[b]
        for p in range(off[c], off[c + 1]):
            acc = np.float32(0.0)
            row = tt[p]  # a row view: indexing tt[p, i] does not vectorise
            for i in range(k):
                acc += f[i] * row[i]
            dv = max(float(sqp[p] - np.float32(2.0) * acc) + ff, 0.0)
            d[j] = dv
            idx[j] = p
            if dv < dmin:
                dmin = dv
                best = p
            j += 1
    inv_scale = 1.0 / max(dmin, 2.0 * noise)
    wsum = 0.0
    acc2 = 0.0
    j = 0
    for b in range(nb):
        c = best_c[b]
        for r in range(off[c + 1] - off[c]):
            e = (d[j] - dmin) * inv_scale
            p = idx[j]
            j += 1
            if e > 50.0:  # weight below 2e-22: nothing to add
                continue
            w = math.exp(-e)
            if r == pad_pos[c]:
                w *= 1.0 + pad_n[c]
            dist2 = 0.0
            for t in range(3):
                dist2 += (candp[p, t] - candp[best, t]) ** 2
            wsum += w
            acc2 += w * dist2
    for t in range(3):
        out[t] = candp[best, t]
        out[3 + t] = candp[best, t]
    out[6] = 1e3 * math.sqrt(acc2 / wsum)


@jit()
def _match_one(
    x: np.ndarray,
    clip: int,
    ct: np.ndarray,
    csq: np.ndarray,
    fine: tuple,
    scratch: tuple,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """One image into ``out (7,)``: features, coarse distances, chosen cells, fine search.

    ``scratch`` = (f (k,) float32, dc (C,) float32, best_v (nb,), best_c (nb,) int).
    """
    f, dc, best_v, best_c = scratch
    ff = _features(x, clip, f)
    _coarse_into(f, ct, csq, dc)
    _best_cells(f, dc, ct, csq, best_v, best_c)
    _fine(f, ff, best_c, fine, out)


@jit(parallel=True)
def _match_many(
    X: np.ndarray,
    clip: int,
    ct: np.ndarray,
    ct_t: np.ndarray,
    csq: np.ndarray,
    fine: tuple,
    n_best: int,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``_match_one`` over the rows of ``X (n, k)`` into ``out (n, 7)``, in parallel chunks.

    Each chunk's coarse distances are one float32 matrix product (BLAS, called with one
    thread per core: see ``MapEngine._predict_rows``); the rest is per row.
    """
    n = X.shape[0]
    for chunk in prange((n + _CHUNK - 1) // _CHUNK):
        r0 = chunk * _CHUNK
        rows = min(n, r0 + _CHUNK) - r0
        F = np.empty((rows, X.shape[1]), dtype=np.float32)
        ff = np.empty(rows)
        for r in range(rows):
            ff[r] = _features(X[r0 + r], clip, F[r])
        DC = np.dot(F, ct_t)  # (rows, C)
        best_v = np.empty(n_best)
        best_c = np.empty(n_best, dtype=np.int64)
        for r in range(rows):
            dc = DC[r]
            for c in range(dc.shape[0]):
                dc[c] = csq[c] - np.float32(2.0) * dc[c]
            _best_cells(F[r], dc, ct, csq, best_v, best_c)
            _fine(F[r], ff[r], best_c, fine, out[r0 + r])


@jit()
def _contact_one(
    x: np.ndarray,
    clip: int,
    ct: np.ndarray,
    csq: np.ndarray,
    fine: tuple,
    scratch: tuple,
    out7: np.ndarray,
    w: np.ndarray,
    z_on: float,
    out: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """``_match_one`` and the detection rule in one call: the single contact (0 or 1)."""
    _match_one(x, clip, ct, csq, fine, scratch, out7)
    return single_into(x, w, z_on, out7, out)


@jit()
def _peel(
    x: np.ndarray,
    n: int,
    rows: np.ndarray,
    arrays: tuple,
    min2: float,
    clip: int,
    ct: np.ndarray,
    csq: np.ndarray,
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
        _match_one(z, clip, ct, csq, fine, scratch, out7)
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
        self._ct = np.ascontiguousarray(table[coarse])  # (C, k)
        self._ct_t = np.ascontiguousarray(self._ct.T)  # (k, C), for the batch's product
        self._csq = sq[coarse]
        self._n_best = min(int(spec.n_cells), len(coarse))
        self._fine = (
            np.ascontiguousarray(table[perm_a]),  # (P', k), grouped by cell
            sq[perm_a],
            np.ascontiguousarray(np.asarray(spec.surface_points)[perm_a], dtype=np.float64),
            np.asarray(off, dtype=np.int64),
            np.asarray(pad_n, dtype=np.int64),
            np.asarray(pad_pos, dtype=np.int64),
            float(spec.noise),
        )
        self._scratch = (
            np.zeros(self.n_features, dtype=np.float32),
            np.zeros(len(coarse), dtype=np.float32),
            np.zeros(self._n_best),
            np.zeros(self._n_best, dtype=np.int64),
        )
        self._tables: SearchTables | None = None
        self._z_on = float(self.rule.z_on)
        self._z = np.zeros(self.n_features, dtype=np.float32)

    def localise_into(self, x: np.ndarray, out: np.ndarray) -> None:
        """One image ``x (n_features,)`` float32 counts into ``out (7,)`` (see ``Engine``)."""
        _match_one(x, self._clip, self._ct, self._csq, self._fine, self._scratch, out)

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
                    self._ct,
                    self._csq,
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
            self._ct,
            self._csq,
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
        if len(X) < _CHUNK:  # a few frames (the app's, per frame): no product to share
            scratch = tuple(np.empty_like(a) for a in self._scratch)  # callers may be threads
            for x, o in zip(X, out, strict=True):
                _match_one(x, self._clip, self._ct, self._csq, self._fine, scratch, o)
        else:
            # BLAS's own threads would fight numba's for the cores (and spin after each
            # product): each chunk's product runs on the thread that handles the chunk.
            # The limit is process-wide: one batch at a time sets and restores it.
            with _BLAS_LOCK, _blas_controller().limit(limits=1, user_api="blas"):
                _match_many(
                    X, self._clip, self._ct, self._ct_t, self._csq, self._fine, self._n_best, out
                )
        return out[:, 3:6].copy(), out[:, :3].copy(), out[:, 6].copy()


_BLAS_LOCK = threading.Lock()


@functools.cache
def _blas_controller() -> Any:
    """The process's ``threadpoolctl`` controller (inspecting the libraries takes a while)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()
