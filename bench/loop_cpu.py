"""The live loop's CPU per frame, in one process: a Runner over ptys, the frames written paced.

    PYTHONPATH=src python bench/loop_cpu.py --skins 50 --frames 800 --out FILE.json

One worker's share of ``skinloc bench --online``'s 100 skins (50, K = 3, the default model of
the online bench, the ROS 2 sink through the rclpy node, or plain DDS, or none), the stream of
``skinloc.bench.many_skins`` (skin ``s`` plays frame ``k + 37 s`` at step ``k``). Unlike
``many_skins``, this process writes the frames itself, ``--group`` skins at a time, then turns
the runner's loop (``Runner._step``) until they are processed, pacing the steps at 100 Hz: the
loop reads a few frames a turn as on a quiet machine, and only its turns are timed, in this
thread's CPU time. That makes the figure a property of the code, comparable between two
revisions run at the same time on the same machine (each sees the same load):

    git archive OLD src | tar -x -C /tmp/old
    PYTHONPATH=/tmp/old/src python bench/loop_cpu.py --out old.json &
    PYTHONPATH=src python bench/loop_cpu.py --out new.json; wait

Reports the loop's CPU per frame (every frame, touched or not), the single-contact NumPy
baseline per touched frame measured in the same process right after
(``many_skins``' ``baseline_cpu_us_per_frame``), their ratio, and frames per turn.
"""

from __future__ import annotations

import argparse
import json
import os
import pty
import tempfile
import time
import tty
from pathlib import Path


def main() -> None:
    from skinloc.bench.many_skins import baseline_cpu_us
    from skinloc.bench.online import train_bench_models
    from skinloc.bench.stream import touch_stream
    from skinloc.hardware.protocol import binary_counts, encode_binary_counts
    from skinloc.live.core import PipelineConfig
    from skinloc.live.runner import Runner, SkinConfig
    from skinloc.models.engine import load_engine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skins", type=int, default=50)
    ap.add_argument("--frames", type=int, default=800, help="frames per skin")
    ap.add_argument("--group", type=int, default=4, help="skins written per loop turn")
    ap.add_argument("--sink", choices=("rclpy", "dds", "none"), default="rclpy")
    ap.add_argument("--max-contacts", type=int, default=3, choices=(1, 2, 3))
    ap.add_argument("--models", type=Path, default=None, help="the bench models' folder")
    ap.add_argument(
        "--model", type=Path, default=None, help="a model file (two revisions side by side: one)"
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    folder = args.models or Path(tempfile.gettempdir()) / "skinloc-bench" / "online-models"
    model = args.model or train_bench_models(folder, ("default",))["default"]
    load_before = os.getloadavg()
    frames, _ = touch_stream(3000, random_state=0)
    counts = [binary_counts(f, 8, 8) for f in frames]
    masters, names = [], []
    for _ in range(args.skins):
        m, s = pty.openpty()
        tty.setraw(s)
        names.append(os.ttyname(s))
        os.close(s)
        masters.append(m)
    config = PipelineConfig(baseline_frames=50, max_contacts=args.max_contacts)
    engine = load_engine(model)
    skins = [
        SkinConfig(model=engine, source=n, name=f"skin{i:03d}", wire_format="binary", config=config)
        for i, n in enumerate(names)
    ]
    n_contacts = 0

    def on_contact(c: object) -> None:  # what many_skins' callback costs the loop, about
        nonlocal n_contacts
        n_contacts += 1
        time.monotonic()

    sinks = []
    if args.sink != "none":
        from skinloc.bench.sinks import bench_dds
        from skinloc.live.sinks.ros2.sink import Ros2Sink

        domain, dds = bench_dds()
        sinks.append(Ros2Sink("skinloc_0", domain_id=domain, backend=args.sink, dds_config=dds))
    runner = Runner(skins, sinks=sinks, callback=on_contact)
    runner.open()
    data = [
        [
            encode_binary_counts(counts[(k + 37 * s) % len(counts)], 8, 8, k)
            for s in range(args.skins)
        ]
        for k in range(args.frames)
    ]
    cpu = 0.0
    turns = 0
    t0 = time.monotonic()
    for k in range(args.frames):
        for g in range(0, args.skins, args.group):
            last = min(g + args.group, args.skins)
            for s in range(g, last):
                os.write(masters[s], data[k][s])
            want = k * args.skins + last
            while sum(c.n_frames for c in runner.cores) < want:
                c0 = time.thread_time()
                runner._step(0.05)
                cpu += time.thread_time() - c0
                turns += 1
        due = t0 + (k + 1) / 100.0
        if due > time.monotonic():
            time.sleep(due - time.monotonic())
    n = args.skins * args.frames
    sink_stats = {s.name: s.stats() for s in sinks}
    runner.close()
    for m in masters:
        os.close(m)
    base = baseline_cpu_us(model)
    loop = cpu / n * 1e6
    out = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "frames": n,
        "contacts": n_contacts,
        "frames_per_turn": n / max(turns, 1),
        "loop_cpu_us_per_frame": loop,
        "baseline_cpu_us_per_frame": base,
        "loop_cpu_over_baseline": loop / base,
        # the ROS 2 publisher process's CPU over the same frames (from ready to the end)
        "publisher_cpu_us_per_frame": sum(float(v.get("cpu_s", 0.0)) for v in sink_stats.values())
        / n
        * 1e6,
        "sink_stats": sink_stats,
    }
    print(
        f"loop cpu {loop:.2f} us/frame, baseline {base:.2f} (x{loop / base:.2f}), "
        f"{out['frames_per_turn']:.1f} frames/turn, {n_contacts} contacts, publisher "
        f"{out['publisher_cpu_us_per_frame']:.2f} us/frame, load {load_before}"
    )
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=2, default=str))


if __name__ == "__main__":
    main()
