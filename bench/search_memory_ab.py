"""The multi-contact search with a stream's memory (``SearchMemory``) against without, same frames.

``Engine.contacts(x, 3)`` frame by frame in stream order, once searching every frame in full
and once with one ``SearchMemory`` per stream (reset at each stream's start), on:

* real streams: each point log of ``--test`` (a touch held over its frames, in order); sums of
  two point logs frame by frame (two fingers held together); *landings*: a point log alone for
  its first half, then with a second log's frames added (a second finger arriving while the
  first is held, the memory's hard case); sums of three. The model is trained on ``--train``.
* the simulated stream of ``skinloc bench --online`` (single touches only) through
  ``SkinCore.process_frame`` with frame-count timestamps (deterministic), both ways: the
  contacts the pipeline emits, frame by frame.

For each: the share of frames whose count changes, or whose positions move by more than 1 mm,
and whether the changed counts were right before or after (the truth of a stream: 1, 2 or 3
fingers; a landing's first half 1). Then the cost, in one process, settings interleaved in
rounds on the simulated stream's touched frames: ``contacts`` at K = 1, K = 3 in full and
K = 3 with the memory, median and p99 (µs) and their ratios to K = 1.

    PYTHONPATH=src python bench/search_memory_ab.py --data ../shared/data/hiro-cone-skin
"""

from __future__ import annotations

import argparse
import itertools
import json
import platform
import time
from pathlib import Path

import numpy as np

from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import train_localizer
from skinloc.models.multi_contact.search import MEM_FRAMES, MEM_VALID, SearchMemory


