"""The landing change on real touches: single fingers called two, shifted pairs found.

The time cue of the count (``skinloc.models.multi_contact.landing``): a touch's image changes
shape when a second finger lands or lifts beside the first. The threshold is calibrated in
``fit`` on the training recording alone (``CountRule.landing_change``, and the hold level
``landing_hold``); this script measures it on recordings that chose nothing: each of their
touches ramped up, held and ramped down with its own recorded frame-to-frame noise is a single
finger, and two of their touches with the second landing and lifting 1-4 frames (10-40 ms at
100 Hz) after the first are a pair. The real recordings hold no landing (50 frames of a held
touch each, no timestamps), so the ramps are synthetic; the noise and the images are real.

    python bench/landing_eval.py --data ../shared/data/hiro-cone-skin --out landing.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from skinloc.bench.paper import TEST_DEC, TRAIN_DEC
from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import train_localizer
from skinloc.models.engine import load_engine
from skinloc.models.multi_contact.landing import landing_sets

BINS_MM = (10, 20, 30, 40, 60, 1000)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("../shared/data/hiro-cone-skin"))
    ap.add_argument("--train", default=TRAIN_DEC)
    ap.add_argument(
        "--test",
        nargs="+",
        default=list(TEST_DEC),
    )
    ap.add_argument("--draws", type=int, default=4, help="Synthetic touches per real touch.")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    engine = load_engine(train_localizer([read_recording(args.data / args.train)]))
    rule = engine.rule
    thr, hold = rule.landing_change, rule.landing_hold
    print(f"trained on {args.train}: landing_change {thr:.2f}, landing_hold {hold:.2f}")
    out: dict = {"train": args.train, "landing_change": thr, "landing_hold": hold, "test": {}}
    all_s, all_p, all_d, all_q = [], [], [], []
    for name in args.test:
        rec = read_recording(args.data / name)
        s, p, ij = landing_sets(
            list(rec.deltas), engine.noise_weights(), rec.targets, z_on=rule.z_on,
            n_draws=args.draws, random_state=1,
        )  # fmt: skip
        d = np.linalg.norm(rec.targets[ij[:, 0]] - rec.targets[ij[:, 1]], axis=1)
        # the pair search on one frame of each touch summed (both fingers down): counted two?
        rng = np.random.default_rng(2)
        pick = rng.integers(0, rec.deltas.shape[1], size=ij.shape)
        x = rec.deltas[ij[:, 0], pick[:, 0]] + rec.deltas[ij[:, 1], pick[:, 1]]
        search = np.array([len(engine.contacts(xi.astype(np.float32))) >= 2 for xi in x])
        all_s.append(s), all_p.append(p), all_d.append(d), all_q.append(search)
        out["test"][name] = {
            "singles": len(s),
            "singles_called_two": float(np.mean(s >= thr)),
            "singles_held": float(np.mean((s >= hold) & (s < thr))),
            "pairs": len(p),
            "pairs_found": float(np.mean(p >= thr)),
            "pairs_found_or_held": float(np.mean(p >= hold)),
        }
        r = out["test"][name]
        print(f"{name}: singles called two {r['singles_called_two']:.3f} (held "
              f"{r['singles_held']:.3f}) of {len(s)}; pairs found {r['pairs_found']:.3f} "
              f"(or held {r['pairs_found_or_held']:.3f}) of {len(p)}")  # fmt: skip
    s, p, d = np.concatenate(all_s), np.concatenate(all_p), 1e3 * np.concatenate(all_d)
    q = np.concatenate(all_q)
    out["all"] = {"singles": len(s), "singles_called_two": float(np.mean(s >= thr)),
                  "singles_held": float(np.mean((s >= hold) & (s < thr))), "pairs": len(p),
                  "pairs_found": float(np.mean(p >= thr)), "search_two": float(np.mean(q)),
                  "either": float(np.mean(q | (p >= thr)))}  # fmt: skip
    out["pairs_by_separation_mm"] = {}
    for lo, hi in zip(BINS_MM, BINS_MM[1:], strict=False):
        m = (d >= lo) & (d < hi)
        if m.any():
            out["pairs_by_separation_mm"][f"{lo}-{hi}"] = {
                "n": int(m.sum()), "found": float(np.mean(p[m] >= thr)),
                "search_two": float(np.mean(q[m])),
                "either": float(np.mean(q[m] | (p[m] >= thr))),
            }  # fmt: skip
    a = out["all"]
    print(f"all: singles called two {a['singles_called_two']:.3f}, held {a['singles_held']:.3f} "
          f"of {a['singles']}; pairs found {a['pairs_found']:.3f} of {a['pairs']}, search two "
          f"{a['search_two']:.3f}, either {a['either']:.3f}")  # fmt: skip
    for b, r in out["pairs_by_separation_mm"].items():
        print(f"  pairs {b} mm: {r['n']}, change found {r['found']:.3f}, search two "
              f"{r['search_two']:.3f}, either {r['either']:.3f}")  # fmt: skip
    if args.out:
        args.out.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
