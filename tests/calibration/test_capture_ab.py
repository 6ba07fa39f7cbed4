"""A/B: the one calibration capture records what the two captures before it recorded.

The same simulated skins, seeds and scripted touches go through the session that ``skinloc
simulate`` runs, the one ``skinloc collect --source sim`` runs (stopped after 3 touches and
resumed on a fresh source, as the command does), and the app's guided capture driven frame
by frame (a retake, an undo and a skip on the way). ``capture_golden.json`` holds what the
code before the capture was one (commit 8521230: ``calibration/session.py``'s pull loop and
``app/capture.py``'s state machine rewriting the whole file on every touch) recorded:
``python tests/calibration/test_capture_ab.py`` with that code on ``PYTHONPATH`` writes it.
Each recording must match it: the same targets, plan, frames (float tolerance), frame
times, baseline and meta (but its time stamps and version).
"""

from __future__ import annotations

import json
import sys
import types
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from skinloc.calibration.session import (
    CalibrationSession,
    ScriptedFinger,
    SessionConfig,
    simulate_session,
)
from skinloc.data.recording import Recording, read_recording
from skinloc.geometry.mesh import cone_skin
from skinloc.sim.skin import SimulatedSkin

GOLDEN = Path(__file__).with_name("capture_golden.json")
#: Meta that differs from run to run.
STAMPS = ("created", "modified", "skinloc_version")


def digest(rec: Recording) -> dict[str, Any]:
    """What a recording holds, compactly: enough to tell two recordings apart."""
    frames = rec.frames.astype(np.float64)
    return {
        "targets": rec.targets.tolist(),
        "planned": None if rec.planned_targets is None else rec.planned_targets.tolist(),
        "frames_sum": frames.sum(axis=(1, 2)).tolist(),
        "frames_weighted": (frames * np.arange(frames.shape[-1])).sum(axis=(1, 2)).tolist(),
        "frames_first": frames[:, :, :3].tolist(),
        "times": None if rec.frame_times is None else rec.frame_times.tolist(),
        "baseline_sum": float(rec.baseline_frames.astype(np.float64).sum()),
        "meta": {k: v for k, v in rec.meta.items() if k not in STAMPS},
    }


def simulated(tmp: Path) -> Recording:
    """``skinloc simulate``'s session: a 6x5 skin, seed 1; targets and touches seed 2."""
    mesh = cone_skin()
    skin = SimulatedSkin(mesh, n_tx=6, n_rx=5, random_state=1)
    cfg = SessionConfig(n_points=8, samples_per_touch=5, n_baseline_frames=10, random_state=2)
    simulate_session(skin, mesh, tmp / "sim.h5", cfg)
    return read_recording(tmp / "sim.h5")


def collected(tmp: Path) -> Recording:
    """``skinloc collect --source sim``'s session: 3 touches, then resumed on a new source."""
    mesh, out, seed = cone_skin(), tmp / "col.h5", 4
    cfg = SessionConfig(n_points=6, samples_per_touch=5, n_baseline_frames=10, random_state=seed)
    for run in range(2):
        src = SimulatedSkin(mesh, random_state=seed)
        with src:
            if run == 0:
                session = CalibrationSession(src, mesh, out, cfg)
                session.capture_baseline()
            else:
                session = CalibrationSession.resume(src, out)
            finger = ScriptedFinger(src, random_state=seed + 1 + session.n_done, move_time_s=1.0)
            stop = 3 if run == 0 else len(session.targets)
            while session.n_done < stop:
                session.record_point(session.n_done, finger)
            session.close()
    return read_recording(out)


