"""What the slowest touched frames of the K = 3 live pipeline run, and why the full search runs.

The same simulated stream and model as ``bench/multitouch_latency.py``. Two parts:

* the touched frames whose contacts needed the full multi-contact search, by cause, read from
  the stream's ``SearchMemory`` before and after each frame (a touch's first frame; after a frame
  the memory could not keep; the refresh every ``REFRESH_FRAMES``; the memory's own checks);
* K = 1 and K = 3 bytes in to contacts out (``SkinCore.feed``), interleaved rounds in one
  process, and what the slowest 1 % of K = 3's touched frames ran (the full search, the pair
  prior's anchored fit, a touch's start).

    PYTHONPATH=src python bench/multitouch_tail.py --out bench/results/multitouch_tail.json
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import Counter
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--models", type=Path, default=Path("/tmp/skinloc-bench-multitouch"))
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()

    from skinloc.bench.online import touch_stream, train_bench_models
    from skinloc.hardware.protocol import encode_binary
    from skinloc.live.core import PipelineConfig, SkinCore
    from skinloc.models.engine import load_engine
    from skinloc.models.multi_contact.search import MEM_FRAMES, REFRESH_FRAMES

    engine = load_engine(train_bench_models(args.models, ("default",))["default"])
    frames, _ = touch_stream(args.frames, random_state=0)

    # why the full search runs (mem.state: valid, row, residual, frames answered since, ...)
    core = SkinCore(engine, PipelineConfig(max_contacts=3))
    mem = core.search_memory
    causes: Counter[str] = Counter()
    touched = 0
    for i, f in enumerate(frames):
        before, n_touches = mem.state.copy(), core.n_touches
        if not core.process_frame(f, 0.01 * i, i):
            continue
        touched += 1
        if mem.state[MEM_FRAMES] != 0.0:
            causes["answered by the memory"] += 1
        elif core.n_touches != n_touches:
            causes["full search: a touch's first frame"] += 1
        elif before[0] == 0.0:
            causes["full search: the frame before was not one safe contact"] += 1
        elif before[3] >= REFRESH_FRAMES:
            causes["full search: the refresh"] += 1
        else:
            causes["full search: the memory's checks"] += 1

    # the slowest frames
    wire = [encode_binary(f, 8, 8, i) for i, f in enumerate(frames)]
    pc = time.perf_counter
    lat: dict[int, list[float]] = {1: [], 3: []}
    what: list[tuple[bool, bool, bool]] = []
    for _ in range(args.rounds):
        for k in (1, 3):
            core = SkinCore(engine, PipelineConfig(max_contacts=k), wire_format="binary")
            for b in wire[:100]:
                core.feed(b)
            mem, pair = core.search_memory, core._tracker.pair if core._tracker else None
            for b in wire[100:]:
                fits, n_touches = (pair.fits if pair is not None else 0), core.n_touches
                t0 = pc()
                out = core.feed(b)
                dt = pc() - t0
                if not out:
                    continue
                lat[k].append(dt * 1e6)
                if k == 3:
                    full = mem is not None and mem.state[MEM_FRAMES] == 0.0
                    fit = pair is not None and pair.fits != fits
                    what.append((full, fit, core.n_touches != n_touches))
    k1, k3 = np.asarray(lat[1]), np.asarray(lat[3])
    w = np.asarray(what)
    slow = k3 >= np.percentile(k3, 99)
    res = {
        "load_average": os.getloadavg(),
        "touched_frames": touched,
        "causes": {k: {"frames": v, "share": v / touched} for k, v in causes.most_common()},
        "k1_median_p99_us": [float(np.median(k1)), float(np.percentile(k1, 99))],
        "k3_median_p99_us": [float(np.median(k3)), float(np.percentile(k3, 99))],
        "p99_over_k1": float(np.percentile(k3, 99) / np.percentile(k1, 99)),
        "slowest_1pc": {
            "frames": int(slow.sum()),
            "full_search": float(w[slow, 0].mean()),
            "anchored_fit": float(w[slow, 1].mean()),
            "both": float((w[slow, 0] & w[slow, 1]).mean()),
            "touch_start": float(w[slow, 2].mean()),
        },
    }
    text = json.dumps(res, indent=2)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
