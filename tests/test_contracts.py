"""The contracts of the registries, run over every registered sink, model kind and source.

A sink: built from its spec, it opens, takes a frame's contacts (start, move, end), a single
contact and a gesture, and closes twice without error; a spec it cannot mean is one line of
``ValueError``. A model kind: a saved model of it loads, predicts the promised shapes, refuses
an image of the wrong width with a message naming the width, survives save-load unchanged and
exports or says why not. A source: built by ``make_source``, it connects once, reads frames of
its grid (or times out), and disconnects once; reading while closed is refused.
"""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest

from skinloc._lazy import extra_installed
from skinloc.live.contact import Contact
from skinloc.live.sinks import Sink, SkinInfo, make_sink, sink_types
from skinloc.models.engine import load_engine
from skinloc.models.kinds import model_kinds
from skinloc.models.localizer import ContactLocalizer

#: Per built-in sink: a spec that works here ({tmp}: a fresh folder, {udp}: a bound port) and
#: one it must refuse. A new sink adds its line (``test_every_sink_has_a_contract``).
SINK_CASES: dict[str, tuple[str, str]] = {
    "jsonl": ("jsonl:{tmp}/c.jsonl", "jsonl:"),
    "ws": ("ws://127.0.0.1:0", "ws://127.0.0.1:port"),
    "udp": ("udp://127.0.0.1:{udp}", "udp:host:notaport"),
    "foxglove": ("foxglove://127.0.0.1:0?mcap={tmp}/f.mcap", "foxglove://:0?mcp=x"),
    "mcap": ("mcap:{tmp}/m.mcap", "mcap:"),
    "lsl": ("lsl:skinloc-contract", "lsl:"),
    "ros2": ("ros2:skinloc_contract", "ros2:9bad name"),
    "mcap-ros2": ("mcap-ros2:{tmp}/r.mcap", "mcap-ros2:"),
}
SCHEMES = [t.scheme for t in sink_types() if t.scheme in SINK_CASES]


def _requires(scheme: str) -> str | None:
    return next(t.requires for t in sink_types() if t.scheme == scheme)


def _contact(state: str, k: int) -> Contact:
    return Contact(
        "arm", 1.0 + k, k, state, (0.01, 0.02, 0.03), (0.01, 0.02, 0.031), 0.8, 20.0,
        math.nan, 15.0, 1,
    )  # fmt: skip


def test_every_sink_has_a_contract():
    assert {t.scheme for t in sink_types()} <= set(SINK_CASES), "add the new sink to SINK_CASES"


@pytest.mark.parametrize("scheme", SCHEMES)
def test_sink_contract(scheme, tmp_path):
    needs = _requires(scheme)
    if needs is not None and not extra_installed(needs):
        pytest.skip(f"the {scheme} sink needs {needs}, not installed here")
    good, bad = SINK_CASES[scheme]
    with pytest.raises(ValueError) as refused:
        make_sink(bad)
    assert "\n" not in str(refused.value) and bad in str(refused.value)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx:
        rx.bind(("127.0.0.1", 0))
        sink = make_sink(good.format(tmp=tmp_path, udp=rx.getsockname()[1]))
        assert isinstance(sink, Sink)
        sink.open([SkinInfo("arm", n_tx=8, n_rx=8)])
        try:
            sink.emit_contacts("arm", 1.0, [_contact("start", 0)])
            sink.emit(_contact("move", 1))
            sink.emit_gesture("arm", 2.0, {"kind": "tap", "track_ids": [1]})
            sink.emit_contacts("arm", 3.0, [_contact("end", 2)])
        finally:
            sink.close()
        sink.close()  # idempotent


