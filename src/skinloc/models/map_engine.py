"""The response-map engine: an image's shape matched against the map at every candidate point.

The match itself (coarse cells by an exact pruned search, then the fine candidates, one kernel
per row) is compiled in ``models.map_match``, which describes it; this module holds the map's
spec, the engine and the multi-contact kernels built on the match.
"""

from __future__ import annotations

import functools
import threading
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from skinloc._jit import compiled_entry, jit
from skinloc._typing import Points
from skinloc.models.engine import Engine, ModelSpec
from skinloc.models.map_match import (
    ROWS,
    coarse_groups,
    match_many,
    match_one,
    match_rows,
    new_scratch,
)
from skinloc.models.multi_contact.contacts import PRM_MIN2
from skinloc.models.multi_contact.search import (
    STAT_ROWS,
    SearchArrays,
    SearchMemory,
    SearchTables,
    recall_into,
    search_remember,
    single_into,
)

__all__ = ["MapEngine", "MapSpec"]


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
    """``match_one`` and the detection rule in one call: the single contact (0 or 1)."""
    match_one(x, clip, groups, fine, scratch, out7)
    return single_into(x, w, z_on, out7, out)


@jit()
def _peel(
    x: np.ndarray,
    n: int,
    rows: np.ndarray,
    arrays: SearchArrays,
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
    w, Ft = arrays.w, arrays.Ft
    for i in range(n):
        for j in range(x.shape[0]):
            v = float(x[j])
            for o in range(n):
                if o != i:
                    v -= out[o, 3] * Ft[int(rows[o]), j] / w[j]
            z[j] = v
        match_one(z, clip, groups, fine, scratch, out7)
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
        # small products: BLAS's threads would cost more to wake than the work (30 ms a
        # product on a loaded machine)
        with _BLAS_LOCK, _blas_controller().limit(limits=1, user_api="blas"):
            self._groups = coarse_groups(table[coarse], sq[coarse])
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
        self._scratch = new_scratch(*self._sizes)
        self._tables: SearchTables | None = None
        self._recall: Any = None  # recall_into compiled for the tables (``compiled_entry``)
        self._z_on = float(self.rule.z_on)
        self._z = np.zeros(self.n_features, dtype=np.float32)
        self._no_memory = np.zeros(7)  # search_remember's memory when the caller has none

    def localise_into(self, x: np.ndarray, out: np.ndarray) -> None:
        """One image ``x (n_features,)`` float32 counts into ``out (7,)`` (see ``Engine``)."""
        match_one(x, self._clip, self._groups, self._fine, self._scratch, out)

    def warm_up(self) -> MapEngine:
        """As ``Engine.warm_up``, with the multi-contact stage (``_peel``) and its memory.

        One point's touch never reaches it: two fingers far apart, each a candidate's image,
        do. Compiled on a live skin's first two-finger touch instead, it held up the loop for
        a second on a cold cache.
        """
        super().warm_up()
        t = self.search_tables()
        w, Ft, Fpos = t.arrays.w, t.arrays.Ft, t.arrays.Fpos
        far = int(np.argmax(np.linalg.norm(Fpos - Fpos[0], axis=1)))
        x = (1e3 * (Ft[0] + Ft[far]) / w).astype(np.float32)
        self.contacts(x, 3)
        # and a stream's memory (``SearchMemory``): the live loop passes one on every frame
        self.contacts(x, 3, SearchMemory())
        return self

    def contacts_into(
        self,
        x: np.ndarray,
        max_contacts: int,
        out: np.ndarray,
        memory: SearchMemory | None = None,
    ) -> int:
        """Up to ``max_contacts`` contacts of ``x`` into ``out`` (see ``Engine.contacts_into``).

        The multi-contact search (``skinloc.models.multi_contact``) on the amplitude map; one
        contact is this map's own single-contact answer. With a stream's ``memory`` a held
        touch skips the full search while nothing suggests a second finger
        (``SearchMemory``).
        """
        if max_contacts > 1:
            t = self._tables if self._tables is not None else self.search_tables()
            n = -1
            if memory is not None:
                recall = self._recall
                if recall is None:
                    recall = self._recall = compiled_entry(
                        recall_into,
                        self._x,
                        t.arrays,
                        t.prm,
                        t.scratch,
                        np.zeros_like(memory.state),
                    )
                if (
                    x.dtype == np.float32
                    and x.flags.c_contiguous
                    and memory.state.dtype == np.float64
                ):
                    # the held touch's frames (most of them): its tables' types known
                    n = recall(x, t.arrays, t.prm, t.scratch, memory.state)
                else:
                    n = recall_into(x, t.arrays, t.prm, t.scratch, memory.state)
            if n < 0:
                n = search_remember(
                    x,
                    max_contacts,
                    t.arrays,
                    t.prm,
                    t.scratch,
                    out,
                    *t.pair.kernel_args,
                    self._no_memory if memory is None else memory.state,
                    memory is not None,
                )
            if n > 1:
                _peel(
                    x,
                    n,
                    t.scratch.stats[STAT_ROWS:],
                    t.arrays,
                    t.prm[PRM_MIN2],
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
        if len(X) < ROWS:
            match_rows(X, self._clip, self._groups, self._fine, self._sizes, out)
        else:
            # BLAS's own threads would fight numba's for the cores (and spin after each
            # product): each task's product runs on the thread that handles the task.
            # The limit is process-wide: one batch at a time sets and restores it.
            with _BLAS_LOCK, _blas_controller().limit(limits=1, user_api="blas"):
                match_many(X, self._clip, self._groups, self._mu_t, self._fine, self._sizes, out)
        return out[:, 3:6].copy(), out[:, :3].copy(), out[:, 6].copy()


_BLAS_LOCK = threading.Lock()


@functools.cache
def _blas_controller() -> Any:
    """The process's ``threadpoolctl`` controller (inspecting the libraries takes a while)."""
    from threadpoolctl import ThreadpoolController

    return ThreadpoolController()
