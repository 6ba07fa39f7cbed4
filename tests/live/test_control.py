"""Live control of a skin: tare, track reset, settings applied live, health; the ROS 2 params."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skinloc.live.config import PipelineConfig
from skinloc.live.core import SkinCore
from skinloc.live.gestures import GestureConfig
from skinloc.live.sinks.ros2.params import (
    apply_values,
    param_specs,
    read_param_dump,
    settings_of,
)
from tests._live import model_path


def _core(**cfg) -> SkinCore:
    return SkinCore(model_path("map"), PipelineConfig(**cfg), name="t")


def _frames(n: int, rng, level: float = 8000.0, touch: float = 0.0) -> np.ndarray:
    f = level + rng.normal(0.0, 5.0, (n, 64))
    f[:, 9] += touch
    return f


def _feed(core: SkinCore, frames: np.ndarray, t0: int = 0) -> list:
    out = []
    for k, f in enumerate(frames, t0):
        out += core.process_frame(f, k * 0.01, k)
    return out


def test_tare_is_refused_while_touched_and_rebaselines_after():
    rng = np.random.default_rng(0)
    core = _core(baseline_frames=20, max_contacts=1)
    with pytest.raises(ValueError, match="capturing"):
        core.tare()  # no baseline yet
    _feed(core, _frames(20, rng))
    assert core.calibrated
    _feed(core, _frames(5, rng, touch=400.0), 20)
    assert core.touching
    with pytest.raises(ValueError, match="touched"):
        core.tare()
    _feed(core, _frames(10, rng), 25)
    assert not core.touching
    core.tare()
    assert core.taring and not core.calibrated
    with pytest.raises(ValueError, match="capturing"):
        core.tare()
    # the skin's level moved by 30 counts: the new baseline has it
    _feed(core, _frames(20, rng, level=8030.0), 35)
    assert core.calibrated and not core.taring
    assert core.last_tare["mean_shift_counts"] == pytest.approx(30.0, abs=3.0)
    assert core.last_tare["max_abs_shift_counts"] >= 25.0


def test_settings_apply_from_the_next_frame_and_a_bad_one_is_refused():
    rng = np.random.default_rng(1)
    core = _core(baseline_frames=20, max_contacts=1)
    _feed(core, _frames(20, rng))
    # z ~ 6 (30 counts on a noise of 5): no touch at touch_on_z 8; a touch at 5
    assert _feed(core, _frames(10, rng, touch=30.0), 20) == []
    new, g = apply_values(
        core.config, None, {"pipeline.touch_on_z": 5.0, "pipeline.touch_off_z": 3}
    )
    assert core.update_config(new, g) == ["touch_on_z", "touch_off_z"]
    assert any(c.state == "start" for c in _feed(core, _frames(10, rng, touch=30.0), 30))
    # the settings' own check refuses, with the reason; nothing changes
    with pytest.raises(ValueError, match="touch_off_z"):
        apply_values(core.config, None, {"pipeline.touch_off_z": 50.0})
    with pytest.raises(ValueError, match="tap_max_s"):
        apply_values(core.config, None, {"gestures.tap_max_s": -1.0})
    with pytest.raises(ValueError, match="unknown"):
        apply_values(core.config, None, {"pipeline.nope": 1})
    assert core.config.touch_on_z == 5.0
    # the tracker's settings wait for the skin to be free; fixed ones never change live
    assert core.touching
    with pytest.raises(ValueError, match="touched"):
        core.update_config(dataclasses.replace(core.config, max_contacts=3))
    with pytest.raises(ValueError, match="restart"):
        core.update_config(dataclasses.replace(core.config, gestures=False))


def test_max_contacts_changes_the_tracker_while_free_and_reset_tracks():
    rng = np.random.default_rng(2)
    core = _core(baseline_frames=20, max_contacts=1)
    _feed(core, _frames(20, rng))
    core.update_config(dataclasses.replace(core.config, max_contacts=3))
    assert core.max_contacts == 3 and core._tracker is not None
    assert core.reset_tracks() == 0
    _feed(core, _frames(5, rng, touch=400.0), 20)
    with pytest.raises(ValueError, match="touched"):
        core.reset_tracks()


def test_health_reports_noise_stuck_sensors_and_drift():
    rng = np.random.default_rng(3)
    core = _core(baseline_frames=20, max_contacts=1)
    assert np.isnan(core.health()["noise"]).all()
    frames = _frames(20, rng)
    frames[:, 5] = 8000.0  # a stuck sensor
    _feed(core, frames)
    h = core.health()
    assert h["stuck"][5] and h["stuck"].sum() == 1
    assert np.nanmedian(h["noise"]) == pytest.approx(5.0, rel=0.3)
    assert np.abs(h["drift"]).max() == 0.0
    _feed(core, _frames(400, rng, level=8003.0), 20)  # slow drift, tracked while untouched
    assert core.health()["drift"].mean() > 0.5  # of 3 counts, the drift tracker's share


def test_param_specs_describe_every_setting_with_ranges():
    specs = {s.key: s for s in param_specs()}
    fields = {f"pipeline.{f.name}" for f in dataclasses.fields(PipelineConfig)}
    fields |= {f"gestures.{f.name}" for f in dataclasses.fields(GestureConfig)}
    assert set(specs) == fields
    assert all(s.description for s in specs.values()), [k for k, s in specs.items()]
    on = specs["pipeline.touch_on_z"]
    assert on.kind == "float" and on.low == 0.0 and "touch starts" in on.description
    assert specs["pipeline.max_contacts"].kind == "int" and specs["pipeline.max_contacts"].low == 1
    assert specs["pipeline.gestures"].read_only and not specs["pipeline.touch_on_z"].read_only
    assert specs["pipeline.filter"].choices == ("one-euro", "none")


def test_a_param_dump_reads_back_as_skins_file_tables(tmp_path):
    values = settings_of(PipelineConfig(touch_on_z=9.0), GestureConfig(tap_max_s=0.25))
    lines = ["/skinloc:", "  ros__parameters:", "    use_sim_time: false", "    arm:"]
    for table in ("pipeline", "gestures"):
        lines.append(f"      {table}:")
        for key, v in values.items():
            if key.startswith(table + "."):
                text = str(v).lower() if isinstance(v, bool) else str(v)
                lines.append(f"        {key.split('.', 1)[1]}: {text}")
    path = tmp_path / "dump.yaml"
    path.write_text("\n".join(lines) + "\n")
    got = read_param_dump(path)
    assert PipelineConfig.from_dict(got["arm"]["pipeline"]) == PipelineConfig(touch_on_z=9.0)
    assert GestureConfig(**got["arm"]["gestures"]) == GestureConfig(tap_max_s=0.25)
    (tmp_path / "bad.yaml").write_text("a: 1\n")
    with pytest.raises(ValueError, match="ros__parameters"):
        read_param_dump(tmp_path / "bad.yaml")
    with pytest.raises(ValueError, match="not found"):
        read_param_dump(tmp_path / "none.yaml")


def test_the_dumps_of_every_workers_node_appended_read_back_as_one(tmp_path, monkeypatch):
    # run --workers: ros2 param dump /skinloc_0 > p.yaml; ros2 param dump /skinloc_1 >> p.yaml
    text = "".join(
        f"/skinloc_{i}:\n  ros__parameters:\n    use_sim_time: false\n    {skin}:\n"
        f"      pipeline:\n        touch_on_z: {z}\n"
        for i, (skin, z) in enumerate((("arm", 9.0), ("leg", 7.5)))
    )
    path = tmp_path / "p.yaml"
    path.write_text(text)
    want = {"arm": {"pipeline": {"touch_on_z": 9.0}}, "leg": {"pipeline": {"touch_on_z": 7.5}}}
    assert read_param_dump(path) == want
    import builtins

    real_import = builtins.__import__

    def no_yaml(name, *args, **kwargs):
        if name == "yaml":
            raise ImportError("no PyYAML here")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_yaml)  # the reader's own subset of YAML
    assert read_param_dump(path) == want


def test_a_skins_file_reads_a_param_dump_back(tmp_path):
    from skinloc.live.skins_file import load_skins

    (tmp_path / "dump.yaml").write_text(
        "/skinloc:\n  ros__parameters:\n    left_arm:\n      pipeline:\n"
        "        touch_on_z: 9.5\n        max_contacts: 2\n      gestures:\n"
        "        tap_max_s: 0.2\n"
    )
    cfg = tmp_path / "robot.toml"
    cfg.write_text(
        'params = "dump.yaml"\n[[skin]]\nname = "left-arm"\nmodel = "m.h5"\nsource = "sim"\n'
        "pipeline = { touch_on_z = 7.0, quiet_z = 2.5 }\n"
        '[[skin]]\nname = "leg"\nmodel = "m.h5"\nsource = "sim"\n'
    )
    (arm, leg), _ = load_skins(cfg)
    assert (arm.config.touch_on_z, arm.config.max_contacts, arm.config.quiet_z) == (9.5, 2, 2.5)
    assert arm.gestures.tap_max_s == 0.2
    assert leg.config == PipelineConfig()
    # a dumped value the settings refuse is refused as in the skins file itself
    (tmp_path / "dump.yaml").write_text(
        "/skinloc:\n  ros__parameters:\n    leg:\n      pipeline:\n        touch_off_z: 50.0\n"
    )
    with pytest.raises(ValueError, match="touch_off_z"):
        load_skins(cfg)


@pytest.mark.parametrize("name", ["9bad", "bad name", "a-b", ""])
def test_a_ros2_node_name_follows_ros_naming_rules(name):
    from skinloc.live.sinks.ros2.sink import Ros2Sink

    with pytest.raises(ValueError, match="node name"):
        Ros2Sink(name)
    assert Ros2Sink("skinloc_2").node_name == "skinloc_2"


def test_a_tare_is_the_baseline_only_recalibration():
    """k = 0: the recalibration keeps the model; the tare's baseline is the capture's mean."""
    from skinloc.evaluation.recalibration import recalibrate
    from skinloc.models.localizer import ContactLocalizer
    from tests.conftest import make_recording

    rng = np.random.default_rng(1)
    old = ContactLocalizer.load(model_path("map"))
    capture = make_recording(2, 4, random_state=3).subset(np.array([], dtype=int))
    capture.baseline_frames = _frames(20, rng, level=8030.0).astype(np.float32)
    done = recalibrate(old, [capture])
    assert done.report.n_touches == 0 and done.report.method == "old map"
    X = _frames(5, rng, touch=400.0) - 8000.0
    np.testing.assert_allclose(done.model.predict(X), old.predict(X))
    # the same frames as a tare on the node: the same fresh baseline as the recording's
    core = _core(baseline_frames=20, max_contacts=1)
    _feed(core, _frames(20, rng))
    core.tare()
    _feed(core, capture.baseline_frames, 20)
    assert core.calibrated and not core.taring
    np.testing.assert_allclose(core.baseline, capture.baseline, rtol=1e-9)


def test_the_ros2_sinks_diagnostics_are_built_a_skin_a_sweep_and_published_whole(monkeypatch):
    """Thirty skins' statuses: one skin a sweep (a zero budget), one message with all of them."""
    import os

    from skinloc.live.sinks.ros2 import sink as sink_module
    from skinloc.live.sinks.ros2.sink import Ros2Sink

    names = [f"s{i}" for i in range(30)]

    class Control:
        skin_names = names

        def __init__(self) -> None:
            self.asked: list[list[int]] = []

        def settings(self, name: str) -> dict:
            return {}

        def handle(self, request: dict) -> None:
            return None

        def finished(self) -> list:
            return []

        def diagnostics(self, now, extra=None, slots=None):
            self.asked.append(list(slots))
            return [{"name": f"skinloc: {names[s]}", "p99": extra[names[s]]} for s in slots]

    monkeypatch.setattr(sink_module, "_DIAG_BUDGET_S", 0.0)
    sink = Ros2Sink("skinloc")
    sent: list[dict] = []
    monkeypatch.setattr(sink, "_control", lambda message, wait_s=0.1: sent.append(message))
    r, w = os.pipe()
    os.set_blocking(r, False)
    sink._proc, sink._r, sink._w, sink.backend_used = object(), r, w, "rclpy"  # as if started
    sink._index = {n: i for i, n in enumerate(names)}
    control = Control()
    try:
        for k in range(29):
            sink.serve(control, now=0.01 * k)
        assert not [m for m in sent if "diagnostics" in m]  # not before every skin is in
        sink.serve(control, now=0.29)
        diags = [m["diagnostics"] for m in sent if "diagnostics" in m]
        assert len(diags) == 1
        assert [d["name"] for d in diags[0]] == [f"skinloc: {n}" for n in names]
        assert control.asked == [[i] for i in range(30)]  # never all skins in one sweep
        for k in range(30, 99):  # the next round waits for its second
            sink.serve(control, now=0.01 * k)
        assert len([m for m in sent if "diagnostics" in m]) == 1
        sink.serve(control, now=1.0)
        assert control.asked[-1] == [0]  # a new round, from the first skin
    finally:
        sink._proc, sink._r, sink._w = None, -1, -1
        os.close(r)
        os.close(w)


