"""`skinloc run` started before the skin is plugged in: it waits, and one Ctrl-C stops it."""

from __future__ import annotations

import json
import signal
import subprocess

from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.sim.virtual_device import VirtualSkin
from tests._helpers import start_skinloc, stop_and_wait, wait_until
from tests._live import model_path


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_run_waits_for_a_port_plugged_in_later_and_stops_on_one_ctrl_c(tmp_path):
    link_dir = tmp_path / "dev"
    port = link_dir / "ttySKIN0"  # appears when the virtual skin starts
    out, err = tmp_path / "out.jsonl", tmp_path / "err.txt"

    def said() -> str:
        return f"skinloc run said: {err.read_text()[-2000:]}"

    with err.open("w") as err_fh:
        proc = start_skinloc(
            "run", "--model", model_path("map"), "--source", port, "--name", "arm",
            "--format", "binary", "--emit-idle", "--sink", f"jsonl:{out}", "--duration", "600",
            stdout=subprocess.DEVNULL, stderr=err_fh,
        )  # fmt: skip
        try:
            waiting = f"waiting for {port} (skin arm): not present; plug it in or press Ctrl-C"
            wait_until(lambda: waiting in err.read_text(), lambda: f"the waiting line; {said()}",
                       180.0, interval_s=0.05, proc=proc)  # fmt: skip
            with VirtualSkin(fmt="binary", rate_hz=200, link_dir=link_dir):
                wait_until(
                    lambda: out.is_file() and out.stat().st_size > 0,
                    lambda: f"output from the plugged-in port; {said()}",
                    180.0,
                    interval_s=0.05,
                    proc=proc,
                )
                stop_and_wait(proc, signal.SIGINT, "skinloc run")  # one Ctrl-C
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    text = err.read_text()
    assert proc.returncode == 0 and "Traceback" not in text, text[-2000:]
    assert text.count("waiting for") == 1  # said once, not at every retry
    assert f"{port} (skin arm) is here" in text
    assert json.loads(out.read_text().splitlines()[0])["skin"] == "arm"
    assert "arm: " in text and ", 0 reconnects" in text  # the summary: a first open


def test_run_no_wait_and_a_skins_file_wait_false_fail_at_once(tmp_path):
    port = tmp_path / "ttyNONE"
    res = run("run", "--model", model_path("map"), "--source", port, "--no-wait")
    assert res.exit_code == 1 and f"cannot open serial port {port}: no such device" in res.output
    assert "Traceback" not in res.output
    cfg = tmp_path / "robot.toml"
    skin = f'[[skin]]\nname = "arm"\nmodel = "{model_path("map")}"\nsource = "{port}"\n'
    cfg.write_text(skin + "wait = false\n")
    res = run("run", "--config", cfg)
    assert res.exit_code == 1 and "no such device" in res.output
    cfg.write_text(skin + 'wait = "yes"\n')
    res = run("run", "--config", cfg)
    assert res.exit_code == 1 and "skin 'arm': wait must be true or false" in res.output
    # Certainly wrong whatever the waiting: not a serial port.
    cfg.write_text(skin.replace(str(port), str(tmp_path)))
    res = run("run", "--config", cfg)
    assert res.exit_code == 1 and "is not a serial port" in res.output
