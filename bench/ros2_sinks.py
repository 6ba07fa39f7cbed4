"""ROS 2 sinks: publishing cost per contact beside JSON lines, and 100 skins at 100 Hz with the
ROS 2 sink on, against the same run without it (docs/benchmarks.md, "ROS 2 sinks").

    PYTHONPATH=src python bench/ros2_sinks.py --repeats 3 --out bench/results/ros2_sinks.json
    PYTHONPATH=src python bench/ros2_sinks.py --repeats 2 --max-contacts 3 1 --out ...

Each repeat runs the 100 skins without sinks, then with the ROS 2 sink, back to back, for each
``--max-contacts`` in turn (the pipeline's contacts per frame; default: its default, 3).

DDS stays on the loopback interface (unicast) unless CYCLONEDDS_URI is set.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from skinloc.bench.online import many_skins, model_code_stamp, train_bench_models
from skinloc.bench.sinks import sink_cost


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--contacts", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--skins", type=int, default=100)
    ap.add_argument("--duration", type=float, default=30.0, help="s per 100-skin run")
    ap.add_argument("--repeats", type=int, default=1, help="pairs of 100-skin runs")
    ap.add_argument(
        "--max-contacts",
        type=int,
        nargs="+",
        default=[3],
        choices=(1, 2, 3),
        help="contacts per frame of every pipeline; several values alternate in each repeat",
    )
    ap.add_argument(
        "--workers", type=int, default=1, help="runner processes, the skins shared among them"
    )
    ap.add_argument("--skip-sink-cost", action="store_true", help="only the 100-skin runs")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    if not 1 <= args.workers <= args.skins:
        ap.error(f"--workers must be 1..{args.skins} (the skins), got {args.workers}")
    folder = Path(tempfile.gettempdir()) / "skinloc-bench" / "online-models"
    model = train_bench_models(folder, ("default",))["default"]
    res: dict = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}",
        "load_average_at_start": os.getloadavg(),
        "started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "model_code_stamp": model_code_stamp(),
    }
    if not args.skip_sink_cost:
        res["sink_cost"] = sink_cost(args.contacts, rounds=args.rounds)
        print(json.dumps(res["sink_cost"], indent=1), flush=True)
    settings = [
        (k, f"K={k}, {what}", sinks)
        for k in args.max_contacts
        for what, sinks in (("without sinks", ()), ("ros2 sink", ("ros2",)))
    ]
    for rep in range(args.repeats):
        for k, label, sinks in settings:
            r = many_skins(
                model,
                args.skins,
                100.0,
                args.duration,
                sinks=sinks,
                max_contacts=k,
                workers=args.workers,
            )
            r["load_average_after"] = os.getloadavg()
            res.setdefault("many_skins", {}).setdefault(label, []).append(r)
            print(
                f"repeat {rep + 1}, {label}: latency median {r['latency_median_us']:.0f} us, "
                f"p99 {r['latency_p99_us']:.0f} us, loop CPU {r['loop_cpu_us_per_frame']:.1f} "
                f"us/frame, {r['frames_processed']}/{r['frames_sent']} frames, sink drops "
                f"{r['sink_frames_dropped']}, load {r['load_average_after'][0]:.1f}",
                flush=True,
            )
    res["load_average_at_end"] = os.getloadavg()
    text = json.dumps(res, indent=2)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
