"""`skinloc run --sink`: a spec the sink cannot mean is one line of error, and a sink registered
from outside the package (here: this test module) runs end to end."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.live.sinks import Sink, SinkSpec, register_sink, unregister_sink
from tests._helpers import one_line_error
from tests._live import model_path, stream_recording

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.mark.parametrize(
    ("spec", "needles"),
    [
        # used to send to 127.0.0.1:9870 without a word  # any-port-ok: never bound
        ("udp:host:notaport", ("bad port 'notaport'", "udp:host:notaport", "0-65535")),
        ("udp://host:", ("bad port", "0-65535")),
        # used to write to stdout without a word
        ("jsonl:", ("'jsonl:'", "names no file", "jsonl alone for stdout")),
        # used to be accepted, and fail (rclpy) or be ignored (plain DDS) later
        ("ros2:9bad name", ("ROS 2 node name '9bad name'", "letters, digits and underscores")),
        ("ros2:9bad", ("must not start with a digit",)),
        ("ros2:", ("name after ':' is empty",)),
        ("foxglove://127.0.0.1:0?mcp=x.mcap", ("unknown option(s) mcp", "known: mcap, live")),
        ("ws://127.0.0.1:8767/path", ("unexpected path '/path'",)),  # any-port-ok: refused
        ("pigeon", ("unknown sink 'pigeon'", "udp://HOST:PORT")),
        ("mcap:", ("'mcap:FILE' needs a file name",)),
    ],
)
def test_a_bad_sink_spec_is_one_line_of_error(spec, needles):
    # a source that ends: before the checks, the run went on with the spec misread
    res = run("run", "--model", model_path("map"), "--source", stream_recording(), "--fast",
              "--sink", spec)  # fmt: skip
    assert res.exit_code == 1
    one_line_error(res, *needles)


class ToySink(Sink):
    """Counts what it gets; ``toy[:LABEL]``."""

    name = "toy"
    last: ToySink | None = None

    def __init__(self, label: str) -> None:
        self.label = label
        self.skins: list[str] = []
        self.contacts: list = []
        self.closed = 0
        ToySink.last = self

    @classmethod
    def from_spec(cls, spec: SinkSpec) -> ToySink:
        return cls(spec.label("toy"))

    def open(self, skins) -> None:
        self.skins = [s.name for s in skins]

    def emit(self, contact) -> None:
        self.contacts.append(contact)

    def close(self) -> None:
        self.closed += 1


@pytest.fixture
def toy_sink():
    register_sink("toy", form="toy[:LABEL] (a test's sink)")(ToySink)
    ToySink.last = None
    yield ToySink
    unregister_sink("toy")


def test_a_sink_registered_from_a_test_module_runs_end_to_end(toy_sink):
    res = run("run", "--model", model_path("map"), "--source", stream_recording(), "--fast",
              "--name", "arm", "--sink", "toy:here")  # fmt: skip
    assert res.exit_code == 0, res.output
    sink = toy_sink.last
    assert sink is not None and sink.label == "here" and sink.skins == ["arm"]
    states = [c.state for c in sink.contacts]
    assert states.count("start") == states.count("end") > 3
    assert sink.closed == 1
    # its form joins the help of an unknown sink; without the registration it is unknown
    sim = ("run", "--model", model_path("map"), "--source", "sim")
    assert "toy[:LABEL]" in one_line_error(run(*sim, "--sink", "x"))
    unregister_sink("toy")
    one_line_error(run(*sim, "--sink", "toy"), "unknown sink 'toy'")


def test_a_scheme_is_registered_once():
    from skinloc.live.sinks.jsonl import JsonLinesSink

    with pytest.raises(ValueError, match="already registered as 'jsonl'"):
        register_sink("jsonl")(JsonLinesSink)
    with pytest.raises(ValueError, match="letters, digits"):
        register_sink("a b", "x:y")
