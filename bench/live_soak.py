"""Soak of the live pipeline: `skinloc run` on a faulty virtual skin with a scripted finger.

The virtual skin (pty, binary format, 100 Hz, faults on: garbage, dropped bytes, split and
merged frames, a disconnect every 30 s on average) runs in this process with a scripted finger
that presses random points of the skin (holds and pauses of 0.8-2 s). `skinloc run` reads the
port in its own process and writes JSON lines. Afterwards every scripted touch is matched with
the pipeline's events: between one press and the next there must be exactly one touch-start
and one touch-end (none lost, none doubled). Also: the runner's resident memory sampled every
10 s, disconnects against reconnects, localisation error of the reported positions, latency.

    python bench/live_soak.py --model model.h5 --minutes 30 --out live-soak.json

With `--gestures` the hand is a `GestureScript`'s (`skinloc.sim.hand.ScriptedHand`): taps,
double taps, long presses, swipes, two-finger taps, rests and drags at the script's timings,
fingers moving and two at once, on the wall clock; the runner runs with `--max-contacts 3`.
Every finger must then be one track (one start, one end, one id while it is down), no track
may match no finger, and no gesture event may be written twice; per-kind precision and recall
are reported (`live_delivery` says how, and what an unplug excuses):

    python bench/live_soak.py --gestures --model model.h5 --minutes 30 --out gesture-soak.json

The model must be trained on the simulated skin with seed 0 (the virtual skin's), e.g.
`skinloc simulate --points 80 --out cal.h5 && skinloc train cal.h5 --out model.h5`.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import numpy as np
from live_delivery import score_gestures, score_tracks

from skinloc.geometry.mesh import sample_surface
from skinloc.sim.gestures import GestureScript
from skinloc.sim.hand import ScriptedHand, script_items
from skinloc.sim.skin import SimulatedSkin
from skinloc.sim.virtual_device import FaultConfig, VirtualSkin


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def finger(dev: VirtualSkin, stop: threading.Event, script: list, seed: int, start_s: float):
    """Press and lift on wall-clock time; log (t_press, t_release, contact) in monotonic s."""
    rng = np.random.default_rng(seed)
    targets = sample_surface(dev.skin.mesh, 4096, rng)[0]
    if stop.wait(start_s):
        return
    while not stop.is_set():
        contact = dev.skin.touch_near(targets[rng.integers(len(targets))], rng)
        t_press = time.monotonic()
        script.append([t_press, None, contact.tolist()])
        stop.wait(rng.uniform(0.8, 2.0))
        dev.skin.release()
        script[-1][1] = time.monotonic()
        if stop.wait(rng.uniform(0.8, 2.0)):
            break


def start_runner(model: Path, port: str, events_path: Path, *extra: str) -> subprocess.Popen:
    """`skinloc run` on ``port`` in its own process, JSON lines to ``events_path``."""
    cmd = [
        sys.executable, "-m", "skinloc", "run", "--model", str(model), "--source", port,
        "--format", "binary", "--sink", f"jsonl:{events_path}", "--stats", *extra,
    ]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    print(f"device on {port}, runner pid {proc.pid}, events in {events_path}", flush=True)
    return proc


def sample_rss(proc: subprocess.Popen, duration_s: float) -> list[tuple[float, float]]:
    """The runner's resident memory every 10 s until ``duration_s`` has passed, (s, MB)."""
    t0 = time.monotonic()
    rss: list[tuple[float, float]] = []
    while time.monotonic() - t0 < duration_s and proc.poll() is None:
        rss.append((time.monotonic() - t0, rss_mb(proc.pid)))
        time.sleep(min(10.0, max(0.0, duration_s - (time.monotonic() - t0))))
    return rss


def stop_runner(proc: subprocess.Popen) -> tuple[dict, str]:
    """SIGTERM the runner; its ``--stats`` of the skin and its stderr."""
    proc.send_signal(signal.SIGTERM)
    try:
        _, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    stats_line = [ln for ln in err.splitlines() if ln.startswith("[")]
    return (json.loads(stats_line[-1])[0] if stats_line else {}), err


