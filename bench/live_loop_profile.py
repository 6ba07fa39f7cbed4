"""Where the 100-skin loop's time goes, per frame: cProfile over ``many_skins`` (one process).

    PYTHONPATH=src python bench/live_loop_profile.py --max-contacts 3 1 --duration 8

Per setting, one run of ``skinloc.bench.many_skins.many_skins`` (no sink) with the profiler on
the loop's thread, timing in the thread's CPU time (not wall time, which the other processes on
the machine would inflate); every stage's cumulative time divided by the frames processed, µs. The
profiler inflates the cost of every Python call (not of the compiled kernels, one call each),
so the Python stages read high; the shares are what to compare. The loop falls behind under
the profiler: frames then arrive several per read, which flatters reading and selecting.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import tempfile
import time
from pathlib import Path

#: (label, file suffix, function): the loop's stages, outermost first
STAGES = [
    ("loop turn (Runner._step)", "live/runner.py", "_step"),
    ("wait for input (epoll)", "~", "<method 'poll' of 'select.epoll' objects>"),
    ("read the ptys (os.read)", "~", "<built-in method posix.read>"),
    ("parse frames (FrameParser.feed)", "hardware/framing.py", "feed"),
    ("one frame (SkinCore.process_frame)", "live/core.py", "process_frame"),
    ("contacts of a touched frame (Engine.contacts)", "models/engine.py", "contacts"),
    ("  the multi-contact search (search_into)", "models/multi_contact/search.py", "search_into"),
    ("  single-contact answer (_contact_one)", "models/map_engine.py", "_contact_one"),
    ("one contact, K = 1 (SkinCore._localise)", "live/core.py", "_localise"),
    ("  single-contact match (MapEngine.localise_into)", "models/map_engine.py", "localise_into"),
    ("tracking (Tracker.update)", "live/tracking.py", "update"),
    ("gestures (GestureRecognizer.update)", "live/gestures.py", "update"),
    ("deliver (Runner._emit)", "live/runner.py", "_emit"),
]


def _stage_times(stats: pstats.Stats) -> dict[str, float]:
    """Cumulative seconds per stage label (0 for stages that never ran)."""
    out = dict.fromkeys((s[0] for s in STAGES), 0.0)
    for (file, _line, func), (_cc, _nc, _tt, ct, _callers) in stats.stats.items():  # type: ignore[attr-defined]
        for label, suffix, name in STAGES:
            if func == name and file.endswith(suffix):
                out[label] += ct
    return out


def main() -> None:
    from skinloc.bench.many_skins import many_skins
    from skinloc.bench.online import train_bench_models

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--max-contacts", type=int, nargs="+", default=[3, 1], choices=(1, 2, 3))
    ap.add_argument("--skins", type=int, default=100)
    ap.add_argument("--duration", type=float, default=8.0, help="s per run")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    folder = Path(tempfile.gettempdir()) / "skinloc-bench" / "online-models"
    model = train_bench_models(folder, ("default",))["default"]
    res: dict = {"load_average_at_start": os.getloadavg(), "runs": {}}
    for k in args.max_contacts:
        prof = cProfile.Profile(time.thread_time)  # CPU time: robust to the machine's load
        prof.enable()
        r = many_skins(model, args.skins, 100.0, args.duration, max_contacts=k)
        prof.disable()
        n = max(r["frames_processed"], 1)
        per = {lab: s / n * 1e6 for lab, s in _stage_times(pstats.Stats(prof)).items()}
        res["runs"][f"K={k}"] = {
            "frames_sent": r["frames_sent"],
            "frames_processed": r["frames_processed"],
            "loop_cpu_us_per_frame_profiled": r["loop_cpu_us_per_frame"],
            "us_per_frame": per,
            "load_average_after": os.getloadavg(),
        }
        print(f"K={k}: {r['frames_processed']}/{r['frames_sent']} frames", flush=True)
        for lab, v in per.items():
            print(f"  {lab:48s} {v:8.1f} us/frame", flush=True)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
