"""The emulated board: skinloc's real firmware in an AVR emulator, streaming the simulated skin.

``EmulatedBoard`` starts ``firmware/sim/skinloc_avrsim`` (simavr running the firmware's
``.elf`` for an Uno, an emulated FT5x06 on its I2C bus, its UART on a pseudo-terminal) and
serves it the raw counts of a ``SimulatedSkin`` over a socket: every raw scan the firmware
starts latches the skin's next frame. skinloc then reads the pseudo-terminal exactly as it
reads a real board (``skinloc monitor --port /dev/pts/N``), so a finger pressed on the simulated
skin goes through the real firmware. Lines ``touch X Y Z`` (m) and ``lift`` sent to the port are
the bench's finger: the harness hands them to the skin instead of the board, so
``skinloc collect --scripted-finger`` runs unattended.

Needs a source checkout with the firmware built (``make -C firmware all sim``: gcc-avr,
avr-libc, arduino-core-avr, simavr, libsimavr-dev; ``build_firmware`` runs it). POSIX only.

Run one from a shell (prints the port, Ctrl-C stops)::

    python -m skinloc.sim.emulated_board [--controller missing] [--dead-rx 3]
"""

from __future__ import annotations

import json
import logging
import shutil
import signal
import socket
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.hardware.protocol import MAX_RX, MAX_TX

log = logging.getLogger(__name__)

__all__ = ["EmulatedBoard", "FirmwareBuild", "build_firmware", "firmware_dir"]

#: Packages the build and the emulator need (Debian names).
PACKAGES = ("gcc-avr", "avr-libc", "arduino-core-avr", "simavr", "libsimavr-dev")
_FRAME_BYTES = MAX_TX * MAX_RX * 2


def firmware_dir() -> Path:
    """The ``firmware/`` folder of the source checkout this package runs from."""
    return Path(__file__).resolve().parents[3] / "firmware"


class FirmwareBuild:
    """Where a build put the firmware and the harness.

    Attributes
    ----------
    elf : Path
        The firmware for the Uno (``skinloc_muca.elf``).
    harness : Path
        The emulator (``skinloc_avrsim``).
    size_line : str
        What the build printed about flash and RAM.
    """

    def __init__(self, elf: Path, harness: Path, size_line: str) -> None:
        self.elf, self.harness, self.size_line = elf, harness, size_line


def missing_tools() -> list[str]:
    """What the build lacks on this machine (empty when it can run)."""
    missing = [t for t in ("make", "avr-gcc", "avr-g++", "avr-size", "cc") if not shutil.which(t)]
    core = Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h")
    if not core.exists():
        missing.append("arduino-core-avr")
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        missing.append("libsimavr-dev")
    return missing


def build_firmware(build_dir: Path | str | None = None, *, extra: str = "") -> FirmwareBuild:
    """Build the firmware and the harness with ``make -C firmware all sim``.

    Parameters
    ----------
    build_dir : path, optional
        Output folder (default ``firmware/build``).
    extra : str
        Extra compiler options for the firmware, e.g. ``"-DSKINLOC_BAUD=115200"``.

    Raises
    ------
    RuntimeError
        With make's output when the build fails.
    """
    fw = firmware_dir()
    build = Path(build_dir) if build_dir is not None else fw / "build"
    cmd = ["make", "-s", "-C", str(fw), f"BUILD={build.resolve()}", "all", "sim"]
    if extra:
        cmd.append(f"EXTRA={extra}")
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{res.stdout}\n{res.stderr}")
    size = next((ln for ln in res.stdout.splitlines() if "static RAM" in ln), "")
    return FirmwareBuild(build / "skinloc_muca.elf", build / "skinloc_avrsim", size)


