"""The runner: Pipeline as an iterator and with a callback, ports, replay, many skins, config."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from skinloc.errors import SkinlocError
from skinloc.live.core import PipelineConfig
from skinloc.live.runner import Pipeline, Runner, SkinConfig
from skinloc.live.sinks import ListSink
from skinloc.live.skins_file import load_skins, runner_from_config
from tests._helpers import wait_until
from tests._live import model_path, stream_recording


def _threads() -> set[str]:
    return {t.name for t in threading.enumerate()}


def assert_no_thread_left(before: set[str]) -> None:
    """Every thread started since ``before`` ends (a joined thread may take a moment to go)."""
    wait_until(lambda: _threads() <= before, f"threads to end: {_threads() - before}", 30.0)


def test_pipeline_iterates_and_leaves_no_thread():
    before = _threads()
    with Pipeline(model_path("map"), "sim", realtime=False) as pipeline:
        contacts = []
        for c in pipeline:
            contacts.append(c)
            if len(contacts) >= 60:
                break
    assert {c.state for c in contacts} >= {"start", "move"}
    assert all(c.skin == "skin" for c in contacts)
    assert_no_thread_left(before)


def test_pipeline_callback_mode_and_close():
    before = _threads()
    got = []
    pipeline = Pipeline(model_path("map"), "sim", realtime=False, sinks=[ListSink()])
    pipeline.start(got.append)
    wait_until(lambda: len(got) >= 30, "30 contacts", 60.0)
    pipeline.close()
    assert len(got) >= 30
    assert (
        pipeline.global_sinks[0].contacts[: len(got)]
        == got[: len(pipeline.global_sinks[0].contacts)]
    )
    assert_no_thread_left(before)
    pipeline.close()  # idempotent


def test_a_turn_ends_though_a_fast_source_keeps_the_queue_full():
    """A source faster than the loop (the simulated skin unpaced, a replay ``--fast``) refills
    the queue while a turn drains it; a turn takes only what was queued when it began, so the
    loop comes back to its deadline (``run --fast --duration 2`` on the simulated skin ran for
    40 s before). The loop is slowed here so that the source is the faster one on any machine."""
    pipeline = Pipeline(model_path("map"), "sim", realtime=False)
    core = pipeline.cores[0]
    process, end_turn = core.process_frame, pipeline._end_turn
    turns = [0]

    def slow_process(*args):
        turns[-1] += 1
        if turns[-1] == 2000:  # the turn would never end: stop the source, fail below
            pipeline.stop()
        time.sleep(0.0002)
        return process(*args)

    def count_turn():
        turns.append(0)
        end_turn()

    core.process_frame = slow_process
    pipeline._end_turn = count_turn
    with pipeline:
        pipeline.run(0.5)
    assert sum(turns) > 0
    assert max(turns) < 2000, f"one turn took {max(turns)} frames"


def test_replay_runs_to_the_end_and_ends_open_touches():
    sink = ListSink()
    with Pipeline(model_path("map"), str(stream_recording()), realtime=False, sinks=[sink]) as p:
        n = sum(1 for _ in p)
    states = [c.state for c in sink.contacts]
    assert n == len(states) > 0
    assert states.count("start") == states.count("end")
    assert p.stats()[0]["frames"] == 1500


def test_close_with_a_finger_down_ends_every_track_before_the_sinks_close():
    """A program's ``close`` mid-touch (the path of Ctrl-C, SIGTERM and ``--duration``)."""
    from tests._live import held_recording

    class Closing(ListSink):
        def close(self) -> None:
            self.closed_after = len(self.contacts)

    sink, got = Closing(), []
    pipeline = Pipeline(model_path("map"), str(held_recording(300.0)), sinks=[sink])
    pipeline.start(got.append)
    try:
        wait_until(lambda: any(c.state == "move" for c in got), "a held touch")
    finally:
        pipeline.close()
    last = {c.track_id: c.state for c in sink.contacts}
    assert last and set(last.values()) == {"end"}
    assert sink.closed_after == len(sink.contacts)  # the ends came before the sink closed
    assert got == sink.contacts  # the callback gets them as well
    pipeline.close()  # idempotent: no second end
    assert len(sink.contacts) == sink.closed_after


class _TurnSink(ListSink):
    """Logs each frame it gets and each end of a turn (a sink that gathers its writes)."""

    def __init__(self, fail: bool = False) -> None:
        super().__init__()
        self.log: list[str] = []
        self.fail = fail

    def emit_contacts(self, skin, timestamp_s, contacts):
        super().emit_contacts(skin, timestamp_s, contacts)
        self.log.append("frame")

    def end_turn(self) -> None:
        self.log.append("end")
        if self.fail:
            raise RuntimeError("end_turn failed")


