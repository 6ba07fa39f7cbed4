"""skinloc's commands against the emulated board: the baud found by itself, --gain and --lines,
one-line errors for a board without a controller, `skinloc ports` and `skinloc doctor`."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.hardware.ports import PortInfo
from skinloc.sim.emulated_board import EmulatedBoard
from skinloc.sim.skin import SimulatedSkin

runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, list(args), env={"COLUMNS": "250"})


def flat(text: str) -> str:
    """The output with rich's line wrapping undone."""
    return " ".join(text.split())


def test_monitor_finds_the_baud_and_sets_gain_and_lines(fw_build):
    with EmulatedBoard(fw_build, SimulatedSkin(random_state=0)) as board:
        res = run("monitor", "--port", board.path, "--seconds", "0.5", "--gain", "12",
                  "--lines", "1111,111")  # fmt: skip
        assert res.exit_code == 0, res.output
        assert "skinloc_muca 1.1.0, grid 4x3, binary, gain 12, controller ok, 1000000" in flat(
            res.output
        )
        # the settings stay: a second command without them reads the board's 4 x 3 grid
        res = run("record", "--port", board.path, "--seconds", "0.3", "--out",
                  str(board.build.elf.parent / "stream-4x3.h5"), "--force")  # fmt: skip
        assert res.exit_code == 0, res.output
        assert "4 TX x 3 RX" in res.output
        res = run("monitor", "--port", board.path, "--seconds", "0.2",
                  "--lines", "11111111,11111111", "--gain", "8")  # fmt: skip
        assert res.exit_code == 0, res.output
    assert board.stats["gain"] == 8 and board.stats["fault"] == "none"


def test_a_board_without_a_controller_is_a_one_line_error(fw_build):
    with EmulatedBoard(fw_build, controller="missing") as board:
        res = run("monitor", "--port", board.path, "--seconds", "0.5")
    assert res.exit_code == 1
    lines = res.output.strip().splitlines()
    assert len(lines) == 1, res.output  # one line, however wide
    assert "finds no touch controller" in lines[0] and "SDA/SCL" in lines[0]


def test_grid_options_that_contradict_the_board_are_refused(fw_build):
    with EmulatedBoard(fw_build) as board:
        res = run("monitor", "--port", board.path, "--seconds", "0.2", "--tx", "4")
        assert res.exit_code == 1 and "sends 8 x 8 lines but --tx/--rx say 4 x None" in (res.output)
        res = run("monitor", "--port", board.path, "--lines", "11,1", "--tx", "3")
        assert res.exit_code == 1 and "--lines selects 2 x 1 lines" in flat(res.output)


def test_ports_marks_a_board_running_skinlocs_firmware(fw_build, monkeypatch):
    with EmulatedBoard(fw_build) as board:
        fake = [PortInfo(board.path, "Arduino Uno", "USB VID:PID=2341:0043", True)]
        monkeypatch.setattr("skinloc.hardware.ports.list_ports", lambda: fake)
        res = run("ports")
        assert res.exit_code == 0, res.output
        assert "skinloc board" in res.output and "skinloc_muca 1.1.0" in res.output
        res = run("ports", "--json")
        row = json.loads(res.output)[0]
        assert row["board"].startswith("skinloc_muca 1.1.0, grid 8x8")
        res = run("ports", "--no-ask")
        assert "skinloc board" not in res.output and "Arduino?" in res.output


@pytest.mark.parametrize(
    "kwargs, code, expect",
    [
        ({}, 0, ["ok controller", "no dead or noisy line", "healthy"]),
        ({"controller": "missing"}, 1, ["FAIL controller", "no touch controller", "not ready"]),
        ({"dead_rx": (3,)}, 1, ["FAIL lines", "RX 3 dead", "--rx-mask 11101111"]),
    ],
    ids=["healthy", "no-controller", "dead-line"],
)
def test_doctor(fw_build, kwargs, code, expect):
    with EmulatedBoard(fw_build, SimulatedSkin(random_state=0), **kwargs) as board:
        res = run("doctor", "--port", board.path, "--seconds", "1")
    assert res.exit_code == code, res.output
    for text in expect:
        assert text in flat(res.output), res.output


def test_run_applies_a_skins_file_line_mask_on_the_board(fw_build, tmp_path):
    """The board sends 9 x 8 lines (the ninth TX line has no wire: it reads 0); a skins file's
    ``tx_mask`` keeps the 8 x 8 the model was trained on, in ``skinloc run``'s own loop.

    Before the one serial reader the loop never applied the masks: the run stopped at start.
    """
    import signal
    import subprocess

    from tests._helpers import start_skinloc, stop_and_wait, wait_until
    from tests._live import model_path

    out, err = tmp_path / "out.jsonl", tmp_path / "err.txt"
    with EmulatedBoard(fw_build, SimulatedSkin(random_state=0)) as board:
        res = run("monitor", "--port", board.path, "--seconds", "0.2",
                  "--lines", "111111111,11111111")  # fmt: skip
        assert res.exit_code == 0 and "grid 9x8" in flat(res.output), res.output
        cfg = tmp_path / "skins.toml"
        cfg.write_text(
            f'[[skin]]\nname = "arm"\nmodel = "{model_path("map")}"\nsource = "{board.path}"\n'
            'wire_format = "binary"\nbaud = 1000000\ntx_mask = "111111110"\n'
            "pipeline = { emit_idle = true }\n"
        )
        with err.open("w") as err_fh:
            proc = start_skinloc("run", "--config", cfg, "--sink", f"jsonl:{out}",
                                 stdout=subprocess.DEVNULL, stderr=err_fh)  # fmt: skip
            try:
                wait_until(
                    lambda: out.is_file() and out.read_text().count("\n") >= 20,
                    lambda: f"20 records from the board; run said: {err.read_text()[-2000:]}",
                    180.0,
                    proc=proc,
                )
                stop_and_wait(proc, signal.SIGINT, "skinloc run")
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.wait()
    text = err.read_text()
    assert proc.returncode == 0 and "Traceback" not in text, text[-2000:]
    records = [json.loads(line) for line in out.read_text().splitlines()]
    assert {r["skin"] for r in records} == {"arm"} and {r["state"] for r in records} == {"idle"}