class EmulatedBoard:
    """The firmware in simavr behind a pseudo-terminal, fed by a simulated skin.

    Parameters
    ----------
    build : FirmwareBuild
        From ``build_firmware``.
    skin : SimulatedSkin, optional
        Serves the raw counts: its TX/RX lines are the controller's first lines, the others
        read 0. ``None``: the harness's own pattern, ``(scan & 0xFF) << 8 | (tx * 12 + rx)``.
    controller : {"ok", "missing", "silent"}
        The emulated controller: present, absent from the bus, or present but never scanning.
    scan_us : int
        Emulated duration of one raw scan, microseconds.
    speed : float
        Emulated seconds per wall second (1: a real board's pace; 0: as fast as it can).
    dead_rx, dead_tx : sequence of int
        Lines that read 0 (a broken wire).
    keep_frames : bool
        Keep every frame served since the board's last reset (``served``).
    hand : callable, optional
        ``hand(skin)`` before every frame: moves the skin's fingers (e.g. on ``skin.time_s``).

    Attributes
    ----------
    path : str
        The pseudo-terminal (``/dev/pts/N``), after ``start``.
    served : list of (n_tx * n_rx,) uint16
        With ``keep_frames``: the skin's frames served since the last reset (a host opening the
        port resets the board), in order. ``served[0]`` is the firmware's trial scan at
        start-up; its frame ``k`` after the reset is ``served[k + 1]``.
    stats : dict
        The harness's counters, after ``stop``.
    """

    def __init__(
        self,
        build: FirmwareBuild,
        skin: Any = None,
        *,
        controller: str = "ok",
        scan_us: int = 1000,
        speed: float = 1.0,
        dead_rx: tuple[int, ...] = (),
        dead_tx: tuple[int, ...] = (),
        keep_frames: bool = False,
        hand: Callable[[Any], None] | None = None,
    ) -> None:
        if controller not in ("ok", "missing", "silent"):
            raise ValueError(f"controller must be ok, missing or silent, got {controller!r}")
        self.build = build
        self.skin = skin
        self.controller = controller
        self.scan_us = int(scan_us)
        self.speed = float(speed)
        self.dead_rx, self.dead_tx = tuple(dead_rx), tuple(dead_tx)
        self.keep_frames = keep_frames
        self.hand = hand
        self.path = ""
        self.served: list[np.ndarray] = []
        self.n_served = 0
        self.n_resets = 0
        self.finger_lines: list[str] = []
        self.stats: dict[str, Any] = {}
        self._proc: subprocess.Popen[str] | None = None
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.feed_error: BaseException | None = None

    def __enter__(self) -> EmulatedBoard:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> str:
        """Start the emulator; returns the pseudo-terminal's path."""
        cmd = [
            str(self.build.harness),
            str(self.build.elf),
            "--controller",
            self.controller,
            "--scan-us",
            str(self.scan_us),
            "--speed",
            repr(self.speed),
        ]
        for r in self.dead_rx:
            cmd += ["--dead-rx", str(int(r))]
        for t in self.dead_tx:
            cmd += ["--dead-tx", str(int(t))]
        pass_fds: tuple[int, ...] = ()
        child = None
        if self.skin is not None:
            if not self.skin.is_connected:
                self.skin.connect()
            self._sock, child = socket.socketpair()
            cmd += ["--feed-fd", str(child.fileno())]
            pass_fds = (child.fileno(),)
            self._thread = threading.Thread(target=self._feed, name="emulated-board-feed")
            self._thread.daemon = True
        self._proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, pass_fds=pass_fds
        )
        if child is not None:
            child.close()
        if self._thread is not None:
            self._thread.start()
        assert self._proc.stdout is not None
        for line in self._proc.stdout:
            if line.startswith("pty "):
                self.path = line.split(None, 1)[1].strip()
                break
        if not self.path:
            err = self._proc.stderr.read() if self._proc.stderr else ""
            raise RuntimeError(f"the emulator did not start: {err.strip()}")
        return self.path

    def snapshot(self) -> dict[str, Any]:
        """The harness's counters now, without stopping it."""
        proc = self._proc
        if proc is None or proc.stdout is None:
            raise RuntimeError("the emulated board is not running")
        proc.send_signal(signal.SIGUSR1)
        for line in proc.stdout:
            if line.startswith("{"):
                return json.loads(line)
        raise RuntimeError("the emulator stopped")

    def stop(self) -> dict[str, Any]:
        """Stop the emulator; returns (and keeps in ``stats``) its counters."""
        proc, self._proc = self._proc, None
        if proc is None:
            return self.stats
        proc.send_signal(signal.SIGTERM)
        try:
            out, err = proc.communicate(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
        if self._sock is not None:
            self._sock.close()
        if self._thread is not None:
            self._thread.join(timeout=5)
        for line in out.splitlines():
            if line.startswith("{"):
                self.stats = json.loads(line)
        self.stats["returncode"] = proc.returncode
        self.stats["stderr"] = err
        return self.stats

    # -- the value feed ------------------------------------------------------------------------
    def _feed(self) -> None:
        sock = self._sock
        assert sock is not None
        skin = self.skin
        grid = np.zeros((MAX_TX, MAX_RX), dtype="<u2")
        try:
            while True:
                kind = sock.recv(1)
                if not kind:
                    return
                if kind == b"S":
                    if self.hand is not None:
                        self.hand(skin)
                    values = np.asarray(skin.read().values)
                    counts = np.clip(np.rint(values), 0, 65535).astype("<u2")
                    grid[: skin.n_tx, : skin.n_rx] = counts.reshape(skin.n_tx, skin.n_rx)
                    sock.sendall(grid.tobytes())
                    with self._lock:
                        self.n_served += 1
                        if self.keep_frames:
                            self.served.append(counts)
                elif kind == b"R":
                    with self._lock:
                        self.n_resets += 1
                        self.served.clear()
                elif kind == b"T":
                    line = bytearray()
                    while not line.endswith(b"\n"):
                        b = sock.recv(1)
                        if not b:
                            return
                        line += b
                    self._finger(line.decode("ascii", "replace").strip())
        except OSError as exc:  # the harness went away
            self.feed_error = exc

    def _finger(self, line: str) -> None:
        self.finger_lines.append(line)
        words = line.split()
        if words[:1] == ["lift"]:
            self.skin.release()
        elif words[:1] == ["touch"] and len(words) == 4:
            try:
                point = np.array([float(w) for w in words[1:]])
            except ValueError:
                return
            if np.all(np.isfinite(point)):
                self.skin.touch_near(point)


def main(argv: list[str] | None = None) -> int:
    """``python -m skinloc.sim.emulated_board``: build, start, print the port, run until Ctrl-C."""
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controller", default="ok", choices=["ok", "missing", "silent"])
    parser.add_argument("--dead-rx", type=int, action="append", default=[])
    parser.add_argument("--dead-tx", type=int, action="append", default=[])
    parser.add_argument("--seed", type=int, default=0, help="Seed of the simulated skin.")
    parser.add_argument("--pattern", action="store_true", help="Serve the harness's pattern.")
    args = parser.parse_args(argv)
    missing = missing_tools()
    if missing:
        sys.stderr.write(
            f"error: missing {', '.join(missing)} (apt-get install {' '.join(PACKAGES)})\n"
        )
        return 1
    if not (firmware_dir() / "Makefile").is_file():
        sys.stderr.write("error: the emulated board needs a source checkout (its firmware/)\n")
        return 1
    try:
        build = build_firmware()
    except RuntimeError as exc:
        sys.stderr.write(f"error: {exc}\n")
        return 1
    skin = None
    if not args.pattern:
        from skinloc.sim.skin import SimulatedSkin

        skin = SimulatedSkin(random_state=args.seed)
    board = EmulatedBoard(
        build, skin, controller=args.controller, dead_rx=args.dead_rx, dead_tx=args.dead_tx
    )
    stopping = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stopping.set())
    signal.signal(signal.SIGTERM, lambda *_: stopping.set())
    with board:
        sys.stdout.write(board.path + "\n")
        sys.stdout.flush()
        sys.stderr.write(f"emulated board on {board.path} ({build.size_line}); Ctrl-C stops\n")
        stopping.wait()
    stats = {k: v for k, v in board.stats.items() if k != "stderr"}
    sys.stderr.write(json.dumps(stats) + "\n")
    return 0 if board.stats.get("fault") == "none" else 3


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
