"""The simulated skin through the real firmware: `skinloc collect`, `train` and `run` on the
emulated board, against the same skin read without the firmware.

The emulated controller serves the frames of a ``SimulatedSkin``; skinloc reads the board's
pseudo-terminal as it reads a real board. The firmware must carry every count exactly (a frame
recorded through it is one the skin produced, bit for bit), lose no frame it sent (the binary
counters), and localise as the direct path does (the same frames replayed without the firmware
give the same contacts).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from skinloc.sim.emulated_board import EmulatedBoard
from skinloc.sim.skin import SimulatedSkin

SKINLOC = [sys.executable, "-m", "skinloc"]
#: Length of the live run, s (the issue asks for 60 s).
RUN_S = float(os.environ.get("SKINLOC_FW_RUN_S", "60"))


def skinloc(*args: str, board: EmulatedBoard | None = None) -> subprocess.CompletedProcess[str]:
    """Run a skinloc command; on failure, say what it and the board (stopped then) reported."""
    env = {**os.environ, "COLUMNS": "250"}  # rich wraps its lines at the terminal's width
    res = subprocess.run([*SKINLOC, *args], capture_output=True, text=True, check=False, env=env)
    if res.returncode != 0 and board is not None:
        stats = board.stop()
        res.stderr += f"\nboard: {stats}"
    assert res.returncode == 0, f"skinloc {' '.join(args)}:\n{res.stdout[-2000:]}\n{res.stderr}"
    return res


def counters(stats_line: str) -> dict[str, int]:
    """The counters of the stats line skinloc prints after a session."""
    pairs = re.findall(r"(received|dropped|corrupted|lost|overflow|reconnects) (\d+)", stats_line)
    return {k: int(v) for k, v in pairs}


class Taps:
    """A hand on the skin's own clock: a tap every second at the next target, from 2 s on."""

    def __init__(self, targets: np.ndarray) -> None:
        self.targets = targets
        self.k = -1
        self.truth: list[tuple[float, np.ndarray]] = []

    def __call__(self, skin: SimulatedSkin) -> None:
        t = skin.time_s - 2.0
        if t < 0:
            return
        k, phase = int(t), t - int(t)
        if phase < 0.4 and k != self.k:
            self.k = k
            target = self.targets[k % len(self.targets)]
            contact = skin.touch_near(target, rng=np.random.default_rng(k))
            self.truth.append((skin.time_s, contact))
        elif phase >= 0.4 and skin.contact is not None:
            skin.release()


@pytest.fixture(scope="module")
def calibration(fw_build, tmp_path_factory):
    """A 20-touch `skinloc collect` on the emulated board, and the frames the skin served."""
    out = tmp_path_factory.mktemp("collect") / "cal.h5"
    board = EmulatedBoard(fw_build, SimulatedSkin(random_state=0), keep_frames=True)
    board.start()
    try:
        res = skinloc(
            "collect",
            "--port",
            board.path,
            "--baud",
            "1000000",
            "--points",
            "20",
            "--scripted-finger",
            "--samples",
            "10",
            "--baseline-frames",
            "20",
            "--out",
            str(out),
            board=board,
        )
    finally:
        stats = board.stop()
    served = list(board.served)
    return out, res, stats, served


def test_collect_on_the_emulated_board(calibration):
    out, res, stats, served = calibration
    assert "20/20 point logs (complete)" in res.stdout
    c = counters(res.stderr)
    assert c["received"] > 200
    assert c["dropped"] == c["corrupted"] == c["lost"] == c["overflow"] == 0, res.stderr
    assert stats["fault"] == "none" and stats["finger_lines"] == 40, stats
    # every frame in the recording is one the simulated skin produced, bit for bit
    from skinloc.data.recording import read_recording

    rec = read_recording(out)
    served_set = {f.tobytes() for f in served}
    stored = np.concatenate([rec.baseline_frames.reshape(-1, 64), rec.frames.reshape(-1, 64)])
    assert len(stored) >= 20 * 10 + 20
    missing = [f for f in stored if f.astype("<u2").tobytes() not in served_set]
    assert not missing, f"{len(missing)} recorded frames the skin never produced"


