"""``skinloc app`` on the command line: bad input ends in one line and exit 1."""

from __future__ import annotations

import socket

from typer.testing import CliRunner

from skinloc.cli import app

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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_bad_serial_port(tmp_path):
    tty = str(tmp_path / "ttyNONE")
    # The app checks its TCP port before the serial port (and rejects --port 0), so it needs a
    # free one; another process may take it between free_port() and the check: try again.
    for _ in range(5):
        result = run("--source", tty, "--data", str(tmp_path), "--port", str(free_port()))
        if "pass another --port" not in result.output:
            break
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
        result = run("--source", source, "--data", str(tmp_path), "--port", str(free_port()))
        assert result.exit_code == 1 and "Traceback" not in result.output
        assert "pyserial URL" in result.output and "'sim'" in result.output
    assert victim.read_text() == "keep me\n"
