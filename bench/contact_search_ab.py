"""``Engine.contacts`` (K = 3) with an older multi-contact search against this one, in one process.

The older search is a copy of its ``skinloc/models/multi_contact/search.py``, imported beside
this tree's; for instance the search before the pruning, its one import pointed at where those
names live now::

    git show 1c8a43e:src/skinloc/models/contact_search.py \
        | sed 's/multi_contact import/multi_contact.contacts import/' > /tmp/contact_search_old.py

The model is trained on ``--train``; the frames are touches of
``--test``: single frames, sums of two frames of different point logs, sums of three. First
both searches' answers are compared frame by frame (count, positions to 1e-9 m, strengths and
uncertainties to rel 1e-9, the search statistics to rel 1e-12), then ``Engine.contacts`` is
timed per frame, the two alternating in rounds: median and p99 (µs) and old / new.

    python bench/contact_search_ab.py --data ../shared/data/hiro-cone-skin \
        --old /tmp/contact_search_old.py
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import sys
import time
from pathlib import Path

import numpy as np

from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import train_localizer
from skinloc.models import map_engine as me


def frame_sets(rec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Singles (every 5th frame), pairs (every 3rd pair of point logs), 200 triples."""
    d = rec.deltas.astype(np.float32)
    n, s = d.shape[:2]
    pairs = [
        d[a, rng.integers(s)] + d[b, rng.integers(s)]
        for a, b in itertools.combinations(range(n), 2)
    ][::3]
    triples = [
        d[a, 0] + d[b, 1] + d[c, 2]
        for a, b, c in (rng.choice(n, 3, replace=False) for _ in range(200))
    ]
    return {
        "singles": d[:, ::5].reshape(-1, d.shape[-1]),
        "pairs": np.array(pairs, dtype=np.float32),
        "triples": np.array(triples, dtype=np.float32),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--old", type=Path, required=True, help="an older contact_search.py")
    ap.add_argument("--train", default="ConeSkinData80Points_RND_80PL_1.mat")
    ap.add_argument("--test", default="ConeSkinData50Points_RND_50PL_1.mat")
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    if not args.old.is_file():
        sys.exit(f"error: no such file: {args.old}")
    spec_ = importlib.util.spec_from_file_location("contact_search_old", args.old)
    old = importlib.util.module_from_spec(spec_)
    sys.modules["contact_search_old"] = old  # numba's cache finds the kernels' module by name
    spec_.loader.exec_module(old)  # type: ignore[union-attr]

    eng = train_localizer([read_recording(args.data / args.train)]).engine().warm_up()
    t = eng.search_tables()
    s = eng.spec
    unit = np.asarray(s.table if s.unit_table is None else s.unit_table)
    ot = old.SearchTables(unit, s.surface_points, s.coarse, s.cells, s.sensor_noise, eng.rule)

    class OldEngine(type(eng)):  # MapEngine.contacts_into with the older search
        def contacts_into(self, x, max_contacts, out, memory=None):
            if max_contacts > 1:
                n = old.search_into(x, max_contacts, ot.arrays, ot.prm, ot.scratch, False, out)
                if n > 1:
                    me._peel(
                        x, n, ot.scratch[-1][8:], ot.arrays, ot.prm[1], self._clip,
                        self._groups, self._fine, self._scratch, self._out, self._z, out,
                    )  # fmt: skip
                if n != 1:
                    return n
            return me._contact_one(
                x, self._clip, self._groups, self._fine, self._scratch, self._out, self._w,
                self._z_on, out,
            )  # fmt: skip

    oe = OldEngine(eng.spec).warm_up()
    F = frame_sets(read_recording(args.data / args.test), np.random.default_rng(0))
    bad = 0
    counts: dict[int, int] = {}
    for X in F.values():
        for x in X:
            for calib in (False, True):
                oo, no = np.zeros((3, 5)), np.zeros((3, 5))
                n0 = old.search_into(x, 3, ot.arrays, ot.prm, ot.scratch, calib, oo)
                n1 = me.search_into(
                    x, 3, t.arrays, t.prm, t.scratch, calib, no, *t.pair.kernel_args
                )
                same = n0 == n1 and np.allclose(oo, no, rtol=1e-9, atol=1e-12, equal_nan=True)
                bad += not (same and np.allclose(ot.scratch[-1], t.scratch[-1], rtol=1e-12, atol=0))
            a, b = oe.contacts(x, 3), eng.contacts(x, 3)
            counts[len(a)] = counts.get(len(a), 0) + 1
            bad += len(a) != len(b) or not np.allclose(
                a.rows, b.rows, rtol=1e-9, atol=1e-12, equal_nan=True
            )
    n_frames = sum(map(len, F.values()))
    print(f"frames {n_frames}, counts (old) {dict(sorted(counts.items()))}, mismatches {bad}")
    pc = time.perf_counter
    for name, X in [*F.items(), ("all", np.concatenate(list(F.values())))]:
        lat: dict[str, list[float]] = {"old": [], "new": []}
        for _ in range(args.rounds):
            for label, e in (("old", oe), ("new", eng)):
                for x in X:
                    t0 = pc()
                    e.contacts(x, 3)
                    lat[label].append(pc() - t0)
        o, n = (1e6 * np.array(lat[k]) for k in ("old", "new"))
        print(
            f"{name:8s} old {np.median(o):6.1f} / {np.percentile(o, 99):6.1f} µs, "
            f"new {np.median(n):6.1f} / {np.percentile(n, 99):6.1f} µs, old/new "
            f"{np.median(o) / np.median(n):.2f} / {np.percentile(o, 99) / np.percentile(n, 99):.2f}"
        )


if __name__ == "__main__":
    main()