def test_a_skins_dead_lines_are_classified_once_per_capture(monkeypatch):
    """The diagnostics classify a skin's lines again only when its noise changed (a capture,
    a tare); a line that died shows at the next capture's diagnostics."""
    import types

    from skinloc.live import control as control_module
    from skinloc.live.control import SkinControl

    rng = np.random.default_rng(4)
    core = _core(baseline_frames=20, max_contacts=1)
    _feed(core, _frames(20, rng))
    skin = types.SimpleNamespace(name="t", source="sim", rate_hz=100.0)
    runner = types.SimpleNamespace(
        skins=[skin], cores=[core], stats=lambda slots: [{"frames": core.n_frames} for _ in slots]
    )
    calls = []
    real = control_module.classify_sensors
    monkeypatch.setattr(
        control_module, "classify_sensors", lambda *a, **k: calls.append(1) or real(*a, **k)
    )
    control = SkinControl(runner)
    first = [control.diagnostics(float(k))[0]["values"] for k in range(3)]
    assert len(calls) == 1
    assert all(v["dead_lines"] == "none" for v in first)
    core.tare()
    frames = _frames(20, rng)
    frames[:, 0:8] = 8000.0  # TX0's eight sensors stopped changing: a dead line
    _feed(core, frames, 100)
    assert core.calibrated
    after = control.diagnostics(5.0)[0]
    assert len(calls) == 2
    assert "TX0" in after["values"]["dead_lines"] and after["level"] == 2
    control.diagnostics(6.0)
    assert len(calls) == 2
