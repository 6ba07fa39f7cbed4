"""`skinloc run` on a board with a masked line: the skins file's tx_mask is applied live."""

from __future__ import annotations

import json
import signal
import subprocess

from skinloc.sim.virtual_device import VirtualSkin
from tests._helpers import start_skinloc, stop_and_wait, wait_until
from tests._live import model_path
from tests.live.test_port_reader import MARK, NinthLine


def test_run_on_a_port_applies_the_skins_file_masks(tmp_path):
    """A 9 x 8 virtual skin whose ninth TX line is masked out, run with a 64-sensor model.

    Before the one serial reader the loop never applied the masks: the run stopped at start.
    """
    out, err = tmp_path / "out.jsonl", tmp_path / "err.txt"
    with VirtualSkin(NinthLine(n_tx=9, n_rx=8, random_state=0), fmt="binary", rate_hz=200) as dev:
        cfg = tmp_path / "skins.toml"
        cfg.write_text(
            f'[[skin]]\nname = "arm"\nmodel = "{model_path("map")}"\nsource = "{dev.path}"\n'
            'wire_format = "binary"\nbaud = 1000000\ntx_mask = "111111110"\n'
            "pipeline = { emit_idle = true }\n"
        )
        with err.open("w") as err_fh:
            proc = start_skinloc("run", "--config", cfg, "--sink", f"jsonl:{out}",
                                 stdout=subprocess.DEVNULL, stderr=err_fh)  # fmt: skip
            try:
                wait_until(
                    lambda: out.is_file() and out.read_text().count("\n") >= 20,
                    lambda: f"20 records from the masked port; run said: {err.read_text()[-2000:]}",
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
    assert {r["skin"] for r in records} == {"arm"}
    # no finger: the ninth line's MARK, had it leaked into the 64 sensors, would be a touch
    assert MARK > 60000 and {r["state"] for r in records} == {"idle"}
