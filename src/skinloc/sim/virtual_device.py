"""A virtual skin device: the simulated skin behind a real serial port (a pseudo-terminal).

``VirtualSkin`` streams frames of a ``SimulatedSkin`` in real time through a pty, in the text or
binary wire format, answers the firmware's commands, lets a scripted finger touch it over the
same port (``touch x y z`` / ``lift``), and can inject faults: garbage bytes, dropped bytes,
split and merged lines, and a disconnect now and then. It keeps the ground truth of every frame
(sent intact, destroyed by a fault, or unheard because no host was listening) so a soak test can
check that the host delivered exactly the intact frames, and nothing else.

POSIX only (it needs ``pty``).
"""

from __future__ import annotations

import logging
import os
import select
import shutil
import tempfile
import threading
import time
import zlib
from collections import Counter, deque
from pathlib import Path

import numpy as np

from skinloc.hardware.protocol import WireFormat, encode_binary, encode_text
from skinloc.sim.device_commands import FIRMWARE_VERSION, answer_command
from skinloc.sim.device_faults import Fate, FaultConfig, Pending, TruthLog

log = logging.getLogger(__name__)

__all__ = ["FIRMWARE_VERSION", "FaultConfig", "Fate", "VirtualSkin"]


class VirtualSkin:
    """A simulated skin on a pseudo-terminal, speaking the Muca firmware's formats.

    Parameters
    ----------
    skin : SimulatedSkin, optional
        The skin to stream (its clock advances one frame per frame sent); a default 8 x 8 paper
        cone skin otherwise.
    fmt : {"binary", "text"}
        Wire format at start; the ``f text`` / ``f binary`` commands switch it.
    rate_hz : float
        Frames per second, wall clock.
    faults : FaultConfig, optional
        Faults to inject; none by default.
    link_dir : str or Path, optional
        Folder for the stable link to the pty (``ttySKIN0``); a fresh temporary folder under
        the system temp dir by default (where ``skinloc ports`` finds it).
    keep_truth : bool
        Keep the per-frame ground truth (``truth()``), for soak tests.
    hand : callable, optional
        ``hand(now)`` (``time.monotonic()`` s) -> the fingers down before each frame, or None to
        leave the skin as it is (``sim.hand.ScriptedHand``: moving fingers, two at once).

    Attributes
    ----------
    downtimes : list of (float, float)
        Each disconnect's unplug and replug, ``time.monotonic()`` s.

    Examples
    --------
    >>> from skinloc.hardware.serial import SerialSource, SerialSourceConfig
    >>> with VirtualSkin(rate_hz=200) as dev:  # doctest: +SKIP
    ...     with SerialSource(SerialSourceConfig(dev.path)) as src:
    ...         frame = src.read(timeout_s=2.0)
    """

    def __init__(
        self,
        skin=None,
        *,
        fmt: str = "binary",
        rate_hz: float = 100.0,
        faults: FaultConfig | None = None,
        link_dir: str | Path | None = None,
        keep_truth: bool = False,
        hand=None,
    ) -> None:
        if not (np.isfinite(rate_hz) and 0 < rate_hz <= 2000):
            raise ValueError(f"rate_hz must be in (0, 2000], got {rate_hz!r}")
        self.fmt = WireFormat(fmt)
        if self.fmt is WireFormat.AUTO:
            raise ValueError("the virtual skin speaks 'text' or 'binary', not 'auto'")
        if skin is None:
            from skinloc.sim.skin import SimulatedSkin

            skin = SimulatedSkin(random_state=0)
        self.skin = skin
        self.rate_hz = float(rate_hz)
        self.faults = faults
        self._rng = np.random.default_rng(faults.random_state if faults else 0)
        self._own_dir = link_dir is None
        self.link_dir = Path(
            tempfile.mkdtemp(prefix="skinloc-virtual-") if link_dir is None else link_dir
        )
        self.path = str(self.link_dir / "ttySKIN0")
        self.keep_truth = keep_truth
        self.hand = hand
        self.downtimes: list[tuple[float, float]] = []
        self._truth = TruthLog()
        self.counts: Counter[str] = Counter()
        self._master: int | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._host = False
        self._host_since = 0.0
        self._pending: Pending | None = None
        self._cmd_buf = bytearray()
        self._next_disconnect = np.inf
        self._written = 0  # bytes written to the current pty
        self._ends: deque[tuple[int, int]] = deque(maxlen=64)  # (frame index, end offset)
        self._slave_name = ""
        self._banner_due = False
        self._merge_next = False
        self.gain = 8
        self.sim_finger_move_s = 0.0

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> VirtualSkin:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> str:
        """Open the pty, start streaming; returns the port path (a stable link)."""
        if self._thread is not None:
            raise RuntimeError("the virtual skin is already running")
        self.link_dir.mkdir(parents=True, exist_ok=True)
        # Who owns the link: `skinloc ports` skips links whose process has gone (killed hard,
        # its pty number since reused by someone else's terminal).
        (self.link_dir / "pid").write_text(f"{os.getpid()}\n")
        if not self.skin.is_connected:
            self.skin.connect()
        self._plug()
        self._schedule_disconnect(time.monotonic())
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="skinloc-virtual-skin", daemon=True)
        self._thread.start()
        return self.path

    def stop(self) -> None:
        """Stop streaming and remove the port."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        self._flush_pending()
        self._drain_then_lose_unread()
        self._unplug()
        Path(self.path).unlink(missing_ok=True)
        (self.link_dir / "pid").unlink(missing_ok=True)
        if self._own_dir:
            shutil.rmtree(self.link_dir, ignore_errors=True)

    def truth(self) -> dict[str, np.ndarray]:
        """Ground truth per frame: ``index``, ``crc`` (CRC-32 of the uint16 LE values), ``fate``."""
        with self._lock:
            return {
                "index": np.asarray(self._truth.index, dtype=np.int64),
                "crc": np.asarray(self._truth.crc, dtype=np.uint32),
                "fate": np.asarray(self._truth.fate, dtype=np.int8),
            }

    # ------------------------------------------------------------------ the pty
    def _plug(self) -> None:
        import pty
        import tty

        master, slave = pty.openpty()
        tty.setraw(slave)
        name = os.ttyname(slave)
        self._slave_name = name
        os.close(slave)  # the host opens it; a POLLHUP on the master means nobody listens
        os.set_blocking(master, False)
        self._master = master
        self._host = False
        self._written = 0
        self._ends.clear()
        tmp = self.link_dir / f".ttySKIN0.{os.getpid()}.tmp"
        tmp.unlink(missing_ok=True)
        os.symlink(name, tmp)
        os.replace(tmp, self.path)
        log.info("virtual skin on %s -> %s", self.path, name)

    def _unplug(self) -> None:
        # The port goes with the device, as a USB serial node does: a link left to the closed
        # pty would lead a host that reopens it to whichever process gets that pty number next.
        Path(self.path).unlink(missing_ok=True)
        if self._master is not None:
            os.close(self._master)
            self._master = None
        self._host = False

    def _host_listening(self) -> bool:
        """Whether a host has the port open; announces itself when one arrives."""
        if self._master is None:
            return False
        poller = select.poll()
        poller.register(self._master, select.POLLIN | select.POLLHUP)
        events = dict(poller.poll(0)).get(self._master, 0)
        present = not events & select.POLLHUP
        now = time.monotonic()
        if present and not self._host:
            self._host, self._host_since = True, now
            self._banner_due = True
        elif not present and self._host:
            self._host = False
            self.counts["host_left"] += 1
        if events & select.POLLIN and present:
            self._read_commands()
        # Give the host 50 ms to configure and flush the port before anything counts as sent.
        return self._host and now - self._host_since > 0.05

    def _unread(self) -> int:
        """Bytes written that the host has not read yet (-1 if unknown)."""
        import fcntl
        import termios

        try:
            fd = os.open(self._slave_name, os.O_RDONLY | os.O_NOCTTY | os.O_NONBLOCK)
        except OSError:
            return -1
        try:
            return int.from_bytes(fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"), "little")
        except OSError:
            return -1
        finally:
            os.close(fd)

    def _drain_then_lose_unread(self) -> None:
        """Give the host 0.5 s to read what was written; frames it never read are destroyed."""
        if self._master is None or not self._host:
            return
        deadline = time.monotonic() + 0.5
        time.sleep(0.02)  # the pty hands written bytes to the reader asynchronously
        unread = self._unread()
        while unread != 0 and time.monotonic() < deadline:
            time.sleep(0.01)
            unread = self._unread()
        if unread == 0:
            return
        cut = self._written - (self._written if unread < 0 else unread)
        lost = {index for index, end in self._ends if end > cut}
        self.counts["lost_in_pty"] += len(lost)
        with self._lock:
            for k in range(len(self._truth.index) - 1, max(-1, len(self._truth.index) - 80), -1):
                if self._truth.index[k] in lost and self._truth.fate[k] == Fate.SENT:
                    self._truth.fate[k] = Fate.DESTROYED
                    self.counts["sent"] -= 1
                    self.counts["destroyed"] += 1

    def _write(self, data: bytes) -> bool:
        """Write all of ``data``; False if the host's buffer stays full (data lost)."""
        view = memoryview(data)
        deadline = time.monotonic() + 0.5
        while view:
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                n = 0
            except OSError:
                return False
            self._written += n
            view = view[n:]
            if view:
                if time.monotonic() > deadline:
                    self.counts["write_stalled"] += 1
                    return False
                time.sleep(0.001)
        return True

    # ------------------------------------------------------------------ commands
    def _read_commands(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except OSError:
            return
        self._cmd_buf += data
        while b"\n" in self._cmd_buf:
            line, _, rest = bytes(self._cmd_buf).partition(b"\n")
            self._cmd_buf = bytearray(rest)
            reply = self.handle_command(line.decode("ascii", "replace"))
            if reply:
                self._flush_pending()
                self._write(reply.encode("ascii") + b"\r\n")
        if len(self._cmd_buf) > 1024:
            self._cmd_buf.clear()

    def handle_command(self, line: str) -> str:
        """Answer one command line like the firmware does (see ``firmware/README.md``)."""
        return answer_command(self, line)

    # ------------------------------------------------------------------ frames and faults
    def _schedule_disconnect(self, now: float) -> None:
        f = self.faults
        if f is None or f.disconnect_every_s <= 0:
            self._next_disconnect = np.inf
        else:
            self._next_disconnect = now + self._rng.exponential(f.disconnect_every_s)

    def _record(self, index: int, values: np.ndarray, fate: int) -> None:
        self.counts[("sent", "destroyed", "unheard")[fate]] += 1
        if self.keep_truth:
            crc = zlib.crc32(values.astype("<u2").tobytes())
            with self._lock:
                self._truth.index.append(index)
                self._truth.crc.append(crc)
                self._truth.fate.append(fate)

    def _set_fate(self, index: int, fate: int) -> None:
        """Change the recorded fate of a recent frame (a merge destroyed it after the fact)."""
        self.counts["sent"] -= 1
        self.counts[("sent", "destroyed", "unheard")[fate]] += 1
        if self.keep_truth:
            with self._lock:
                for k in range(len(self._truth.index) - 1, max(-1, len(self._truth.index) - 8), -1):
                    if self._truth.index[k] == index:
                        self._truth.fate[k] = fate
                        break

    def _encode(self, values: np.ndarray, index: int) -> bytes:
        if self.fmt is WireFormat.BINARY:
            return encode_binary(values, self.skin.n_tx, self.skin.n_rx, index)
        return encode_text(values)

    def _flush_pending(self) -> None:
        if self._pending is not None:
            p, self._pending = self._pending, None
            if self._write(p.data):
                self._ends.append((p.index, self._written))

    def _send(self, index: int, values: np.ndarray) -> None:
        data = self._encode(values, index)
        text = self.fmt is WireFormat.TEXT
        f, rng = self.faults, self._rng
        kind = "none" if f is None else f.choose(rng)
        self.counts[f"fault_{kind}"] += 1 if kind != "none" else 0
        pieces, destroyed = [data], False
        if kind == "garbage":
            junk = rng.integers(0, 256, rng.integers(1, 33), dtype=np.uint8).tobytes()
            if rng.random() < 0.5:  # between frames
                pieces = [junk, data]
                # A text line starts after the last newline: junk without one corrupts it.
                destroyed = text and not junk.endswith(b"\n")
            else:  # inside the frame
                cut = int(rng.integers(1, len(data) - 1))
                pieces = [data[:cut] + junk + data[cut:]]
                destroyed = True
        elif kind == "drop":
            body = len(data) - 2 if text else len(data)  # text: keep the CRLF
            n = int(rng.integers(1, 17))
            at = int(rng.integers(0, max(1, body - n)))
            pieces = [data[:at] + data[at + min(n, body - at) :]]
            destroyed = True
        elif kind == "split":
            if text and rng.random() < 0.5:
                cut = int(rng.integers(1, len(data) - 2))
                pieces = [data[:cut] + b"\r\n" + data[cut:]]
                destroyed = True
            else:
                cuts = sorted(rng.choice(np.arange(1, len(data)), rng.integers(1, 4), False))
                pieces = [data[a:b] for a, b in zip([0, *cuts], [*cuts, len(data)], strict=True)]
        if kind == "merge":
            if self._pending is not None:
                self._flush_pending()
            if text:
                # The line end is lost: this line and the next run together; both are destroyed.
                self._record(index, values, Fate.DESTROYED)
                self._pending = Pending(index, data[:-2])
                self._merge_next = True
            else:
                self._record(index, values, Fate.SENT)
                self._pending = Pending(index, data)
                self._merge_next = False
            return
        if self._pending is not None:
            p, self._pending = self._pending, None
            if getattr(self, "_merge_next", False) and not destroyed:
                self._record(index, values, Fate.DESTROYED)
                destroyed_now = True
            else:
                self._record(index, values, Fate.DESTROYED if destroyed else Fate.SENT)
                destroyed_now = destroyed
            ok = self._write(p.data + b"".join(pieces))
            if ok:
                self._ends.append((p.index, self._written - len(b"".join(pieces))))
                self._ends.append((index, self._written))
            else:
                self._set_fate(index, Fate.DESTROYED) if not destroyed_now else None
            return
        self._record(index, values, Fate.DESTROYED if destroyed else Fate.SENT)
        for k, piece in enumerate(pieces):
            if not self._write(piece):
                if not destroyed:
                    self._set_fate(index, Fate.DESTROYED)
                return
            if kind == "split" and k < len(pieces) - 1:
                time.sleep(float(rng.uniform(0.001, 0.02)))
        self._ends.append((index, self._written))

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        start = time.monotonic()
        k = 0
        self._banner_due = False
        while not self._stop.is_set():
            due = start + k * period
            now = time.monotonic()
            if due > now:
                if self._stop.wait(due - now):
                    break
            elif now - due > 1.0:  # far behind (the machine stalled): skip ahead, don't burst
                skipped = int((now - due) / period)
                k += skipped
                self.counts["skipped_late"] += skipped
                continue
            if time.monotonic() >= self._next_disconnect:
                self._disconnect()
                start, k = time.monotonic(), 0
                continue
            frame = self._next_frame()
            index = frame.index
            if self._host_listening():
                if self._banner_due:
                    self._banner_due = False
                    self._flush_pending()
                    self._write(f"{FIRMWARE_VERSION} ready\r\n".encode())
                self._send(index, frame.values)
            else:
                self._pending = None
                self._record(index, frame.values, Fate.UNHEARD)
            k += 1
        self._flush_pending()

    def _next_frame(self):
        """The skin's next frame, with the hand's fingers as they are now."""
        if self.hand is not None:
            fingers = self.hand(time.monotonic())
            if fingers is not None:
                self.skin.touch(fingers)
        return self.skin.read()

    def _disconnect(self) -> None:
        """Pull the plug: the frames the host has not read are lost; come back after downtime."""
        assert self.faults is not None
        self._flush_pending()
        self._drain_then_lose_unread()
        self._unplug()
        self.counts["disconnects"] += 1
        log.info("virtual skin: disconnect %d", self.counts["disconnects"])
        start = time.monotonic()
        end = start + self.faults.downtime_s
        while time.monotonic() < end and not self._stop.is_set():
            frame = self._next_frame()
            self._record(frame.index, frame.values, Fate.UNHEARD)
            self._stop.wait(1.0 / self.rate_hz)
        self._plug()
        self.downtimes.append((start, time.monotonic()))
        self._schedule_disconnect(time.monotonic())
