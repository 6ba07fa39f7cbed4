"""``skinloc bench --online``: the live path's latency and throughput, with a baseline.

Figures (docs/benchmarks.md, "Live pipeline"):

* per-frame latency, bytes in to contact out, one 64-sensor stream: ``SkinCore.feed`` on the
  wire bytes of each frame (skinloc binary format) through parsing, baseline, detection,
  localiser, surface constraint and filter, timed per frame; against a plain baseline timed in
  the same run on the same frames: for a network, a NumPy forward pass plus a scipy KD-tree
  snap; for a response map, the coarse-to-fine match in NumPy. Neither baseline parses,
  subtracts or detects anything, so the ratio is conservative;
* single-stream frames/s: the same ``feed`` back to back;
* batched frames/s: the engine's ``predict_batch`` on 200,000 touched frames, against the same
  baseline on the same batch;
* 100 skins at 100 Hz (``skinloc.bench.many_skins``): a feeder process writes every skin's
  frames to its own pseudo-terminal on schedule; one ``Runner`` per worker process (one per
  core, as ``skinloc run --workers``) reads its share, and once one ``Runner`` reads all;
  latency from the bytes' arrival to the contact, and end to end from the frame's scheduled
  write time; then with the ROS 2 sink on (through a real rclpy node per worker when rclpy
  is installed, else plain DDS on loopback), quiet and beside two CPU-heavy processes; each
  with the load average and the loop's CPU per frame over the single-contact NumPy
  baseline's, measured in the same processes;
* publishing cost per contact of the sinks (``skinloc.bench.sinks``).
"""

from __future__ import annotations

import importlib.util
import logging
import os
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.bench.baseline import PLAIN_BASELINES, baseline_fn, plain_baseline
from skinloc.bench.many_skins import many_skins
from skinloc.bench.stream import touch_stream

log = logging.getLogger(__name__)

__all__ = [
    "PLAIN_BASELINES",
    "baseline_fn",
    "many_skins",
    "model_code_stamp",
    "online_bench",
    "plain_baseline",
    "single_stream",
    "touch_stream",
    "train_bench_models",
]

Step = Callable[[str, int, int], None]


def _noop(label: str, done: int, total: int) -> None:
    pass


#: Subpackages whose code decides what a trained benchmark model is (simulation, training,
#: the model's arrays); the live path and its front ends do not.
_MODEL_CODE = ("calibration", "data", "evaluation", "geometry", "models", "sensors", "sim")


def model_code_stamp() -> str:
    """A hash of the code that simulates and trains the benchmark models (16 hex digits).

    A cached model trained by other code (before a model gained its amplitude map and
    calibrated count rule, say) would time another search than the one users run.
    """
    import hashlib

    import skinloc

    root = Path(skinloc.__file__).parent
    h = hashlib.sha256()
    for sub in _MODEL_CODE:
        for f in sorted((root / sub).rglob("*.py")):
            h.update(f.relative_to(root).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:16]


def train_bench_models(folder: Path, archs: tuple[str, ...], step: Step = _noop) -> dict[str, Path]:
    """Simulate a calibration (80 touches) and train each architecture; cached in ``folder``.

    The cache holds while the code that trains them is unchanged (``model_code_stamp``, kept
    in ``folder / "code-stamp"``); otherwise the calibration and the models are moved to
    ``folder / "older-<stamp>"`` and made again.
    """
    from skinloc.calibration.session import SessionConfig, simulate_session
    from skinloc.evaluation.scoring import train_localizer
    from skinloc.geometry.mesh import cone_skin
    from skinloc.sim.skin import SimulatedSkin

    folder.mkdir(parents=True, exist_ok=True)
    cal_path = folder / "cal.h5"
    paths = {a: folder / f"{a}.h5" for a in archs}
    stamp_path = folder / "code-stamp"
    stamp = model_code_stamp()
    old = stamp_path.read_text().strip() if stamp_path.is_file() else "unstamped"
    if old != stamp:
        # made by other code: set aside (never deleted: ``folder`` may be under a user's --out)
        # and made again
        aside = folder / f"older-{old}"
        for p in (cal_path, *(folder / f"{a}.h5" for a in ("default", "mlp", "paper", *archs))):
            if p.is_file():
                aside.mkdir(exist_ok=True)
                p.replace(aside / p.name)
        stamp_path.write_text(stamp + "\n")
    if all(p.is_file() for p in paths.values()):
        return paths
    mesh = cone_skin()
    if not cal_path.is_file():
        step("online: simulating a calibration", 0, 1)
        with SimulatedSkin(mesh, random_state=0) as skin:
            simulate_session(
                skin,
                mesh,
                cal_path,
                SessionConfig(n_points=80, mode="even", samples_per_touch=20, random_state=0),
            )
    from skinloc.data.recording import read_recording

    cal = read_recording(cal_path)
    for i, a in enumerate(archs):
        if not paths[a].is_file():
            step("online: training", i, len(archs))
            train_localizer([cal], arch=a, random_state=0).save(paths[a])
    return paths


