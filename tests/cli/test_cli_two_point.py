"""``skinloc sensors`` and ``coverage`` show the skin's two-point threshold (docs/sensors.md)."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from tests._live import model_path
from tests.cli.conftest import GOLDEN_MODEL


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.mark.slow  # a model trained with its two-point search
def test_a_new_model_shows_its_threshold_in_words_and_json():
    path = model_path("map")
    res = run("coverage", path, "--json", "--points", "60")
    assert res.exit_code == 0, res.output
    tp = json.loads(res.output)["two_point"]
    assert tp["measured"] and tp["within_mm"] == 15.0 and tp["share"] == 0.9
    assert tp["bins"] and tp["text"].startswith("two-point threshold:")
    if tp["counted_two_mm"] is not None:
        assert f"closer than {tp['counted_two_mm']:.0f} mm are read as one" in tp["text"]
    for command in (("sensors", path), ("coverage", path, "--points", "60")):
        res = run(*command)
        assert res.exit_code == 0, res.output
        assert "two-point threshold:" in res.output and "unknown" not in res.output
    res = run("sensors", path, "--json")
    assert json.loads(res.output)["two_point"] == tp


def test_a_model_saved_before_it_says_unknown():
    res = run("sensors", GOLDEN_MODEL, "--json")
    assert res.exit_code == 0, res.output
    tp = json.loads(res.output)["two_point"]
    assert not tp["measured"] and tp["counted_two_mm"] is None and "unknown" in tp["text"]
    res = run("coverage", GOLDEN_MODEL, "--points", "60")
    assert res.exit_code == 0, res.output
    assert "two-point threshold: unknown" in res.output
