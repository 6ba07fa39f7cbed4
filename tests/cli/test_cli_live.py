"""`skinloc run` and `skinloc export` through the CLI runner, error paths included."""

from __future__ import annotations

import json
import re
import signal
import socket
import sys

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from tests._live import model_path, stream_recording

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def test_help():
    for cmd in ("run", "export"):
        res = run(cmd, "--help")
        assert res.exit_code == 0 and "Example" in res.output
    assert "--online" in run("bench", "--help").output


def test_run_replays_a_recording_to_json_lines(tmp_path):
    out = tmp_path / "c.jsonl"
    res = run(
        "run", "--model", model_path("map"), "--source", stream_recording(), "--fast",
        "--sink", "jsonl", "--sink", f"jsonl:{out}", "--stats",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    lines = [json.loads(ln) for ln in res.stdout.splitlines() if ln.startswith("{")]
    assert lines and lines == [json.loads(ln) for ln in out.read_text().splitlines()]
    states = [c["state"] for c in lines if "event" not in c]  # gesture lines have "event"
    assert states.count("start") == states.count("end") > 3
    for key in ("timestamp_s", "position_m", "confidence", "state", "latency_us"):
        assert key in lines[0]


def test_run_writes_gesture_events_next_to_the_contacts(tmp_path):
    from tests._live import gesture_recording

    out = tmp_path / "g.jsonl"
    r = run(
        "run", "--model", model_path("map"), "--source", gesture_recording(), "--fast",
        "--sink", f"jsonl:{out}",
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    lines = [json.loads(ln) for ln in out.read_text().splitlines()]
    gestures = [d for d in lines if d.get("event") == "gesture"]
    assert [g["kind"] for g in gestures] == ["tap", "long_press", "swipe"]
    keys = {"event", "kind", "direction", "start_s", "end_s", "timestamp_s", "track_ids"}
    assert all(keys <= set(g) for g in gestures)
    assert {"path_m", "speed_m_s"} <= set(gestures[2])
    contacts = [d for d in lines if "event" not in d]
    assert contacts and all(d["slot"] == 0 and d["track_id"] >= 1 for d in contacts)
    # --max-contacts 1 and --no-gestures: today's single-contact stream, no gesture lines
    out1 = tmp_path / "one.jsonl"
    r = run(
        "run", "--model", model_path("map"), "--source", gesture_recording(), "--fast",
        "--sink", f"jsonl:{out1}", "--max-contacts", "1", "--no-gestures",
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    one = [json.loads(ln) for ln in out1.read_text().splitlines()]
    assert one and all("event" not in d and d["track_id"] == d["touch_id"] for d in one)
    r = run("run", "--model", model_path("map"), "--max-contacts", "0")
    assert r.exit_code != 0


def test_run_says_which_port_a_port_zero_server_got(tmp_path):
    res = run(
        "run", "--model", model_path("map"), "--source", stream_recording(), "--fast",
        "--sink", f"jsonl:{tmp_path / 'c.jsonl'}", "--sink", "ws://127.0.0.1:0",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    found = re.findall(r"serving contacts on ws://127\.0\.0\.1:(\d+)", res.output)
    assert len(found) == 1 and int(found[0]) > 0, res.output


def test_run_with_a_port_in_use_is_one_line(tmp_path):
    with socket.create_server(("127.0.0.1", 0)) as busy:
        port = busy.getsockname()[1]
        res = run(
            "run", "--model", model_path("map"), "--source", stream_recording(), "--fast",
            "--sink", f"ws://127.0.0.1:{port}",
        )  # fmt: skip
    assert res.exit_code == 1 and "Traceback" not in res.output
    assert res.output.strip() == (
        f"error: WebSocket sink cannot listen on 127.0.0.1:{port}: Address already in use"
    )


def test_run_with_a_skins_file(tmp_path):
    cfg = tmp_path / "skins.toml"
    cfg.write_text(
        f'[defaults]\nmodel = "{model_path("map")}"\nrealtime = false\n'
        f'[[skin]]\nname = "a"\nsource = "{stream_recording()}"\n'
        f'[[skin]]\nname = "b"\nsource = "{stream_recording()}"\n'
    )
    res = run("run", "--config", cfg, "--sink", f"jsonl:{tmp_path / 'o.jsonl'}")
    assert res.exit_code == 0, res.output
    skins = {json.loads(ln)["skin"] for ln in (tmp_path / "o.jsonl").read_text().splitlines()}
    assert skins == {"a", "b"}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("run",), "give --model"),
        (("run", "--model", "nope.h5"), "model not found"),
        (("run", "--model", "MAP", "--source", "sim", "--sink", "pigeon"), "unknown sink"),
        (("run", "--model", "MAP"), "--source sim"),
        (
            ("run", "--model", "MAP", "--source", "/dev/ttyNOPE0", "--no-wait"),
            "cannot open serial port /dev/ttyNOPE0: no such device",
        ),
        (("run", "--model", "MAP", "--source", "/dev/null"), "/dev/null: not a serial port"),
        (("run", "--model", "MAP", "--source", "/dev"), "is not a serial port"),
        (("run", "--model", "MAP", "--source", "socket://127.0.0.1:9"), "--allow-url"),
        (("run", "--model", "MAP", "--config", "x.toml"), "not both"),
        (("run", "--config", "missing.toml"), "skins file not found"),
        (("export", "MAP"), "nothing to do"),
        (("export", "MAP", "--c-header", "x.h"), "too big for a microcontroller"),
        (("export", "nope.h5", "--onnx", "x.onnx"), "model not found"),
    ],
)
def test_errors_are_one_line(args, message, tmp_path):
    args = [model_path("map") if a == "MAP" else a for a in args]
    args = [tmp_path / a if str(a).endswith((".h", ".onnx", ".toml")) else a for a in args]
    res = run(*args)
    assert res.exit_code == 1
    assert message in res.output
    assert "Traceback" not in res.output


def test_export_writes_both(tmp_path):
    res = run(
        "export", model_path("paper"), "--onnx", tmp_path / "m.onnx", "--c-header",
        tmp_path / "m.h", "--prefix", "arm",
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    assert (tmp_path / "m.onnx").stat().st_size > 0
    assert "arm_predict" in (tmp_path / "m.h").read_text()


@pytest.mark.slow  # a multi-process benchmark
def test_online_bench_functions_run_small():
    from skinloc.bench.online import many_skins, single_stream

    r = single_stream(model_path("map"), n_frames=600, batch_rows=5000)
    assert r["frames"] == 500 and r["touched_frames"] > 0 and r["speedup_median"] > 0
    m = many_skins(model_path("map"), n_skins=3, rate_hz=50.0, duration_s=2.0)
    assert m["frames_sent"] == 300 and m["frames_dropped"] == 0
    assert m["parser_dropped_or_lost"] == 0


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_one_ctrl_c_stops_run_even_where_python_drops_exceptions(tmp_path, monkeypatch):
    """A Ctrl-C handled inside a destructor still stops ``skinloc run``.

    Python drops an exception raised in a destructor or a weakref callback ("Exception
    ignored"), and on a loaded machine a signal may be handled anywhere in the loop's work: the
    handler must ask the loop to stop, not raise. After the Ctrl-C the run may finish the turn
    it is in (a few frames), never hundreds more.
    """
    from skinloc.live.sinks.jsonl import JsonLinesSink

    class Dropped:
        def __del__(self) -> None:
            signal.raise_signal(signal.SIGINT)  # handled right here, inside the destructor

    emitted: list[int] = []
    emit = JsonLinesSink.emit

    def counting_emit(self, contact) -> None:
        emitted.append(1)
        if len(emitted) == 20:
            Dropped()  # freed at once
        if len(emitted) > 20 + 500:
            raise AssertionError("skinloc run went on after one Ctrl-C")
        emit(self, contact)

    monkeypatch.setattr(JsonLinesSink, "emit", counting_emit)
    out = tmp_path / "c.jsonl"
    # pytest started in the background has SIGINT ignored, which skinloc rightly keeps
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        res = run("run", "--model", model_path("map"), "--source", "sim", "--emit-idle",
                  "--sink", f"jsonl:{out}", "--duration", "600")  # fmt: skip
    finally:
        signal.signal(signal.SIGINT, before)
    assert res.exit_code == 0, res.output
    assert "went on after" not in res.output and "skin: " in res.output  # the summary
    assert 20 <= len(emitted) <= 20 + 500


def test_run_needs_a_source_the_simulator_only_when_asked(tmp_path):
    """No --source (or a skins file's skin without one) fed the simulator to the sinks."""
    from tests._helpers import one_line_error

    out = tmp_path / "c.jsonl"
    stop = ("--duration", "2")  # before, each ran the simulator; now none starts
    res = run("run", "--model", model_path("map"), "--sink", f"jsonl:{out}", *stop)
    one_line_error(res, "give --source", "--source sim")
    cfg = tmp_path / "skins.toml"
    cfg.write_text(f'[[skin]]\nname = "arm"\nmodel = "{model_path("map")}"\n')
    res = run("run", "--config", cfg, "--sink", f"jsonl:{out}", *stop)
    one_line_error(res, str(cfg), "skin 'arm' has no source", 'source = "sim"', "--source sim")
    assert not out.exists()  # nothing reached a sink
    res = run("run", "--config", cfg, "--source", "sim", "--sink", f"jsonl:{out}", *stop)
    one_line_error(res, "--source", "--config")


@pytest.mark.parametrize(
    ("line", "needles"),
    [
        ('realtime = "no"', ("realtime must be true or false", "'no'")),
        ('loop = "yes"', ("loop must be true or false", "'yes'")),
        ('baud = "fast"', ("baud must be a whole number", "'fast'")),
        ("baud = 12.5", ("baud must be a whole number", "12.5")),
        ('wire_format = "morse"', ("wire_format must be one of auto, binary, text", "'morse'")),
        ("rate_hz = -1", ("rate_hz must be a number", "-1")),
        ('n_tx = "8"', ("n_tx must be a whole number", "'8'")),
        ('pipeline = { drift_tracking = "no" }', ("drift_tracking must be true or false", "'no'")),
        ("pipeline = { touch_on_z = true }", ("touch_on_z must be a number", "True")),
        ("name = 3", ("name must be a non-empty text", "3")),
        ('sinks = ["jsonl", 3]', ("sinks must be a list of strings",)),
    ],
)
def test_a_skins_file_value_of_the_wrong_type_is_one_line_naming_file_key_and_value(
    tmp_path, line, needles
):
    from tests._helpers import one_line_error

    cfg = tmp_path / "skins.toml"
    cfg.write_text(f'[[skin]]\nmodel = "{model_path("map")}"\nsource = "sim"\n{line}\n')
    sink = f"jsonl:{tmp_path / 'o.jsonl'}"
    res = run("run", "--config", cfg, "--sink", sink, "--duration", "2")  # before: it ran
    one_line_error(res, str(cfg), *needles)


def test_fast_and_loop_apply_to_every_skin_of_a_skins_file(tmp_path, monkeypatch):
    """``--fast`` (and ``--loop``) were ignored with ``--config``: the replays kept real time."""
    from skinloc.live.runner import Runner

    seen: list[tuple[str, bool, bool]] = []

    def fake_run(self, duration_s=None) -> int:
        seen.extend((s.name, s.realtime, s.loop) for s in self.skins)
        return 0

    monkeypatch.setattr(Runner, "run", fake_run)
    cfg = tmp_path / "skins.toml"
    cfg.write_text(
        f'[defaults]\nmodel = "{model_path("map")}"\nsource = "{stream_recording()}"\n'
        '[[skin]]\nname = "a"\n[[skin]]\nname = "b"\nrealtime = false\n'
    )
    sink = f"jsonl:{tmp_path / 'o.jsonl'}"
    assert run("run", "--config", cfg, "--sink", sink).exit_code == 0
    assert seen == [("a", True, False), ("b", False, False)]  # the file's own settings
    seen.clear()
    res = run("run", "--config", cfg, "--sink", sink, "--fast", "--loop")
    assert res.exit_code == 0, res.output
    assert seen == [("a", False, True), ("b", False, True)]


def test_run_ends_when_the_reader_of_its_stdout_goes_away():
    """``skinloc run ... | head``: a sink's closed stdout ends the run (no sink back-off)."""
    import subprocess

    from tests._helpers import start_skinloc, wait_until

    proc = start_skinloc("run", "--model", model_path("map"), "--source", "sim",
                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        assert proc.stdout.readline().startswith(b"{")  # a contact line
        proc.stdout.close()  # the reader goes away
        wait_until(lambda: proc.poll() is not None, "skinloc run to end", 60.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
