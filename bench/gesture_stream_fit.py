"""Does a model trained on ``skinloc simulate --points 80 --skin-seed K`` fit a gesture stream?

Makes (in a temporary folder) a calibration session and a gesture stream of the same skin
seed, trains the default model on the session, replays the stream through ``skinloc run
--fast`` and compares each reported one-finger contact with the true finger of that frame
(``truth/fingers_m``). Prints the median and 90th percentile error (mm) and the share of
frames with a finger down that were reported; with ``--control``, the same for a model trained
on another skin (skin seed K + 1), which should not fit.

    python bench/gesture_stream_fit.py --skin-seed 1 --seed 2 --gestures 20
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import h5py
import numpy as np


def skinloc(*args: object) -> None:
    cmd = [sys.executable, "-c", "from skinloc.cli.main import main; main()", *map(str, args)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def fit(model_skin_seed: int, args: argparse.Namespace) -> dict:
    """Errors of a model trained on skin ``model_skin_seed`` on the stream of ``args``."""
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        skinloc("simulate", "--points", 80, "--skin-seed", model_skin_seed, "--seed",
                args.seed + 1000, "--out", d / "cal.h5")  # fmt: skip
        skinloc("train", d / "cal.h5", "--out", d / "model.h5")
        skinloc("simulate", "--gestures", args.gestures, "--skin-seed", args.skin_seed,
                "--seed", args.seed, "--out", d / "g.h5")  # fmt: skip
        skinloc("run", "--model", d / "model.h5", "--source", d / "g.h5", "--fast",
                "--sink", f"jsonl:{d / 'out.jsonl'}")  # fmt: skip
        rows = [json.loads(line) for line in (d / "out.jsonl").read_text().splitlines()]
        with h5py.File(d / "g.h5") as f:
            times = f["stream/times_s"][()]
            fingers = f["truth/fingers_m"][()]
    one = np.isfinite(fingers[:, 0, 0]) & np.isnan(fingers[:, 1, 0])
    errors, seen = [], set()
    for r in rows:
        if "position_m" not in r:
            continue
        k = int(np.argmin(np.abs(times - r["timestamp_s"])))
        if one[k]:
            errors.append(1e3 * np.linalg.norm(np.asarray(r["position_m"]) - fingers[k, 0]))
            seen.add(k)
    e = np.asarray(errors)
    return {
        "one_finger_frames": int(one.sum()),
        "reported": len(seen) / max(int(one.sum()), 1),
        "error_mm_median": float(np.median(e)) if len(e) else None,
        "error_mm_p90": float(np.percentile(e, 90)) if len(e) else None,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skin-seed", type=int, default=1)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--gestures", type=int, default=20)
    ap.add_argument("--control", action="store_true", help="also a model of another skin")
    args = ap.parse_args()
    out = {"skin_seed": args.skin_seed, "seed": args.seed, "gestures": args.gestures}
    out["model_same_skin"] = fit(args.skin_seed, args)
    if args.control:
        out["model_other_skin"] = fit(args.skin_seed + 1, args)
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