def guided(tmp: Path) -> Recording:
    """The app's guided capture on the simulated skin, fed frame by frame (no threads)."""
    import skinloc.app.workspace.finger as finger_module
    from skinloc.app.device import DeviceLink
    from skinloc.app.hub import Hub
    from skinloc.app.workspace.core import Workspace
    from skinloc.app.workspace.state import AppConfig
    from skinloc.sources.base import SourceOptions

    clock = finger_module.time
    finger_module.time = types.SimpleNamespace(time=lambda: 7.0)  # the finger's seed
    try:
        ws = Workspace(AppConfig(data_dir=tmp / "app", finger_delay_s=0.0), Hub())
        ws.create_session("ab", n_points=6, samples=5, baseline_frames=10, seed=3)
        link = DeviceLink(SourceOptions(source="sim", seed=5), ws.on_frame, mesh=ws.active.mesh)
        link.source.realtime = False
        link.source.connect()
        ws.device = link

        def until(done) -> None:
            for _ in range(5000):
                if done():
                    return
                while link._jobs:  # the baseline capture, run where the reader would run it
                    job, fut = link._jobs.popleft()
                    fut.set_result(job(link.source))
                ws.on_frame(link.source.read(), link)
            raise AssertionError(f"the capture is stuck: {ws.message}")

        def n_done() -> int:
            rec = ws.active.cal.recording if ws.active.cal is not None else None
            return -1 if rec is None else rec.n_point_logs

        ws.start_calibration()
        until(lambda: n_done() == 0)
        ws.set_finger(True)
        until(lambda: n_done() >= 3)
        ws.retake(1)
        until(lambda: n_done() >= 4)
        ws.undo()
        until(lambda: n_done() >= 4)
        ws.skip()
        until(lambda: ws.message == "calibration complete")
        link.source.disconnect()
        return read_recording(ws.active.folder.calibration)
    finally:
        finger_module.time = clock


CASES = {"simulate": simulated, "collect": collected, "app": guided}


def assert_same(got: Any, want: Any, where: str) -> None:
    """``got`` equals ``want`` (JSON-like), numbers within float tolerance."""
    if isinstance(want, dict):
        assert isinstance(got, dict) and got.keys() == want.keys(), where
        for k in want:
            assert_same(got[k], want[k], f"{where}.{k}")
    elif isinstance(want, list):
        assert isinstance(got, list) and len(got) == len(want), where
        if want and all(isinstance(w, int | float) or w is None for w in np.ravel(want)):
            np.testing.assert_allclose(
                np.asarray(got, dtype=float),
                np.asarray(want, dtype=float),
                rtol=1e-6,
                atol=1e-9,
                err_msg=where,
            )
        else:
            for i, (g, w) in enumerate(zip(got, want, strict=True)):
                assert_same(g, w, f"{where}[{i}]")
    elif isinstance(want, float):
        assert got == pytest.approx(want, rel=1e-6, abs=1e-9), where
    else:
        assert got == want, where


#: What the app keeps per touch since the golden was written (issue 33): each touch's target
#: number and attempt, whether it is left out, and the numbers' bookkeeping.
NEW_APP_META = ("target_numbers", "attempts", "left_out", "numbers_used", "next_numbers")


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_capture_records_what_the_old_captures_recorded(case, tmp_path):
    want = json.loads(GOLDEN.read_text())[case]
    got = json.loads(json.dumps(digest(CASES[case](tmp_path))))
    added = {
        k: got["meta"].get("app", {}).pop(k)
        for k in NEW_APP_META
        if k in got["meta"].get("app", {})
    }
    assert_same(got, want, case)
    if case == "app":
        # 3 touches, #2 retaken (its 2nd attempt), #4, #4 undone and touched again, #5 skipped
        # (its number not given to another), #6.
        assert added == {
            "target_numbers": [1, 3, 2, 4, 6],
            "attempts": [1, 1, 2, 2, 1],
            "left_out": [False] * 5,
            "numbers_used": 6,
            "next_numbers": [],
        }


if __name__ == "__main__":  # write the golden from the skinloc on PYTHONPATH
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        golden = {name: digest(make(Path(d))) for name, make in CASES.items()}
    GOLDEN.write_text(json.dumps(golden, sort_keys=True) + "\n")
    sys.stderr.write(f"wrote {GOLDEN}\n")
