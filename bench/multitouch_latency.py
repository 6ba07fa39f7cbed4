"""Live latency per frame with K = 1 and K = 3 contacts (tracking, gestures), in one run.

Bytes in to contacts out (``SkinCore.feed``, the figure of ``skinloc bench --online``) on the
same simulated touch stream and model as ``skinloc.bench.online.single_stream``; the settings are
timed in interleaved rounds so that they share the machine's load. Frames with an output
(touched) only: median and p99, microseconds.

    PYTHONPATH=src python bench/multitouch_latency.py --out bench/results/multitouch_latency.json

Run with an older skinloc on ``PYTHONPATH`` (one without ``max_contacts``), it times that
version's only setting, ``today``, for the before/after comparison.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--models", type=Path, default=Path("/tmp/skinloc-bench-multitouch"))
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()

    try:
        from skinloc.hardware.protocol import encode_binary
    except ImportError:  # a skinloc from before the wire module (the `today` run)
        from skinloc.hardware.framing import encode_binary
    from skinloc.bench.online import touch_stream, train_bench_models
    from skinloc.live.core import PipelineConfig, SkinCore
    from skinloc.models.engine import load_engine

    model = train_bench_models(args.models, ("default",))["default"]
    fast = load_engine(model)
    frames, _ = touch_stream(args.frames, random_state=0)
    wire = [encode_binary(f, 8, 8, i) for i, f in enumerate(frames)]
    has_k = "max_contacts" in {f.name for f in dataclasses.fields(PipelineConfig)}
    settings = (
        {
            "K=1, no gestures": {"max_contacts": 1, "gestures": False},
            "K=1": {"max_contacts": 1},
            "K=3": {"max_contacts": 3},
            "K=3, full search every frame": {"max_contacts": 3, "search_memory": False},
        }
        if has_k
        else {"today": {}}
    )
    lat: dict[str, list[float]] = {k: [] for k in settings}
    n_out: dict[str, int] = {}
    pc = time.perf_counter
    for _ in range(args.rounds):
        for label, cfg in settings.items():
            cfg = dict(cfg)
            memory = cfg.pop("search_memory", True)
            core = SkinCore(fast, PipelineConfig(**cfg), wire_format="binary")
            if not memory:  # the live loop before the search memory
                core.search_memory = None
            for b in wire[:100]:
                core.feed(b)
            n = 0
            for b in wire[100:]:
                t0 = pc()
                out = core.feed(b)
                dt = pc() - t0
                if out:
                    lat[label].append(dt * 1e6)
                    n += len(out)
            n_out[label] = n
    res = {
        "machine": f"{platform.machine()}, {platform.python_version()}",
        "load_average": os.getloadavg(),
        "model": str(model),
        "frames": len(wire) - 100,
        "rounds": args.rounds,
        "engine_has_contacts": hasattr(fast, "contacts"),
        "settings": {
            label: {
                "touched_frames": len(v),
                "contacts_per_round": n_out[label],
                "median_us": float(np.median(v)),
                "p99_us": float(np.percentile(v, 99)),
            }
            for label, v in lat.items()
        },
    }
    text = json.dumps(res, indent=2)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