def test_every_turn_of_the_loop_ends_for_the_sinks_that_gather_their_writes():
    """The ROS 2 sink writes a turn's frames at its end: the runner must end every turn."""
    sink, plain = _TurnSink(), ListSink()
    with Pipeline(
        model_path("map"), str(stream_recording()), realtime=False, sinks=[sink, plain]
    ) as p:
        n = 0
        for _ in p:  # a turn's contacts come once the turn is over
            assert sink.log[-1] == "end"  # its frames went out
            n += 1
    assert n > 0 and sink.log.count("frame") > 0
    assert len(plain.frames) == sink.log.count("frame")  # a sink without end_turn: as before


def test_a_sink_whose_end_of_turn_raises_does_not_stop_the_loop(caplog):
    sink, plain = _TurnSink(fail=True), ListSink()
    with caplog.at_level("ERROR"):
        with Pipeline(
            model_path("map"), str(stream_recording()), realtime=False, sinks=[sink, plain]
        ) as p:
            n = sum(1 for _ in p)
    assert n > 0 and len(plain.contacts) == n  # every contact still reached the other sink
    assert sink.log.count("end") > 1  # and the failing one was asked again each turn
    assert sum("end_turn failed" in r.getMessage() for r in caplog.records) == 1  # logged once


def test_runner_on_a_virtual_skin_port_reconnects():
    from skinloc.sim.virtual_device import FaultConfig, VirtualSkin

    faults = FaultConfig(0, 0, 0, 0, disconnect_every_s=0.8, downtime_s=0.2)
    with VirtualSkin(fmt="binary", rate_hz=200, faults=faults) as dev:
        # wait: the port is down a fifth of the time, and a loaded machine may open it then
        spec = SkinConfig(model=model_path("map"), source=dev.path, wire_format="binary", wait=True)
        sink = ListSink()
        runner = Runner([spec], sinks=[sink])
        runner.start()
        try:
            # Wait on what the runner reports, not on the clock: a busy machine is slower.
            wait_until(lambda: runner.cores[0].calibrated, "the baseline", 60.0)
            dev.skin.press(dev.skin.sensor_positions[27], pressure=1.0)
            wait_until(lambda: "start" in [c.state for c in sink.contacts], "a touch", 60.0)

            def reconnected() -> bool:
                s = runner.stats()[0]
                return s["frames"] > 200 and s["reconnects"] >= 1 and s["disconnects"] >= 1

            wait_until(reconnected, "a disconnect, a reconnect and 200 frames", 60.0)
        finally:
            runner.close()


def test_many_skins_from_one_config(tmp_path):
    model = model_path("map")
    cfg = tmp_path / "skins.toml"
    cfg.write_text(
        f"""
sinks = []
[defaults]
model = "{model}"
realtime = false
[defaults.pipeline]
touch_on_z = 9.0
[[skin]]
name = "left"
source = "sim:0"
[[skin]]
name = "right"
source = "sim:0"
pipeline = {{ drift_tracking = false }}
"""
    )
    specs, sinks = load_skins(cfg)
    assert [s.name for s in specs] == ["left", "right"]
    assert specs[0].config.touch_on_z == 9.0 and not specs[1].config.drift_tracking
    runner = runner_from_config(cfg)
    assert runner.cores[0].engine is runner.cores[1].engine  # one compiled model, shared
    seen = set()
    with runner:
        for c in runner:
            seen.add(c.skin)
            if seen == {"left", "right"}:
                break
    assert seen == {"left", "right"}


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('[[skin]]\nname = "a"\n', "no model"),
        ('[[skin]]\nmodel = "m.h5"\ncolour = "red"\n', "unknown key"),
        ('[[skn]]\nmodel = "m.h5"\n', "unknown top-level"),
        ('[[skin]]\nmodel = "m.h5"\npipeline = { touch_on = 3 }\n', "unknown key"),
        ("not toml [", "cannot read"),
        ("", "no \\[\\[skin\\]\\]"),
    ],
)
def test_config_errors(tmp_path, text, match):
    cfg = tmp_path / "skins.toml"
    cfg.write_text(text)
    with pytest.raises(ValueError, match=match):
        load_skins(cfg)


def test_runner_errors(tmp_path):
    with pytest.raises(ValueError, match="unique"):
        Runner([SkinConfig(model_path("map")), SkinConfig(model_path("map"))])
    with pytest.raises(SkinlocError, match="cannot open serial port"):
        Runner([SkinConfig(model_path("map"), source=str(tmp_path / "ttyNONE"))]).open()
    with pytest.raises(SkinlocError, match="recording not found"):
        Runner([SkinConfig(model_path("map"), source=str(tmp_path / "x.h5"))]).open()
    spec = SkinConfig(model_path("map"), config=PipelineConfig(), n_tx=4, n_rx=4)
    with pytest.raises(ValueError, match="16 sensors"):
        Runner([spec])


def test_serial_url_without_file_descriptor_uses_a_thread():
    from skinloc.hardware.protocol import encode_binary

    spec = SkinConfig(model_path("map"), source="loop://", wire_format="binary")
    runner = Runner([spec]).open()
    try:
        src = runner._threads[0].source
        rng = np.random.default_rng(0)
        for k in range(80):
            src.write(encode_binary(rng.integers(9000, 9010, 64), 8, 8, k))

        def stepped() -> bool:  # the loop driven by hand, one turn per poll
            runner._step(0.05)
            return runner.cores[0].n_frames >= 80

        wait_until(stepped, "80 frames through the loop", 60.0, interval_s=0)
    finally:
        runner.close()
    assert runner.cores[0].n_frames == 80 and runner.cores[0].calibrated


