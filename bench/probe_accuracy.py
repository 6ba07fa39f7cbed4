"""A robot's probe against a person's touch, on simulated skins (docs/accuracy.md).

For each skin seed and session size, two calibration sessions of the same simulated skin are
recorded with the command line as a user would: ``skinloc simulate`` (the simulator's scripted
person, 5.3 mm probing error per axis) and ``skinloc collect --probe sim --probe-error-mm E``
(a simulated arm). Each trains the default model (``train_localizer``, what ``skinloc train``
fits); both are scored on fresh random touches of the same skin (``skinloc simulate --seed
100 --mode random``) against where the finger really pressed (``meta["true_contacts"]``), per
touch (the mean of its frames) and per frame. No real arm was used.

    python bench/probe_accuracy.py [--skins 11 12] [--points 80 240] [--probe-error-mm 0.5]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import evaluate, train_localizer

FRESH_SEED = 100


def skinloc(*args: object) -> None:
    """Run ``skinloc ARGS`` (this interpreter's package) and fail loudly if it fails."""
    cmd = [sys.executable, "-m", "skinloc", *(str(a) for a in args)]
    res = subprocess.run(cmd, capture_output=True, text=True)
    if res.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{res.stdout}{res.stderr}")


def truth(path: Path):
    """The recording at ``path`` labelled with where the finger really pressed."""
    rec = read_recording(path)
    return dataclasses.replace(
        rec, targets=np.asarray(rec.meta["true_contacts"], dtype=np.float64).reshape(-1, 3)
    )


def fresh_touches(folder: Path, skin_seed: int, n: int) -> Path:
    """``n`` random human-like touches of simulated skin ``skin_seed``, the test set (a file)."""
    fresh = folder / f"fresh{skin_seed}.h5"
    skinloc(
        "simulate", "--skin-seed", skin_seed, "--seed", FRESH_SEED, "--mode", "random",
        "--points", n, "--out", fresh,
    )  # fmt: skip
    return fresh


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skins", type=int, nargs="+", default=[11, 12])
    ap.add_argument("--points", type=int, nargs="+", default=[80, 240])
    ap.add_argument("--probe-error-mm", type=float, default=0.5)
    ap.add_argument("--rim-mm", type=float, default=5.0, help="collect --rim-mm of the probe")
    ap.add_argument("--no-person", action="store_true", help="only the probe's sessions")
    ap.add_argument("--fresh", type=int, default=40, help="fresh random touches per skin")
    ap.add_argument("--out", type=Path, default=None, help="write the rows as JSON here")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        for s in args.skins:
            fresh = fresh_touches(d, s, args.fresh)
            test = [truth(fresh)]
            for n in args.points:
                human, probe = d / f"human{s}_{n}.h5", d / f"probe{s}_{n}.h5"
                if not args.no_person:
                    skinloc("simulate", "--skin-seed", s, "--points", n, "--out", human)
                skinloc(
                    "collect", "--probe", "sim", "--probe-error-mm", args.probe_error_mm,
                    "--points", n, "--skin-seed", s, "--rim-mm", args.rim_mm, "--out", probe,
                )  # fmt: skip
                runs = [("probe (sim)", probe)]
                if not args.no_person:
                    runs.insert(0, ("person (sim)", human))
                for who, path in runs:
                    rec = read_recording(path)
                    label_mm = 1e3 * np.linalg.norm(
                        np.asarray(rec.meta["true_contacts"]) - rec.targets, axis=1
                    )
                    model = train_localizer([rec])
                    touch = evaluate(model, test).stats
                    per_frame = evaluate(model, test, per_frame=True)
                    frame = per_frame.stats
                    t = rec.frame_times
                    s_per_touch = float(t[-1, -1] - t[0, 0]) / max(rec.n_point_logs - 1, 1)
                    row = {
                        "skin": s,
                        "points": n,
                        "who": who,
                        "label_error_mm": round(float(label_mm.mean()), 2),
                        "touch_mean_mm": round(touch.mean_mm, 2),
                        "touch_median_mm": round(touch.median_mm, 2),
                        "frame_mean_mm": round(frame.mean_mm, 2),
                        "frames_over_30mm_pct": round(
                            100 * float(np.mean(per_frame.errors_mm > 30)), 1
                        ),
                        "sim_s_per_touch": round(s_per_touch, 2),
                    }
                    rows.append(row)
                    print(json.dumps(row), flush=True)
    print()
    print("| who | touches | label error | per touch mean (median) | per frame mean | > 30 mm |")
    print("|---|---|---|---|---|---|")
    for who in ("person (sim)", "probe (sim)"):
        for n in args.points:
            sel = [r for r in rows if r["who"] == who and r["points"] == n]
            if not sel:
                continue
            m = {k: np.mean([r[k] for r in sel]) for k in sel[0] if k not in ("who", "skin")}
            print(
                f"| {who} | {n} | {m['label_error_mm']:.1f} mm | {m['touch_mean_mm']:.1f} "
                f"({m['touch_median_mm']:.1f}) mm | {m['frame_mean_mm']:.1f} mm | "
                f"{m['frames_over_30mm_pct']:.1f} % |"
            )
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