@pytest.fixture(scope="module")
def model(calibration, tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "model.h5"
    skinloc("train", str(calibration[0]), "--out", str(out))
    return out


@pytest.mark.slow  # a 60 s run on the emulated board
def test_run_on_the_emulated_board_localises_as_the_direct_path(
    calibration, model, fw_build, tmp_path
):
    """`skinloc run` on the board for RUN_S s; the same frames replayed without the firmware
    give the same contacts, and no frame the firmware sent is lost."""
    from skinloc.data.recording import read_recording
    from skinloc.sources.replay import write_stream_recording

    rec = read_recording(calibration[0])
    taps = Taps(np.asarray(rec.targets))
    board = EmulatedBoard(fw_build, SimulatedSkin(random_state=1), keep_frames=True, hand=taps)
    board.start()
    live = tmp_path / "live.jsonl"
    try:
        res = skinloc(
            "run",
            "--model",
            str(model),
            "--source",
            board.path,
            "--gain",
            "8",
            "--lines",
            "11111111,11111111",
            "--duration",
            f"{RUN_S:g}",
            "--filter",
            "none",
            "--no-gestures",
            "--max-contacts",
            "1",
            "--sink",
            f"jsonl:{live}",
            "--stats",
            "--emit-idle",
            "--no-wait",
            board=board,
        )
    finally:
        stats = board.stop()
    assert stats["fault"] == "none", stats
    counters_ = json.loads(res.stderr.strip().splitlines()[-1])[0]
    wire = counters_["wire"]
    assert wire["n_lost"] == wire["n_corrupted"] == wire["n_dropped"] == 0, wire
    n = counters_["frames"]
    assert n >= 100
    # served[0] is the firmware's trial scan at start-up; its frame k is served[k + 1]
    served = np.stack(board.served[1 : n + 1]).astype(np.float32)
    assert len(served) == n, "the board sent fewer frames than skinloc counted"

    # the live path's arrival times, so that both paths see the same time steps (drift
    # tracking and the touch level follow them)
    seen = [json.loads(x) for x in live.read_text().splitlines()]
    stamps = {int(d["index"]): float(d["timestamp_s"]) for d in seen if "event" not in d}
    known = np.array(sorted(stamps))
    times = np.interp(np.arange(n), known, [stamps[k] for k in known])
    replay = tmp_path / "served.h5"
    write_stream_recording(
        replay,
        n_tx=8,
        n_rx=8,
        mesh=rec.mesh,
        baseline_frames=served[:20],
        frames=served,
        times_s=times - times[0],
        index=np.arange(n, dtype=np.int64),
        meta={"source": "emulated board, served frames", "description": "direct path"},
    )
    direct = tmp_path / "direct.jsonl"
    skinloc(
        "run",
        "--model",
        str(model),
        "--source",
        str(replay),
        "--fast",
        "--filter",
        "none",
        "--no-gestures",
        "--max-contacts",
        "1",
        "--sink",
        f"jsonl:{direct}",
    )

    def contacts(path: Path) -> dict[int, np.ndarray]:
        out = {}
        for line in path.read_text().splitlines():
            d = json.loads(line)
            if "event" not in d and d["state"] != "idle" and None not in d["raw_m"]:
                out[int(d["index"])] = np.asarray(d["raw_m"], dtype=float)
        return out

    got, want = contacts(live), contacts(direct)
    assert len(taps.truth) >= 3 and len(want) > 0
    assert set(got) == set(want), (len(got), len(want))
    errs = {k: float(np.linalg.norm(got[k] - want[k])) for k in want}
    worst = max(errs, key=errs.get)
    assert errs[worst] < 1e-6, (
        f"contacts differ by up to {errs[worst] * 1e3:.3f} mm (frame {worst}; "
        f"{sum(e > 1e-6 for e in errs.values())} of {len(errs)} differ; "
        f"{sorted(k for k in errs if errs[k] > 1e-6)[:20]})"
    )
