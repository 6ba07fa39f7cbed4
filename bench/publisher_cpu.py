"""The ROS 2 sink's CPU per frame, both sides: the loop's hand-over and the publisher process.

    PYTHONPATH=src python bench/publisher_cpu.py --skins 50 --frames 800 --model M --out FILE

One worker's share of ``skinloc bench --online`` (50 skins at 100 Hz, K = 3, the rclpy node or
plain DDS). The frames' contacts are those of the online bench's stream (``skinloc.bench.
many_skins``: skin ``s`` plays frame ``k + 37 s`` of ``touch_stream`` at step ``k``), processed
once by the skins' pipelines and kept in ``--stream`` (a pickle, made when missing), so every
run and revision hands the sink the same contacts. This process is the loop: each 10 ms step it
hands the sink the step's frames ``--group`` skins a turn, the turns spread over the step (as
the feeder writes them), calling ``Ros2Sink.emit_contacts``/``emit_gesture`` and, where the
sink has it, ``end_turn`` (the runner's call at the end of a turn); ``serve`` every 0.1 s (the
runner's sweep) with a stand-in control giving each skin a status of the real one's keys.

Reports, as CPU time (robust to what else runs, so that two revisions run one after the other
at the same moment compare): ``loop_cpu_us_per_frame`` (this thread's CPU in the sink's calls,
per frame, touched or not) and ``publisher_cpu_us_per_frame`` (the publisher process's CPU,
its DDS and executor threads included, over the same frames). Two revisions:

    git archive main src | tar -x -C /tmp/base
    PYTHONPATH=/tmp/base/src python bench/publisher_cpu.py --out base.json
    PYTHONPATH=src python bench/publisher_cpu.py --out new.json
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import tempfile
import time
from pathlib import Path
from typing import Any

_STEP_S = 0.01  # 100 Hz


def make_stream(path: Path, skins: int, frames: int, model: Path) -> None:
    """The skins' emitted frames ``(skin, timestamp_s, contacts' fields, gestures)``, pickled."""
    import dataclasses

    from skinloc.bench.stream import touch_stream
    from skinloc.live.core import PipelineConfig, SkinCore
    from skinloc.models.engine import load_engine

    stream, _ = touch_stream(3000, random_state=0)
    engine = load_engine(model)
    config = PipelineConfig(baseline_frames=50, max_contacts=3)
    cores = [SkinCore(engine, config=config, name=f"skin{i:03d}") for i in range(skins)]
    emits = []
    for k in range(frames):
        t = 1000.0 + k * _STEP_S
        for s, core in enumerate(cores):
            contacts = core.process_frame(stream[(k + 37 * s) % len(stream)].astype(float), t, k)
            gestures = core.take_gestures() if core.gestures else []
            if contacts or gestures:
                fields = [dataclasses.astuple(c) for c in contacts]
                emits.append((k, s, t, fields, list(gestures)))
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps({"skins": skins, "frames": frames, "emits": emits}))


def _thread_cpu(pid: int | None) -> dict[str, float]:
    """CPU time (s) of each thread of process ``pid`` (Linux; else empty).

    Keyed ``main`` for the process's main thread (the publisher's loop), else ``NAME:TID``.
    """
    out: dict[str, float] = {}
    tick = os.sysconf("SC_CLK_TCK")
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            comm = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        key = "main" if task.name == str(pid) else f"{comm}:{task.name}"
        out[key] = (int(fields[11]) + int(fields[12])) / tick
    return out


class _Control:
    """What ``Ros2Sink.serve`` asks of the runner's ``SkinControl``, without skins behind it."""

    def __init__(self, names: list[str]) -> None:
        self.skin_names = names

    def settings(self, name: str) -> dict[str, Any]:
        return {}

    def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        return {"ok": False, "message": "a benchmark"}

    def finished(self) -> list[tuple[Any, dict[str, Any]]]:
        return []

    def diagnostics(
        self, now: float, extra: dict[str, dict[str, float]] | None = None, slots: Any = None
    ) -> list[dict[str, Any]]:
        keys = (
            "frame_rate_hz expected_rate_hz link reconnects nonfinite_frames dropped_frames "
            "corrupt_frames errors sink_errors publisher_dropped calibrated touching dead_lines "
            "weak_lines noisy_lines baseline_drift_mean_counts baseline_drift_max_counts "
            "latency_p99_us publisher_queue_bytes"
        ).split()
        return [
            {
                "name": f"skinloc: {self.skin_names[i]}",
                "hardware_id": f"/dev/pts/{i}",
                "level": 0,
                "message": "OK",
                "values": dict.fromkeys(keys, "1.0"),
            }
            for i in slots
        ]


