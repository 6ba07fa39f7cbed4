"""Batch throughput and per-frame time of the engine against the plain NumPy implementation.

For each bench model (default map, mlp, paper; trained once and cached), 200,000 touched frames
of the simulated stream go through ``engine.predict_batch`` and through the plain NumPy baseline
of ``skinloc bench --online`` (the map's coarse-to-fine match in NumPy; a network's NumPy
forward pass and a scipy KD-tree snap), alternately, ``--repeat`` times. Printed per model: the
best frames/s of each, and the median over the repeats of each one's ratio to the NumPy run of
the same repeat (the machine is shared: a ratio within one repeat is what holds still), with
the load average before and after.

``--old FILE`` adds the fast path as it was before the engine (the ``inference.py`` of commit
780f4d6, e.g. ``git show 780f4d6:src/skinloc/inference.py``); ``--old-map FILE`` adds an
earlier ``map_engine.py`` (e.g. ``git show 7fd474a:src/skinloc/models/map_engine.py``) for the
map. Per frame: the median time of ``localise_into`` (the pipeline's call) over 3,000 touched
frames, best of ``--repeat``, each engine alternated.

    python bench/engine_batch.py --repeat 5 [--arch default] [--old-map /tmp/map_engine_old.py]
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import tempfile
import time
from pathlib import Path
from types import ModuleType

import numpy as np

from skinloc.bench.online import baseline_fn, touch_stream, train_bench_models
from skinloc.models.localizer import ContactLocalizer
from skinloc.models.map_engine import MapSpec


def _module(path: Path, name: str) -> ModuleType:
    """A module loaded from a file (an earlier version of an engine)."""
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses look their module up
    spec.loader.exec_module(mod)
    return mod


def _load() -> str:
    return "/".join(f"{v:.1f}" for v in os.getloadavg())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--arch", action="append", choices=("default", "mlp", "paper"))
    ap.add_argument("--old", type=Path, help="inference.py from before the engine")
    ap.add_argument("--old-map", type=Path, help="an earlier map_engine.py")
    ap.add_argument("--models", type=Path, default=Path(tempfile.gettempdir()) / "skinloc-bench")
    args = ap.parse_args()
    archs = tuple(args.arch or ("default", "mlp", "paper"))
    paths = train_bench_models(args.models / "online-models", archs)
    frames, _ = touch_stream(20000, random_state=0)
    deltas = frames[100:].astype(np.float64) - frames[:100].mean(axis=0)
    touched = deltas[np.max(deltas, axis=1) > 60][:5000].astype(np.float32)
    batch = np.tile(touched, (args.frames // len(touched) + 1, 1))[: args.frames]
    old_mod = _module(args.old, "old_inference") if args.old else None
    old_map = _module(args.old_map, "old_map_engine") if args.old_map else None
    for arch, path in paths.items():
        model = ContactLocalizer.load(path)
        engine = model.engine().warm_up()
        runs = {"engine": engine.predict_batch}
        plain = baseline_fn(model)
        runs["numpy"] = lambda X, plain=plain: plain(X.astype(np.float64))
        per_frame = {"engine": engine}
        if old_mod is not None:
            old = old_mod.FastLocalizer(old_mod.InferenceSpec.from_localizer(model)).warm_up()
            runs["before"] = per_frame["before"] = old
        spec = model.spec()
        if old_map is not None and isinstance(spec, MapSpec):  # an earlier map engine: maps
            runs["before"] = per_frame["before"] = old_map.MapEngine(spec).warm_up()
        runs = {k: getattr(v, "predict_batch", v) for k, v in runs.items()}
        load0 = _load()
        secs: dict[str, list[float]] = {k: [] for k in runs}
        for _ in range(args.repeat):
            for name, fn in runs.items():
                t0 = time.perf_counter()
                fn(batch)
                secs[name].append(time.perf_counter() - t0)
        t = {k: np.asarray(v) for k, v in secs.items()}
        rate = {k: len(batch) / v.min() for k, v in t.items()}
        ratio = {k: float(np.median(t["numpy"] / v)) for k, v in t.items() if k != "numpy"}
        frame_us = {k: np.inf for k in per_frame}
        out = np.empty(7)
        for _ in range(args.repeat):
            for name, e in per_frame.items():
                ts = np.empty(3000)
                for i, x in enumerate(touched[:3000]):
                    t0 = time.perf_counter()
                    e.localise_into(x, out)
                    ts[i] = time.perf_counter() - t0
                frame_us[name] = min(frame_us[name], 1e6 * float(np.median(ts)))
        line = ", ".join(f"{k} {v:,.0f} frames/s" for k, v in rate.items())
        ratios = ", ".join(f"{k}/numpy {v:.1f} (median)" for k, v in ratio.items())
        if "before" in t:
            ratios += f", engine/before {float(np.median(t['before'] / t['engine'])):.2f} (median)"
        frames_line = ", ".join(f"{k} {v:.2f} us" for k, v in frame_us.items())
        print(
            f"{arch}: best of {args.repeat}: {line}; {ratios}; per frame {frames_line}; "
            f"load average {load0} -> {_load()}"
        )


if __name__ == "__main__":
    main()
