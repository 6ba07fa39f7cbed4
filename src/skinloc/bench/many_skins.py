"""100 skins at 100 Hz (``skinloc bench --online``, ``bench/ros2_sinks.py``): the live loop.

A feeder process writes every skin's frames to its own pseudo-terminal on schedule (staggered
phases); runners read them: one in this process, or, with ``workers`` > 1, one per worker
process, each over its share of the skins (what running several ``skinloc live`` processes,
one skins file each, would do). Latency is from the bytes' arrival to the contact; end to end
from the frame's scheduled write time.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.bench.stream import touch_stream

__all__ = ["baseline_cpu_us", "many_skins"]


def _feeder(
    conn: Any, n_skins: int, rate_hz: float, duration_s: float, frames: np.ndarray, nice: int = 0
) -> None:
    """Child process: one pty per skin, frames written on schedule (staggered phases).

    ``nice``: added to its niceness; it stands for the boards, which other processes' load
    does not slow, so it gets the loops' priority (else the loops wait on it, not on their work).
    """
    if nice:
        os.nice(nice)
    import pty
    import tty

    from skinloc.hardware.protocol import binary_counts, encode_binary_counts

    masters, names = [], []
    for _ in range(n_skins):
        m, s = pty.openpty()
        tty.setraw(s)
        names.append(os.ttyname(s))
        os.close(s)
        os.set_blocking(m, False)
        masters.append(m)
    conn.send(names)
    t0 = conn.recv()  # the parent has opened every port
    period = 1.0 / rate_hz
    n_per = int(duration_s * rate_hz)
    late = 0
    written = np.zeros(n_skins, dtype=np.int64)
    failed = 0
    order = [(k, s) for k in range(n_per) for s in range(n_skins)]
    L = len(frames)
    # the images converted once: the feeder stands for the boards, whose frames cost this
    # machine nothing to make (encoding each one took about 9 us of the two cores' time)
    counts = [binary_counts(f, 8, 8) for f in frames]
    for k, s in order:
        due = t0 + k * period + s * period / n_skins
        wait = due - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        elif wait < -0.002:
            late += 1
        data = encode_binary_counts(counts[(k + 37 * s) % L], 8, 8, k)
        try:
            os.write(masters[s], data)
            written[s] += 1
        except OSError:
            failed += 1
    time.sleep(0.5)
    conn.send(
        {
            "written": written.tolist(),
            "late_over_2ms": late,
            "write_errors": failed,
            "cpu_s": time.process_time(),  # the feeder's share of the cores
        }
    )
    conn.recv()
    for m in masters:
        os.close(m)


def _shard(
    model_path: Path,
    names: list[str],
    first: int,
    n_skins: int,
    rate_hz: float,
    duration_s: float,
    sinks: tuple[str, ...],
    max_contacts: int | None,
    domain: int | None,
    dds_config: str | None,
    start: Callable[[], float],
    worker: int = 0,
    backend: str = "dds",
    profile_path: str | None = None,
    nice: int = 0,
) -> dict:
    """One ``Runner`` over the skins ``first .. first + len(names) - 1`` (their ptys ``names``).

    ``start()`` is called once every port is open and returns the feeder's start time
    (``time.monotonic`` s; the clock is the machine's, shared by processes). Returns the
    contacts' latencies (s), the runner's and the sinks' statistics and the loop's CPU.
    ``profile_path``: cProfile the loop (in thread CPU time) and write its stats there.
    ``nice``: added to this process's niceness before the runner opens (its ROS 2 publisher
    inherits it), and taken back at the end.
    """
    from skinloc.live.core import PipelineConfig
    from skinloc.live.runner import Runner, SkinConfig
    from skinloc.models.engine import load_engine

    fast = load_engine(model_path)
    extra = {} if max_contacts is None else {"max_contacts": int(max_contacts)}
    config = PipelineConfig(baseline_frames=50, **extra)
    specs = [
        SkinConfig(
            model=fast,
            source=name,
            name=f"skin{first + i:03d}",
            wire_format="binary",
            config=config,
        )
        for i, name in enumerate(names)
    ]
    lat: list[float] = []
    e2e: list[float] = []
    phase = {f"skin{i:03d}": i / (rate_hz * n_skins) for i in range(n_skins)}
    holder: dict[str, float] = {}

    def on_contact(c: Any) -> None:
        now = time.monotonic()
        lat.append(c.latency_us)
        e2e.append(now - (holder["t0"] + c.index / rate_hz + phase[c.skin]))

    sink_objs: list[Any] = []
    for spec in sinks:
        if spec.startswith("ros2"):
            from skinloc.live.sinks.ros2.sink import Ros2Sink

            # one node per worker, named as ``skinloc run --workers`` names them
            node = "skinloc" if worker < 0 else f"skinloc_{worker}"
            sink_objs.append(
                Ros2Sink(node, domain_id=domain, backend=backend, dds_config=dds_config)
            )
        else:
            sink_objs.append(spec)
    if nice:
        os.nice(nice)  # a negative one needs the right to raise priority (root, CAP_SYS_NICE)
    try:
        runner = Runner(specs, sinks=sink_objs, callback=on_contact)
        runner.open()
    except BaseException:
        if nice:
            with contextlib.suppress(OSError):
                os.nice(-nice)
        raise
    t0 = holder["t0"] = start()
    end = t0 + duration_s + 1.0
    # CPU of the loop thread and of the whole process (Cyclone's own threads included):
    # what the sinks cost, less sensitive than latency to other processes on the machine
    prof = None
    if profile_path is not None:
        import cProfile

        prof = cProfile.Profile(time.thread_time)  # CPU time: robust to the machine's load
    cpu_thread0, cpu_proc0 = time.thread_time(), time.process_time()
    turns: list[float] = []  # each busy turn's CPU, s: a turn's CPU delays the frames behind it
    if prof is not None:
        prof.enable()
    while time.monotonic() < end:
        c0 = time.thread_time()
        runner._step(0.05)
        turns.append(time.thread_time() - c0)
    if prof is not None:
        prof.disable()
    cpu_thread = time.thread_time() - cpu_thread0
    cpu_proc = time.process_time() - cpu_proc0
    if prof is not None:
        prof.dump_stats(profile_path)
    for _ in range(20):
        runner._step(0.01)
    stats = runner.stats()
    runner.close()  # the ROS 2 sink publishes what is queued and joins its thread
    if nice:
        # back (in this process, with workers=1), where the process may lower its niceness
        with contextlib.suppress(OSError):
            os.nice(-nice)
    sink_stats = {getattr(s, "name", str(s)): s.stats() for s in sink_objs if hasattr(s, "stats")}
    base_us = baseline_cpu_us(model_path)
    return {
        "baseline_cpu_us_per_frame": base_us,
        "lat_us": np.asarray(lat, dtype=np.float64),
        "e2e_s": np.asarray(e2e, dtype=np.float64),
        "stats": stats,
        "sink_stats": sink_stats,
        "cpu_thread": cpu_thread,
        "cpu_proc": cpu_proc,
        "turn_cpu_s": np.asarray(turns, dtype=np.float64),
        "max_contacts": config.max_contacts,
    }


def baseline_cpu_us(model_path: Path, n: int = 2000) -> float:
    """CPU (this thread's) of the single-contact NumPy baseline per touched frame, us.

    ``skinloc.bench.baseline.baseline_fn`` on the touch stream's touched frames, one frame a
    call, as the loop gets them: the yardstick the loop's CPU per frame is divided by, taken
    in the loop's own process right after it, so both see the same machine.
    """
    from skinloc.bench.baseline import baseline_fn
    from skinloc.models.localizer import ContactLocalizer

    plain = baseline_fn(ContactLocalizer.load(model_path))
    frames, _ = touch_stream(n + 200, random_state=1)
    deltas = frames[100:].astype(np.float64) - frames[:100].mean(axis=0)
    touched = deltas[np.max(deltas, axis=1) > 60][:n]
    for x in touched[:50]:  # warm
        plain(x[None])
    t0 = time.thread_time()
    for x in touched:
        plain(x[None])
    return (time.thread_time() - t0) / max(len(touched), 1) * 1e6


def _hog(stop: Any) -> None:
    """A CPU-heavy process (a busy loop) until ``stop`` is set: the robot computer's load."""
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def _worker(conn: Any, kw: dict) -> None:
    """Worker process: one shard; says "ready" once its ports are open, then waits for t0."""

    def start() -> float:
        conn.send("ready")
        return float(conn.recv())

    try:
        conn.send(_shard(start=start, **kw))
    except Exception as exc:  # the parent reports it instead of waiting for ever
        conn.send({"error": f"{type(exc).__name__}: {exc}"})


def _merge_sink_stats(parts: list[dict]) -> dict:
    """Every worker's sink statistics summed per sink (counts and CPU seconds).

    Delays (``publish_delay_*``) cannot be summed: the worst worker's is kept.
    """
    out: dict[str, dict] = {}
    for part in parts:
        for name, st in part.items():
            acc = out.setdefault(name, {})
            for k, v in st.items():
                if k.startswith("publish_delay"):
                    acc[k] = max((x for x in (acc.get(k), v) if x is not None), default=None)
                elif isinstance(v, int | float):
                    acc[k] = acc.get(k, 0) + v
                else:
                    acc[k] = v
    return out


def many_skins(
    model_path: Path,
    n_skins: int = 100,
    rate_hz: float = 100.0,
    duration_s: float = 30.0,
    random_state: int = 0,
    sinks: tuple[str, ...] = (),
    max_contacts: int | None = None,
    workers: int = 1,
    hogs: int = 0,
    backend: str = "dds",
    profile_dir: Path | None = None,
    nice: int = 0,
) -> dict:
    """``n_skins`` pipelines at ``rate_hz`` each, fed through ptys.

    ``sinks``: sink specs every skin's contacts go to (``ros2``: plain DDS on loopback, no
    subscriber). End-to-end times are taken after the sinks, so they include what the loop
    pays for them (for ``ros2``, packing a record into its pipe; its publisher process's CPU is in
    ``sink_stats``).
    ``max_contacts``: contacts per frame each pipeline looks for (``PipelineConfig``'s; ``None``:
    its default). ``workers``: 1, one ``Runner`` in this process; more, one per worker
    process over the shares of ``skinloc.live.workers.partition`` (as ``skinloc run
    --workers``; loop CPU then summed over the workers). ``hogs``: CPU-heavy processes (busy
    loops) running beside, for the figure on a loaded machine. ``backend``: the ROS 2 sink's
    (``rclpy``: through a real node, one per worker, ``skinloc_<w>``; ``dds``: plain DDS).
    ``profile_dir``: cProfile each loop (thread CPU time) into ``loop-<w>.prof`` there (the
    profiler slows the loop: its run's latencies are not the loop's own). ``nice``: added to
    the niceness of the loops (and their ROS 2 publishers) and of the feeder, which stands for
    the boards, relative to the CPU-heavy processes and the rest of the machine (``-10``: what a
    robot gives its touch loop with ``nice -n -10``; negative values need root or
    CAP_SYS_NICE).

    The end-to-end time of a contact splits into its *queueing* (``end_to_end - latency``: the
    feeder's lateness, the pty, the wake-up and the wait while the loop was busy with earlier
    frames) and its *latency* (bytes read to contact, ``Contact.latency_us``: the frames read
    before it in the same turn, then its own compute); the ROS 2 publisher's delay from the
    sink's ``emit`` to the write is ``sink_stats``' ``publish_delay_*_us``.

    Every run reports the load average before and after, and the loop's CPU per frame beside
    the single-contact NumPy baseline's, both measured in the loops' processes
    (``loop_cpu_over_baseline``).
    """
    from skinloc.bench.sinks import bench_dds
    from skinloc.live.workers import partition

    if not 1 <= workers <= n_skins:
        raise ValueError(f"workers must be 1..{n_skins} (the skins), got {workers}")
    if hogs < 0:
        raise ValueError(f"hogs must be 0 or more, got {hogs}")
    if backend not in ("dds", "rclpy"):
        raise ValueError(f"backend must be dds or rclpy, got {backend!r}")
    load_before = os.getloadavg()
    frames, _ = touch_stream(3000, random_state=random_state)
    domain, dds = bench_dds() if any(s.startswith("ros2") for s in sinks) else (None, None)
    ctx = mp.get_context("spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(
        target=_feeder, args=(child, n_skins, rate_hz, duration_s, frames, nice), daemon=True
    )
    proc.start()
    procs: list[Any] = []
    stop_hogs = ctx.Event()
    for _ in range(hogs):
        procs.append(ctx.Process(target=_hog, args=(stop_hogs,), daemon=True))
        procs[-1].start()
    try:
        names = parent.recv()
        common = {
            "model_path": Path(model_path),
            "n_skins": n_skins,
            "rate_hz": rate_hz,
            "duration_s": duration_s,
            "sinks": tuple(sinks),
            "max_contacts": max_contacts,
            "domain": domain,
            "dds_config": dds,
            "backend": backend,
            "nice": nice,
        }
        if profile_dir is not None:
            Path(profile_dir).mkdir(parents=True, exist_ok=True)

        def prof_path(w: int) -> str | None:
            return (
                None if profile_dir is None else str(Path(profile_dir) / f"loop-{max(w, 0)}.prof")
            )

        def go() -> float:
            t0 = time.monotonic() + 0.5
            parent.send(t0)
            return t0

        if workers == 1:
            parts = [
                _shard(
                    names=names, first=0, start=go, worker=-1, profile_path=prof_path(0), **common
                )
            ]
        else:
            pipes = []
            for w, share in enumerate(partition(n_skins, workers)):
                a, b = ctx.Pipe()
                kw = dict(
                    common,
                    names=names[share.start : share.stop],
                    first=share.start,
                    worker=w,
                    profile_path=prof_path(w),
                )
                p = ctx.Process(target=_worker, args=(b, kw), daemon=True)
                p.start()
                procs.append(p)
                pipes.append(a)
            for a in pipes:
                if a.recv() != "ready":
                    raise RuntimeError("a bench worker failed before it started")
            t0 = go()
            for a in pipes:
                a.send(t0)
            parts = [a.recv() for a in pipes]
            bad = [p["error"] for p in parts if "error" in p]
            if bad:
                raise RuntimeError(f"a bench worker failed: {bad[0]}")
        report = parent.recv()
        parent.send("done")
    finally:
        stop_hogs.set()
        for p in (*procs, proc):
            p.join(10)
            if p.is_alive():
                p.terminate()
    stats = [s for p in parts for s in p["stats"]]
    lat = np.concatenate([p["lat_us"] for p in parts])
    e2e = np.concatenate([p["e2e_s"] for p in parts])
    sink_stats = _merge_sink_stats([p["sink_stats"] for p in parts])
    cpu_thread = sum(p["cpu_thread"] for p in parts)
    cpu_proc = sum(p["cpu_proc"] for p in parts)
    frames_in = [s["frames"] for s in stats]
    wire = [s.get("wire", {}) for s in stats]
    sent = report["written"]
    has = len(lat) > 0
    turn_us = np.concatenate([p["turn_cpu_s"] for p in parts]) * 1e6
    # a contact's end to end less its latency: the time before its bytes were read
    queue_us = e2e * 1e6 - lat
    frames_total = max(sum(frames_in), 1)
    loop_us = cpu_thread / max(sum(frames_in), 1) * 1e6
    base_us = float(np.mean([p["baseline_cpu_us_per_frame"] for p in parts]))
    return {
        "skins": n_skins,
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "workers": workers,
        "cpu_heavy_processes_beside": hogs,
        "loop_nice": nice,
        "ros2_backend": backend if any(s.startswith("ros2") for s in sinks) else None,
        "load_average_before": list(load_before),
        "load_average_after": list(os.getloadavg()),
        "frames_sent": int(sum(sent)),
        "frames_processed": int(sum(frames_in)),
        "frames_dropped": int(sum(sent) - sum(frames_in)),
        "parser_dropped_or_lost": int(
            sum(w.get("n_dropped", 0) + w.get("n_lost", 0) + w.get("n_corrupted", 0) for w in wire)
        ),
        "contacts": len(lat),
        "latency_median_us": float(np.median(lat)) if has else None,
        "latency_p99_us": float(np.percentile(lat, 99)) if has else None,
        "latency_max_us": float(np.max(lat)) if has else None,
        "end_to_end_median_us": float(np.median(e2e)) * 1e6 if has else None,
        "end_to_end_p99_us": float(np.percentile(e2e, 99)) * 1e6 if has else None,
        "feeder_writes_late_over_2ms": report["late_over_2ms"],
        "feeder_write_errors": report["write_errors"],
        "model": str(model_path),
        "sinks": list(sinks),
        "max_contacts": parts[0]["max_contacts"],
        # the publisher processes: frames queued, dropped (pipe full), sent; their CPU s, delays
        "sink_stats": sink_stats,
        "sink_frames_dropped": int(sum(v["dropped"] for v in sink_stats.values())),
        "loop_thread_cpu_s": cpu_thread,
        "process_cpu_s": cpu_proc,
        "loop_cpu_us_per_frame": loop_us,
        # the single-contact NumPy baseline per touched frame, in the same processes
        "baseline_cpu_us_per_frame": base_us,
        "loop_cpu_over_baseline": loop_us / base_us if base_us > 0 else None,
        "end_to_end_max_us": float(np.max(e2e)) * 1e6 if has else None,
        # the end to end split: before the bytes were read / read to contact
        "queueing_median_us": float(np.median(queue_us)) if has else None,
        "queueing_p99_us": float(np.percentile(queue_us, 99)) if has else None,
        # CPU per frame (us) of each process kind: where the cores go
        "loop_cpu_us_per_frame_each": [
            p["cpu_thread"] / max(sum(s["frames"] for s in p["stats"]), 1) * 1e6 for p in parts
        ],
        "loop_process_cpu_us_per_frame": cpu_proc / frames_total * 1e6,
        "publisher_cpu_us_per_frame": sum(float(v.get("cpu_s", 0.0)) for v in sink_stats.values())
        / frames_total
        * 1e6,
        # the loop's turns' CPU (us; load-robust): a long turn holds every frame behind it
        "turn_cpu_p99_us": float(np.percentile(turn_us, 99)) if len(turn_us) else None,
        "turn_cpu_p999_us": float(np.percentile(turn_us, 99.9)) if len(turn_us) else None,
        "turn_cpu_max_us": float(np.max(turn_us)) if len(turn_us) else None,
        "turns_over_1ms_cpu": int(np.sum(turn_us > 1000.0)),
        "turns": len(turn_us),
        "feeder_cpu_us_per_frame": float(report.get("cpu_s", 0.0)) / frames_total * 1e6,
    }
