"""CPU of the live /diagnostics on the loop's thread: one round of 50 skins, and one skin.

    PYTHONPATH=src python bench/diagnostics_cost.py --out bench/results/diagnostics-cost-DATE.json

50 calibrated skins of one ``Runner`` (a worker's share of 100 skins on 2 cores; the default
model of ``skinloc bench --online``), ``SkinControl.diagnostics`` timed in thread CPU time (robust
to the machine's load): a whole round at once, as the ROS 2 sink built it once a second before,
and one skin (``slots=[s]``), as it builds a round now, a skin or a few a sweep. The loop does
nothing else while either runs: the frames that arrive meanwhile wait.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np


def main() -> None:
    from skinloc.bench.online import train_bench_models
    from skinloc.bench.stream import touch_stream
    from skinloc.live.config import PipelineConfig
    from skinloc.live.runner import Runner, SkinConfig
    from skinloc.models.engine import load_engine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skins", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=20)
    ap.add_argument("--models", type=Path, default=None, help="the bench models' folder")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    folder = args.models or Path(tempfile.gettempdir()) / "skinloc-bench" / "online-models"
    engine = load_engine(train_bench_models(folder, ("default",))["default"])
    config = PipelineConfig(baseline_frames=50)
    specs = [
        SkinConfig(model=engine, source="sim", name=f"skin{i:03d}", config=config)
        for i in range(args.skins)
    ]
    runner = Runner(specs)  # not opened: its cores are fed here, frame by frame
    frames, _ = touch_stream(100, random_state=0)
    for core in runner.cores:
        for j in range(60):
            core.process_frame(frames[j].astype(np.float64), j * 0.01, j)
    control = runner.control
    control.diagnostics(0.0)  # the first look (no frame rate yet)
    whole, one = [], []
    for r in range(args.rounds):
        t0 = time.thread_time()
        control.diagnostics(1.0 + r)
        whole.append(time.thread_time() - t0)
        for s in range(args.skins):
            t0 = time.thread_time()
            control.diagnostics(1.0 + r, slots=[s])
            one.append(time.thread_time() - t0)
    out = {
        "skins": args.skins,
        "rounds": args.rounds,
        "load_average": list(os.getloadavg()),
        "round_at_once_cpu_ms_median": float(np.median(whole)) * 1e3,
        "round_at_once_cpu_ms_max": float(np.max(whole)) * 1e3,
        "one_skin_cpu_us_median": float(np.median(one)) * 1e6,
        "one_skin_cpu_us_p99": float(np.percentile(one, 99)) * 1e6,
    }
    print(json.dumps(out, indent=2))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
