"""Recalibration (``skinloc train NEW --init OLD``) against the old model and the new touches alone.

For k = 0, 5, 10, 20 new touches of a later session (random draws), tested on the rest of it:
the old model untouched, a model of the k touches alone (the default: with the prior where it
applies), and the old model recalibrated on them (cross-validation over the k touches chooses
how much of the old map to keep: ``skinloc.models.recalibration``).

- ``--simulated``: simulated skins (their physics jittered as the prior's build does, seeds
  9000-) and a later session of each (``skinloc.sim.session_change``, the ``real`` and ``mild``
  changes); 80 touches on random mesh edges make the old map, 20 more its own-day error; the
  later session has 60, the k drawn from the first 40, the last 20 tested. Maps are scored by
  matching touch means against their table (as ``skinloc prior build`` does). Also: the old
  map with a correction layer only (``--init`` before the choice), the choice with 1 standard
  error of slack, and without the blends: the variants the method was chosen among.
- ``--real``: the real cone skin, 2023-12-10 -> 2024-05-23 (the model of the four 2023-12-10
  recordings, k drawn from the 60 touches of 20PL_2 + 40PL_1) and back (the model of 20PL_2 +
  40PL_1, k drawn from the 70 of 20PL_1 + 50PL_1), through ``ContactLocalizer`` as the CLI
  does. Own-day error: 2023-12-10's three other recordings tested on 20PL_1; 40PL_1 tested on
  20PL_2.
- ``--targets active``: the k touches are those ``recalibration_targets`` asks for from the
  old map (``skinloc.calibration.active``; the draw seeds its first target) among the same
  candidates, instead of random ones (``--targets random``, the default).

    python bench/recalibration.py --simulated --real --data ../shared/data/hiro-cone-skin \\
        --json bench/results/recalibration.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from skinloc.bench.paper import REAL_DEC, REAL_MAY
from skinloc.calibration.active import TARGET_STRATEGIES, recalibration_targets
from skinloc.data.recording import Recording, read_recording
from skinloc.evaluation.scoring import evaluate, train_localizer, training_arrays
from skinloc.geometry.mesh import cone_skin, sample_targets, surface_points
from skinloc.models.map_prior import load_prior
from skinloc.models.recalibration import choose_recalibration
from skinloc.models.response_map import ResponseMap, shape_features
from skinloc.sim.prior_build import draw_params, errors_mm, touch_means
from skinloc.sim.session_change import later_session
from skinloc.sim.skin import SimulatedSkin

KS = (0, 5, 10, 20)


def touch_features(skin: SimulatedSkin, targets: np.ndarray, rng: np.random.Generator):
    """Shape features ``(n, 64)`` of one touch (mean of 50 frames) near each target."""
    return shape_features(touch_means(skin, targets, rng))


def simulated(
    n_skins: int,
    first_seed: int,
    draws: int,
    changes: tuple[str, ...],
    targets: str = "random",
    ks: tuple[int, ...] = KS,
) -> dict:
    mesh = cone_skin()
    cands, prior = surface_points(mesh, 4000), load_prior()
    rows: dict = {}
    for seed in range(first_seed, first_seed + n_skins):
        rng = np.random.default_rng([seed, 35])
        skin = SimulatedSkin(mesh, params=draw_params(rng, 8, 8), random_state=seed)
        t1 = sample_targets(mesh, 100, "edge", rng)
        F1 = touch_features(skin, t1, rng)
        old = ResponseMap.fit(t1[:80], F1[:80], cands)  # 80 touches: beyond the prior's reach
        own = float(errors_mm(old, F1[80:], t1[80:]).mean())
        for change in changes:
            t2 = sample_targets(mesh, 60, "edge", rng)
            F2 = touch_features(later_session(skin, change, seed), t2, rng)
            ft, yt = F2[40:], t2[40:]
            for k in ks:
                for d in range(draws if k else 1):
                    if targets == "random":
                        idx = np.random.default_rng([seed, k, d]).permutation(40)[:k]
                    else:
                        idx = recalibration_targets(old, k, t2[:40], random_state=d)
                    q, F = t2[idx], F2[idx]

                    def err(m: ResponseMap, ft: np.ndarray = ft, yt: np.ndarray = yt) -> float:
                        return float(errors_mm(m, ft, yt).mean())

                    row = {"own day": own, "old untouched": err(old)}
                    if k >= 2:
                        use = prior if prior.applies(k) else None
                        row["k alone"] = err(ResponseMap.fit(q, F, cands, prior=use))
                    row["correction only"] = err(old.refined(q, F)) if k else err(old)
                    m, choice = choose_recalibration(old, q, F, prior)
                    row["recalibrated"] = err(m)
                    row["recalibrated, slack 1 SE"] = err(
                        choose_recalibration(old, q, F, prior, slack_se=1.0)[0]
                    )
                    row["recalibrated, no blends"] = err(
                        choose_recalibration(old, q, F, prior, blend_weights=())[0]
                    )
                    row["chose"] = choice.method
                    rows.setdefault(f"{change} k={k}", []).append(row)
        print(f"skin {seed} done", flush=True)
    return summarise(rows)


def summarise(rows: dict) -> dict:
    """Mean of every figure over skins and draws, and how often each method was chosen."""
    out: dict = {}
    for key, rs in rows.items():
        figs = {h for r in rs for h, v in r.items() if h != "chose"}
        res = {h: float(np.mean([r[h] for r in rs if h in r])) for h in sorted(figs)}
        chose = [r["chose"] for r in rs]
        res["chose"] = {c: chose.count(c) for c in sorted(set(chose))}
        res["n"] = len(rs)
        out[key] = res
        show = ", ".join(f"{h} {v:.1f}" for h, v in res.items() if isinstance(v, float))
        print(f"{key}: {show}; chose {res['chose']}", flush=True)
    return out


def split(recs: list[Recording], k: int, rng: np.random.Generator, idx: np.ndarray | None = None):
    """k touches of the pooled recordings (random, or ``idx``), and the rest: two lists."""
    sizes = [r.n_point_logs for r in recs]
    pick = np.zeros(sum(sizes), dtype=bool)
    pick[rng.permutation(sum(sizes))[:k] if idx is None else idx] = True
    cal, test, start = [], [], 0
    for r, n in zip(recs, sizes, strict=True):
        mine = pick[start : start + n]
        start += n
        if mine.any():
            cal.append(r.subset(np.flatnonzero(mine)))
        if (~mine).any():
            test.append(r.subset(np.flatnonzero(~mine)))
    return cal, test


def real(data: Path, draws: int, targets: str = "random", ks: tuple[int, ...] = KS) -> dict:
    names = (*REAL_DEC, *REAL_MAY)
    missing = [n for n in names if not (data / n).is_file()]
    if missing:
        raise SystemExit(f"error: {data} lacks {', '.join(missing)} (give --data)")
    recs = {n: read_recording(data / n) for n in names}
    dec_own = evaluate(train_localizer([recs[n] for n in REAL_DEC[1:]]), [recs[REAL_DEC[0]]])
    may_own = evaluate(train_localizer([recs[REAL_MAY[1]]]), [recs[REAL_MAY[0]]])
    directions = {
        "2023-12-10 -> 2024-05-23": (REAL_DEC, REAL_MAY, dec_own.stats.mean_mm),
        "2024-05-23 -> 2023-12-10": (REAL_MAY, REAL_DEC[:2], may_own.stats.mean_mm),
    }
    rows: dict = {}
    for name, (before, after, own) in directions.items():
        base = train_localizer([recs[n] for n in before])
        pool = [recs[n] for n in after]
        where = np.concatenate([r.targets for r in pool])
        for k in ks:
            for d in range(draws if k else 1):
                idx = None
                if targets == "active":
                    idx = recalibration_targets(base.map_, k, where, random_state=d)
                cal, test = split(pool, k, np.random.default_rng([k, d]), idx)
                row = {"own day": float(own), "old untouched": evaluate(base, test).stats.mean_mm}
                if cal:
                    X, y, g = training_arrays(cal)
                    row["k alone"] = evaluate(train_localizer(cal), test).stats.mean_mm
                else:
                    X, y, g = np.zeros((0, base.n_features_in_)), np.zeros((0, 3)), None
                new = base.recalibrate(X, y, groups=g)
                row["recalibrated"] = evaluate(new, test).stats.mean_mm
                row["chose"] = new.recalibration_["method"]
                rows.setdefault(f"{name} k={k}", []).append(row)
                print(name, k, d, {h: v for h, v in row.items()}, flush=True)
    return summarise(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("../shared/data/hiro-cone-skin"))
    ap.add_argument("--simulated", action="store_true", help="simulated skins and changes")
    ap.add_argument("--real", action="store_true", help="the real pair, both directions")
    ap.add_argument("--skins", type=int, default=8, help="simulated skins")
    ap.add_argument("--first-seed", type=int, default=9000)
    ap.add_argument("--draws", type=int, default=3, help="random draws of the k touches")
    ap.add_argument("--changes", nargs="+", default=["real", "mild"])
    ap.add_argument(
        "--targets", choices=TARGET_STRATEGIES, default="random", help="how the k are chosen"
    )
    ap.add_argument("--ks", type=int, nargs="+", default=list(KS), help="numbers of new touches")
    ap.add_argument("--json", type=Path, help="write the figures as JSON")
    args = ap.parse_args(argv)
    if not (args.simulated or args.real):
        ap.error("give --simulated, --real or both")
    ks = tuple(args.ks)
    out: dict = {"ks": list(ks), "draws": args.draws, "targets": args.targets}
    if args.simulated:
        out["simulated"] = simulated(
            args.skins, args.first_seed, args.draws, tuple(args.changes), args.targets, ks
        )
        out["simulated_skins"] = [args.first_seed, args.first_seed + args.skins - 1]
    if args.real:
        out["real"] = real(args.data, args.draws, args.targets, ks)
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
