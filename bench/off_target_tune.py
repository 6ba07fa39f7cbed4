"""The sessions the off-target check was chosen on (never ``off_target_eval.py``'s).

The same protocol as ``bench/off_target_eval.py`` (1 to 3 bad touches, 40-100 mm off), on
other sessions: simulated skins 200-239 (rng seed ``1000 + size``) and sessions drawn from three
of the six recordings (20PL_1, 30PL, 80PL; rng seed ``5000 + size``). Prints caught and falsely
flagged shares for ``skinloc.calibration.touch_check.off_target`` with the options given.

    python bench/off_target_tune.py [--sizes 10 20 40 80] [--sessions 40]
        [--power 0.5] [--k 2.0] [--floor-mm 30] [--score-floor 0.4]
        [--data ../shared/data/hiro-cone-skin]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from off_target_eval import real_sessions, simulated_sessions

from skinloc.calibration.touch_check import off_target

#: The recordings the check was chosen on; the other three are the eval's alone.
TUNING_RECORDINGS = (
    "ConeSkinData_RND_20PL_1.mat",
    "ConeSkinData30Points_RND_30PL_1.mat",
    "ConeSkinData80Points_RND_80PL_1.mat",
)


def real_tuning_sessions(size: int, n_sessions: int, data: Path):
    """``(targets, touch_means, bad, surface)`` from the tuning recordings, relabelled."""
    rng = np.random.default_rng(5000 + size)
    return real_sessions(size, n_sessions, rng, data, list(TUNING_RECORDINGS))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 20, 40, 80])
    ap.add_argument("--sessions", type=int, default=40)
    ap.add_argument("--power", type=float, default=0.5)
    ap.add_argument("--k", type=float, default=2.0)
    ap.add_argument("--floor-mm", type=float, default=30.0)
    ap.add_argument("--score-floor", type=float, default=0.4)
    ap.add_argument("--data", type=Path, default=Path("../shared/data/hiro-cone-skin"))
    args = ap.parse_args()
    opts = dict(power=args.power, k=args.k, floor_mm=args.floor_mm, score_floor=args.score_floor)
    for kind in ("sim", "real"):
        for size in args.sizes:
            if kind == "sim":
                rng = np.random.default_rng(1000 + size)
                gen = simulated_sessions(size, args.sessions, rng, 200)
            else:
                gen = real_tuning_sessions(size, args.sessions, args.data)
            hit = n_bad = false = n_good = 0
            for t, m, bad, surf in gen:
                flags = off_target(t, m, surf, **opts).flags
                hit += int((flags & bad).sum())
                n_bad += int(bad.sum())
                false += int((flags & ~bad).sum())
                n_good += int((~bad).sum())
            print(
                f"{kind} {size} touches: caught {hit / n_bad:.0%} ({hit}/{n_bad}), good touches "
                f"flagged {false / n_good:.1%} ({false}/{n_good})",
                flush=True,
            )


if __name__ == "__main__":
    main()
