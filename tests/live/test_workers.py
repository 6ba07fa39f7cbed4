"""``skinloc run --workers N``: the skins over N processes (``skinloc.live.workers``)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
from pathlib import Path

import pytest
from typer.testing import CliRunner

from skinloc.cli.main import app
from skinloc.live.workers import partition, worker_sinks
from tests._helpers import Lines, one_line_error, scaled, start_skinloc, wait_until

cli = CliRunner()


def _skins_file(tmp_path: Path, n: int, model: Path | None = None) -> Path:
    from tests._live import model_path

    cfg = tmp_path / "skins.toml"
    body = [f'[defaults]\nmodel = "{model or model_path("map")}"\nsource = "sim"\n']
    for i in range(n):
        body.append(f'[[skin]]\nname = "s{i}"\nsource = "sim:{i}"\n')
    cfg.write_text("".join(body))
    return cfg


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie is gone for our purpose (its parent, the test, did not reap a grandchild)
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


def _worker_pids(text: str) -> dict[int, int]:
    """``{worker index: pid}`` of the latest ``worker I (pid P): ...`` line of each worker."""
    return {int(w): int(p) for w, p in re.findall(r"worker (\d+) \(pid (\d+)\)", text)}


def test_partition_gives_consecutive_shares_within_one_of_each_other():
    shares = partition(100, 3)
    assert [len(s) for s in shares] == [34, 33, 33]
    assert [i for s in shares for i in s] == list(range(100))
    assert partition(2, 2) == [range(0, 1), range(1, 2)]
    assert partition(5, 1) == [range(0, 5)]
    for n, w in ((3, 4), (3, 0)):
        with pytest.raises(ValueError, match="workers must be 1..3"):
            partition(n, w)


def test_each_worker_gets_its_own_node_and_shared_sinks_only():
    assert worker_sinks(["ros2", "jsonl", "udp://127.0.0.1:9"], 1) == [
        "ros2:skinloc_1",
        "jsonl",
        "udp://127.0.0.1:9",
    ]
    assert worker_sinks(["ros2:arm"], 0) == ["ros2:arm_0"]
    for spec in ("ws://127.0.0.1:0", "jsonl:out.jsonl", "mcap:x.mcap", "lsl"):
        with pytest.raises(ValueError, match="every worker would open it"):
            worker_sinks([spec], 0)


def test_workers_need_a_skins_file_enough_skins_and_shareable_sinks(tmp_path):
    from tests._live import model_path

    res = cli.invoke(app, ["run", "--model", str(model_path("map")), "--source", "sim",
                           "--workers", "2"])  # fmt: skip
    one_line_error(res, "--workers", "skins file")
    cfg = _skins_file(tmp_path, 2)
    res = cli.invoke(app, ["run", "--config", str(cfg), "--workers", "3"])
    one_line_error(res, "workers must be 1..2")
    res = cli.invoke(app, ["run", "--config", str(cfg), "--workers", "2",
                           "--sink", "ws://127.0.0.1:0"])  # fmt: skip
    one_line_error(res, "ws://127.0.0.1:0", "every worker would open it")


def test_a_worker_that_cannot_start_fails_the_run_with_its_reason(tmp_path):
    bad = tmp_path / "broken.h5"
    bad.write_bytes(b"not a model at all")
    cfg = _skins_file(tmp_path, 2, model=bad)
    proc = start_skinloc("run", "--config", cfg, "--workers", "2", "--duration", "60",
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)  # fmt: skip
    _, err = proc.communicate(timeout=scaled(180.0))
    assert proc.returncode == 1, err
    assert "Traceback" not in err, err
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "could not start" in lines[0], err


def test_a_killed_worker_is_reported_and_restarted_and_ctrl_c_stops_every_worker(tmp_path):
    cfg = _skins_file(tmp_path, 3)
    # a session of its own: Ctrl-C in a terminal reaches the whole process group
    proc = start_skinloc(
        "run", "--config", cfg, "--workers", "2", "--stats", "--duration", "900",
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
    )  # fmt: skip
    out, err = Lines(proc.stdout), Lines(proc.stderr)
    try:
        wait_until(
            lambda: len(_worker_pids(err.text)) == 2, lambda: err.text[-2000:], 180.0, proc=proc
        )
        first = _worker_pids(err.text)
        assert "s0, s1" in err.text and "worker 1 (pid" in err.text
        wait_until(lambda: '"skin":"s2"' in out.text, lambda: out.text[-500:], 120.0)
        os.kill(first[1], signal.SIGKILL)  # worker 1 (skin s2) dies without a word
        err.wait_for("died (signal SIGKILL); restarting it", "the death reported", 60.0)
        wait_until(
            lambda: _worker_pids(err.text).get(1) not in (None, first[1]),
            lambda: err.text[-2000:],
            180.0,
            proc=proc,
        )
        assert "worker 1 (s2) restarted (1 so far)" in err.text
        n_before = out.text.count('"skin":"s2"')
        wait_until(lambda: out.text.count('"skin":"s2"') > n_before, lambda: err.text, 120.0)
        now = _worker_pids(err.text)
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C: the parent and both workers get it
        proc.wait(scaled(90.0))
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    text = err.rest()
    out.rest()
    assert proc.returncode == 0 and "Traceback" not in text, text[-3000:]
    for pid in (*first.values(), *now.values()):
        wait_until(lambda pid=pid: not _alive(pid), lambda pid=pid: f"worker {pid} alive", 30.0)
    # the merged statistics: every skin, its worker, the restart counted where it happened
    stats = json.loads(text.strip().splitlines()[-1])
    assert [(d["skin"], d["worker"], d["worker_restarts"]) for d in stats] == [
        ("s0", 0, 0),
        ("s1", 0, 0),
        ("s2", 1, 1),
    ]
    assert all(d["frames"] > 0 and d["errors"] == 0 for d in stats)
    for skin in ("s0", "s1", "s2"):
        assert re.search(rf"^{skin}: \d+ frames", text, re.M), text
    assert "s2: " in text and "worker restarted 1 time(s)" in text
    # both workers wrote whole lines to the one stdout, and every touch ended
    contacts = [json.loads(line) for line in out.lines]
    for skin in ("s0", "s2"):
        states = [c["state"] for c in contacts if c.get("skin") == skin and "state" in c]
        assert states and states[-1] == "end", (skin, states[-5:])