def link_report(
    counts: dict,
    stats: dict,
    rss: list,
    events: list[dict],
    proc: subprocess.Popen,
    err: str,
) -> dict:
    """What both soaks report: unplugs against reconnects, frames, faults, latency, memory."""
    lat = np.array([e["latency_us"] for e in events if e["state"] in ("start", "move")])
    rss_arr = np.array(rss)
    warm = rss_arr[rss_arr[:, 0] >= 120] if len(rss_arr) and rss_arr[-1, 0] >= 240 else rss_arr
    disconnects = counts.get("disconnects", 0)
    reconnects = stats.get("reconnects", -1)
    return {
        "device_disconnects": disconnects,
        "runner_reconnects": reconnects,
        "every_disconnect_recovered": reconnects >= disconnects - 1
        and stats.get("link_up", False)
        or reconnects >= disconnects,
        "device_frames": {k: v for k, v in counts.items() if k in ("sent", "destroyed", "unheard")},
        "device_faults": {k: v for k, v in counts.items() if k.startswith("fault_")},
        "device_downtime_s_total": counts.get("downtime_s_total"),
        "runner_frames": stats.get("frames"),
        # every frame the runner reads is one the device sent intact: more means it read
        # another device (a pty number reused while this one was unplugged)
        "runner_frames_minus_sent": (stats.get("frames") or 0) - counts.get("sent", 0),
        "runner_wire": stats.get("wire"),
        "latency_median_us": float(np.median(lat)) if len(lat) else None,
        "latency_p99_us": float(np.percentile(lat, 99)) if len(lat) else None,
        "rss_mb_first_after_2min_last_max": [
            float(rss_arr[0, 1]),
            float(warm[0, 1]) if len(warm) else None,
            float(rss_arr[-1, 1]),
            float(warm[:, 1].max()) if len(warm) else None,
        ]
        if len(rss_arr)
        else None,
        "rss_mb_samples": rss,
        "load_average_1_5_15": list(os.getloadavg()),
        "runner_exit_code": proc.returncode,
        "runner_stderr_tail": err.strip().splitlines()[-3:],
    }


def read_lines(path: Path) -> tuple[list[dict], list[dict]]:
    """The runner's contact lines and gesture lines."""
    lines = [json.loads(ln) for ln in path.read_text().splitlines() if ln.strip()]
    return [e for e in lines if "event" not in e], [e for e in lines if e.get("event") == "gesture"]


def single_finger(args: argparse.Namespace, tmp: Path) -> tuple[dict, bool]:
    events_path = tmp / "contacts.jsonl"
    faults = FaultConfig(disconnect_every_s=args.disconnect_every, random_state=args.seed + 1)
    dev = VirtualSkin(fmt="binary", rate_hz=args.rate, faults=faults)
    port = dev.start()
    proc = start_runner(args.model, port, events_path)
    script: list = []
    stop = threading.Event()
    # 3 s untouched at start: the runner starts, compiles and captures its baseline.
    th = threading.Thread(target=finger, args=(dev, stop, script, args.seed, 4.0), daemon=True)
    th.start()
    rss = sample_rss(proc, args.minutes * 60)
    stop.set()
    th.join()
    dev.skin.release()
    time.sleep(2.0)  # the last touch-end reaches the file
    runner_stats, err = stop_runner(proc)
    counts = dict(dev.counts)
    dev.stop()

    events, _ = read_lines(events_path)
    starts = np.array([e["timestamp_s"] for e in events if e["state"] == "start"])
    ends = np.array([e["timestamp_s"] for e in events if e["state"] == "end"])
    press = np.array([s[0] for s in script])
    bounds = np.concatenate([press, [np.inf]])
    lost = doubled = lost_end = doubled_end = 0
    errors_mm = []
    for i in range(len(press)):
        lo, hi = bounds[i], bounds[i + 1]
        n_s = int(((starts >= lo) & (starts < hi)).sum())
        n_e = int(((ends >= lo) & (ends < hi)).sum())
        lost += n_s == 0
        doubled += n_s > 1
        lost_end += n_e == 0
        doubled_end += n_e > 1
        contact = np.asarray(script[i][2])
        pos = [
            e["position_m"]
            for e in events
            if e["state"] == "move"
            and lo <= e["timestamp_s"] < hi
            and e["position_m"][0] is not None
        ]
        if pos:
            err_i = np.linalg.norm(np.asarray(pos) - contact, axis=1) * 1e3
            errors_mm.append(float(np.median(err_i)))
    before_first = int((starts < press[0]).sum()) if len(press) else len(starts)
    result = {
        "command": " ".join(["python", "bench/live_soak.py", *sys.argv[1:]]),
        "minutes": args.minutes,
        "rate_hz": args.rate,
        "scripted_touches": len(press),
        "touch_starts": len(starts),
        "touch_ends": len(ends),
        "touches_lost": int(lost),
        "touches_doubled": int(doubled),
        "ends_lost": int(lost_end),
        "ends_doubled": int(doubled_end),
        "starts_before_first_touch": before_first,
        "median_error_mm_per_touch": float(np.median(errors_mm)) if errors_mm else None,
        "p95_error_mm_per_touch": float(np.percentile(errors_mm, 95)) if errors_mm else None,
        **link_report(counts, runner_stats, rss, events, proc, err),
    }
    ok = lost == 0 and doubled == 0 and lost_end == 0 and doubled_end == 0
    return result, ok


