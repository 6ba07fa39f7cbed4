"""The multi-contact search of an older revision against this tree's, same frames, one process.

The older ``search.py``, ``pairs.py`` and ``refit.py`` of ``skinloc/models/multi_contact`` are
taken from git (``--old``, a revision) into a package of their own, imported beside this
tree's (their ``contacts`` is this tree's). The model is trained on ``--train``; the frames:

* *frames*: touches of ``--test``: single frames, sums of two frames of different point logs,
  sums of three. ``search_into`` (plain and calibration mode) compared frame by frame: count,
  contacts, statistics;
* *streams*: ``Engine.contacts(x, 3, memory)`` in stream order with one ``SearchMemory`` per
  stream (``bench/search_memory_ab.py``'s real streams: single touches, two held, a second
  landing, three held) and the simulated stream of ``skinloc bench --online``'s touched
  frames;
* *anchored fits*: ``PairRefit.fit`` on every stream frame, anchored at the stream's first
  frame's one-contact answer.

Counted: frames whose count differs, whose positions move by more than 1 mm, and whose
numbers differ beyond rel 1e-9 at all. Then the cost, the settings interleaved in rounds on the
simulated touched frames: ``contacts`` at K = 1, K = 3 (memory) old and new; the anchored fit
old and new. Median and p99, µs, and the ratios to K = 1.

    PYTHONPATH=src python bench/contact_search_ab.py --data ../shared/data/hiro-cone-skin \
        --old c73932c
"""

from __future__ import annotations

import argparse
import importlib
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import train_localizer
from skinloc.models import map_engine as me
from skinloc.models.multi_contact import refit as new_refit
from skinloc.models.multi_contact.search import (
    SearchArrays,
    SearchMemory,
    SearchScratch,
    search_into,
)

MODULES = ("pairs", "search", "refit")
PKG = "multi_contact_old"


def import_old(rev: str):
    """The revision's modules as package ``multi_contact_old``: ``(search, pairs, refit)``."""
    root = Path(tempfile.gettempdir()) / f"skinloc-ab-{rev}"
    pkg = root / PKG
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / "__init__.py").write_text("")
    for name in MODULES:
        src = subprocess.run(
            ["git", "show", f"{rev}:src/skinloc/models/multi_contact/{name}.py"],
            capture_output=True,
            text=True,
        )
        if src.returncode:
            raise SystemExit(f"error: no {name}.py at {rev}: {src.stderr.strip()}")
        text = src.stdout
        for other in ("pairs", "search"):
            text = text.replace(f"skinloc.models.multi_contact.{other}", f"{PKG}.{other}")
        path = pkg / f"{name}.py"
        if not path.is_file() or path.read_text() != text:  # numba's cache keys on the file
            path.write_text(text)
    sys.path.insert(0, str(root))
    return tuple(importlib.import_module(f"{PKG}.{n}") for n in ("search", "pairs", "refit"))


def old_engine(eng, old):
    """``eng``'s model with the older search (its own tables and scratch)."""
    s = eng.spec
    unit = np.asarray(s.table if s.unit_table is None else s.unit_table)
    ot = old.SearchTables(unit, s.surface_points, s.coarse, s.cells, s.sensor_noise, eng.rule)
    # this tree's engine (its warm-up, the peel) reads the tables by name: the same arrays
    ot.arrays, ot.scratch = SearchArrays(*ot.arrays), SearchScratch(*ot.scratch)

    class OldEngine(type(eng)):
        def search_tables(self):
            return ot

        def contacts_into(self, x, max_contacts, out, memory=None):
            if max_contacts > 1:
                n = -1
                if memory is not None:
                    n = old.recall_into(x, ot.arrays, ot.prm, ot.scratch, memory.state)
                if n < 0:
                    n = old.search_into(
                        x, max_contacts, ot.arrays, ot.prm, ot.scratch, False, out,
                        *ot.pair.kernel_args,
                    )  # fmt: skip
                    if memory is not None:
                        old.remember(max_contacts, n, ot.arrays, ot.prm, ot.scratch, memory.state)
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

    return OldEngine(eng.spec).warm_up()


