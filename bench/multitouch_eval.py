"""Multi-contact localisation on real images: sums of real single touches (issue 14).

There are no real multi-touch recordings, so two (three) fingers are made by summing the
baseline-subtracted images of two (three) point logs of one recording: touch means with touch
means, and single frames with single frames (each frame keeps its own noise, so a sum of two
frames has the noise of two). The model is trained on ``--train`` only; the images come from
the other recordings (``--test``), never from the training one. Every pair of point logs of a
test recording is used; triples are drawn at random (``--triples`` per recording, each finger at
least 20 mm from the others).

Reported by separation (<30, 30-60, >60 mm) x strength ratio (weaker / stronger strength, the
L2 norm of each touch mean's positive part: <0.33, 0.33-0.66, >0.66): how often the count is
right, the share with every contact within 15 mm (best assignment; a missed finger is a
miss), the per-contact error of the pairs counted two against the single-touch error of the
same touches (the model's own single-contact answer on each touch alone), and how often a
single touch is called two. ``--latency`` times ``Engine.contacts`` with K = 1 and K = 3 and the
single-contact ``localise_into`` in one run, alternated.

    python bench/multitouch_eval.py --data ../shared/data/hiro-cone-skin --latency
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from skinloc.bench.paper import TEST_DEC, TRAIN_DEC
from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import train_localizer
from skinloc.models.multi_contact.two_point import (
    describe,
    threshold_from_pairs,
    two_point_of,
)

SEP_BINS = ((0.0, 30.0, "<30"), (30.0, 60.0, "30-60"), (60.0, np.inf, ">60"))
RATIO_BINS = ((0.0, 0.33, "<0.33"), (0.33, 0.66, "0.33-0.66"), (0.66, 1.01, ">0.66"))
WITHIN_MM = 15.0


def strength(X: np.ndarray) -> np.ndarray:
    """L2 norm of the positive part of each image ``(n, k)`` -> ``(n,)`` counts."""
    return np.linalg.norm(np.maximum(X, 0.0), axis=-1)


def assign(pred: np.ndarray, true: np.ndarray) -> tuple[np.ndarray, int]:
    """Errors (mm) of the best assignment of predicted to true points, and the misses."""
    if len(pred) == 0:
        return np.zeros(0), len(true)
    D = 1e3 * np.linalg.norm(pred[:, None, :] - true[None, :, :], axis=2)
    r, c = linear_sum_assignment(D)
    return D[r, c], len(true) - len(r)


def run_sets(engine, images: np.ndarray, truths: list[np.ndarray], k_max: int) -> list[dict]:
    rows = []
    for x, true in zip(images, truths, strict=True):
        cs = engine.contacts(x, k_max)
        err, missed = assign(cs.positions_m, true)
        rows.append(
            {
                "count": len(cs),
                "errors": err,
                "all_within": missed == 0 and bool(np.all(err <= WITHIN_MM)),
            }
        )
    return rows


def _pairs_of(t: tuple[int, ...]) -> list[tuple[int, int]]:
    return list(itertools.combinations(t, 2))


def build(rec, rng: np.random.Generator, n_triples: int, min_sep_mm: float):
    """Pairs and triples of one recording: indices, mean sums and frame sums."""
    n = rec.n_point_logs
    means = rec.touch_means.astype(np.float64)
    deltas = rec.deltas.astype(np.float64)
    pairs = list(itertools.combinations(range(n), 2))
    triples: list[tuple[int, ...]] = []
    tries = 0
    while len(triples) < n_triples and tries < 100 * n_triples:
        tries += 1
        t = tuple(sorted(rng.choice(n, 3, replace=False).tolist()))
        d = [
            np.linalg.norm(rec.targets[a] - rec.targets[b]) for a, b in itertools.combinations(t, 2)
        ]
        if min(d) * 1e3 >= min_sep_mm and t not in triples:
            triples.append(t)
    s = rec.samples_per_touch

    def sums(sets):
        m = np.array([means[list(t)].sum(axis=0) for t in sets], dtype=np.float32)
        picks = [[(i, int(rng.integers(s))) for i in t] for t in sets]
        f = np.array([sum(deltas[i, j] for i, j in p) for p in picks], dtype=np.float32)
        return m, f, picks

    return pairs, triples, sums(pairs), sums(triples)


def summarise(rows, meta, sel) -> dict:
    rs = [r for r, keep in zip(rows, sel, strict=True) if keep]
    kept_meta = [m for m, keep in zip(meta, sel, strict=True) if keep]
    if not rs:
        return {"n": 0}
    two = [r for r in rs if r["count"] == 2]
    err = np.concatenate([r["errors"] for r in two]) if two else np.zeros(0)
    single = np.concatenate([m["single_err"] for m, keep in zip(meta, sel, strict=True) if keep])
    single_two = (
        np.concatenate(
            [
                m["single_err"]
                for m, r, keep in zip(meta, rows, sel, strict=True)
                if keep and r["count"] == 2
            ]
        )
        if two
        else np.zeros(0)
    )
    return {
        "n": len(rs),
        "counted_two": float(np.mean([r["count"] == 2 for r in rs])),
        "counted_one": float(np.mean([r["count"] == 1 for r in rs])),
        "all_within_15mm": float(np.mean([r["all_within"] for r in rs])),
        "contact_median_mm": float(np.median(err)) if len(err) else None,
        "single_median_mm": float(np.median(single_two)) if len(single_two) else None,
        "single_median_all_mm": float(np.median(single)),
        # the ceiling the single-contact answer sets: both touches within 15 mm when alone
        "alone_within_15mm": float(
            np.mean([np.all(m["single_err"] <= WITHIN_MM) for m in kept_meta])
        ),
        # the same, of the sets whose touches alone are each within 15 mm (the figure)
        "all_within_15mm_of_alone_within": float(
            np.mean(
                [
                    r["all_within"]
                    for r, m in zip(rs, kept_meta, strict=True)
                    if np.all(m["single_err"] <= WITHIN_MM)
                ]
                or [np.nan]
            )
        ),
    }


def two_point(rows, meta, min_ratio: float = 0.5) -> dict:
    """The skin's two-point threshold on pairs of similar strength (ratio > ``min_ratio``).

    ``skinloc.models.multi_contact.two_point.threshold_from_pairs`` (the one ``fit`` stores),
    every bin with pairs deciding: per 10 mm bin the share counted two and the share with both
    fingers placed within 15 mm.
    """
    keep = [i for i, m in enumerate(meta) if m["ratio"] > min_ratio]
    return threshold_from_pairs(
        np.array([meta[i]["sep_mm"] for i in keep]),
        np.array([rows[i]["count"] == 2 for i in keep], dtype=bool),
        np.array([rows[i]["all_within"] for i in keep], dtype=bool),
        min_pairs=1,
    )


class Tally:
    """What the evaluation of one or more test recordings accumulates."""

    def __init__(self) -> None:
        self.pair_rows: dict[str, list] = {"means": [], "frames": []}
        self.pair_meta: dict[str, list[dict]] = {"means": [], "frames": []}
        self.triple_rows: dict[str, list] = {"means": [], "frames": []}
        self.singles: dict[str, list] = {"means": [], "frames": []}
        self.frames: list[np.ndarray] = []
        self.pair_frames: list[np.ndarray] = []

    def add(self, engine, rec, rng: np.random.Generator, n_triples: int) -> None:
        """Pairs, triples and singles of the test recording ``rec``."""
        min_sep = float(engine.rule.min_separation_mm)
        pairs, triples, (pm, pf, picks), (tm, tf, _) = build(rec, rng, n_triples, min_sep)
        means = rec.touch_means.astype(np.float32)
        frames = rec.deltas.reshape(-1, rec.n_sensors).astype(np.float32)
        self.frames.append(frames)
        self.pair_frames.append(pf)
        st = strength(means)
        single_err = 1e3 * np.linalg.norm(engine.predict_batch(means)[0] - rec.targets, axis=1)
        fr3 = rec.deltas
        for (a, b), pk in zip(pairs, picks, strict=True):
            sep = 1e3 * float(np.linalg.norm(rec.targets[a] - rec.targets[b]))
            ratio = float(min(st[a], st[b]) / max(st[a], st[b]))
            self.pair_meta["means"].append(
                {"sep_mm": sep, "ratio": ratio, "single_err": single_err[[a, b]]}
            )
            pts = engine.predict_batch(np.stack([fr3[i, j] for i, j in pk]))[0]
            err = 1e3 * np.linalg.norm(pts - rec.targets[[a, b]], axis=1)
            self.pair_meta["frames"].append({"sep_mm": sep, "ratio": ratio, "single_err": err})
        truth_p = [rec.targets[list(p)] for p in pairs]
        truth_t = [rec.targets[list(t)] for t in triples]
        self.pair_rows["means"] += run_sets(engine, pm, truth_p, 3)
        self.pair_rows["frames"] += run_sets(engine, pf, truth_p, 3)
        self.triple_rows["means"] += run_sets(engine, tm, truth_t, 3)
        self.triple_rows["frames"] += run_sets(engine, tf, truth_t, 3)
        self.singles["means"] += [len(engine.contacts(x, 3)) for x in means]
        self.singles["frames"] += [len(engine.contacts(x, 3)) for x in frames]

    def table(self) -> dict:
        """The results by kind (touch means, frames)."""
        table = {}
        for kind in ("means", "frames"):
            rows = self.pair_rows[kind]
            meta = self.pair_meta[kind]
            cells = {}
            for lo, hi, sl in SEP_BINS:
                for rlo, rhi, rl in RATIO_BINS:
                    sel = [lo <= m["sep_mm"] < hi and rlo <= m["ratio"] < rhi for m in meta]
                    cells[f"{sl} | {rl}"] = summarise(rows, meta, sel)
            target = [m["sep_mm"] > 30 and m["ratio"] > 0.5 for m in meta]
            cells["target: >30 mm | >0.5"] = summarise(rows, meta, target)
            cells["all | all"] = summarise(rows, meta, [True] * len(rows))
            s = np.asarray(self.singles[kind])
            tr = self.triple_rows[kind]
            table[kind] = {
                "two_point": two_point(rows, meta),
                "pairs": cells,
                "singles": {
                    "n": len(s),
                    "called_none": float(np.mean(s == 0)),
                    "called_two_or_more": float(np.mean(s >= 2)),
                    "called_two_or_more_of_detected": float(np.mean(s[s > 0] >= 2)),
                },
                "triples": {
                    "n": len(tr),
                    "counted_three": float(np.mean([r["count"] == 3 for r in tr])),
                    "counted_two": float(np.mean([r["count"] == 2 for r in tr])),
                    "all_within_15mm": float(np.mean([r["all_within"] for r in tr])),
                },
            }
        return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("../shared/data/hiro-cone-skin"))
    ap.add_argument("--train", default=TRAIN_DEC)
    ap.add_argument(
        "--test",
        nargs="+",
        default=list(TEST_DEC),
    )
    ap.add_argument(
        "--cv",
        type=int,
        default=0,
        help="Instead: K-fold cross-validation inside --train (the tuning set; no --test)",
    )
    ap.add_argument("--triples", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--latency", action="store_true")
    ap.add_argument("--repeat", type=int, default=3, help="Latency runs (the best median kept)")
    ap.add_argument("--out", type=Path, help="JSON results")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    train = read_recording(args.data / args.train)
    tally = Tally()
    if args.cv:
        folds = np.array_split(rng.permutation(train.n_point_logs), args.cv)
        rules = []
        for test in folds:
            rest = np.setdiff1d(np.arange(train.n_point_logs), test)
            model = train_localizer([train.subset(rest)])
            rules.append(model.contact_rule_)
            engine = model.engine().warm_up()
            tally.add(engine, train.subset(np.sort(test)), rng, args.triples // args.cv)
        results: dict = {"train": args.train, "cv": args.cv, "rule": rules}
    else:
        model = train_localizer([train])
        engine = model.engine().warm_up()
        results = {"train": args.train, "test": args.test, "rule": model.contact_rule_}
        for name in args.test:
            tally.add(engine, read_recording(args.data / name), rng, args.triples)
    results["real"] = tally.table()
    if args.latency:
        results["latency"] = latency(
            engine, np.concatenate(tally.frames), np.concatenate(tally.pair_frames), args.repeat
        )
    print_markdown(results)
    if args.out:
        args.out.write_text(json.dumps(results, indent=2, default=float))


def latency(engine, singles: np.ndarray, pairs: np.ndarray, repeat: int = 3) -> dict:
    """Per-frame time (us) of contacts K=1, K=3 and the single-contact calls, best of runs.

    Frames: every 5th single frame of the test recordings and the pairs' frame sums, shuffled
    (at most 3000); each call's median and p99 over them, the run with the best median kept.
    """
    X = np.concatenate([singles[::5], pairs])
    rng = np.random.default_rng(1)
    X = X[rng.permutation(len(X))][:3000]
    out7 = np.empty(7)
    rows = np.empty((3, 5))
    fns = {
        "localise_into": lambda x: engine.localise_into(x, out7),
        "predict_one": engine.predict_one,
        "contacts_into K=1": lambda x: engine.contacts_into(x, 1, rows),
        "contacts K=1": lambda x: engine.contacts(x, 1),
        "contacts K=3": lambda x: engine.contacts(x, 3),
    }
    # wall time, and the thread's CPU time: what a call costs when the other processes on the
    # shared cores preempt it
    best = {(k, c): (np.inf, np.inf) for k in fns for c in ("wall", "cpu")}
    for _ in range(repeat):
        for name, fn in fns.items():
            for clock, now in (("wall", time.perf_counter), ("cpu", time.thread_time)):
                ts = np.empty(len(X))
                for i, x in enumerate(X):
                    t0 = now()
                    fn(x)
                    ts[i] = now() - t0
                med, p99 = 1e6 * np.median(ts), 1e6 * np.percentile(ts, 99)
                if med < best[name, clock][0]:
                    best[name, clock] = (med, p99)
    res = {f"{k} ({c})": {"median_us": v[0], "p99_us": v[1]} for (k, c), v in best.items()}
    return res | {"frames": len(X)}


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.0f} %"


def _mm(v) -> str:
    return "-" if v is None else f"{v:.1f}"


def print_markdown(res: dict) -> None:
    rule = res["rule"]
    print(f"count rule: {json.dumps(rule)}\n")
    if isinstance(rule, dict):
        own = two_point_of(rule)
        print("the model's own, from its calibration: " + describe(own) + "\n")
    for kind, t in res["real"].items():
        tp = t["two_point"]
        print(f"### Two-point threshold, {kind} (ratio > 0.5)\n")
        print("| separation (mm) | n | counted two | all within 15 mm |\n|---|---|---|---|")
        for key, c in tp["bins"].items():
            print(f"| {key} | {c['n']} | {c['counted_two']:.0%} | {c['all_within_15mm']:.0%} |")
        print(f"\ncounted two >= 90 % from: {tp['counted_two_mm']} mm; and placed within 15 mm: "
              f"{tp['threshold_mm']} mm\n")  # fmt: skip
        print(f"### Pairs, {kind}\n")
        print(
            "| separation (mm) | strength ratio | n | counted two | counted one | all within "
            "15 mm | both alone within 15 mm | per-contact median (mm) | single-touch median, "
            "same touches (mm) |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        for key, c in t["pairs"].items():
            sep, _, ratio = key.partition(" | ")
            if not c["n"]:
                print(f"| {sep} | {ratio} | 0 | | | | | | |")
                continue
            print(
                f"| {sep} | {ratio} | {c['n']} | {_pct(c['counted_two'])} | "
                f"{_pct(c['counted_one'])} | {_pct(c['all_within_15mm'])} | "
                f"{_pct(c['alone_within_15mm'])} | "
                f"{_mm(c['contact_median_mm'])} | {_mm(c['single_median_mm'])} |"
            )
        s, tr = t["singles"], t["triples"]
        print(
            f"\nSingle touches ({kind}, n={s['n']}): called two or more "
            f"{_pct(s['called_two_or_more'])} ({_pct(s['called_two_or_more_of_detected'])} of "
            f"those detected), none {_pct(s['called_none'])}."
        )
        print(
            f"Triples ({kind}, n={tr['n']}): counted three {_pct(tr['counted_three'])}, two "
            f"{_pct(tr['counted_two'])}, all within 15 mm {_pct(tr['all_within_15mm'])}.\n"
        )
    if "latency" in res:
        print("### Latency per frame (us)\n")
        print("| call | median | p99 |\n|---|---|---|")
        for k, v in res["latency"].items():
            if isinstance(v, dict):
                print(f"| {k} | {v['median_us']:.1f} | {v['p99_us']:.1f} |")


if __name__ == "__main__":
    main()
