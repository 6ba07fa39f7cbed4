"""Figures of docs/accuracy.md, "Active calibration": which touches to ask for.

Pool: the 2023-12-10 recordings other than the test one. Each strategy picks N point logs
from the pool in its own order (``calibration.active.select_point_logs``; active uses only the
images of touches already chosen); a default map is trained on them and scored on the test
recording (mean error, mm). Orders are nested, so one 40-touch order gives N = 10, 20, 40.

    python bench/active_eval.py --test ConeSkinData80Points_RND_80PL_1.mat \
        --seeds 0 1 2 3 4 --active-seeds 0 1 2 [--json bench/results/active.json]
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from _day import DAY, day_parser, load_day

from skinloc.calibration.active import select_point_logs, subset_recordings
from skinloc.evaluation.scoring import evaluate, train_localizer


def curve(
    pool, test, strategy: str, seed: int, sizes: list[int], eval_at: str = "surface"
) -> list[float]:
    """Mean test error (mm) after the first N picks of one order, for each N in ``sizes``."""
    picks = select_point_logs(pool, max(sizes), strategy, seed, eval_at=eval_at)
    out = []
    for n in sizes:
        model = train_localizer(subset_recordings(pool, picks[:n]))
        out.append(float(evaluate(model, [test]).stats.mean_mm))
    return out


def main() -> None:
    ap = day_parser(__doc__)
    ap.add_argument("--test", nargs="*", default=[DAY[2]])
    ap.add_argument("--sizes", type=int, nargs="*", default=[10, 20, 40])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 3, 4])
    ap.add_argument("--active-seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument(
        "--eval-at",
        choices=("pool", "surface"),
        default="surface",
        help="active: average the expected error over the pool's targets or the surface",
    )
    args = ap.parse_args()
    recs = load_day(args.data)
    results = []
    for test_name in args.test:
        pool = [recs[n] for n in DAY if n != test_name]
        test = recs[test_name]
        row: dict = {"test": test_name, "sizes": args.sizes, "eval_at": args.eval_at}
        for strategy, seeds in (
            ("random", args.seeds),
            ("even", args.seeds),
            ("active", args.active_seeds),
        ):
            errs = np.array(
                [curve(pool, test, strategy, s, args.sizes, args.eval_at) for s in seeds]
            )
            row[strategy] = {
                "seeds": seeds,
                "mean_mm": errs.mean(axis=0).round(2).tolist(),
                "std_mm": errs.std(axis=0).round(2).tolist(),
                "per_seed_mm": errs.round(2).tolist(),
            }
            curve_mm = dict(zip(args.sizes, row[strategy]["mean_mm"], strict=True))
            print(test_name, strategy, curve_mm, flush=True)
        row["active_over_random"] = [
            round(a / r, 3)
            for a, r in zip(row["active"]["mean_mm"], row["random"]["mean_mm"], strict=True)
        ]
        print(test_name, "active / random:", row["active_over_random"], flush=True)
        results.append(row)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")


if __name__ == "__main__":
    main()
