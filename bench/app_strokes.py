"""Quick mouse strokes on the app's simulated skin: how many are swipes, how many tracks split.

The app's path for a mouse drag on the Live page, without the browser: a session of
``--points`` scripted touches is calibrated and trained on the simulated skin (``--seed``),
the live view runs, and ``--strokes`` strokes of ``--length`` mm in ``--duration`` s (18 mouse
points, sent in pieces of three every 50 ms as the page sends them, played on the page's clock
by ``PageClock``) are drawn between random points of the mesh. Each should be one track and one
swipe. Printed per stroke: the gestures, the track ids, and for a split stroke each contact.

    python bench/app_strokes.py --seed 0 --strokes 10
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=0, help="simulated skin's seed")
    p.add_argument("--points", type=int, default=24, help="calibration touches")
    p.add_argument("--strokes", type=int, default=10)
    p.add_argument("--length", type=float, default=75.0, help="stroke length, mm")
    p.add_argument("--duration", type=float, default=0.3, help="stroke duration, s")
    p.add_argument("--verbose", action="store_true", help="print a split stroke's contacts")
    args = p.parse_args(argv)
    from skinloc.app.server import create_app
    from skinloc.app.workspace import AppConfig
    from skinloc.sources.base import SourceOptions

    def wait(check, what: str, timeout_s: float = 600.0) -> None:
        end = time.monotonic() + timeout_s
        while not check():
            if time.monotonic() > end:
                raise SystemExit(f"timed out waiting for {what}")
            time.sleep(0.05)

    app = create_app(AppConfig(data_dir=Path(tempfile.mkdtemp()), finger_delay_s=0.15))
    ws = app.state.workspace
    ws.connect(SourceOptions(source="sim", seed=args.seed))
    ws.create_session("strokes", n_points=args.points, samples=10, baseline_frames=20)
    ws.set_finger(True)  # the scripted finger presses every target
    ws.start_calibration()
    wait(lambda: ws.message == "calibration complete", "calibration")
    ws.set_finger(False)
    ws.train()
    wait(lambda: ws.training and not ws.training.get("running"), "training", 300)
    gestures: list[dict] = []
    log: list[tuple] = []
    sink = ws.live_sink
    emit_gesture, emit_contacts = sink.emit_gesture, sink.emit_contacts

    def on_gesture(skin, t, event):
        gestures.append(event)
        return emit_gesture(skin, t, event)

    def on_contacts(skin, t, contacts):
        for c in contacts:
            pos = np.round(np.asarray(c.position_m) * 1e3, 0).tolist()
            log.append((round(t, 3), c.state, c.track_id, c.touch_id, pos))
        return emit_contacts(skin, t, contacts)

    sink.emit_gesture, sink.emit_contacts = on_gesture, on_contacts
    ws.start_live()
    wait(lambda: ws.mode.value == "live" and ws.detector is not None, "live")
    time.sleep(1.0)
    vertices = ws.active.mesh.vertices
    rng = np.random.default_rng(1)
    lo, hi = (args.length - 5) * 1e-3, (args.length + 5) * 1e-3
    swipes = whole = 0
    for k in range(args.strokes):
        g0, l0 = len(gestures), len(log)
        while True:
            a, b = vertices[rng.integers(len(vertices))], vertices[rng.integers(len(vertices))]
            if lo < np.linalg.norm(a - b) < hi:
                break
        times = np.linspace(0.0, args.duration, 18)
        t0 = 1000.0 + 10.0 * k
        path = [(t0 + t, (a + (b - a) * t / args.duration).tolist()) for t in times]
        path.append((t0 + args.duration + 0.02, None))
        for i in range(0, len(path), 3):
            ws.sim_path(path[i : i + 3])
            time.sleep(0.05)
        time.sleep(1.5)
        kinds = [g["kind"] for g in gestures[g0:]]
        ids = sorted({row[2] for row in log[l0:] if row[1] == "start"})
        swipes += kinds == ["swipe"]
        whole += len(ids) == 1
        print(f"stroke {k}: gestures {kinds}, tracks {ids}", flush=True)
        if args.verbose and len(ids) > 1:
            for row in log[l0:]:
                print("    ", row)
    ws.stop()
    print(f"{swipes} of {args.strokes} strokes one swipe; {whole} one track")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
