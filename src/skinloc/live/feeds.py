"""How frames reach a runner's loop.

Serial ports are read by the loop itself (``_PortFeed``); any other ``FrameSource`` is read on
a small thread of its own (``_ThreadFeed``).
"""

from __future__ import annotations

import io
import logging
import os
import selectors
import threading
import time
from typing import TYPE_CHECKING, Any, Protocol

from skinloc.errors import FrameTimeoutError, SkinlocError
from skinloc.sources.base import FrameSource

if TYPE_CHECKING:
    import collections

    from skinloc.live.core import SkinCore
    from skinloc.live.spec import SkinSpec

log = logging.getLogger(__name__)

_MAX_QUEUED = 256  # frames waiting for the loop before a fast source is held back


class _Loop(Protocol):
    """What a thread feed needs of the runner's loop (``skinloc.live.runner.Runner``)."""

    _stop_event: threading.Event
    _queue: collections.deque

    def _push(self, slot: int, frame: Any, t_in: float) -> None: ...

    def _wake(self) -> None: ...


class _NoFileDescriptor(Exception):
    """The port (a pyserial URL such as ``loop://``) has no file descriptor to wait on."""


class _PortFeed:
    """A serial port read by the loop itself (non-blocking file descriptor, no thread)."""

    def __init__(self, slot: int, spec: SkinSpec, core: SkinCore) -> None:
        from skinloc.hardware.serial import SerialSourceConfig

        self.slot = slot
        self.core = core
        self.cfg = SerialSourceConfig(
            str(spec.source),
            baud=spec.baud,
            n_tx=spec.n_tx or core.n_tx,
            n_rx=spec.n_rx or core.n_rx,
            tx_mask=spec.tx_mask,
            rx_mask=spec.rx_mask,
            format=spec.wire_format,
        )
        self.port = self.cfg.port
        self.ser: Any = None
        self.fd = -1
        self.n_disconnects = 0
        self.n_reconnects = 0
        self.n_bytes = 0
        self.retry_at = 0.0
        self.last_error = ""

    def open(self) -> None:
        import serial

        self.ser = serial.serial_for_url(self.port, baudrate=self.cfg.baud, timeout=0)
        try:
            fd = self.ser.fileno()
            if not isinstance(fd, int):
                raise AttributeError("fileno")
            self.fd = fd
        except (AttributeError, io.UnsupportedOperation):
            self.ser.close()
            self.ser = None
            raise _NoFileDescriptor(self.port) from None
        os.set_blocking(self.fd, False)

    def close(self) -> None:
        if self.ser is not None:
            try:
                self.ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port may fail in many ways
                pass
        self.ser = None
        self.fd = -1

    def lost(self, sel: selectors.BaseSelector | None, exc: BaseException | str) -> None:
        """The port failed: stop waiting on it, close it, retry in 0.1 s."""
        self.last_error = str(exc) or type(exc).__name__
        log.warning("lost %s: %s", self.port, self.last_error)
        if sel is not None and self.fd >= 0:
            try:
                sel.unregister(self.fd)
            except (KeyError, ValueError):
                pass
        self.close()
        self.core.reset_link()
        self.n_disconnects += 1
        self.retry_at = time.monotonic() + 0.1

    def retry(self, sel: selectors.BaseSelector, now: float) -> None:
        """Reopen a lost port when its retry time has come (still unplugged: later)."""
        if self.ser is None and now >= self.retry_at:
            try:
                self.open()
            except Exception:  # noqa: BLE001 - still unplugged: try again later
                self.retry_at = now + 0.1
                return
            sel.register(self.fd, selectors.EVENT_READ, self)
            self.n_reconnects += 1
            log.warning("reconnected to %s", self.port)


class _ThreadFeed:
    """Any ``FrameSource`` read on a thread of its own; frames are queued for the loop."""

    def __init__(
        self, slot: int, source: FrameSource, runner: _Loop, realtime_replay: bool
    ) -> None:
        self.slot = slot
        self.source = source
        self.runner = runner
        self.realtime = realtime_replay
        self.finished = False
        self.error: BaseException | None = None
        self.thread = threading.Thread(
            target=self._run, name=f"skinloc-feed-{source.name}", daemon=True
        )
        self._arrival_is_timestamp = type(source).__name__ == "SerialSource"

    def _run(self) -> None:
        src = self.source
        stop = self.runner._stop_event
        replay = getattr(src, "is_replay", False) or type(src).__name__ == "ReplaySource"
        wall0 = ts0 = None
        try:
            if not src.is_connected:
                src.connect()
            while not stop.is_set():
                try:
                    frame = src.read(timeout_s=0.2)
                except FrameTimeoutError:
                    if replay:
                        break
                    continue
                if replay and self.realtime:
                    if wall0 is None:
                        wall0, ts0 = time.monotonic(), frame.timestamp_s
                    wait = wall0 + (frame.timestamp_s - ts0) - time.monotonic()
                    if wait > 0 and stop.wait(wait):
                        break
                t_in = frame.timestamp_s if self._arrival_is_timestamp else time.monotonic()
                self.runner._push(self.slot, frame, t_in)
                # Back-pressure for sources faster than the loop (replay with --fast).
                while len(self.runner._queue) > _MAX_QUEUED and not stop.is_set():
                    stop.wait(0.0005)
        except (SkinlocError, OSError, ValueError) as exc:
            self.error = exc
            log.error("%s: %s", src.name, exc)
        finally:
            self.finished = True
            self.runner._wake()

    def close(self) -> None:
        if self.thread.is_alive():
            self.thread.join(5.0)
        if self.source.is_connected:
            try:
                self.source.disconnect()
            except (SkinlocError, OSError):
                pass
