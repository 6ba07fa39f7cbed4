"""Batch throughput and per-frame time of the engine against the plain NumPy implementation.

For each bench model (default map, mlp, paper; trained once and cached), 200,000 touched frames
of the simulated stream go through ``engine.predict_batch`` and through the plain NumPy baseline
of ``skinloc bench --online`` (the map's coarse-to-fine match in NumPy; a network's NumPy
forward pass and a scipy KD-tree snap), alternately, ``--repeat`` times; the best of each and
their ratio are printed. ``--old FILE`` adds the fast path as it was before the engine (the
``inference.py`` of commit 780f4d6, e.g. ``git show 780f4d6:src/skinloc/inference.py``) to the
same alternation. Per frame: the median time of ``localise_into`` (the pipeline's call) over
3,000 touched frames, best of ``--repeat``, engine and before alternated.

    python bench/engine_batch.py --repeat 5 [--old /tmp/old_inference.py]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from skinloc.live.bench import _baseline_fn, touch_stream, train_bench_models
from skinloc.models.localizer import ContactLocalizer


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--frames", type=int, default=200_000)
    ap.add_argument("--old", type=Path, help="inference.py from before the engine")
    ap.add_argument("--models", type=Path, default=Path(tempfile.gettempdir()) / "skinloc-bench")
    args = ap.parse_args()
    paths = train_bench_models(args.models / "online-models", ("default", "mlp", "paper"))
    frames, _ = touch_stream(20000, random_state=0)
    deltas = frames[100:].astype(np.float64) - frames[:100].mean(axis=0)
    touched = deltas[np.max(deltas, axis=1) > 60][:5000].astype(np.float32)
    batch = np.tile(touched, (args.frames // len(touched) + 1, 1))[: args.frames]
    old_mod = None
    if args.old:
        spec = importlib.util.spec_from_file_location("old_inference", args.old)
        old_mod = importlib.util.module_from_spec(spec)
        sys.modules["old_inference"] = old_mod  # dataclasses look their module up
        spec.loader.exec_module(old_mod)
    for arch, path in paths.items():
        model = ContactLocalizer.load(path)
        runs = {"engine": model.engine().warm_up().predict_batch}
        plain = _baseline_fn(model)
        runs["numpy"] = lambda X, plain=plain: plain(X.astype(np.float64))
        if old_mod is not None:
            old = old_mod.FastLocalizer(old_mod.InferenceSpec.from_localizer(model)).warm_up()
            runs["before"] = old.predict_batch
        best = {k: np.inf for k in runs}
        for _ in range(args.repeat):
            for name, fn in runs.items():
                t0 = time.perf_counter()
                fn(batch)
                best[name] = min(best[name], time.perf_counter() - t0)
        rate = {k: len(batch) / v for k, v in best.items()}
        per_frame = {"engine": model.engine()}
        if old_mod is not None:
            per_frame["before"] = old
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
        ratios = f"engine/numpy {rate['engine'] / rate['numpy']:.1f}"
        if "before" in rate:
            ratios += f", engine/before {rate['engine'] / rate['before']:.2f}"
        frames_line = ", ".join(f"{k} {v:.2f} us" for k, v in frame_us.items())
        print(f"{arch}: {line}; {ratios}; per frame {frames_line}")


if __name__ == "__main__":
    main()