def gesture_hand(seed: int, duration_s: float) -> tuple[SimulatedSkin, ScriptedHand]:
    """The virtual skin's simulated skin (seed 0) and a scripted hand for ``duration_s``."""
    skin = SimulatedSkin(random_state=0)
    skin.reseed(seed)
    # about one item per 1.5 s; generously many, only those that end in time are drawn
    script = GestureScript(
        skin.mesh,
        max(5, int(duration_s)),
        random_state=seed,
        draw_touch=lambda rng: skin.draw_touch(rng, weak=False),
    )
    items = script_items(script, duration_s, skin)
    return skin, ScriptedHand(items, t0=float("inf"), ramp_s=script.timing.ramp_s)


def gestures(args: argparse.Namespace, tmp: Path) -> tuple[dict, bool]:
    events_path = tmp / "events.jsonl"
    duration = args.minutes * 60
    skin, hand = gesture_hand(args.seed, duration - 1.0)
    faults = FaultConfig(disconnect_every_s=args.disconnect_every, random_state=args.seed + 1)
    dev = VirtualSkin(skin, fmt="binary", rate_hz=args.rate, faults=faults, hand=hand)
    port = dev.start()
    proc = start_runner(args.model, port, events_path, "--max-contacts", "3")
    # The runner starts, compiles and captures its baseline: 2 s of frames heard first.
    deadline = time.monotonic() + 120
    while dev.counts["sent"] < 2 * args.rate and time.monotonic() < deadline:
        if proc.poll() is not None:
            break
        time.sleep(0.1)
    hand.t0 = time.monotonic()  # the script's own lead-in (2 s untouched) follows
    rss = sample_rss(proc, hand.end_s + 0.5)
    time.sleep(2.0)  # the last end and the last gesture reach the file
    runner_stats, err = stop_runner(proc)
    counts = dict(dev.counts)
    downtimes = list(dev.downtimes)
    dev.stop()
    counts["downtime_s_total"] = float(sum(b - a for a, b in downtimes))

    contacts, events = read_lines(events_path)
    truth = hand.truth()
    tracks = score_tracks(contacts, truth["strokes"], downtimes)
    gest = score_gestures(
        events,
        truth["truth_gestures"],
        truth["truth_touches"],
        downtimes,
        n_recognised=runner_stats.get("gestures"),
        contact_track_ids={int(c["track_id"]) for c in contacts},
    )
    result = {
        "command": " ".join(["python", "bench/live_soak.py", *sys.argv[1:]]),
        "mode": "gestures",
        "minutes": args.minutes,
        "rate_hz": args.rate,
        "script_items": len(hand.items),
        "script_kinds": dict(Counter(i.kind for i in hand.items)),
        "tracks": tracks,
        "gestures": gest,
        **link_report(counts, runner_stats, rss, contacts, proc, err),
    }
    ok = (
        tracks["lost"] == tracks["restarted"] == tracks["ghost_tracks"] == tracks["bad_tracks"] == 0
        and tracks["held_across_unplug"] == tracks["held_across_unplug_one_track"]
        and gest["duplicates"] == gest["second_event_for_one_gesture"] == 0
        and gest["unknown_track_ids"] == 0
        and gest["recognised_equals_written"] is not False
    )
    return result, ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--disconnect-every", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--gestures", action="store_true", help="A scripted hand's gestures.")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    tmp = Path(tempfile.mkdtemp(prefix="skinloc-live-soak-"))
    result, ok = (gestures if args.gestures else single_finger)(args, tmp)
    text = json.dumps(result, indent=2)
    if args.out:
        args.out.write_text(text)
    print(json.dumps({k: v for k, v in result.items() if k != "rss_mb_samples"}, indent=2))
    return 0 if ok else 1


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
