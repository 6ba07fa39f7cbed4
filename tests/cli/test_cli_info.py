"""``skinloc info`` opens every file skinloc writes: recordings, models, histories, MCAP files.

(Recordings and histories: ``test_cli.py``; the wrong kinds of file: ``test_cli_file_kinds.py``.)
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from tests.cli.conftest import GOLDEN_MODEL

runner = CliRunner()


def info(path: Path, *extra: str) -> dict:
    res = runner.invoke(app, ["info", str(path), "--json", *extra])
    assert res.exit_code == 0, res.output
    return json.loads(res.output)


def test_info_describes_a_model_without_building_it():
    from skinloc.models.localizer import ContactLocalizer

    got = info(GOLDEN_MODEL)
    assert got["format"] == "skinloc-model" and got["kind"] in ("map", "network")
    assert got["n_sensors"] == ContactLocalizer.load(GOLDEN_MODEL).n_features_in_
    assert got["config"]["kind"] == got["kind"]
    assert got["mesh_faces"] > 0 and got["surface_points"] > 0
    table = runner.invoke(app, ["info", str(GOLDEN_MODEL)])
    assert table.exit_code == 0 and "n_sensors" in table.output


def test_info_of_a_model_it_trained_names_what_it_was_trained_on(tmp_path):
    from skinloc.data.recording import write_recording
    from tests.conftest import make_recording

    rec, model = tmp_path / "cal.h5", tmp_path / "m.h5"
    write_recording(make_recording(12, 4), rec)
    res = runner.invoke(app, ["train", str(rec), "--out", str(model)])
    assert res.exit_code == 0, res.output
    got = info(model)
    assert got["training"]["n_point_logs"] == 12 and got["training"]["n_recordings"] == 1
    assert got["created"] and got["skinloc_version"]


@pytest.mark.parametrize(
    ("sink", "topics", "replayable"),
    [
        ("mcap-ros2:{}", {"/skinloc/skin/frames", "/skinloc/skin/contacts", "/tf_static"}, True),
        ("mcap:{}", {"/skinloc/contacts", "/skinloc/scene"}, False),
    ],
    ids=["ros2-bag", "foxglove"],
)
def test_info_describes_the_mcap_files_run_writes(tmp_path, sink, topics, replayable):
    pytest.importorskip("mcap")
    if sink.startswith("mcap:"):
        pytest.importorskip("foxglove")
    from tests._live import model_path, stream_recording

    out = tmp_path / "run.mcap"
    res = runner.invoke(
        app,
        ["run", "--model", str(model_path("map")), "--source", str(stream_recording()), "--fast",
         "--sink", sink.format(out)],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    got = info(out)
    assert got["format"] == "mcap" and got["n_messages"] > 0 and got["duration_s"] > 0
    by_topic = {ch["topic"]: ch for ch in got["channels"]}
    assert topics <= set(by_topic), sorted(by_topic)
    assert sum(ch["n_messages"] for ch in got["channels"]) == got["n_messages"]
    if replayable:
        assert got["profile"] == "ros2"
        assert got["replayable"] == ["/skinloc/skin/frames"]
        assert by_topic["/skinloc/skin/frames"]["schema"] == "sensor_msgs/msg/Image"
    else:
        assert got["replayable"] == []
    table = runner.invoke(app, ["info", str(out)])
    assert table.exit_code == 0 and "channels" in table.output


def test_info_of_an_unfinished_mcap_file_is_one_line(tmp_path):
    pytest.importorskip("mcap")
    from tests._live import model_path, stream_recording
    from tests.cli.test_cli_bad_input import one_line_error

    out = tmp_path / "run.mcap"
    res = runner.invoke(
        app,
        ["run", "--model", str(model_path("map")), "--source", str(stream_recording()), "--fast",
         "--sink", f"mcap-ros2:{out}"],
    )  # fmt: skip
    assert res.exit_code == 0, res.output
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(out.read_bytes()[: out.stat().st_size // 2])  # a writer killed mid-run
    one_line_error(runner.invoke(app, ["info", str(cut)]), "cut.mcap")
