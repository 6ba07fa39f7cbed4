"""The footprint cue on images that chose nothing: single touches called two, pairs found.

The footprint score (``skinloc.models.multi_contact.footprint``) is calibrated in ``fit`` on the
training recording alone (``CountRule.footprint_two`` and ``footprint_hold``). Real: the default
model trained on ``--train``; the touches of the other recordings (``--test``, touch means and
5 frames each) are single fingers, and every pair of their touches summed (means with means,
a frame with a frame) two fingers, as in ``bench/multitouch_eval.py``. Simulated
(``--skin-seeds``): the calibration and model of ``bench/two_point_sim.py``'s skins, then the
simulator's physical single-finger and two-finger images plus one frame of noise. Each image
is searched once (``Engine.contacts``, K = 3) and scored by the live path's
``FootprintWatch``; reported by separation: counted two by the search, by the footprint,
either, and the share of the search's misses the footprint catches.

    python bench/footprint_eval.py --data ../shared/data/hiro-cone-skin
    python bench/footprint_eval.py --skin-seeds 11 12 13
"""

from __future__ import annotations

import argparse
import itertools
import json
import tempfile
from pathlib import Path

import numpy as np

from skinloc.bench.paper import TEST_DEC, TRAIN_DEC
from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import train_localizer
from skinloc.live.footprint import FootprintWatch

BINS_MM = (10, 20, 30, 40, 50, 60, 1000)