def frame_sets(rec, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Singles (every 5th frame), pairs (every 3rd pair of point logs), 200 triples."""
    d = rec.deltas.astype(np.float32)
    n, s = d.shape[:2]
    pairs = [
        d[a, rng.integers(s)] + d[b, rng.integers(s)] for a in range(n) for b in range(a + 1, n)
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


def close(a, b) -> bool:
    return np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True)


def compare_frames(old, ot, t, F) -> dict[str, int]:
    """``search_into`` old and new, plain and calibration mode, frame by frame."""
    res = {"frames": 0, "count_differs": 0, "positions_1mm": 0, "numbers_differ": 0}
    for X in F.values():
        for x in X:
            for calib in (False, True):
                oo, no = np.zeros((3, 5)), np.zeros((3, 5))
                n0 = old.search_into(
                    x, 3, ot.arrays, ot.prm, ot.scratch, calib, oo, *ot.pair.kernel_args
                )
                n1 = search_into(x, 3, t.arrays, t.prm, t.scratch, calib, no, *t.pair.kernel_args)
                res["frames"] += 1
                res["count_differs"] += int(n0 != n1)
                m = min(n0, n1)
                res["positions_1mm"] += bool(m > 1 and np.abs(oo[:m, :3] - no[:m, :3]).max() > 1e-3)
                res["numbers_differ"] += not (
                    n0 == n1 and close(oo, no) and close(ot.scratch[-1], t.scratch[-1])
                )
    return {k: int(v) for k, v in res.items()}


def compare_streams(oe, ne, streams) -> dict[str, int]:
    """``contacts(x, 3, memory)`` old and new in stream order; the anchored fits."""
    res = {"frames": 0, "count_differs": 0, "positions_1mm": 0, "numbers_differ": 0}
    fit = {"fits": 0, "found_differs": 0, "numbers_differ": 0, "places_1mm": 0}
    ro, rn = oe.refit_old, new_refit.PairRefit(ne)
    for X in streams:
        mo, mn = SearchMemory(), SearchMemory()
        anchor = None
        for x in X:
            a, b = oe.contacts(x, 3, mo), ne.contacts(x, 3, mn)
            res["frames"] += 1
            res["count_differs"] += len(a) != len(b)
            same = len(a) == len(b)
            if same and len(a):
                res["positions_1mm"] += np.abs(a.rows[:, :3] - b.rows[:, :3]).max() > 1e-3
            res["numbers_differ"] += not (same and close(a.rows, b.rows))
            if anchor is None and len(b):
                anchor = b.rows[0, :3].copy()
            if anchor is not None:
                fo, fn = ro.fit(x, anchor), rn.fit(x, anchor)
                fit["fits"] += 1
                if (fo is None) != (fn is None):
                    fit["found_differs"] += 1
                elif fo is not None:
                    far = max(
                        np.linalg.norm(fo.first_m - fn.first_m),
                        np.linalg.norm(fo.second_m - fn.second_m),
                    )
                    fit["places_1mm"] += far > 1e-3
                    fit["numbers_differ"] += not (
                        close([fo.ratio, fo.z2], [fn.ratio, fn.z2]) and far == 0.0
                    )
    return {k: int(v) for k, v in {**res, **{f"fit_{k}": v for k, v in fit.items()}}.items()}


def real_streams(rec, rng: np.random.Generator) -> list[np.ndarray]:
    """``bench/search_memory_ab.py``'s streams (every 4th pair of point logs)."""
    d = rec.deltas.astype(np.float32)
    n, s = d.shape[:2]
    half = s // 2
    pairs = [(a, b) for a in range(n) for b in range(a + 1, n)][::28]
    return (
        [d[a] for a in range(n)]
        + [d[a] + d[b] for a, b in pairs]
        + [np.concatenate([d[a, :half], d[a, half:] + d[b, half:]]) for a, b in pairs]
        + [d[a] + d[b] + d[c] for a, b, c in (rng.choice(n, 3, replace=False) for _ in range(10))]
    )


def stats(v: list[float], base: np.ndarray | None = None) -> dict[str, float]:
    a = 1e6 * np.asarray(v)
    r = {"median_us": float(np.median(a)), "p99_us": float(np.percentile(a, 99))}
    if base is not None:
        r["median_over_k1"] = r["median_us"] / float(np.median(base))
        r["p99_over_k1"] = r["p99_us"] / float(np.percentile(base, 99))
    return r


def timing(oe, ne, X: np.ndarray, rounds: int) -> dict[str, dict[str, float]]:
    """``contacts`` K = 1, K = 3 (memory) old and new; the anchored fit old and new."""
    lat: dict[str, list[float]] = {
        "K=1": [],
        "K=3 old": [],
        "K=3 new": [],
        "fit old": [],
        "fit new": [],
    }
    pc = time.perf_counter
    ro, rn = oe.refit_old, new_refit.PairRefit(ne)
    anchor = ne.contacts(X[0], 1).rows[0, :3].copy()
    for _ in range(rounds):
        for label in lat:
            if label.startswith("fit"):
                r = ro if label == "fit old" else rn
                for x in X[::4]:
                    t0 = pc()
                    r.fit(x, anchor)
                    lat[label].append(pc() - t0)
                continue
            e = oe if label == "K=3 old" else ne
            k = 1 if label == "K=1" else 3
            mem = SearchMemory()
            for x in X:
                t0 = pc()
                e.contacts(x, k, mem)
                lat[label].append(pc() - t0)
    base = 1e6 * np.asarray(lat["K=1"])
    return {k: stats(v, None if k.startswith("fit") else base) for k, v in lat.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--old", required=True, help="the older revision (git)")
    ap.add_argument("--train", default="ConeSkinData80Points_RND_80PL_1.mat")
    ap.add_argument("--test", default="ConeSkinData50Points_RND_50PL_1.mat")
    ap.add_argument("--frames", type=int, default=20000, help="simulated stream's frames")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--models", type=Path, default=Path("/tmp/skinloc-bench-search-memory"))
    ap.add_argument("--skip-ab", action="store_true", help="the timing only")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    for f in (args.train, args.test):
        if not (args.data / f).is_file():
            raise SystemExit(f"error: no such recording: {args.data / f}")
    old, _, old_refit = import_old(args.old)

    from skinloc.bench.online import touch_stream, train_bench_models
    from skinloc.live.core import PipelineConfig, SkinCore
    from skinloc.models.engine import load_engine

    res: dict[str, object] = {
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "old": args.old,
    }
    sim = load_engine(train_bench_models(args.models, ("default",))["default"]).warm_up()
    frames, _ = touch_stream(args.frames, random_state=0)
    seen: list[np.ndarray] = []
    core = SkinCore(sim, PipelineConfig(max_contacts=3), wire_format="binary")
    orig = sim.contacts

    def spy(x, max_contacts=3, memory=None):
        seen.append(np.array(x, dtype=np.float32))
        return orig(x, max_contacts, memory)

    sim.contacts = spy
    for i, f in enumerate(frames):
        core.process_frame(f, 0.01 * i, i)
    del sim.contacts
    X = np.array(seen)
    osim = old_engine(sim, old)
    osim.refit_old = old_refit.PairRefit(osim)

    if not args.skip_ab:
        eng = train_localizer([read_recording(args.data / args.train)]).engine().warm_up()
        oe = old_engine(eng, old)
        oe.refit_old = old_refit.PairRefit(oe)
        test = read_recording(args.data / args.test)
        rng = np.random.default_rng(0)
        res["frames"] = compare_frames(
            old, oe.search_tables(), eng.search_tables(), frame_sets(test, rng)
        )
        res["real_streams"] = compare_streams(oe, eng, real_streams(test, rng))
        # the simulated stream as runs of touched frames (a new memory every 500 frames)
        res["simulated_stream"] = compare_streams(
            osim, sim, np.array_split(X, max(1, len(X) // 500))
        )
        print(
            json.dumps(
                {k: res[k] for k in ("frames", "real_streams", "simulated_stream")}, indent=1
            )
        )
    res["timing_simulated"] = timing(osim, sim, X, args.rounds)
    res["timing_simulated"]["frames"] = len(X)
    print(json.dumps(res["timing_simulated"], indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
