"""A serial port missing when the runner opens: waited for (``SkinConfig.wait``) or refused."""

from __future__ import annotations

import errno
import threading

import pytest

from skinloc.errors import SourceNotConnectedError
from skinloc.live.runner import Runner, SkinConfig
from skinloc.sim.virtual_device import VirtualSkin
from tests._helpers import wait_until
from tests._live import model_path


def test_a_port_plugged_in_after_start_is_waited_for_and_read(tmp_path):
    before = {t.name for t in threading.enumerate()}
    link_dir = tmp_path / "dev"
    port = str(link_dir / "ttySKIN0")  # the virtual skin's link, made when it starts
    spec = SkinConfig(model_path("map"), source=port, name="arm", wire_format="binary", wait=True)
    runner = Runner([spec]).start()
    try:
        assert runner.waiting == [("arm", port)]
        s = runner.stats()[0]
        assert s["waiting"] and not s["link_up"] and runner.cores[0].n_frames == 0
        with VirtualSkin(fmt="binary", rate_hz=200, link_dir=link_dir):
            wait_until(
                lambda: runner.cores[0].n_frames > 20, "frames from the plugged-in port", 120.0
            )
            s = runner.stats()[0]
            assert runner.waiting == [] and not s["waiting"] and s["link_up"]
            assert s["reconnects"] == 0 and s["disconnects"] == 0  # a first open, not a recovery
        runner.wait(0.0)  # re-raises an error of the loop, if any
    finally:
        runner.close()
    assert runner.wait(0.0)
    wait_until(lambda: {t.name for t in threading.enumerate()} <= before, "threads to end", 30.0)


def test_a_missing_port_fails_without_wait(tmp_path):
    port = str(tmp_path / "ttyNONE")
    for wait in (None, False):  # None: the Python API's default is to fail, as before
        runner = Runner([SkinConfig(model_path("map"), source=port, wait=wait)])
        with pytest.raises(SourceNotConnectedError, match=f"cannot open serial port {port}: no"):
            runner.open()


def test_what_is_certainly_wrong_fails_even_when_waiting(tmp_path, monkeypatch):
    not_a_port = tmp_path / "notes.txt"
    not_a_port.write_text("hello\n")
    for path, match in ((not_a_port, "not a serial port"), (tmp_path, "not a serial port")):
        runner = Runner([SkinConfig(model_path("map"), source=str(path), wait=True)])
        with pytest.raises(SourceNotConnectedError, match=match):
            runner.open()
    # Permission denied (not reproducible as root): one line naming the dialout group.
    import serial

    def denied(url, **kw):
        raise serial.SerialException(errno.EACCES, f"could not open port {url}: denied")

    monkeypatch.setattr(serial, "serial_for_url", denied)
    runner = Runner([SkinConfig(model_path("map"), source="/dev/ttyACM9", wait=True)])
    with pytest.raises(SourceNotConnectedError, match="permission denied.*dialout"):
        runner.open()


def test_wait_must_be_a_bool():
    with pytest.raises(ValueError, match="wait must be true or false"):
        SkinConfig(model_path("map"), wait="yes")
