"""The runner: Pipeline as an iterator and with a callback, ports, replay, many skins, config."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from skinloc.errors import SkinlocError
from skinloc.multiskin import load_skins, runner_from_config
from skinloc.pipeline import Pipeline, PipelineConfig
from skinloc.runner import Runner, SkinSpec
from skinloc.sinks import ListSink
from tests._live import model_path, stream_recording


def _threads() -> set[str]:
    return {t.name for t in threading.enumerate()}


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
    time.sleep(0.1)
    assert _threads() <= before


def test_pipeline_callback_mode_and_close():
    before = _threads()
    got = []
    pipeline = Pipeline(model_path("map"), "sim", realtime=False, sinks=[ListSink()])
    pipeline.start(got.append)
    deadline = time.monotonic() + 30
    while len(got) < 30 and time.monotonic() < deadline:
        time.sleep(0.05)
    pipeline.close()
    assert len(got) >= 30
    assert (
        pipeline.global_sinks[0].contacts[: len(got)]
        == got[: len(pipeline.global_sinks[0].contacts)]
    )
    time.sleep(0.1)
    assert _threads() <= before
    pipeline.close()  # idempotent


def test_replay_runs_to_the_end_and_ends_open_touches():
    sink = ListSink()
    with Pipeline(model_path("map"), str(stream_recording()), realtime=False, sinks=[sink]) as p:
        n = sum(1 for _ in p)
    states = [c.state for c in sink.contacts]
    assert n == len(states) > 0
    assert states.count("start") == states.count("end")
    assert p.stats()[0]["frames"] == 1500


def test_runner_on_a_virtual_skin_port_reconnects():
    from skinloc.virtual_skin import FaultConfig, VirtualSkin

    faults = FaultConfig(0, 0, 0, 0, disconnect_every_s=0.8, downtime_s=0.2)
    with VirtualSkin(fmt="binary", rate_hz=200, faults=faults) as dev:
        spec = SkinSpec(model=model_path("map"), source=dev.path, wire_format="binary")
        sink = ListSink()
        runner = Runner([spec], sinks=[sink])
        runner.start()
        time.sleep(1.0)
        dev.skin.press(dev.skin.sensor_positions[27], pressure=1.0)
        time.sleep(2.0)
        stats = runner.stats()[0]
        runner.close()
    assert stats["frames"] > 200
    assert stats["reconnects"] >= 1 and stats["disconnects"] >= 1
    assert "start" in [c.state for c in sink.contacts]


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
    assert runner.cores[0].fast is runner.cores[1].fast  # one compiled model, shared
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
        Runner([SkinSpec(model_path("map")), SkinSpec(model_path("map"))])
    with pytest.raises(SkinlocError, match="cannot open serial port"):
        Runner([SkinSpec(model_path("map"), source=str(tmp_path / "ttyNONE"))]).open()
    with pytest.raises(SkinlocError, match="recording not found"):
        Runner([SkinSpec(model_path("map"), source=str(tmp_path / "x.h5"))]).open()
    spec = SkinSpec(model_path("map"), config=PipelineConfig(), n_tx=4, n_rx=4)
    with pytest.raises(ValueError, match="16 sensors"):
        Runner([spec])


def test_serial_url_without_file_descriptor_uses_a_thread():
    from skinloc.framing import encode_binary

    spec = SkinSpec(model_path("map"), source="loop://", wire_format="binary")
    runner = Runner([spec]).open()
    try:
        src = runner._threads[0].source
        rng = np.random.default_rng(0)
        for k in range(80):
            src.write(encode_binary(rng.integers(9000, 9010, 64), 8, 8, k))
        deadline = time.monotonic() + 10
        while runner.cores[0].n_frames < 80 and time.monotonic() < deadline:
            runner._step(0.05)
    finally:
        runner.close()
    assert runner.cores[0].n_frames == 80 and runner.cores[0].calibrated
