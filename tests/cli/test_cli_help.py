"""``--help`` reads as a reference: flags read as flags (``--force``, not ``--force <bool>``)."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app

COMMANDS = sorted(
    {c.name or c.callback.__name__.replace("_", "-") for c in app.registered_commands}
)


@pytest.mark.parametrize("command", ["", *COMMANDS])
def test_flags_show_no_value_type(command):
    res = CliRunner().invoke(app, [*command.split(), "--help"], env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "<bool>" not in res.output
    # --help itself is a flag: nothing between its name and its help text
    assert re.search(r"--help\s+Show this message and exit", res.output), res.output


def test_options_with_values_still_show_their_type():
    res = CliRunner().invoke(app, ["run", "--help"], env={"COLUMNS": "200"})
    assert re.search(r"--model\s+-m\s+<path>", res.output), res.output
    assert re.search(r"--fast\s+Replay recordings", res.output), res.output
