"""The live loop never stops on one part's exception, and ``run`` keeps its duration and pace.

A model that raises on one frame loses that frame only; a sink (or a frame recorder, or a
callback) that raises on every frame loses its deliveries only, backs off and is tried again;
the other skins and sinks go on, and every error is counted in ``Runner.stats``. ``run(duration)``
ends on time when no contact comes, and a looped replay keeps its recorded rate on every pass.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import numpy as np
import pytest

from skinloc.live import guard
from skinloc.live.core import PipelineConfig
from skinloc.live.guard import ErrorLog, SinkRoute
from skinloc.live.runner import Runner, SkinConfig
from skinloc.live.sinks import ListSink
from skinloc.models.engine import load_engine
from tests._helpers import wait_until
from tests._live import model_path, stream_recording


class _Raising(ListSink):
    """A sink whose first ``fail`` deliveries (every one by default) raise."""

    name = "failing"

    def __init__(self, fail: float = math.inf) -> None:
        super().__init__()
        self.fail = fail
        self.calls = 0

    def emit_contacts(self, skin, timestamp_s, contacts) -> None:
        self.calls += 1
        if self.calls <= self.fail:
            raise ConnectionError("the robot's bus is down")
        super().emit_contacts(skin, timestamp_s, contacts)


def _replay(name: str, model=None, sinks=()) -> SkinConfig:
    return SkinConfig(
        model=model_path("map") if model is None else model,
        source=str(stream_recording()),
        name=name,
        realtime=False,
        sinks=list(sinks),
    )


def _tracebacks(caplog, what: str) -> list[logging.LogRecord]:
    return [r for r in caplog.records if r.exc_info and r.getMessage().startswith(what)]


def test_a_model_that_raises_on_one_frame_loses_that_frame_and_every_skin_goes_on(caplog):
    engine = load_engine(model_path("map"))  # its own engine: the other skin's stays sound
    calls = {"n": 0}
    real = engine.contacts

    def contacts(*args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 5:  # the fifth touched frame
            raise FloatingPointError("the model blew up")
        return real(*args, **kwargs)

    engine.contacts = contacts
    good, bad = ListSink(), ListSink()
    runner = Runner([_replay("bad", engine, [bad]), _replay("good", sinks=[good])])
    with caplog.at_level(logging.WARNING), runner:
        runner.run()
    s_bad, s_good = runner.stats()
    assert s_bad["frames"] == s_good["frames"] == 1500  # both replays played to the end
    assert s_bad["errors"] == 1 and "FloatingPointError: the model blew up" in s_bad["last_error"]
    assert s_good["errors"] == 0 and s_good["sink_errors"] == 0
    assert calls["n"] > 5 and len(bad.contacts) > 5  # the skin went on after the bad frame
    states = [c.state for c in good.contacts]
    assert states.count("start") == states.count("end") > 3
    assert len(_tracebacks(caplog, "skin 'bad'")) == 1  # logged once, with its traceback


def test_a_sink_that_raises_on_every_frame_leaves_the_other_sinks_and_skins_alone(caplog):
    class Recorder(ListSink):
        """A raw-frame recorder (as the ROS 2 bag sink) that fails on every frame."""

        name = "recorder"
        wants_frames = True

        def emit_frame(self, skin, values, timestamp_s, index) -> None:
            raise OSError(28, "No space left on device")

    failing, recorder, everyone = _Raising(), Recorder(), ListSink()
    got: list = []

    def callback(contact) -> None:
        got.append(contact)
        if len(got) == 3:
            raise RuntimeError("the program's callback failed once")

    runner = Runner(
        [_replay("a", sinks=[failing, recorder]), _replay("b")],
        sinks=[everyone],
        callback=callback,
    )
    with caplog.at_level(logging.WARNING), runner:
        runner.run()
    a, b = runner.stats()
    assert a["frames"] == b["frames"] == 1500
    assert a["errors"] == b["errors"] == 0  # the skins themselves are sound
    routes = {s["sink"]: s for s in a["sinks"]}
    assert list(routes) == ["failing", "recorder", "list", "recorder (frames)", "callback"]
    assert routes["recorder"]["errors"] == 0  # it takes the contacts; the frames fail
    for name in ("failing", "recorder (frames)"):  # every frame: tried, failed, backed off...
        r = routes[name]
        assert r["errors"] >= 2 and r["skipped"] > 0 and r["failing"], r
        assert r["retry_in_s"] <= guard.BACKOFF_MAX_S
    assert "ConnectionError: the robot's bus is down" == routes["failing"]["last_error"]
    assert "No space left on device" in routes["recorder (frames)"]["last_error"]
    # the callback's third contact may be either skin's (the two replays run side by side)
    calls = [next(s for s in x["sinks"] if s["sink"] == "callback") for x in (a, b)]
    assert sum(r["errors"] for r in calls) == 1 and not any(r["failing"] for r in calls)
    assert routes["list"]["errors"] == routes["list"]["skipped"] == 0
    assert a["sink_errors"] == sum(r["errors"] for r in routes.values())
    assert b["sink_errors"] == calls[1]["errors"]
    assert all(s["errors"] == 0 for s in b["sinks"] if s["sink"] != "callback")
    # every contact of both skins reached the sound sink and (but one) the callback
    assert {c.skin for c in everyone.contacts} == {"a", "b"}
    assert len(everyone.contacts) == a["contacts"] + b["contacts"] == len(got)
    assert failing.contacts == []
    # one traceback per sink, however often it failed
    for what in ("sink failing", "sink recorder", "callback"):
        assert len(_tracebacks(caplog, what)) == 1, what


def test_a_sink_that_fails_then_works_gets_the_contacts_again(monkeypatch):
    monkeypatch.setattr(guard, "BACKOFF_FIRST_S", 0.0)  # retried at once: no clock in the test
    flaky, sound = _Raising(fail=4), ListSink()
    runner = Runner([_replay("a", sinks=[flaky, sound])])
    with runner:
        runner.run()
    route = runner.stats()[0]["sinks"][0]
    assert route["errors"] == 4 and not route["failing"]
    assert len(flaky.frames) == len(sound.frames) - 4 > 0
    assert flaky.frames == sound.frames[4:]


def test_a_failing_sink_backs_off_exponentially_to_a_cap_and_recovers():
    route = SinkRoute("udp://127.0.0.1:9", ErrorLog("sink udp://127.0.0.1:9", "lost"))
    exc = ConnectionRefusedError("refused")
    assert route.ready(0.0)
    route.failed(exc, 0.0)  # one failure: tried again at the next delivery
    assert route.ready(0.0)
    waits = []
    t = 0.0
    for _ in range(12):
        route.failed(exc, t)
        waits.append(route.retry_at - t)
        assert not route.ready(t + waits[-1] * 0.99)
        t = route.retry_at
        assert route.ready(t)
    assert waits[:3] == pytest.approx([guard.BACKOFF_FIRST_S * k for k in (1, 2, 4)])
    assert max(waits) == waits[-1] == guard.BACKOFF_MAX_S
    assert route.n_errors == 13 and route.n_skipped == 12
    route.succeeded()
    assert route.ready(t) and route.as_dict(t)["failing"] is False


def test_repeated_errors_are_summed_up_not_logged_each(caplog):
    errors = ErrorLog("skin 'arm'", "the frame is dropped")
    with caplog.at_level(logging.WARNING):
        for k in range(1000):
            errors.record(ValueError(f"bad frame {k}"), k * 0.01)  # 10 s of 100 Hz
        errors.record(KeyError("another kind"), 10.0)
    assert errors.n == 1001 and errors.last == "KeyError: 'another kind'"
    tracebacks = [r for r in caplog.records if r.exc_info]
    assert len(tracebacks) == 2  # the first of each kind
    assert len(caplog.records) <= 4  # and at most a summary every REPEAT_S


def test_run_ends_at_its_duration_when_no_contact_comes():
    """``--duration`` held only when a contact was yielded: untouched, it never ended."""
    from skinloc.sim.virtual_device import VirtualSkin

    with VirtualSkin(fmt="binary", rate_hz=100) as dev:  # nobody touches it
        runner = Runner([SkinConfig(model_path("map"), source=dev.path, wire_format="binary")])
        done = threading.Event()
        result: dict = {}

        def run() -> None:
            try:
                result["n"] = runner.run(0.5)
            finally:
                done.set()

        thread = threading.Thread(target=run, daemon=True)
        try:
            with runner:
                thread.start()
                wait_until(done.is_set, "run(0.5) to end with no contact", 30.0)
        finally:
            runner.stop()
            thread.join(30.0)
    assert result["n"] == 0 and runner.stats()[0]["frames"] > 0


def test_a_looped_replay_goes_on_in_time_and_keeps_its_rate_on_every_pass(tmp_path):
    from skinloc.geometry.mesh import cone_skin
    from skinloc.sources.replay import ReplaySource, write_stream_recording

    path = tmp_path / "five.h5"
    rng = np.random.default_rng(0)
    write_stream_recording(
        path,
        n_tx=8,
        n_rx=8,
        mesh=cone_skin(),
        baseline_frames=rng.normal(1000, 2, (20, 64)),
        frames=rng.normal(1000, 2, (5, 64)),
        times_s=np.arange(5) / 100,
        index=np.arange(5),
    )
    with ReplaySource(path, loop=True) as src:
        frames = [src.read(1.0) for _ in range(12)]
    assert [f.index for f in frames] == [0, 1, 2, 3, 4] * 2 + [0, 1]  # the counter repeats
    assert [f.timestamp_s for f in frames] == pytest.approx(np.arange(12) / 100)  # time goes on
    # paced by those times, every pass keeps 100 Hz: a 5-frame file looped for 0.5 s gives
    # about 50 frames (before, the second pass on came as fast as the loop took them)
    skin = SkinConfig(model_path("map"), source=str(path), loop=True, realtime=True)
    runner = Runner([skin])
    t0 = time.monotonic()
    with runner:
        runner.run(0.5)
        elapsed = time.monotonic() - t0
        frames_seen = runner.stats()[0]["frames"]
    assert 0 < frames_seen <= 100 * elapsed + 10, (frames_seen, elapsed)


def test_pipeline_config_refuses_a_text_where_a_flag_goes():
    for key in ("drift_tracking", "emit_idle"):
        with pytest.raises(ValueError, match=f"{key} must be true or false, got 'no'"):
            PipelineConfig(**{key: "no"})
    with pytest.raises(ValueError, match="touch_on_z must be a number > 0, got True"):
        PipelineConfig(touch_on_z=True)