def real_streams(rec, rng: np.random.Generator) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Streams ``(frames (s, k) float32, truth count (s,))`` by kind."""
    d = rec.deltas.astype(np.float32)
    n, s = d.shape[:2]
    ones = np.ones(s, dtype=np.int64)
    pairs = list(itertools.combinations(range(n), 2))[::7]
    half = s // 2
    landing = np.r_[np.ones(half, dtype=np.int64), np.full(s - half, 2)]
    return {
        "single touches": [(d[a], ones) for a in range(n)],
        "two held": [(d[a] + d[b], 2 * ones) for a, b in pairs],
        "second lands": [
            (np.concatenate([d[a, :half], d[a, half:] + d[b, half:]]), landing) for a, b in pairs
        ],
        "three held": [
            (d[a] + d[b] + d[c], 3 * ones)
            for a, b, c in (rng.choice(n, 3, replace=False) for _ in range(40))
        ],
    }


def compare(eng, streams) -> dict[str, float]:
    """Frames whose count or positions (> 1 mm) change, who was right where counts differ, and
    the frames the memory answered (the others were searched in full)."""
    n = n_count = n_pos = old_right = new_right = n_memory = 0
    for X, truth in streams:
        mem = SearchMemory()
        for x, tr in zip(X, truth, strict=True):
            a = eng.contacts(x, 3).rows.copy()
            since = mem.state[MEM_FRAMES]
            b = eng.contacts(x, 3, mem).rows
            n += 1
            n_memory += mem.state[MEM_VALID] == 1.0 and mem.state[MEM_FRAMES] == since + 1
            if len(a) != len(b):
                n_count += 1
                old_right += int(len(a) == tr)
                new_right += int(len(b) == tr)
            elif len(a) and np.abs(a[:, :3] - b[:, :3]).max() > 1e-3:
                n_pos += 1
    return {
        "frames": n,
        "answered_by_the_memory": int(n_memory),
        "count_changed": n_count,
        "count_changed_share": n_count / max(n, 1),
        "positions_changed_1mm": n_pos,
        "changed_right_before": old_right,
        "changed_right_after": new_right,
    }


def pipeline_ab(eng, frames: np.ndarray) -> dict[str, float]:
    """``SkinCore`` with and without the memory on the same frames and timestamps."""
    from skinloc.live.core import PipelineConfig, SkinCore

    outs = []
    for use in (False, True):
        core = SkinCore(eng, PipelineConfig(max_contacts=3), wire_format="binary")
        if not use:
            core.search_memory = None
        outs.append([core.process_frame(f, 0.01 * i, i) for i, f in enumerate(frames)])
    n = n_count = n_pos = extra_before = extra_after = 0
    for a, b in zip(*outs, strict=True):
        if not a and not b:
            continue
        n += 1
        extra_before += len(a) > 1  # every touch of this stream is one finger
        extra_after += len(b) > 1
        if len(a) != len(b):
            n_count += 1
        elif any(
            np.linalg.norm(np.subtract(p.position_m, q.position_m)) > 1e-3
            for p, q in zip(a, b, strict=True)
        ):
            n_pos += 1
    return {
        "frames_with_contacts": n,
        "count_changed": n_count,
        "positions_changed_1mm": n_pos,
        "frames_with_two_or_more_before": extra_before,
        "frames_with_two_or_more_after": extra_after,
    }


def timing(eng, X: np.ndarray, rounds: int) -> dict[str, dict[str, float]]:
    """``contacts`` per frame: K = 1, K = 3 in full, K = 3 with the memory; interleaved."""
    lat: dict[str, list[float]] = {"K=1": [], "K=3 full": [], "K=3 memory": []}
    pc = time.perf_counter
    for _ in range(rounds):
        for label in lat:
            k = 1 if label == "K=1" else 3
            mem = SearchMemory() if label == "K=3 memory" else None
            n_memory = 0
            for x in X:
                since = -1.0 if mem is None else mem.state[MEM_FRAMES]
                t0 = pc()
                eng.contacts(x, k, mem)
                lat[label].append(pc() - t0)
                n_memory += (
                    mem is not None
                    and mem.state[MEM_VALID] == 1.0
                    and mem.state[MEM_FRAMES] == since + 1
                )
    res: dict = {"answered_by_the_memory_share": n_memory / max(len(X), 1)}
    base = np.array(lat["K=1"]) * 1e6
    for label, v in lat.items():
        a = np.array(v) * 1e6
        res[label] = {
            "median_us": float(np.median(a)),
            "p99_us": float(np.percentile(a, 99)),
            "median_over_k1": float(np.median(a) / np.median(base)),
            "p99_over_k1": float(np.percentile(a, 99) / np.percentile(base, 99)),
        }
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--train", default="ConeSkinData80Points_RND_80PL_1.mat")
    ap.add_argument("--test", default="ConeSkinData50Points_RND_50PL_1.mat")
    ap.add_argument("--frames", type=int, default=20000, help="simulated stream's frames")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--models", type=Path, default=Path("/tmp/skinloc-bench-search-memory"))
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    for f in (args.train, args.test):
        if not (args.data / f).is_file():
            raise SystemExit(f"error: no such recording: {args.data / f}")

    from skinloc.bench.online import touch_stream, train_bench_models
    from skinloc.live.core import PipelineConfig, SkinCore
    from skinloc.models.engine import load_engine

    res: dict[str, object] = {"machine": f"{platform.machine()}, {platform.python_version()}"}
    eng = train_localizer([read_recording(args.data / args.train)]).engine().warm_up()
    streams = real_streams(read_recording(args.data / args.test), np.random.default_rng(0))
    res["real"] = {kind: compare(eng, s) for kind, s in streams.items()}
    print(json.dumps(res["real"], indent=1))

    sim = load_engine(train_bench_models(args.models, ("default",))["default"]).warm_up()
    frames, _ = touch_stream(args.frames, random_state=0)
    res["simulated_pipeline"] = pipeline_ab(sim, frames)
    print(json.dumps(res["simulated_pipeline"], indent=1))
    # the touched frames the pipeline searches, in order, for the timing
    seen: list[np.ndarray] = []
    core = SkinCore(sim, PipelineConfig(max_contacts=3), wire_format="binary")
    orig = sim.contacts

    def spy(x, max_contacts=3, memory=None):
        seen.append(np.array(x, dtype=np.float32))
        return orig(x, max_contacts, memory)

    sim.contacts = spy
    for i, f in enumerate(frames):
        core.process_frame(f, 0.01 * i, i)
    del sim.contacts
    res["timing_simulated"] = timing(sim, np.array(seen), args.rounds)
    res["timing_simulated"]["frames"] = len(seen)
    print(json.dumps(res["timing_simulated"], indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