def single_stream(
    model_path: Path, n_frames: int = 20000, random_state: int = 0, batch_rows: int = 200_000
) -> dict:
    """Latency and throughput of one 64-sensor stream, bytes in to contact out.

    ``batch_rows``: rows of the batched-prediction comparison (the touched frames repeated).
    """
    from skinloc.hardware.protocol import encode_binary
    from skinloc.live.core import SkinCore
    from skinloc.models.engine import load_engine
    from skinloc.models.localizer import ContactLocalizer

    model = ContactLocalizer.load(model_path)
    fast = load_engine(model)
    frames, _ = touch_stream(n_frames, random_state=random_state)
    wire = [encode_binary(f, 8, 8, i) for i, f in enumerate(frames)]

    def fresh_core() -> SkinCore:
        core = SkinCore(fast, wire_format="binary")
        for b in wire[:100]:  # baseline capture
            core.feed(b)
        return core

    # latency: one frame at a time, with perf_counter around each feed
    core = fresh_core()
    lat_touch: list[float] = []
    lat_all: list[float] = []
    pc = time.perf_counter
    for b in wire[100:]:
        t0 = pc()
        out = core.feed(b)
        dt = pc() - t0
        lat_all.append(dt)
        if out:
            lat_touch.append(dt)
    # the plain baseline on the touched frames' deltas, interleaved in the same run
    plain = baseline_fn(model)
    deltas = frames[100:].astype(np.float64) - frames[:100].mean(axis=0)
    touched = deltas[np.max(deltas, axis=1) > 60][:5000]
    lat_plain = []
    for x in touched:
        t0 = pc()
        plain(x[None])
        lat_plain.append(pc() - t0)
    # throughput: back to back, no timing inside
    core = fresh_core()
    t0 = pc()
    n_out = 0
    for b in wire[100:]:
        n_out += len(core.feed(b))
    elapsed = pc() - t0
    # batched prediction of touched frames
    reps = max(1, batch_rows // max(len(touched), 1))
    batch = np.tile(touched.astype(np.float32), (reps, 1))
    fast.predict_batch(batch[:1000])
    t0 = pc()
    fast.predict_batch(batch)
    batch_s = pc() - t0
    t0 = pc()
    plain(batch.astype(np.float64))
    plain_batch_s = pc() - t0
    us = 1e6
    med = float(np.median(lat_touch)) * us
    plain_med = float(np.median(lat_plain)) * us
    return {
        "model": str(model_path),
        "arch": model.config_.get("arch"),
        "kind": fast.kind,
        "frames": len(wire) - 100,
        "touched_frames": len(lat_touch),
        "latency_touched_median_us": med,
        "latency_touched_p99_us": float(np.percentile(lat_touch, 99)) * us,
        "latency_all_median_us": float(np.median(lat_all)) * us,
        "latency_all_p99_us": float(np.percentile(lat_all, 99)) * us,
        "baseline": plain_baseline(fast.kind)[1],
        "baseline_median_us": plain_med,
        "baseline_p99_us": float(np.percentile(lat_plain, 99)) * us,
        "speedup_median": plain_med / med,
        "stream_frames_per_s": (len(wire) - 100) / elapsed,
        "stream_contacts": n_out,
        "batch_frames": len(batch),
        "batch_frames_per_s": len(batch) / batch_s,
        "baseline_batch_frames_per_s": len(batch) / plain_batch_s,
        "batch_ratio": plain_batch_s / batch_s,
    }


def online_bench(
    models: list[Path] | None = None,
    out: Path | None = None,
    *,
    n_frames: int = 20000,
    n_skins: int = 100,
    skins_duration_s: float = 30.0,
    step: Step = _noop,
    archs: tuple[str, ...] = ("default", "mlp", "paper"),
) -> dict:
    """Every figure of the live path; trains the models of ``archs`` when none are given.

    What needs an extra that is not installed (the ROS 2 sink's figures need cyclonedds) is
    left out, and ``results["left_out"]`` says what and how to install it.
    """
    import platform

    from skinloc._lazy import extra_installed, missing_extra_message
    from skinloc.bench.sinks import sink_cost

    if not models:
        folder = (out or Path(tempfile.gettempdir()) / "skinloc-bench") / "online-models"
        paths = train_bench_models(folder, archs, step)
        models = list(paths.values())
    results: dict[str, Any] = {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}",
        "single_stream": [],
        "left_out": [],
    }
    for i, m in enumerate(models):
        step("online: single stream", i, len(models))
        results["single_stream"].append(single_stream(Path(m), n_frames))
    ros2 = extra_installed("cyclonedds.domain")
    if ros2:
        step("online: sink cost", 0, 1)
        results["sink_cost"] = sink_cost()
    else:
        what = "measuring the ROS 2 sink (its cost, 100 skins through it)"
        results["left_out"].append(missing_extra_message("cyclonedds", what))
    # the skins over the cores, as ``skinloc run --workers`` spreads them; one process too
    workers = max(min(os.cpu_count() or 1, n_skins), 1)
    # the ROS 2 sink's own choice (rclpy when it imports), made here once for the figures
    backend = "rclpy" if importlib.util.find_spec("rclpy") is not None else "dds"
    if ros2 and backend == "dds":
        results["left_out"].append(
            "the ROS 2 figures through a real node need rclpy (pip install 'skinloc[ros2]'); "
            "measured over plain DDS instead"
        )
    runs: list[tuple[str, dict[str, Any]]] = [
        ("many_skins", {"workers": workers}),
        ("many_skins_one_process", {"workers": 1}),
    ]
    if ros2 or backend == "rclpy":
        runs += [
            ("many_skins_ros2", {"workers": workers, "sinks": ("ros2",), "backend": backend}),
            (
                "many_skins_ros2_loaded",
                {"workers": workers, "sinks": ("ros2",), "backend": backend, "hogs": 2},
            ),
        ]
    for i, (key, kw) in enumerate(runs):
        step(f"online: 100 skins ({key})", i, len(runs))
        results[key] = many_skins(Path(models[0]), n_skins, 100.0, skins_duration_s, **kw)
    step("online: done", 1, 1)
    return results
