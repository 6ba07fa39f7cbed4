"""Every command given the wrong kind of file says what it got and what it expects, in one line.

The same cases run in the plain install (``test_plain_install.py``) for a few of them; here
they run in process, all of them.
"""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from tests.cli.test_cli_bad_input import one_line_error

CASES = [
    (["coverage", "{stream}"], "raw stream"),
    (["sensors", "{stream}"], "raw stream"),
    (["train", "{stream}", "--out", "{out}/m.h5"], "raw stream"),
    (["evaluate", "{model}", "{stream}"], "raw stream"),
    (["snr", "{stream}"], "raw stream"),
    (["evaluate", "{rec}", "{rec}"], "is a recording, not a model"),
    (["run", "--model", "{rec}", "--source", "sim"], "is a recording, not a model"),
    (["export", "{rec}", "--c-header", "{out}/m.h"], "is a recording, not a model"),
    (["predict", "{rec}", "{rec}"], "is a recording, not a model"),
    (["train", "{rec}", "--init", "{rec}", "--out", "{out}/m.h5"], "is a recording, not a model"),
    (["info", "{bag}"], "cannot read the MCAP file"),
    (["snr", "{model}"], "is a model, not a recording"),
    (["convert", "{model}", "{out}/x.mat"], "is a model, not a recording"),
    (["run", "--model", "{model}", "--source", "{model}"], "is a model, not a recording"),
    (
        ["run", "--model", "{model}", "--source", "sim", "--baseline", "{model}"],
        "is a model, not a recording",
    ),
    (["info", "{text}"], "notes.h5"),
    (["info", "{empty}"], "empty"),
    (["coverage", "{text}"], "notes.h5"),
    (["predict", "{model}", "{text}"], "notes.h5"),
    (["simulate", "--mesh", "{model}", "--out", "{out}/s.h5"], "cannot read mesh"),
    (["record", "--source", "sim", "--mesh", "{text}", "--out", "{out}/r.h5"], "mesh"),
    (["collect", "--source", "sim", "--mesh", "{empty}", "--out", "{out}/c.h5"], "mesh"),
    (["app", "--mesh", "{text}", "--no-browser", "--port", "0"], "mesh"),
    (["run", "--config", "{text}"], "notes.h5"),
    (["virtual-skin", "--truth", "{out}", "--seconds", "0.5"], ".npz"),
    (["bench", "--real", "{out}/nowhere", "--out", "{out}/bench"], "not a folder"),
    (["demo", "--out", "{rec}"], "is a file"),
]


@pytest.mark.parametrize(("args", "needle"), CASES, ids=[" ".join(a[:2]) for a, _ in CASES])
def test_the_wrong_kind_of_file_is_one_line_saying_what_it_is(wrong_inputs, args, needle):
    from skinloc.cli.main import app

    names = {k: str(v) for k, v in wrong_inputs.items()}
    res = CliRunner().invoke(app, [a.format(**names) for a in args])
    one_line_error(res, needle)
