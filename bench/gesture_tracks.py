"""The gesture soak's tracks offline: its scripted hand on the simulated skin, no port, no clock.

``bench/live_soak.py --gestures`` performs a ``GestureScript`` on a virtual skin over a pty for
30 minutes of wall clock and scores every finger contact (stroke) as one track
(``live_delivery.score_tracks``). This replays the same hand (the soak's ``gesture_hand``: skin
seed 0, the same script seed) on the simulated skin's own clock at ``--rate`` Hz, straight into
a ``SkinCore`` with the runner's settings (``--max-contacts 3``, gestures on), without faults
or unplugs, and scores the tracks the same way. Minutes of script take seconds of CPU, and a
run is the same every time:

    python bench/gesture_tracks.py --model model.h5 --minutes 30
    python bench/gesture_tracks.py --model model.h5 --minutes 30 --trace 31.2 31.6

``--noise-seed N`` performs the same script on other noise (the soak's own frames differ from
the replay's by their noise and timing: its restarts are other strokes' on one seed, the same
strokes' over several), ``--no-memory`` and ``--no-pair`` take the search memory or the pair
prior out, ``--jitter-ms`` stamps frames with their time plus a random delay (the pty's
arrival times), ``--trace T0 T1`` prints each frame between script times T0 and T1 (s): the
fingers, the search's contacts, the pair prior's state, the memory's answer and the tracks. The
model must be trained on the simulated skin with seed 0, as for the soak.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from live_delivery import score_gestures, score_tracks
from live_soak import gesture_hand

from skinloc.live.config import PipelineConfig
from skinloc.live.core import SkinCore
from skinloc.models.multi_contact.search import MEM_FRAMES, MEM_VALID


def replay(
    model: Path,
    minutes: float,
    seed: int,
    rate_hz: float,
    jitter_ms: float = 0.0,
    trace: tuple[float, float] | None = None,
    memory: bool = True,
    pair: bool = True,
    noise_seed: int | None = None,
) -> dict:
    """Perform the soak's script offline; the contacts, gestures and the truth (script time s)."""
    skin, hand = gesture_hand(seed, minutes * 60 - 1.0)
    hand.t0 = 0.0
    if noise_seed is not None:
        skin.reseed(noise_seed)  # the same script on other noise
    core = SkinCore(str(model), PipelineConfig(max_contacts=3), name="skin0")
    if not memory:
        core.search_memory = None
    if not pair:
        core._tracker.pair = None
    elif trace is not None and core._tracker.pair is not None:
        pp = core._tracker.pair
        fit_once = pp.refit.fit

        def fit_logged(x, anchor):
            pp.last_fit = fit_once(x, anchor)
            return pp.last_fit

        pp.refit.fit = fit_logged
    skin.connect()
    rng = np.random.default_rng(seed + 7)
    dt = 1.0 / rate_hz
    contacts: list[dict] = []
    events: list[dict] = []
    n_base = core.config.baseline_frames + 10
    # the baseline first, untouched; script time 0 follows (its own 2 s lead-in untouched)
    for _ in range(n_base):
        f = skin.read()
        core.process_frame(f.values, f.timestamp_s - n_base * dt, f.index)
    end_s = hand.end_s + 1.0
    k = 0
    while (t := k * dt) < end_s:
        fingers = hand(t)
        if fingers is not None:
            skin.touch(fingers)
        f = skin.read()
        ts = t + (rng.exponential(jitter_ms * 1e-3) if jitter_ms > 0 else 0.0)
        out = core.process_frame(f.values, ts, f.index)
        for c in out:
            contacts.append(_contact_dict(c))
        events += core.take_gestures()
        if trace is not None and trace[0] <= t <= trace[1]:
            _trace_frame(t, fingers, core, out)
        k += 1
    contacts += [_contact_dict(c) for c in core.end_open(float("inf"))]
    core.flush_gestures()
    events += core.take_gestures()
    return {"contacts": contacts, "events": events, "truth": hand.truth(), "core": core}


def _contact_dict(c) -> dict:
    return {
        "state": c.state,
        "timestamp_s": c.timestamp_s,
        "track_id": c.track_id,
        "slot": c.slot,
        "position_m": list(c.position_m),
        "raw_m": list(c.raw_m),
    }


def _mm(p) -> str:
    return "(" + ",".join(f"{1e3 * v:6.1f}" for v in p) + ")"


def _trace_frame(t: float, fingers, core: SkinCore, out) -> None:
    tr = core._tracker
    fs = " ".join(f"{_mm(f.position_m)}p{f.pressure:.2f}" for f in fingers or [])
    pp = tr.pair
    mem = core.search_memory
    memo = "-" if mem is None else f"{mem.state[MEM_VALID]:.0f}/{mem.state[MEM_FRAMES]:.0f}"
    tracks = " ".join(
        f"#{c.track_id}/{c.slot}:{c.state[0]}{_mm(c.raw_m)}->{_mm(c.position_m)}" for c in out
    )
    cands = " ".join(f"cand{c.seen}{_mm(c.last_m)}" for c in tr.candidates)
    pstate = f"run={pp.run} fits={pp.fits}" if pp is not None else ""
    fit = getattr(pp, "last_fit", None)
    if fit is not None:
        pstate += (
            f" fit r={fit.ratio:.2f} z2={fit.z2:.1f} 1st{_mm(fit.first_m)} 2nd{_mm(fit.second_m)}"
        )
        pp.last_fit = None
    print(
        f"t={t:8.3f} z={out[0].signal_z if out else float('nan'):5.1f} lvl={core._level:5.1f} "
        f"touching={int(core.touching)} below={core._below} "
        f"fingers[{fs}] tracks[{tracks}] {cands} pair[{pstate}] mem={memo}"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--minutes", type=float, default=5.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rate", type=float, default=100.0)
    ap.add_argument("--jitter-ms", type=float, default=0.0)
    ap.add_argument("--trace", type=float, nargs=2, default=None, metavar=("T0", "T1"))
    ap.add_argument("--noise-seed", type=int, default=None, help="The same script on other noise.")
    ap.add_argument("--no-memory", action="store_true", help="Search every frame in full.")
    ap.add_argument("--no-pair", action="store_true", help="Without the pair prior.")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    r = replay(
        args.model,
        args.minutes,
        args.seed,
        args.rate,
        args.jitter_ms,
        args.trace,
        memory=not args.no_memory,
        pair=not args.no_pair,
        noise_seed=args.noise_seed,
    )
    truth = r["truth"]
    tracks = score_tracks(r["contacts"], truth["strokes"])
    gest = score_gestures(r["events"], truth["truth_gestures"], truth["truth_touches"])
    result = {
        "command": " ".join(["python", "bench/gesture_tracks.py", *sys.argv[1:]]),
        "minutes": args.minutes,
        "strokes_by_kind": dict(Counter(s["kind"] for s in truth["strokes"])),
        "tracks": tracks,
        "gestures": gest,
    }
    text = json.dumps(result, indent=2, default=float)
    if args.out:
        args.out.write_text(text)
    summary = {k: v for k, v in tracks.items() if k != "examples"}
    print(json.dumps(summary))
    for label in ("restarted", "lost", "split"):
        for e in tracks["examples"].get(label, []):
            print(label, json.dumps(e))
    print(json.dumps({k: v for k, v in gest["per_kind"].items()}, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
