"""The per-skin core: baseline and drift, touch events with hysteresis and debouncing, filter."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from skinloc.hardware.protocol import encode_binary, encode_text
from skinloc.live.core import Contact, PipelineConfig, SkinCore, TouchState
from tests._live import model_path, stream


def _core(**cfg) -> SkinCore:
    return SkinCore(model_path("map"), PipelineConfig(**cfg), name="t")


def _run(core: SkinCore, frames: np.ndarray, dt: float = 0.01) -> list[Contact]:
    out = []
    for k, f in enumerate(frames):
        out += core.process_frame(f, k * dt, k)[:1]  # K = 1: at most one
    return out


def test_events_follow_the_script():
    frames, script = stream()
    contacts = _run(_core(), frames)
    starts = [c for c in contacts if c.state == "start"]
    ends = [c for c in contacts if c.state == "end"]
    assert len(starts) == len(script)
    assert len(ends) in (len(script), len(script) - 1)  # the last touch may run to the end
    for (first, _, _), s in zip(script, starts, strict=True):
        assert first <= s.index <= first + 3  # debounced by 2 frames, no more
    errors = [
        np.linalg.norm(np.array(c.position_m) - script[c.touch_id - 1][2]) * 1e3
        for c in contacts
        if c.state == "move"
    ]
    assert np.median(errors) < 15.0
    assert all(0.0 <= c.confidence <= 1.0 for c in contacts)
    assert all(c.latency_us >= 0 for c in contacts)


def _synthetic(n: int, spikes: dict[int, float], rng: np.random.Generator) -> np.ndarray:
    frames = 8000.0 + rng.normal(0.0, 5.0, (n, 64))
    for k, amp in spikes.items():
        frames[k, 9] += amp
    return frames


def test_hysteresis_and_debounce():
    rng = np.random.default_rng(0)
    cfg = dict(baseline_frames=50, debounce_on_frames=2, debounce_off_frames=3, release_fraction=0)
    # one frame above the threshold is a glitch, not a touch
    frames = _synthetic(120, {80: 400.0}, rng)
    assert _run(_core(**cfg), frames) == []
    # two frames above: a touch; between the thresholds it holds; 3 frames below end it
    amps = {k: 400.0 for k in range(80, 90)}
    amps.update({k: 30.0 for k in range(90, 100)})  # z ~ 6: between off (4) and on (8)
    frames = _synthetic(130, amps, rng)
    states = [(c.index, c.state) for c in _run(_core(**cfg), frames)]
    assert states[0] == (81, "start")
    assert [s for _, s in states].count("start") == 1
    end = [i for i, s in states if s == "end"]
    assert end == [102]
    # with the release fraction, a fall to a quarter of the touch's level ends it earlier
    states = [(c.index, c.state) for c in _run(_core(**{**cfg, "release_fraction": 0.25}), frames)]
    assert [i for i, s in states if s == "end"] == [92]


def test_baseline_tracks_drift_only_while_untouched():
    rng = np.random.default_rng(1)
    n = 2000
    frames = 8000.0 + rng.normal(0.0, 5.0, (n, 64))
    frames += np.linspace(0.0, 40.0, n)[:, None]  # slow drift of 40 counts
    core = _core()
    assert _run(core, frames) == []  # drift alone is no touch
    assert abs(core.baseline.mean() - 8040.0) < 8.0  # lags 2 counts/s x 3 s behind the drift
    # a touch held for 30 s is never tracked away, and ends when released
    before = core.baseline.copy()
    held = 8000.0 + 40.0 + rng.normal(0.0, 5.0, (3000, 64))
    held[:, [9, 10, 17]] += 300.0
    contacts = _run(core, held)
    assert [c.state for c in contacts].count("start") == 1
    assert "end" not in [c.state for c in contacts]
    assert np.abs(core.baseline - before)[[9, 10, 17]].max() < 2.0
    assert len(contacts) == 3000 - 1
    released = 8040.0 + rng.normal(0.0, 5.0, (10, 64))
    assert [c.state for c in _run(core, released)] == ["move", "move", "end"]  # debounced


def test_no_drift_tracking_when_switched_off():
    rng = np.random.default_rng(2)
    frames = 8000.0 + rng.normal(0.0, 5.0, (400, 64))
    frames[100:] += 20.0
    core = _core(drift_tracking=False)
    _run(core, frames)
    assert abs(core.baseline.mean() - 8000.0) < 1.0


def test_link_lost_ends_a_touch_after_stale_s():
    frames, script = stream()
    core = _core(stale_s=0.5)
    first = script[0][0]
    for k in range(first + 20):
        core.process_frame(frames[k], k * 0.01, k, t_in=100.0 + k * 0.01)
    assert core.touching
    assert core.end_stale(now=100.0 + (first + 20) * 0.01 + 0.1) == []
    (end,) = core.end_stale(now=100.0 + (first + 20) * 0.01 + 1.0)
    assert end.state == "end" and not core.touching


@pytest.mark.parametrize("fmt", ["binary", "text"])
def test_feed_bytes_equals_process(fmt):
    """Bytes through the parser give the events of the decoded frames.

    One contact per frame: the two paths stamp frames differently (``feed``: arrival time),
    the baseline is tracked in time, and the multi-contact count of a borderline frame may
    then differ; the wire path itself is what this checks.
    """
    frames, _ = stream()
    frames = np.round(frames[:400]).astype(np.uint16)  # what the wire carries, for both paths
    a = _core(max_contacts=1)
    b = SkinCore(a.engine, PipelineConfig(max_contacts=1), name="t", wire_format=fmt)
    want = [c.state for c in _run(a, frames)]
    enc = (
        (lambda f, k: encode_binary(f, 8, 8, k))
        if fmt == "binary"
        else (lambda f, k: encode_text(f))
    )
    data = b"".join(enc(f, k) for k, f in enumerate(frames))
    got = []
    for i in range(0, len(data), 97):  # arbitrary chunks
        got += [c.state for c in b.feed(data[i : i + 97])]
    assert got == want
    # text: the bytes before the first line end are dropped (we may have joined mid-line)
    assert b.parser_stats["n_frames"] == len(frames) - (fmt == "text")


def test_contact_json_and_config_errors():
    c = Contact("s", 1.0, 3, "start", (0.1, 0.2, 0.3), (0.1, 0.2, 0.3), 0.5, 9.0, math.nan, 12.0, 1)
    d = json.loads(c.to_json())
    assert d["position_m"] == [0.1, 0.2, 0.3] and d["uncertainty_mm"] is None
    assert TouchState("end") is TouchState.END
    with pytest.raises(ValueError, match="touch state"):
        TouchState("hover")
    with pytest.raises(ValueError, match="touch_off_z"):
        PipelineConfig(touch_on_z=3.0, touch_off_z=5.0)
    with pytest.raises(ValueError, match="debounce_on_frames"):
        PipelineConfig(debounce_on_frames=0)
    with pytest.raises(ValueError, match="unknown key"):
        PipelineConfig.from_dict({"touch_on": 3})
    assert PipelineConfig.from_dict({"touch-on-z": 9.0}).touch_on_z == 9.0
    with pytest.raises(ValueError, match="sensors"):
        _core().process_frame(np.zeros(10), 0.0)


def test_a_model_the_engine_cannot_run_is_an_error_not_a_silent_fallback():
    # there is one implementation of prediction: no second path to fall back on
    from skinloc.models.engine import load_engine
    from skinloc.models.localizer import ContactLocalizer

    model = ContactLocalizer.load(model_path("mlp"))
    model.config_ = {**model.config_, "activation": "softsign"}  # unknown to the engine
    with pytest.raises(ValueError, match="activation must be one of relu, tanh, gelu"):
        load_engine(model)
    with pytest.raises(ValueError, match="activation must be one of relu, tanh, gelu"):
        SkinCore(model, PipelineConfig())


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_frame_with_a_nan_is_dropped_and_does_not_poison_the_baseline(bad):
    """One corrupt frame (a replayed file's NaN) is dropped and counted; the baseline, which
    drifts with untouched frames, stays finite, so the touches after it are found as before."""
    frames, script = stream()
    clean = _run(_core(), frames)
    frames = frames.astype(np.float64)
    # untouched frames after the baseline, and one during the first touch
    hit = [script[0][0] - 5, script[0][0] + 3, script[1][0] - 5]
    for k in hit:
        frames[k, 7] = bad
    core = _core()
    got = _run(core, frames)
    assert core.n_nonfinite == len(hit)
    assert [c.state for c in got if c.state != "move"] == [
        c.state for c in clean if c.state != "move"
    ]
    assert all(np.isfinite(c.position_m).all() for c in got)
    assert np.isfinite(core._baseline).all()


def test_an_engine_refuses_an_image_with_a_nan():
    from skinloc.models.engine import load_engine

    engine = load_engine(model_path("map"))
    x = np.zeros(64, np.float32)
    x[9] = 300.0
    x[3] = np.nan
    for call in (lambda: engine.contacts(x, 3), lambda: engine.predict_one(x)):
        with pytest.raises(ValueError, match="NaN or infinite"):
            call()
    with pytest.raises(ValueError, match="NaN or infinite"):
        engine.predict(np.stack([np.zeros(64), x]))
