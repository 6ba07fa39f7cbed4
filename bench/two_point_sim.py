"""The simulated skin's two-point threshold, on the simulator's physical two-finger images.

For each skin seed: a calibration session of that skin (``skinloc simulate --points 80
--skin-seed K``, the calibration ``bench/gesture_eval.py`` trains on) and the default model
trained on it, which measures its own threshold at calibration (held-out pairs of its touch
means, summed). Then pairs of fingers on the same skin, each finger's pressure and radius
drawn as in a session (light touches left out: two fingers of similar strength), separations
spread evenly over 10-110 mm; the image is the physical two-finger image
(``sim.fingers.multi_touch_image``: shared crossing fields, line loading) plus one frame of the
skin's noise. Counted by ``Engine.contacts(x, 3)`` and placed within 15 mm (better
assignment); the threshold by ``skinloc.models.multi_contact.two_point.threshold_from_pairs``.

    python bench/two_point_sim.py --skin-seeds 11 12 13 --pairs 600 --out two-point-sim.json
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from skinloc.geometry.mesh import cone_skin, sample_surface
from skinloc.models.localizer import ContactLocalizer
from skinloc.models.multi_contact.two_point import (
    describe,
    placed_both,
    threshold_from_pairs,
    two_point_of,
)
from skinloc.sim.fingers import Finger, multi_touch_image
from skinloc.sim.skin import SimulatedSkin

#: Separations drawn, mm.
SEP_RANGE_MM = (10.0, 110.0)


def skinloc(*args: object) -> None:
    cmd = [sys.executable, "-c", "from skinloc.cli.main import main; main()", *map(str, args)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def pairs_at_even_separations(mesh, n: int, rng: np.random.Generator) -> np.ndarray:
    """``(n, 2, 3)`` m: pairs of surface points, separations spread evenly over the range."""
    pts, _ = sample_surface(mesh, 4000, rng)
    D = 1e3 * np.linalg.norm(pts[:, None] - pts[None], axis=2)
    out = np.empty((n, 2, 3))
    for k, want in enumerate(rng.uniform(*SEP_RANGE_MM, n)):
        i = rng.integers(len(pts))
        j = int(np.argmin(np.abs(D[i] - want)))
        out[k] = pts[i], pts[j]
    return out


def one_skin(skin_seed: int, seed: int, n_pairs: int, tmp: Path) -> dict:
    d = tmp / f"skin{skin_seed}"
    d.mkdir(exist_ok=True)
    if not (d / "cal.h5").exists():
        skinloc("simulate", "--points", 80, "--skin-seed", skin_seed, "--seed", seed + 1000,
                "--out", d / "cal.h5")  # fmt: skip
    if not (d / "model.h5").exists():
        skinloc("train", d / "cal.h5", "--out", d / "model.h5")
    model = ContactLocalizer.load(d / "model.h5")
    engine = model.engine().warm_up()
    mesh = cone_skin()
    skin = SimulatedSkin(mesh, random_state=skin_seed)
    rng = np.random.default_rng([seed, skin_seed])
    truth = pairs_at_even_separations(mesh, n_pairs, rng)
    sep, two, placed = [], [], []
    for t in truth:
        fingers = [Finger(p, *skin.draw_touch(rng, weak=False)) for p in t]
        x = multi_touch_image(skin.layout, skin.params, fingers)
        x = x + skin.layout.noise_std_counts * rng.standard_normal(x.shape)
        cs = engine.contacts(x.astype(np.float32), 3)
        sep.append(1e3 * float(np.linalg.norm(t[0] - t[1])))
        two.append(len(cs) == 2)
        placed.append(len(cs) == 2 and placed_both(cs.positions_m, t))
    return {
        "skin_seed": skin_seed,
        "calibration": two_point_of(model.contact_rule_),
        "physical": threshold_from_pairs(np.array(sep), np.array(two), np.array(placed)),
        "pairs": {"sep_mm": sep, "counted_two": two, "placed": placed},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skin-seeds", type=int, nargs="+", default=[11, 12, 13])
    ap.add_argument("--seed", type=int, default=5, help="as bench/gesture_eval.py's --seed")
    ap.add_argument("--pairs", type=int, default=600, help="pairs per skin")
    ap.add_argument("--keep", type=Path, help="keep the calibrations and models here")
    ap.add_argument("--out", type=Path, help="JSON results")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as td:
        tmp = args.keep or Path(td)
        tmp.mkdir(parents=True, exist_ok=True)
        runs = [one_skin(k, args.seed + k, args.pairs, tmp) for k in args.skin_seeds]
    p = {k: np.concatenate([r["pairs"][k] for r in runs]) for k in runs[0]["pairs"]}
    pooled = threshold_from_pairs(p["sep_mm"], p["counted_two"], p["placed"])
    for r in runs:
        print(f"skin {r['skin_seed']}: calibration: {describe(r['calibration'])}")
        print(f"skin {r['skin_seed']}: physical pairs: {describe(r['physical'])}")
    print("\n| separation (mm) | n | counted two | both within 15 mm |\n|---|---|---|---|")
    for key, b in pooled["bins"].items():
        print(f"| {key} | {b['n']} | {b['counted_two']:.0%} | {b['all_within_15mm']:.0%} |")
    print(f"\npooled physical pairs: {describe(pooled)}")
    if args.out:
        res = {
            "pooled": pooled,
            "skins": [{k: v for k, v in r.items() if k != "pairs"} for r in runs],
        }
        args.out.write_text(json.dumps(res, indent=2, default=float))


if __name__ == "__main__":
    main()