def main() -> None:
    from skinloc.bench.sinks import bench_dds
    from skinloc.live.contact import Contact
    from skinloc.live.sinks.base import SkinInfo
    from skinloc.live.sinks.ros2.sink import Ros2Sink

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skins", type=int, default=50)
    ap.add_argument("--frames", type=int, default=800, help="frames per skin")
    ap.add_argument("--group", type=int, default=4, help="skins handed over per loop turn")
    ap.add_argument("--backend", choices=("rclpy", "dds"), default="rclpy")
    ap.add_argument("--gather-ms", type=float, default=None, help="the sink's gather_s, ms")
    ap.add_argument("--model", type=Path, default=None, help="for a missing --stream")
    ap.add_argument("--stream", type=Path, default=None, help="the frames' contacts (pickle)")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    stream_path = args.stream or Path(tempfile.gettempdir()) / (
        f"skinloc-publisher-stream-{args.skins}x{args.frames}.pkl"
    )
    if not stream_path.exists():
        if args.model is None:
            ap.error(f"{stream_path} is missing: give --model to make it")
        make_stream(stream_path, args.skins, args.frames, args.model)
    d = pickle.loads(stream_path.read_bytes())  # noqa: S301 - our own file
    names = [f"skin{i:03d}" for i in range(d["skins"])]
    n_groups = -(-d["skins"] // args.group)
    # per step, per turn: [(skin name, timestamp, contacts, gestures)]
    turns: list[list[list[Any]]] = [[[] for _ in range(n_groups)] for _ in range(d["frames"])]
    for k, s, t, fields, gestures in d["emits"]:
        turns[k][s // args.group].append((names[s], t, [Contact(*f) for f in fields], gestures))

    domain, dds = bench_dds()
    extra = {} if args.gather_ms is None else {"gather_s": args.gather_ms / 1000}
    sink = Ros2Sink("skinloc_0", domain_id=domain, backend=args.backend, dds_config=dds, **extra)
    sink.open([SkinInfo(n) for n in names])
    control = _Control(names)
    end_turn = getattr(sink, "end_turn", None)
    sink.serve(control)  # the node declares the skins' parameters before the clock starts
    before = sink.stats()
    threads_before = _thread_cpu(sink.publisher_pid)
    load_before = os.getloadavg()
    cpu = 0.0
    next_sweep = 0.0
    t0 = time.monotonic() + 0.05
    for k, step in enumerate(turns):
        for g, turn in enumerate(step):
            due = t0 + (k + g / n_groups) * _STEP_S
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            c0 = time.thread_time()
            for name, t, contacts, gestures in turn:
                if contacts:
                    sink.emit_contacts(name, t, contacts)
                for ev in gestures:
                    sink.emit_gesture(name, ev["timestamp_s"], ev)
            if end_turn is not None:
                end_turn()
            now = time.monotonic()
            if now >= next_sweep:
                next_sweep = now + 0.1
                sink.serve(control, now)
            cpu += time.thread_time() - c0
    after = sink.stats()
    threads_after = _thread_cpu(sink.publisher_pid)
    sink.close()
    n = d["skins"] * d["frames"]
    pub_cpu = after["cpu_s"] - before["cpu_s"]
    out = {
        "args": {k: str(v) for k, v in vars(args).items()},
        "load_average_before": load_before,
        "load_average_after": os.getloadavg(),
        "frames": n,
        "frames_emitted": len(d["emits"]),
        "loop_cpu_us_per_frame": cpu / n * 1e6,
        "publisher_cpu_us_per_frame": pub_cpu / n * 1e6,
        "publisher_batches": after["batches"] - before["batches"],
        "publisher_threads_cpu_us_per_frame": {
            k: (v - threads_before.get(k, 0.0)) / n * 1e6 for k, v in threads_after.items()
        },
        "sink_stats": after,
    }
    print(
        f"loop {out['loop_cpu_us_per_frame']:.2f} us/frame, publisher "
        f"{out['publisher_cpu_us_per_frame']:.2f} us/frame ({out['publisher_batches']} reads, "
        f"{after['dropped']} dropped; emit to write median / p99 "
        f"{after['publish_delay_median_us']:.0f} / {after['publish_delay_p99_us']:.0f} us), "
        f"load {load_before[0]:.2f}"
    )
    for name, us in sorted(out["publisher_threads_cpu_us_per_frame"].items()):
        if us > 0:
            print(f"  thread {name}: {us:.2f} us/frame")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(out, indent=2, default=str))


if __name__ == "__main__":
    main()