@pytest.mark.parametrize("kind", model_kinds())
def test_model_kind_contract(kind, tmp_path):
    from tests._live import model_path

    arch = {"map": "map", "network": "paper"}.get(kind)
    if arch is None:
        pytest.skip(f"no trained model of kind {kind!r} in tests/_live.py")
    path = model_path(arch)
    model = ContactLocalizer.load(path)
    assert model.config_["kind"] == kind and model.spec().kind == kind
    n = model.n_features_in_
    X = np.random.default_rng(0).uniform(0, 300, (5, n))
    pred = model.predict_full(X)
    assert pred.points.shape == (5, 3) and pred.raw.shape == (5, 3)
    assert pred.uncertainty_mm.shape == (5,)
    engine = load_engine(path)
    point, raw, spread = engine.predict_one(X[0].astype(np.float32))
    assert point.shape == raw.shape == (3,) and isinstance(spread, float)
    np.testing.assert_allclose(point, pred.points[0], atol=1e-6)
    for call in (model.predict, engine.predict_batch):
        with pytest.raises(ValueError, match=f"\\(n, {n}\\)"):
            call(np.zeros((2, n + 1)))
    copy = tmp_path / "again.h5"
    model.save(copy)
    np.testing.assert_allclose(ContactLocalizer.load(copy).predict(X), pred.points, atol=1e-9)
    from skinloc.models.export import c_header_source, onnx_model

    for export in (onnx_model, c_header_source):
        try:
            assert export(path) is not None
        except ValueError as why:  # not exportable: it says so in one line
            assert str(why) and "\n" not in str(why)


# ------------------------------------------------------------------------------- sources
def _source_options(kind, tmp_path):
    """Options that make a working source of ``kind`` here, and whether it sends frames."""
    from skinloc.sources import SourceKind, SourceOptions

    if kind is SourceKind.SIM:
        return SourceOptions("sim", seed=0, realtime=False), True
    if kind is SourceKind.SERIAL:
        return SourceOptions("loop://", n_tx=8, n_rx=8), False  # a port nobody writes to
    if kind is SourceKind.REPLAY:
        from skinloc.geometry.mesh import cone_skin
        from skinloc.sources.replay import write_stream_recording

        path = tmp_path / "stream.h5"
        rng = np.random.default_rng(0)
        write_stream_recording(
            path,
            n_tx=8,
            n_rx=8,
            mesh=cone_skin(),
            baseline_frames=rng.normal(1000, 2, (20, 64)),
            frames=rng.normal(1000, 2, (30, 64)),
            times_s=np.arange(30) / 100,
            index=np.arange(30),
        )
        return SourceOptions(str(path), realtime=False), True
    if kind is SourceKind.BAG:
        if not extra_installed("mcap"):
            pytest.skip("a ROS 2 bag needs the live extra (mcap), not installed here")
        path = tmp_path / "frames.mcap"
        sink = make_sink(f"mcap-ros2:{path}")
        sink.open([SkinInfo("arm", n_tx=8, n_rx=8)])
        for k in range(5):
            sink.emit_frame("arm", np.full(64, 1000.0 + k), 0.01 * k, k)
        sink.close()
        return SourceOptions(str(path), realtime=False), True
    raise AssertionError(f"add a contract case for the source kind {kind!r}")


def _source_kinds():
    from skinloc.sources import SourceKind

    return list(SourceKind)


@pytest.mark.parametrize("kind", _source_kinds(), ids=str)
def test_source_contract(kind, tmp_path):
    """Every source: connect once, read frames of its grid or time out, disconnect once."""
    from skinloc.errors import (
        FrameTimeoutError,
        SourceAlreadyConnectedError,
        SourceNotConnectedError,
    )
    from skinloc.sources import FrameSource, make_source

    options, sends = _source_options(kind, tmp_path)
    src = make_source(options)
    assert isinstance(src, FrameSource) and src.n_sensors == 64
    with pytest.raises(SourceNotConnectedError):
        src.read(0.1)
    with src:
        assert src.is_connected
        with pytest.raises(SourceAlreadyConnectedError):
            src.connect()
        if sends:
            frame = src.read(5.0)
            assert frame.values.shape == (64,) and np.all(np.isfinite(frame.values))
        else:
            with pytest.raises(FrameTimeoutError):
                src.read(0.2)
    assert not src.is_connected
    with pytest.raises(SourceNotConnectedError):
        src.disconnect()
    with pytest.raises(SourceNotConnectedError):
        src.read(0.1)
