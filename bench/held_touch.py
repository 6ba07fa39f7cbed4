"""A touch held for minutes with drift tracking on: reported throughout, at the right place.

The simulated skin (its clock, 100 Hz) is touched once and held for ``--minutes``, while its
baselines drift (the simulator's Ornstein-Uhlenbeck drift; ``--drift-counts`` sets its std,
5 times the fitted 3 counts by default to make the point). The pipeline runs with
drift tracking on. Reported: touch events during the hold (exactly one start, no end), the
localisation error at the start and at the end of the hold, the end event after the release,
and for comparison a naive baseline tracker that follows every frame (the known failure of
other skins: the held touch is tracked away and ends by itself).

    python bench/held_touch.py --model model.h5 --minutes 5 --out held-touch.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from skinloc.live.core import PipelineConfig, SkinCore
from skinloc.sim.skin import SimulatedSkin, SkinParams


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--drift-counts", type=float, default=15.0)
    ap.add_argument("--drift-tau-s", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    params = dataclasses.replace(
        SkinParams.default(),
        drift_std_counts=args.drift_counts,
        drift_time_constant_s=args.drift_tau_s,
    )
    skin = SimulatedSkin(params=params, random_state=0)
    skin.reseed(args.seed)
    skin.connect()
    core = SkinCore(args.model, PipelineConfig(drift_tracking=True), name="held")
    cfg = core.config
    rng = np.random.default_rng(args.seed)

    events = []

    def step(n: int) -> list:
        out = []
        for _ in range(n):
            f = skin.read()
            out += core.process_frame(f.values, f.timestamp_s, f.index)[:1]
        return out

    # 2 min untouched: baseline capture, then drift tracking while idle
    events += step(int(120 * skin.rate_hz))
    idle_events = len(events)
    baseline_before = core.baseline
    from skinloc.geometry.mesh import sample_surface

    target = sample_surface(skin.mesh, 1, rng)[0][0]
    contact = skin.touch_near(target, rng)
    n_hold = int(args.minutes * 60 * skin.rate_hz)
    hold = step(10)
    under = core._delta * (1.0 / core.noise) > cfg.touch_on_z  # sensors under the finger
    hold += step(n_hold - 10)
    baseline_after = core.baseline
    skin.release()
    after = step(int(5 * skin.rate_hz))

    def err_mm(cs: list) -> float:
        pos = np.array([c.position_m for c in cs if c.state in ("start", "move")])
        return float(np.median(np.linalg.norm(pos - contact, axis=1)) * 1e3) if len(pos) else None

    states = [c.state for c in hold]
    first = [c for c in hold if c.timestamp_s - hold[0].timestamp_s < 10.0]
    last = [c for c in hold if hold[-1].timestamp_s - c.timestamp_s < 10.0]

    # the naive tracker: an exponential baseline that follows every frame (tau as ours)
    skin2 = SimulatedSkin(params=params, random_state=0)
    skin2.reseed(args.seed)
    skin2.connect()
    frames = np.array([skin2.read().values for _ in range(int(120 * skin2.rate_hz))], float)
    base = frames[:50].mean(axis=0)
    sigma = np.maximum(frames[:50].std(axis=0), cfg.noise_floor_counts)
    alpha = 1.0 / (skin2.rate_hz * cfg.drift_time_constant_s)
    for f in frames[50:]:
        base += alpha * (f - base)
    skin2.press(contact)
    naive_end_s = None
    for k in range(n_hold):
        f = skin2.read().values.astype(float)
        z = ((f - base) / sigma).max()
        base += alpha * (f - base)
        if z < cfg.touch_off_z and naive_end_s is None:
            naive_end_s = k / skin2.rate_hz
    result = {
        "command": " ".join(["python", "bench/held_touch.py", *sys.argv[1:]]),
        "hold_minutes": args.minutes,
        "drift_std_counts": args.drift_counts,
        "drift_time_constant_s": args.drift_tau_s,
        "events_while_idle_2min": idle_events,
        "frames_held": n_hold,
        "outputs_during_hold": len(hold),
        "starts_during_hold": states.count("start"),
        "ends_during_hold": states.count("end"),
        "reported_every_held_frame": len(hold) == n_hold - (cfg.debounce_on_frames - 1),
        "error_mm_first_10s": err_mm(first),
        "error_mm_last_10s": err_mm(last),
        "sensors_under_finger": int(under.sum()),
        "baseline_change_under_finger_counts": float(
            np.abs(baseline_after - baseline_before)[under].max()
        ),
        "end_after_release": [c.state for c in after].count("end"),
        "end_delay_ms": (after[0].timestamp_s - hold[-1].timestamp_s) * 1e3 if after else None,
        "naive_tracker_touch_lost_after_s": naive_end_s,
    }
    text = json.dumps(result, indent=2)
    if args.out:
        args.out.write_text(text)
    print(text)
    ok = (
        result["starts_during_hold"] == 1
        and result["ends_during_hold"] == 0
        and result["end_after_release"] == 1
    )
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
