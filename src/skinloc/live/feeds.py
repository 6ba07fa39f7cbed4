"""How frames reach a runner's loop.

Serial ports are read by the loop itself (``PortFeed``); any other ``FrameSource`` is read on
a small thread of its own (``ThreadFeed``). A port missing at start is waited for when its
skin asks to (``SkinConfig.wait``): the loop retries it on the unplug recovery's schedule.
"""

from __future__ import annotations

import errno
import logging
import os
import selectors
import threading
import time
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any, Protocol

from skinloc.errors import FrameTimeoutError, SkinlocError, SourceNotConnectedError
from skinloc.sources.base import FrameSource

if TYPE_CHECKING:
    import collections

    from skinloc.live.contact import Contact
    from skinloc.live.core import SkinCore
    from skinloc.live.skin_config import SkinConfig

log = logging.getLogger(__name__)

_MAX_QUEUED = 256  # frames waiting for the loop before a fast source is held back
_RETRY_S = 0.1  # how often a lost (or not yet plugged) port is tried again, s
#: Errors that mean "no such device yet" (a USB node not created, a link not made): waited for.
_MISSING = (errno.ENOENT, errno.ENODEV, errno.ENXIO)


class _Loop(Protocol):
    """What a thread feed needs of the runner's loop (``skinloc.live.runner.Runner``)."""

    _stop_event: threading.Event
    _queue: collections.deque

    def _push(self, slot: int, frame: Any, t_in: float) -> None: ...

    def _wake(self) -> None: ...


class PortFeed:
    """A serial port read by the loop itself (non-blocking file descriptor, no thread).

    The port's link and its decoding are the one serial reader of ``hardware.link`` (as in
    ``SerialSource``): reconnects, the line masks, the counter unwrapped, frames stamped by the
    device counter.
    """

    def __init__(self, slot: int, skin: SkinConfig, core: SkinCore) -> None:
        from skinloc.hardware.link import PortLink, WireDecoder

        self.slot = slot
        self.core = core
        self.port = str(skin.source)
        self.link = PortLink(self.port, skin.baud, nonblocking=True)
        self.decoder = WireDecoder(
            skin.wire_format,
            skin.n_tx or core.n_tx,
            skin.n_rx or core.n_rx,
            skin.tx_mask,
            skin.rx_mask,
        )
        if self.decoder.n_sensors != core.n_sensors:
            raise ValueError(
                f"skin {skin.name!r}: the port {self.port} keeps {self.decoder.n_sensors} "
                f"sensors ({self.decoder.n_tx} x {self.decoder.n_rx}) but the model takes "
                f"{core.n_sensors}"
            )
        self.n_bytes = 0
        self.retry_at = 0.0
        #: Missing at start and waited for (no reconnect is counted when it appears).
        self.waiting = False
        self._told_denied = False
        self.name = skin.name

    @property
    def ser(self) -> Any:
        """The open port, None while the link is down."""
        return self.link.ser

    @property
    def fd(self) -> int:
        """The port's file descriptor, -1 while the link is down."""
        return self.link.fd

    @property
    def n_disconnects(self) -> int:
        """Times the port was lost."""
        return self.link.n_disconnects

    @property
    def n_reconnects(self) -> int:
        """Times the port was reopened after a loss."""
        return self.link.n_reconnects

    @property
    def last_error(self) -> str:
        """Why the port was last lost."""
        return self.link.last_error

    def open(self) -> None:
        """Open the port (``hardware.link.PortLink.open``)."""
        self.link.open()

    def close(self) -> None:
        """Close the port."""
        self.link.close()

    def contacts(self, data: bytes, t_in: float) -> Iterator[Sequence[Contact]]:
        """Bytes read at ``t_in`` through the skin's core: the contacts of each frame that has any.

        Frames are stamped by the device counter; ``t_in`` (the read) is kept for the latency.
        """
        self.n_bytes += len(data)
        core = self.core
        for frame in self.decoder.feed(data, t_in):
            contacts = core.process_frame(frame.values, frame.timestamp_s, frame.index, t_in)
            if contacts:
                yield contacts

    def lost(self, sel: selectors.BaseSelector | None, exc: BaseException | str) -> None:
        """The port failed: stop waiting on it, close it, retry in 0.1 s."""
        if sel is not None and self.fd >= 0:
            try:
                sel.unregister(self.fd)
            except (KeyError, ValueError):
                pass
        self.link.lost(exc)
        self.decoder.reset()
        self.retry_at = time.monotonic() + _RETRY_S

    def retry(self, sel: selectors.BaseSelector, now: float) -> None:
        """Reopen a lost or awaited port when its retry time has come (still absent: later)."""
        if self.ser is None and now >= self.retry_at:
            if not self.link.reopen(count=not self.waiting):
                self.retry_at = now + _RETRY_S
                # A node that appeared but stays unreadable is told once (udev may fix the
                # group a moment after the node appears, so this is no reason to stop).
                exc = self.link.open_error
                if getattr(exc, "errno", None) == errno.EACCES and not self._told_denied:
                    from skinloc.hardware.link import why_not_open

                    self._told_denied = True
                    log.warning("%s (skin %s): %s", self.port, self.name, why_not_open(exc))
                return
            sel.register(self.fd, selectors.EVENT_READ, self)
            if self.waiting:
                self.waiting = False
                log.warning("%s (skin %s) is here: reading it", self.port, self.name)


def open_port_feed(slot: int, skin: SkinConfig, core: SkinCore) -> PortFeed | None:
    """The loop's feed of a serial port, opened; None for a URL without a file descriptor.

    A port that does not exist (yet) is waited for when ``skin.wait``: the feed is returned
    closed, marked ``waiting``, and the loop's ``retry`` opens it once it appears.

    Raises
    ------
    SourceNotConnectedError
        For a port that cannot be opened and is not waited for, in one line saying why
        (missing, permission denied: the dialout group, busy, not a serial port).
    """
    from skinloc.hardware.link import NoFileDescriptor, why_not_open

    feed = PortFeed(slot, skin, core)
    try:
        feed.open()
    except NoFileDescriptor:
        return None  # a URL without a file descriptor (loop://): read on a thread
    except (OSError, ValueError) as exc:  # serial.SerialException is an OSError
        code = getattr(exc, "errno", None)
        if skin.wait and (code in _MISSING or (code is None and not os.path.exists(feed.port))):
            feed.waiting = True
            feed.link.last_error = "not present"
            return feed
        raise SourceNotConnectedError(
            f"cannot open serial port {skin.source}: {why_not_open(exc)}"
        ) from None
    return feed


class ThreadFeed:
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
        """Join the thread (bounded) and disconnect the source."""
        if self.thread.is_alive():
            self.thread.join(5.0)
        if self.source.is_connected:
            try:
                self.source.disconnect()
            except (SkinlocError, OSError):
                pass