def test_a_recording_of_gestures_gives_each_gesture_once_to_sinks_and_callback():
    from tests._live import gesture_recording

    sink, got = ListSink(), []
    spec = SkinConfig(model=model_path("map"), source=str(gesture_recording()), realtime=False)
    with Runner([spec], sinks=[sink], gesture_callback=got.append) as runner:
        runner.run()
        stats = runner.stats()
    kinds = [(g["kind"], g["direction"]) for g in sink.gestures]
    assert kinds == [("tap", None), ("long_press", None), ("swipe", "up")]
    assert got == sink.gestures and stats[0]["gestures"] == 3
    tap, press, swipe = sink.gestures
    assert tap["timestamp_s"] - tap["end_s"] <= 0.30 + 0.011  # the double-tap window, + a frame
    assert press["timestamp_s"] - press["start_s"] <= 0.60 + 0.011
    assert swipe["timestamp_s"] == swipe["end_s"] and swipe["speed_m_s"] > 0.08
    assert {c.track_id for c in sink.contacts} == {1, 2, 3}
    assert all(len(f) == 1 and f[0].slot == 0 for f in sink.frames)  # one finger at a time


def test_skins_file_up_and_max_contacts(tmp_path):
    cfg = tmp_path / "skins.toml"
    cfg.write_text(
        f'[[skin]]\nmodel = "{model_path("map")}"\nsource = "sim"\nup = [0.0, 0.0, 1.0]\n'
        "pipeline = { max_contacts = 2 }\n"
    )
    specs, _ = load_skins(cfg)
    assert specs[0].up == (0.0, 0.0, 1.0) and specs[0].config.max_contacts == 2
    cfg.write_text(f'[[skin]]\nmodel = "{model_path("map")}"\nup = [0.0, 0.0, 0.0]\n')
    with pytest.raises(ValueError, match="up must be a direction"):
        load_skins(cfg)


def test_skins_file_gesture_thresholds_reach_the_recogniser(tmp_path):
    from tests._live import gesture_recording

    cfg = tmp_path / "skins.toml"
    cfg.write_text(
        f'[defaults]\nmodel = "{model_path("map")}"\nrealtime = false\n'
        "[defaults.gestures]\nswipe-min-mm = 250.0\n"
        f'[[skin]]\nname = "a"\nsource = "{gesture_recording()}"\n'
        "gestures = { long_press_s = 0.8 }\n"
    )
    specs, _ = load_skins(cfg)
    assert specs[0].gestures.swipe_min_mm == 250.0 and specs[0].gestures.long_press_s == 0.8
    sink = ListSink()
    with Runner(specs, sinks=[sink]) as runner:
        runner.run()
    # The recording's swipe is shorter than 250 mm: with that threshold it is no gesture.
    assert [(g["kind"], g["direction"]) for g in sink.gestures] == [
        ("tap", None),
        ("long_press", None),
    ]


@pytest.mark.parametrize(
    ("gestures", "match"),
    [
        ("{ tap_max = 0.2 }", "unknown key.*tap_max.*known: double_tap_gap_s"),
        ("{ tap_max_s = -1.0 }", "tap_max_s must be a number > 0"),
        ("{ tap_max_s = 0.9 }", "long_press_s must be longer than tap_max_s"),
        ('"fast"', "gestures must be a table"),
    ],
)
def test_skins_file_gesture_errors_name_the_skin(tmp_path, gestures, match):
    cfg = tmp_path / "skins.toml"
    cfg.write_text(f'[[skin]]\nname = "arm"\nmodel = "m.h5"\ngestures = {gestures}\n')
    with pytest.raises(ValueError, match=f"skin 'arm'.*{match}"):
        load_skins(cfg)


def test_the_skins_file_in_the_docs_loads(tmp_path):
    import re
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "live.md").read_text(encoding="utf-8")
    block = re.search(r"### Many skins: a skins file\n\n```toml\n(.*?)```", text, re.S)
    assert block is not None
    for name in ("arm.h5", "right.h5"):
        (tmp_path / name).write_bytes(b"")  # paths resolve against the file's folder
    cfg = tmp_path / "robot.toml"
    cfg.write_text(block.group(1))
    specs, sinks = load_skins(cfg)
    left, right = specs
    assert sinks == ["jsonl", "ws://127.0.0.1:8767"]  # any-port-ok: text read, nothing bound
    assert left.gestures.long_press_s == 0.8 and left.gestures.swipe_min_mm == 30.0
    assert right.gestures.swipe_min_mm == 40.0 and right.config.max_contacts == 2
    assert right.parent_frame == "fr3_link7" and right.model == str(tmp_path / "right.h5")
