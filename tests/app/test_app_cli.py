"""``skinloc app`` on the command line: bad input ends in one line and exit 1."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import time

import httpx
from typer.testing import CliRunner

from skinloc.cli.main import app

runner = CliRunner()


def run(*args: str):
    return runner.invoke(app, ["app", "--no-browser", *args])


def test_help():
    result = runner.invoke(app, ["app", "--help"])
    assert result.exit_code == 0 and "--source" in result.output


def test_missing_mesh(tmp_path):
    result = run("--mesh", str(tmp_path / "nope.obj"), "--data", str(tmp_path))
    assert result.exit_code == 1
    assert "mesh file not found" in result.output and "Traceback" not in result.output


def test_bad_serial_port(tmp_path):
    tty = str(tmp_path / "ttyNONE")
    result = run("--source", tty, "--data", str(tmp_path), "--port", "0")
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert f"cannot open serial port {tty}" in result.output


def test_unknown_format(tmp_path):
    result = run("--format", "morse", "--data", str(tmp_path))
    assert result.exit_code == 1 and "morse" in result.output


def test_port_in_use(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        result = run("--port", str(port), "--data", str(tmp_path))
    assert result.exit_code == 1 and "pass another --port" in result.output
    assert len(result.output.strip().splitlines()) == 1


def test_pyserial_url_is_refused(tmp_path):
    victim = tmp_path / "precious.txt"
    victim.write_text("keep me\n")
    for source in (f"spy://loop://?file={victim}", "socket://127.0.0.1:9"):
        result = run("--source", source, "--data", str(tmp_path), "--port", "0")
        assert result.exit_code == 1 and "Traceback" not in result.output
        assert "pyserial URL" in result.output and "'sim'" in result.output
    assert victim.read_text() == "keep me\n"


def test_port_0_serves_on_the_port_it_got(tmp_path):
    """``--port 0`` binds any free port and prints the URL with the port it got."""

    cmd = [sys.executable, "-m", "skinloc", "app", "--no-browser", "--port", "0"]
    proc = subprocess.Popen(
        [*cmd, "--data", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        line = proc.stdout.readline()  # blocks until the app prints its URL (or exits)
        match = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
        assert match, f"no URL in {line!r}"
        port = int(match.group(1))
        assert port != 0
        page = None
        for _ in range(600):  # bounded: the server may take a while to start on a busy machine
            try:
                page = httpx.get(f"http://127.0.0.1:{port}/", timeout=10)
                break
            except httpx.TransportError:
                if proc.poll() is not None:
                    break
                time.sleep(0.1)
        assert page is not None and page.status_code == 200
        assert "skinloc-token" in page.text
    finally:
        proc.terminate()
        proc.wait(timeout=60)