def score(engine, watch: FootprintWatch, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(count (n,), footprint score (n,))`` of images ``(n, k)`` counts (nan: no score)."""
    counts, scores = np.zeros(len(images), dtype=int), np.full(len(images), np.nan)
    for i, x in enumerate(np.ascontiguousarray(images, dtype=np.float32)):
        counts[i] = len(engine.contacts(x, 3))
        watch.start()
        watch.step()
        if watch.n:
            scores[i] = watch.mean
    return counts, scores


def table(rule, singles: tuple, pairs: tuple, sep_mm: np.ndarray) -> dict:
    """Singles called two (search, footprint, held) and pairs found, by separation."""
    two, hold = rule.footprint_two, rule.footprint_hold
    c, s = singles
    ok = np.isfinite(s)
    res: dict = {
        "singles": {
            "n": int(ok.sum()),
            "search_two": float(np.mean(c[ok] >= 2)),
            "footprint_two": float(np.mean(s[ok] >= two)),
            "footprint_held": float(np.mean(s[ok] >= hold)),
            "either_two": float(np.mean((c[ok] >= 2) | (s[ok] >= two))),
        },
        "pairs": {},
    }
    c, s = pairs
    fp = np.nan_to_num(s, nan=-np.inf) >= two
    search = c >= 2
    for lo, hi in itertools.pairwise(BINS_MM):
        sel = (sep_mm >= lo) & (sep_mm < hi)
        if not sel.any():
            continue
        miss = sel & ~search
        res["pairs"][f"{lo}-{hi}" if hi < 1000 else f">{lo}"] = {
            "n": int(sel.sum()),
            "search_two": float(search[sel].mean()),
            "footprint_two": float(fp[sel].mean()),
            "either": float((search | fp)[sel].mean()),
            "search_missed": int(miss.sum()),
            "footprint_of_missed": float(fp[miss].mean()) if miss.any() else None,
        }
    return res


def real(args) -> dict:
    model = train_localizer([read_recording(args.data / args.train)])
    engine = model.engine().warm_up()
    watch = FootprintWatch(engine.search_tables(), engine.rule).warm_up()
    rng = np.random.default_rng(args.seed)
    S_img, P_img, P_sep = [], [], []
    for name in args.test:
        rec = read_recording(args.data / name)
        means, deltas = rec.touch_means.astype(np.float64), rec.deltas.astype(np.float64)
        S_img.append(means)
        S_img.append(
            np.stack([d[rng.choice(len(d), 5, replace=False)] for d in deltas]).reshape(
                -1, means.shape[1]
            )
        )
        for a, b in itertools.combinations(range(len(means)), 2):
            d = 1e3 * np.linalg.norm(rec.targets[a] - rec.targets[b])
            P_img.append(means[a] + means[b])
            P_img.append(
                deltas[a][rng.integers(len(deltas[a]))] + deltas[b][rng.integers(len(deltas[b]))]
            )
            P_sep += [d, d]
    res = table(
        engine.rule,
        score(engine, watch, np.concatenate(S_img)),
        score(engine, watch, np.asarray(P_img)),
        np.asarray(P_sep),
    )
    return {"train": args.train, "test": args.test, **_levels(engine.rule), **res}


def simulated(args, tmp: Path) -> dict:
    from two_point_sim import pairs_at_even_separations, skinloc

    from skinloc.geometry.mesh import cone_skin
    from skinloc.models.localizer import ContactLocalizer
    from skinloc.sim.fingers import Finger, multi_touch_image
    from skinloc.sim.skin import SimulatedSkin

    out = {}
    for k in args.skin_seeds:
        d = tmp / f"skin{k}"
        d.mkdir(parents=True, exist_ok=True)
        seed = args.sim_seed + k
        if not (d / "cal.h5").exists():
            skinloc("simulate", "--points", 80, "--skin-seed", k, "--seed", seed + 1000,
                    "--out", d / "cal.h5")  # fmt: skip
        if not (d / "model.h5").exists():
            skinloc("train", d / "cal.h5", "--out", d / "model.h5")
        engine = ContactLocalizer.load(d / "model.h5").engine().warm_up()
        watch = FootprintWatch(engine.search_tables(), engine.rule).warm_up()
        mesh = cone_skin()
        skin = SimulatedSkin(mesh, random_state=k)
        rng = np.random.default_rng([seed, k, 7])
        truth = pairs_at_even_separations(mesh, args.pairs, rng)
        noise = skin.layout.noise_std_counts

        def image(fingers: list, skin=skin, noise=noise, rng=rng) -> np.ndarray:
            x = multi_touch_image(skin.layout, skin.params, fingers)
            return x + noise * rng.standard_normal(x.shape)

        singles = [image([Finger(t[0], *skin.draw_touch(rng, weak=False))]) for t in truth]
        pairs = [image([Finger(p, *skin.draw_touch(rng, weak=False)) for p in t]) for t in truth]
        sep = 1e3 * np.linalg.norm(truth[:, 0] - truth[:, 1], axis=1)
        out[str(k)] = {
            **_levels(engine.rule),
            **table(
                engine.rule,
                score(engine, watch, np.asarray(singles)),
                score(engine, watch, np.asarray(pairs)),
                sep,
            ),
        }
    return out


def _levels(rule) -> dict:
    return {"footprint_two": rule.footprint_two, "footprint_hold": rule.footprint_hold}


def print_table(name: str, res: dict) -> None:
    s = res["singles"]
    print(
        f"\n{name}: single touches (n {s['n']}) called two: search {s['search_two']:.1%}, "
        f"footprint {s['footprint_two']:.1%}, either {s['either_two']:.1%}; "
        f"held by the footprint {s['footprint_held']:.1%}"
    )
    print(
        "| separation (mm) | n | search | footprint | either | footprint of the search's misses |"
    )
    print("|---|---|---|---|---|---|")
    for key, b in res["pairs"].items():
        fm = "" if b["footprint_of_missed"] is None else f"{b['footprint_of_missed']:.0%}"
        print(
            f"| {key} | {b['n']} | {b['search_two']:.0%} | {b['footprint_two']:.0%} | "
            f"{b['either']:.0%} | {fm} of {b['search_missed']} |"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=Path("../shared/data/hiro-cone-skin"))
    ap.add_argument("--train", default=TRAIN_DEC)
    ap.add_argument(
        "--test",
        nargs="+",
        default=list(TEST_DEC),
    )
    ap.add_argument("--skin-seeds", type=int, nargs="*", help="Simulated skins instead")
    ap.add_argument("--sim-seed", type=int, default=5, help="as bench/two_point_sim.py's --seed")
    ap.add_argument("--pairs", type=int, default=400, help="Simulated pairs per skin")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, help="Keep the simulated calibrations and models here")
    ap.add_argument("--out", type=Path, help="JSON results")
    args = ap.parse_args()
    if args.skin_seeds:
        with tempfile.TemporaryDirectory() as td:
            res = {"simulated": simulated(args, args.keep or Path(td))}
        for k, r in res["simulated"].items():
            print_table(f"skin {k}", r)
    else:
        res = {"real": real(args)}
        r = res["real"]
        two, hold = r["footprint_two"], r["footprint_hold"]
        print(f"trained on {args.train}: footprint_two {two:.2f}, hold {hold:.2f}")
        print_table("other recordings", r)
    if args.out:
        args.out.write_text(json.dumps(res, indent=2, default=float))


if __name__ == "__main__":
    main()
