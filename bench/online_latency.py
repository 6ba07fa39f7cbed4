"""Where the 100-skin online bench's time goes: CPU per frame by process, latency split, profile.

    PYTHONPATH=src python bench/online_latency.py --workers 2 --backend rclpy --duration 15 \
        --profile --out bench/results/online-latency-DATE.json

One run of ``skinloc.bench.many_skins.many_skins`` (K = 3, the default model of ``skinloc bench
--online``, as its ``many_skins_ros2`` run) with the ROS 2 sink (or none: ``--no-sink``). Reports
the CPU per frame of the loops, the ROS 2 publishers and the feeder (process CPU time, not wall
time: robust to what else runs), the loop's against the single-contact NumPy baseline of the
same processes, the end to end split into queueing and latency, the publisher's delay, and with
``--profile`` the loop's functions by own CPU per frame (cProfile in thread CPU time; the
profiler inflates every Python call, so its run's latencies are not the loop's).
"""

from __future__ import annotations

import argparse
import json
import pstats
import tempfile
from pathlib import Path

#: the stages of one frame (label, file suffix, function), as bench/live_loop_profile.py
STAGES = [
    ("loop turn (Runner._step)", "live/runner.py", "_step"),
    ("read + parse + process (PortFeed.contacts)", "live/feeds.py", "contacts"),
    ("parse frames (FrameParser.feed)", "hardware/framing.py", "feed"),
    ("one frame (SkinCore.process_frame)", "live/core.py", "process_frame"),
    ("contacts of a touched frame (Engine.contacts)", "models/engine.py", "contacts"),
    ("tracking (Tracker.update)", "live/tracking.py", "update"),
    ("gestures (GestureRecognizer.update)", "live/gestures.py", "update"),
    ("deliver (Runner._emit)", "live/runner.py", "_emit"),
    ("ROS 2 sink (Ros2Sink.emit_contacts)", "ros2/sink.py", "emit_contacts"),
    ("  pack the record (pack_frame)", "ros2/records.py", "pack_frame"),
    ("  write to the pipe (Ros2Sink._put)", "ros2/sink.py", "_put"),
    ("the sweep's ROS 2 serve (SkinControl.serve)", "live/control.py", "serve"),
]


def profile_summary(paths: list[Path], frames: int, top: int = 25) -> dict:
    """Stage cumulative and top functions' own CPU per frame (us) over the loops' profiles."""
    stats = pstats.Stats(*(str(p) for p in paths))
    stages = dict.fromkeys((s[0] for s in STAGES), 0.0)
    own = []
    for (file, line, func), (_cc, nc, tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        for label, suffix, name in STAGES:
            if func == name and file.endswith(suffix):
                stages[label] += ct / frames * 1e6
        own.append((tt / frames * 1e6, nc / frames, f"{Path(file).name}:{line}({func})"))
    own.sort(reverse=True)
    return {
        "stages_cumulative_us_per_frame": stages,
        "top_own_us_per_frame": [
            {"function": f, "own_us_per_frame": round(t, 2), "calls_per_frame": round(c, 2)}
            for t, c, f in own[:top]
        ],
    }


def main() -> None:
    from skinloc.bench.many_skins import many_skins
    from skinloc.bench.online import train_bench_models

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--backend", choices=("rclpy", "dds"), default="rclpy")
    ap.add_argument("--no-sink", action="store_true")
    ap.add_argument("--hogs", type=int, default=0, help="CPU-heavy processes beside")
    ap.add_argument("--skins", type=int, default=100)
    ap.add_argument("--duration", type=float, default=15.0, help="s")
    ap.add_argument("--max-contacts", type=int, default=3, choices=(1, 2, 3))
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--nice", type=int, default=0, help="added to the loops' niceness (-10)")
    ap.add_argument("--models", type=Path, default=None, help="the bench models' folder")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    folder = args.models or Path(tempfile.gettempdir()) / "skinloc-bench" / "online-models"
    model = train_bench_models(folder, ("default",))["default"]
    prof_dir = Path(tempfile.mkdtemp(prefix="skinloc-prof-")) if args.profile else None
    r = many_skins(
        model,
        args.skins,
        100.0,
        args.duration,
        sinks=() if args.no_sink else ("ros2",),
        max_contacts=args.max_contacts,
        workers=args.workers,
        hogs=args.hogs,
        backend=args.backend,
        profile_dir=prof_dir,
        nice=args.nice,
    )
    r.pop("model", None)
    out = {"args": {k: str(v) for k, v in vars(args).items()}, "run": r}
    if prof_dir is not None:
        out["profile"] = profile_summary(
            sorted(prof_dir.glob("loop-*.prof")), max(r["frames_processed"], 1)
        )
    keys = [
        "load_average_before",
        "frames_sent",
        "frames_dropped",
        "sink_frames_dropped",
        "end_to_end_median_us",
        "end_to_end_p99_us",
        "queueing_median_us",
        "queueing_p99_us",
        "latency_median_us",
        "latency_p99_us",
        "loop_cpu_us_per_frame",
        "loop_cpu_us_per_frame_each",
        "baseline_cpu_us_per_frame",
        "loop_cpu_over_baseline",
        "loop_process_cpu_us_per_frame",
        "turn_cpu_p99_us",
        "turn_cpu_max_us",
        "turns_over_1ms_cpu",
        "feeder_writes_late_over_2ms",
        "publisher_cpu_us_per_frame",
        "feeder_cpu_us_per_frame",
        "load_average_after",
    ]
    for k in keys:
        print(f"{k:32s} {r.get(k)}")
    for name, st in r["sink_stats"].items():
        print(
            f"{name}: publish delay median / p99 {st.get('publish_delay_median_us')} / "
            f"{st.get('publish_delay_p99_us')} us"
        )
    if "profile" in out:
        for lab, v in out["profile"]["stages_cumulative_us_per_frame"].items():
            print(f"  {lab:48s} {v:8.1f} us/frame")
        for row in out["profile"]["top_own_us_per_frame"]:
            print(
                f"  {row['own_us_per_frame']:7.2f} {row['calls_per_frame']:6.2f} {row['function']}"
            )
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=2, default=str))


if __name__ == "__main__":
    main()
