"""``skinloc prior build|show`` and the prior options of ``skinloc train``."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.data.recording import write_recording
from tests._helpers import one_line_error
from tests.conftest import make_recording


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


@pytest.fixture
def rec_path(tmp_path):
    p = tmp_path / "rec.h5"
    write_recording(make_recording(8, 4), p)
    return p


def test_show_the_package_prior():
    res = run("prior", "show")
    assert res.exit_code == 0, res.output
    assert "length scale" in res.output and "skinloc prior build" in res.output
    data = json.loads(run("prior", "show", "--json").output)
    assert data["version"] == 1 and "max_touches" in data


@pytest.mark.slow  # simulates skins and fits their maps
def test_build_a_small_prior_and_train_with_it(tmp_path, rec_path):
    out = tmp_path / "p.json"
    args = ("prior", "build", "--out", out, "--skins", "2", "--eval-skins", "1")
    res = run(*args, "--touches", "40", "--jobs", "1")
    assert res.exit_code == 0, res.output
    assert "skins per minute" in res.output and out.is_file()
    res = run(*args, "--touches", "40")
    one_line_error(res, "--force")  # never over an existing file unasked
    res = run("train", rec_path, "--out", tmp_path / "m.h5", "--prior", out)
    assert res.exit_code == 0, res.output
    assert "map prior" in res.output


def test_train_says_whether_it_used_the_prior(tmp_path, rec_path):
    res = run("train", rec_path, "--out", tmp_path / "a.h5")
    assert res.exit_code == 0, res.output
    assert "map prior" in res.output
    res = run("train", rec_path, "--out", tmp_path / "b.h5", "--no-prior")
    assert res.exit_code == 0, res.output
    assert "Without the map prior" in res.output


def test_prior_options_bad_input(tmp_path, rec_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{}")
    one_line_error(run("train", rec_path, "--out", tmp_path / "m.h5", "--prior", bad), "prior")
    assert not (tmp_path / "m.h5").exists()
    res = run("train", rec_path, "--out", tmp_path / "m.h5", "--no-prior", "--arch", "paper")
    one_line_error(res, "default model")
    one_line_error(run("prior", "show", bad), "bad.json", "version")
    res = run("prior", "build", "--out", tmp_path / "d.json", "--backend", "dask")
    one_line_error(res, "pip install 'skinloc[cluster]'")


@pytest.mark.parametrize("flag", [[], ["--no-prior"]])
def test_active_selection_with_and_without_the_prior(tmp_path, rec_path, flag):
    out = tmp_path / "m.h5"
    res = run("train", rec_path, "--select", "6", "--strategy", "active", "--out", out, *flag)
    assert res.exit_code == 0, res.output
    assert "Chose 6 point logs" in res.output and out.is_file()


def test_the_build_command_defaults_are_the_library_defaults():
    import inspect

    from typer.main import get_command

    from skinloc.sim.prior_build import build_prior

    cmd = get_command(app).commands["prior"].commands["build"]
    cli = {p.name: p.default for p in cmd.params}
    lib = {k: p.default for k, p in inspect.signature(build_prior).parameters.items()}
    assert cli["skins"] == lib["n_skins"] and cli["eval_skins"] == lib["n_eval_skins"]
    assert cli["touches"] == lib["n_touches"] and cli["seed"] == lib["seed"]
