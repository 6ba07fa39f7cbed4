"""Tests of the virtual skin device (a pty) read through SerialSource, faults included."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from skinloc.errors import FrameTimeoutError
from skinloc.hardware.ports import list_ports
from skinloc.hardware.serial import SerialSource, SerialSourceConfig
from skinloc.sim.skin import SimulatedSkin
from skinloc.sim.virtual_device import Fate, FaultConfig, VirtualSkin
from tests._helpers import wait_until

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="needs a POSIX pty")


def crc(values: np.ndarray) -> int:
    return zlib.crc32(np.asarray(values).astype("<u2").tobytes())


def read_n(src, n: int) -> list:
    return [src.read(timeout_s=30.0) for _ in range(n)]


@pytest.mark.parametrize("fmt", ["binary", "text"])
def test_streams_the_simulated_skin(fmt):
    with VirtualSkin(fmt=fmt, rate_hz=200, keep_truth=True) as dev:
        assert os.path.islink(dev.path)
        with SerialSource(SerialSourceConfig(dev.path)) as src:
            frames = read_n(src, 20)
            assert src.stats().format == fmt
        truth = dev.truth()
    sent = dict(zip(truth["crc"].tolist(), truth["fate"].tolist(), strict=True))
    assert all(sent.get(crc(f.values)) == Fate.SENT for f in frames)
    assert np.all(np.diff([f.index for f in frames]) == 1)


def test_listed_by_ports():
    with VirtualSkin(rate_hz=50) as dev:
        assert dev.path in [p.device for p in list_ports() if p.virtual]


def test_ports_skip_links_of_dead_devices():
    """A device killed hard leaves its link; its pty may since belong to another terminal."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = Path(tempfile.mkdtemp(prefix="skinloc-virtual-"))
    try:
        (stale / "ttySKIN0").symlink_to(os.devnull)
        assert str(stale / "ttySKIN0") not in [p.device for p in list_ports()]  # no pid file
        (stale / "pid").write_text(f"{dead.pid}\n")
        assert str(stale / "ttySKIN0") not in [p.device for p in list_ports()]
        (stale / "pid").write_text(f"{os.getpid()}\n")
        assert str(stale / "ttySKIN0") in [p.device for p in list_ports()]
    finally:
        shutil.rmtree(stale)


def test_commands_and_scripted_finger():
    skin = SimulatedSkin(random_state=0)
    with VirtualSkin(skin, fmt="binary", rate_hz=200) as dev:
        with SerialSource(SerialSourceConfig(dev.path)) as src:
            base = np.mean([f.values for f in read_n(src, 10)], axis=0)
            x, y, z = skin.sensor_positions[9]
            src.write(f"touch {x} {y} {z}\n".encode())
            wait_until(lambda: dev.counts["touches"] > 0, "the device to take the touch")

            # Frames from before the touch may still be in the pty on a busy machine: read
            # until the touch shows (bounded). The scripted finger misses its target like a
            # person (5.3 mm per axis) and may press lightly, but always hard enough to be felt.
            def strongest_touched() -> tuple[int] | None:
                touched = src.read(30.0).values - base
                k = int(np.argmax(touched))
                return (k,) if touched[k] > 25 else None  # a tuple: sensor 0 counts too

            (k,) = wait_until(strongest_touched, "the touch to show in the frames", 60.0, 0)
            assert np.linalg.norm(skin.contact - skin.sensor_positions[9]) < 0.03
            src.write(b"lift\nf text\n")
            wait_until(lambda: dev.fmt.value == "text", "the device to switch to text")
            # Frames sent before the lift may still be in the pty on a busy machine: the
            # promise is that the sensor comes back to its baseline, not when.
            src.clear()
            wait_until(lambda: abs(src.read(30.0).values[k] - base[k]) < 40,
                       f"sensor {k} to return to its baseline", 30.0, 0)  # fmt: skip
    assert dev.handle_command("v").startswith("skinloc_muca 1.1.0 grid 8x8 format text")
    assert dev.handle_command("g 300").startswith("error")
    assert dev.handle_command("g 0") == "error gain must be 1-31"
    assert dev.handle_command("g 20") == "ok gain 20"
    assert dev.handle_command("bogus").startswith("error unknown command")
    assert dev.handle_command("l 11110000 111") == "ok lines 4x3"  # the firmware's reply
    assert dev.handle_command("l 1111x 111").startswith("error usage")
    assert dev.handle_command("?").startswith("commands: v | f text|binary")


def test_reconnects_after_unplug_and_never_delivers_a_wrong_frame():
    faults = FaultConfig(
        p_garbage=0.1,
        p_drop=0.1,
        p_split=0.1,
        p_merge=0.05,
        disconnect_every_s=0.4,
        downtime_s=0.1,
        random_state=3,
    )
    with VirtualSkin(fmt="binary", rate_hz=200, faults=faults, keep_truth=True) as dev:
        src = SerialSource(SerialSourceConfig(dev.path, reconnect_interval_s=0.02))
        src.connect()
        got = []
        while dev.counts["disconnects"] < 3 or src.stats().n_reconnects < 3:
            try:
                got.append(src.read(timeout_s=30.0))
            except FrameTimeoutError:
                pytest.fail(f"the source did not recover: {src.stats()}")
        got += read_n(src, 5)  # frames flow again after the last reconnect
        dev.stop()

        # Drain: once the reader has seen the port go, it has delivered all it read before.
        # Not "1 s without a frame": a busy machine may pause longer than that.
        def drained() -> bool:
            try:
                got.append(src.read(timeout_s=1.0))
            except FrameTimeoutError:
                return not src.stats().link_up
            return False

        wait_until(drained, "the reader to see the port go", 60.0, interval_s=0)
        stats = src.stats()
        src.disconnect()
    truth = dev.truth()
    intact = set(truth["crc"][truth["fate"] == Fate.SENT].tolist())
    delivered = [crc(f.values) for f in got]
    assert all(c in intact for c in delivered)  # no wrong frame
    assert len(delivered) == len(intact)  # every intact frame arrived
    assert stats.n_reconnects >= 3 and stats.n_corrupted > 0


def test_config_checks():
    with pytest.raises(ValueError, match="rate_hz"):
        VirtualSkin(rate_hz=0)
    with pytest.raises(ValueError, match="'text' or 'binary'"):
        VirtualSkin(fmt="auto")
    with pytest.raises(ValueError, match="probabilities"):
        FaultConfig(p_drop=1.5)


def test_an_unplugged_virtual_skin_takes_its_port_away():
    """While unplugged, the port's link is gone: a host retrying it never opens someone else's
    pty that got the closed one's number (the gesture soak once read another test's skin)."""
    faults = FaultConfig(0, 0, 0, 0, disconnect_every_s=0.05, downtime_s=3.0)
    with VirtualSkin(rate_hz=100, faults=faults) as dev:
        wait_until(lambda: dev.counts["disconnects"] >= 1, "an unplug", 30.0, 0.005)
        assert dev.counts["disconnects"] == 1 and not dev.downtimes  # still unplugged
        assert not os.path.lexists(dev.path)
        wait_until(lambda: dev.downtimes, "the replug", 30.0, 0.01)
        a, b = dev.downtimes[0]  # plugged back in (and the link made anew) after the downtime
        assert b - a >= 3.0
