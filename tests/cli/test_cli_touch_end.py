"""No touch without an end: `skinloc run` stopped with a finger down ends it on the sinks.

One test per way out (end of a replay, ``--duration``, Ctrl-C, SIGTERM, a port lost beyond
``stale_s``), each with a jsonl sink and a touch held when the run stops; ``skinloc run`` is its
own process, as a user runs it. Every wait is bounded on what the test can observe and stretched
with the machine's load.
"""

from __future__ import annotations

import json
import signal
import subprocess
from pathlib import Path

import pytest

from skinloc.sim.virtual_device import VirtualSkin
from tests._helpers import start_skinloc, stop_and_wait, wait_until
from tests._live import held_recording, model_path


def _start(args: list[object], err: Path) -> subprocess.Popen:
    """``skinloc run --model MODEL ARGS`` as its own process, its stderr to ``err``."""
    with err.open("w") as fh:
        return start_skinloc(
            "run", "--model", model_path("map"), *args, stdout=subprocess.DEVNULL, stderr=fh
        )


def _poll(check, what: str, timeout_s: float, proc: subprocess.Popen, err: Path) -> None:
    """Poll ``check()`` (bounded, scaled by the load); fail with the run's stderr."""
    wait_until(check, lambda: f"{what}; skinloc run said: {err.read_text()[-2000:]}", timeout_s,
               proc=proc)  # fmt: skip


def _ended_cleanly(proc: subprocess.Popen, err: Path) -> None:
    text = err.read_text()
    assert proc.returncode == 0 and "Traceback" not in text, text[-2000:]


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def _contacts(out: Path) -> list[dict]:
    """The contact lines written so far (gesture lines have ``"event"``; a partial line waits)."""
    if not out.is_file():
        return []
    lines = out.read_text().split("\n")[:-1]
    return [d for d in map(json.loads, lines) if "event" not in d]


def _touched(out: Path) -> bool:
    return any(c["state"] == "start" for c in _contacts(out))


def _open_tracks(contacts: list[dict]) -> set[tuple[str, int]]:
    """``(skin, track id)`` of every track whose last contact is not an ``end``."""
    last = {(c["skin"], c["track_id"]): c["state"] for c in contacts}
    return {k for k, state in last.items() if state != "end"}


def _assert_every_touch_ended(out: Path) -> None:
    contacts = _contacts(out)
    starts = [c for c in contacts if c["state"] == "start"]
    assert starts, "the touch was never seen"
    assert not _open_tracks(contacts), f"tracks left open: {_open_tracks(contacts)}"
    ends = [c for c in contacts if c["state"] == "end"]
    assert {c["track_id"] for c in ends} == {c["track_id"] for c in starts}


def test_end_of_a_replay_that_stops_mid_touch(tmp_path):
    out, err = tmp_path / "out.jsonl", tmp_path / "err.txt"
    proc = _start(["--source", held_recording(0.5), "--fast", "--sink", f"jsonl:{out}"], err)
    try:
        _poll(lambda: proc.poll() is not None, "the end of the replay", 180.0, None, err)
    finally:
        _kill(proc)
    _ended_cleanly(proc, err)
    _assert_every_touch_ended(out)


@pytest.mark.slow  # skinloc run on the paced simulator
def test_duration_stops_with_the_finger_down(tmp_path):
    """The replay holds the touch for 300 s; ``--duration`` stops the run long before."""
    out, err = tmp_path / "out.jsonl", tmp_path / "err.txt"
    src = held_recording(300.0)
    proc = _start(["--source", src, "--duration", "10", "--sink", f"jsonl:{out}"], err)
    try:
        _poll(lambda: proc.poll() is not None, "the end of --duration", 180.0, None, err)
    finally:
        _kill(proc)
    _ended_cleanly(proc, err)
    _assert_every_touch_ended(out)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_a_signal_stops_the_run_with_the_finger_down(tmp_path, sig):
    out, err = tmp_path / "out.jsonl", tmp_path / "err.txt"
    proc = _start(["--source", held_recording(300.0), "--sink", f"jsonl:{out}"], err)
    try:
        _poll(lambda: _touched(out), "a touch", 120.0, proc, err)
        assert _open_tracks(_contacts(out))  # still touched when the signal comes
        stop_and_wait(proc, sig, "skinloc run")
    finally:
        _kill(proc)
    _ended_cleanly(proc, err)
    _assert_every_touch_ended(out)


def test_a_port_lost_with_the_finger_down_ends_the_touch(tmp_path):
    """The skin is unplugged mid-touch: its end comes after ``stale_s``, the run goes on."""
    out, err = tmp_path / "out.jsonl", tmp_path / "err.txt"
    dev = VirtualSkin(fmt="binary", rate_hz=100)  # the skin the recording's baseline is from
    dev.start()
    plugged = True
    try:
        dev.skin.press(dev.skin.sensor_positions[27], pressure=1.0, finger_radius_m=0.008)
        proc = _start(
            ["--source", dev.path, "--format", "binary", "--baseline", held_recording(0.5),
             "--sink", f"jsonl:{out}", "--duration", "600"],
            err,
        )  # fmt: skip
        try:
            _poll(lambda: _touched(out), "a touch", 120.0, proc, err)
            dev.stop()  # unplugged, the finger still on the skin
            plugged = False
            _poll(
                lambda: not _open_tracks(_contacts(out)), "end after the port went", 60.0, proc, err
            )
            stop_and_wait(proc, signal.SIGINT, "skinloc run")
        finally:
            _kill(proc)
        _ended_cleanly(proc, err)
    finally:
        if plugged:
            dev.stop()
    _assert_every_touch_ended(out)
