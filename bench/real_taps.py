"""Real single touches tapped through the live pipeline: how many become two fingers.

The real recordings hold touches pressed and held at points, never gestures. This replays each
touch of the test recordings as a tap: 0.6 s of idle frames (the recording's own per-sensor
frame-to-frame scatter as noise), the touch's first ``--tap-frames`` recorded frames (its own
noise; optionally ramped up over ``--ramp`` frames, a finger landing), then idle again, through
``SkinCore`` with K = 3 and the gesture recogniser, the model trained on ``--train``. Every
touch is one finger, so a second track, a two-finger tap, or any gesture but a tap is wrong.
Reported per recording: touches given a second track, gestures by kind, taps held back.

    python bench/real_taps.py --data ../shared/data/hiro-cone-skin --out real-taps.json
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from skinloc.bench.paper import TEST_DEC, TRAIN_DEC

IDLE_FRAMES = 60
BASE_COUNTS = 1000.0


def tap_frames(touch: np.ndarray, noise: np.ndarray, n: int, ramp: int, rng) -> np.ndarray:
    """Frames ``(2 * IDLE_FRAMES + n, k)`` counts: idle, the touch's first ``n`` frames, idle.

    ``touch (s, k)``: the touch's baseline-subtracted frames; ``noise (k,)``: idle scatter.
    """
    k = touch.shape[1]
    t = touch[:n].copy()
    if ramp > 0:
        t[:ramp] *= (np.arange(1, ramp + 1) / (ramp + 1))[:, None]
    idle = [BASE_COUNTS + rng.normal(0.0, 1.0, (IDLE_FRAMES, k)) * noise for _ in range(2)]
    return np.concatenate([idle[0], BASE_COUNTS + t, idle[1]])


def replay(engine, frames: np.ndarray, footprint: bool = False) -> tuple[int, list[str], int]:
    """Tracks, gesture kinds and held taps of one stream at 100 Hz (``footprint``: the cue on)."""
    from skinloc.live.core import PipelineConfig, SkinCore

    cfg = PipelineConfig(max_contacts=3, baseline_frames=50, footprint_gestures=footprint)
    core = SkinCore(engine, cfg, name="s")
    ids = set()
    for i, f in enumerate(frames):
        for c in core.process_frame(f, 0.01 * i, i):
            ids.add(c.track_id)
    core.flush_gestures()
    kinds = [g["kind"] for g in core.take_gestures()]
    held = core._recognizer.n_held if core._recognizer is not None else 0
    return len(ids), kinds, held


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--train", default=TRAIN_DEC)
    ap.add_argument("--test", nargs="+", default=list(TEST_DEC))
    ap.add_argument("--tap-frames", type=int, default=12, help="Frames of the touch (100 Hz).")
    ap.add_argument("--ramp", type=int, nargs="+", default=[0, 3])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--footprint", action="store_true", help="The footprint cue on in the recogniser."
    )
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    for f in [args.train, *args.test]:
        if not (args.data / f).is_file():
            print(f"error: no recording {args.data / f}", file=sys.stderr)
            return 1
    if args.tap_frames < 3 or min(args.ramp) < 0 or max(args.ramp) >= args.tap_frames:
        print(
            "error: --tap-frames must be >= 3 and each --ramp in [0, tap frames)", file=sys.stderr
        )
        return 1
    if args.out is not None and args.out.exists():
        print(f"error: {args.out} exists", file=sys.stderr)
        return 1

    from skinloc.data.recording import read_recording
    from skinloc.evaluation.scoring import train_localizer

    engine = train_localizer([read_recording(args.data / args.train)]).engine().warm_up()
    rng = np.random.default_rng(args.seed)
    res: dict[str, dict] = {}
    for name in args.test:
        d = read_recording(args.data / name).deltas.astype(np.float64)
        for ramp in args.ramp:
            n_two = held = 0
            kinds: Counter = Counter()
            for a in range(d.shape[0]):
                noise = np.std(np.diff(d[a], axis=0), axis=0) / np.sqrt(2.0) + 1e-3
                frames = tap_frames(d[a], noise, args.tap_frames, ramp, rng)
                n_tracks, k, h = replay(engine, frames, args.footprint)
                n_two += n_tracks > 1
                kinds.update(k)
                held += h
            key = f"{name} ramp {ramp}"
            res[key] = {
                "touches": int(d.shape[0]),
                "second_track": n_two,
                "gestures": dict(kinds),
                "held": held,
            }
            print(f"{key}: {d.shape[0]} touches, {n_two} with a second track, "
                  f"gestures {dict(kinds)}, held {held}")  # fmt: skip
    tot = {r: sum(v["touches"] for k, v in res.items() if k.endswith(f" {r}")) for r in args.ramp}
    for r in args.ramp:
        two = sum(
            v["gestures"].get("two_finger_tap", 0) for k, v in res.items() if k.endswith(f" {r}")
        )
        print(f"ramp {r}: two-finger taps {two} of {tot[r]} single touches")
    if args.out is not None:
        tmp = args.out.with_suffix(args.out.suffix + ".tmp")
        tmp.write_text(
            json.dumps({"args": {k: str(v) for k, v in vars(args).items()}, **res}, indent=1)
        )
        tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
