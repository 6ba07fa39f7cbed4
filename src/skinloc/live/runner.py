"""The engine that runs skin pipelines: sources in, ``SkinCore`` per skin, sinks out.

One ``Runner`` serves one skin or many from one thread: serial ports are read without a thread
each (their file descriptors wait in one ``selectors`` loop, bytes go straight to the skin's
parser; an unplugged port is reopened by the loop), and any other ``FrameSource`` (the
simulated skin, a recording, a ``SerialSource`` on a URL without a file descriptor) is read on a
small thread of its own that hands frames to the loop. ``Pipeline`` is the one-skin form a robot
program embeds::

    with Pipeline("model.h5", "/dev/ttyACM0", sinks=["jsonl"]) as pipeline:
        for contact in pipeline:
            ...

or ``pipeline.start(callback)`` to run on a background thread; ``close`` stops and joins every
thread it started.
"""

from __future__ import annotations

import collections
import io
import logging
import math
import os
import selectors
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.errors import FrameTimeoutError, SkinlocError, SourceNotConnectedError
from skinloc.live.core import Contact, PipelineConfig, SkinCore, load_fast_localizer
from skinloc.live.sinks.base import Sink, SkinInfo, make_sink
from skinloc.sources.base import Frame, FrameSource

log = logging.getLogger(__name__)

__all__ = ["Pipeline", "Runner", "ScriptedFinger", "SkinSpec", "open_source"]

_RECORDING_SUFFIXES = (".h5", ".hdf5", ".mat", ".mcap")
_MAX_QUEUED = 256  # frames waiting for the loop before a fast source is held back


# --------------------------------------------------------------------------------------------
# a scripted finger on the simulated skin


class ScriptedFinger(FrameSource):
    """A ``SimulatedSkin`` touched by a scripted finger: random targets, holds and pauses.

    The script runs on the skin's simulated clock: after ``start_s`` the finger presses near a
    random target for ``hold_s`` (uniform in the range), lifts for ``gap_s``, and so on. Every
    touch is logged in ``script`` as ``(t_press_s, t_release_s, contact (3,) m)``.

    Parameters
    ----------
    skin : SimulatedSkin
        The skin.
    start_s : float
        Untouched time at start (the pipeline's baseline capture), s.
    hold_s, gap_s : (float, float)
        Ranges of touch and pause durations, s.
    random_state : int
        Seed of the script.
    """

    def __init__(
        self,
        skin: Any,
        *,
        start_s: float = 1.5,
        hold_s: tuple[float, float] = (0.6, 1.5),
        gap_s: tuple[float, float] = (0.6, 1.5),
        random_state: int = 0,
    ) -> None:
        self.skin = skin
        self.n_tx, self.n_rx = skin.n_tx, skin.n_rx
        self.start_s, self.hold_s, self.gap_s = start_s, hold_s, gap_s
        self._rng = np.random.default_rng(random_state)
        self._next = start_s
        self._pressed = False
        self.script: list[tuple[float, float, np.ndarray]] = []
        from skinloc.geometry.mesh import sample_surface

        self._targets = sample_surface(skin.mesh, 4096, self._rng)[0]

    @property
    def name(self) -> str:
        """The skin's name, scripted."""
        return f"{self.skin.name} + scripted finger"

    @property
    def is_connected(self) -> bool:
        """Whether the skin is connected."""
        return self.skin.is_connected

    def _connect(self) -> None:
        self.skin.connect()

    def _disconnect(self) -> None:
        self.skin.disconnect()

    def _read(self, timeout_s: float) -> Frame:
        t = self.skin.time_s
        if t >= self._next:
            if self._pressed:
                self.skin.release()
                p, _, c = self.script[-1]
                self.script[-1] = (p, t, c)
                self._next = t + self._rng.uniform(*self.gap_s)
            else:
                target = self._targets[self._rng.integers(len(self._targets))]
                contact = self.skin.touch_near(target, self._rng)
                self.script.append((t, math.inf, contact))
                self._next = t + self._rng.uniform(*self.hold_s)
            self._pressed = not self._pressed
        return self.skin.read(timeout_s)


# --------------------------------------------------------------------------------------------
# configuration of one skin


@dataclass
class SkinSpec:
    """One skin of a ``Runner``: model, source, sinks and settings.

    Attributes
    ----------
    model : str, Path, ContactLocalizer or Engine
        The localiser.
    source : str or FrameSource
        ``sim`` (simulated skin with a scripted finger; ``sim:SEED`` picks the skin), a serial
        port or pyserial URL, a recording (``.h5``, ``.mat``), or any ``FrameSource``.
    name : str
        Name carried by the contacts.
    sinks : list of str or Sink
        This skin's sinks (see ``skinloc.live.sinks.make_sink``).
    config : PipelineConfig
        Detection, drift and filter settings.
    baud : int
        Baud rate of a serial port.
    wire_format : {"auto", "binary", "text"}
        Wire format of a serial port.
    n_tx, n_rx : int or None
        Grid the device sends (default: 8 x 8 for a 64-input model).
    tx_mask, rx_mask : str or None
        Lines to keep, as for ``SerialSourceConfig``.
    realtime : bool
        Replay a recording at its recorded rate (``False``: as fast as possible); run the
        simulated skin in real time.
    loop : bool
        Replay a recording over and over.
    rate_hz : float
        Frame rate of the simulated skin, Hz.
    baseline : str, Path or None
        A recording whose baseline capture to use instead of capturing one at start.
    parent_frame : str or None
        The robot frame (link) the skin is mounted on, for ROS 2 ``/tf_static``
        (``parent_frame -> skin/<name>``); None: no transform is published.
    translation : (3,) float
        Origin of the skin's mesh frame in ``parent_frame``, m.
    rotation : (4,) float or None
        Orientation of the mesh frame in ``parent_frame``, quaternion ``x, y, z, w``.
    rpy : (3,) float or None
        The same as fixed-axis roll, pitch, yaw, rad (give ``rotation`` or ``rpy``, not both).
    """

    model: Any
    source: Any = "sim"
    name: str = "skin"
    sinks: list[Any] = field(default_factory=list)
    config: PipelineConfig = field(default_factory=PipelineConfig)
    baud: int = 115200
    wire_format: str = "auto"
    n_tx: int | None = None
    n_rx: int | None = None
    tx_mask: str | None = None
    rx_mask: str | None = None
    realtime: bool = True
    loop: bool = False
    rate_hz: float = 100.0
    baseline: str | Path | None = None
    parent_frame: str | None = None
    translation: Sequence[float] = (0.0, 0.0, 0.0)
    rotation: Sequence[float] | None = None
    rpy: Sequence[float] | None = None

    def __post_init__(self) -> None:
        self._mount = _mount_pose(self)

    @property
    def mount(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """The skin frame's pose in ``parent_frame``: translation (m), quaternion ``xyzw``."""
        return self._mount


def _vector(value: Any, n: int, what: str) -> tuple[float, ...]:
    try:
        out = tuple(float(v) for v in value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be {n} numbers, not {value!r}") from None
    if len(out) != n or not all(math.isfinite(v) for v in out):
        raise ValueError(f"{what} must be {n} finite numbers, not {value!r}")
    return out


def _mount_pose(
    spec: SkinSpec,
) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """Check and normalise a spec's mounting pose (translation m, unit quaternion xyzw)."""
    if spec.parent_frame is not None and (
        not isinstance(spec.parent_frame, str) or not spec.parent_frame.strip()
    ):
        raise ValueError(f"parent_frame must be a frame name, not {spec.parent_frame!r}")
    t = _vector(spec.translation, 3, "translation")
    if spec.rotation is not None and spec.rpy is not None:
        raise ValueError("give rotation (quaternion x, y, z, w) or rpy (rad), not both")
    if spec.rpy is not None:
        from skinloc.live.sinks.ros2 import quaternion_from_rpy

        q = quaternion_from_rpy(*_vector(spec.rpy, 3, "rpy"))
    elif spec.rotation is not None:
        q = _vector(spec.rotation, 4, "rotation (quaternion x, y, z, w)")
        norm = math.sqrt(sum(v * v for v in q))
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(f"rotation must be a unit quaternion x, y, z, w (norm {norm:.4g})")
        q = tuple(v / norm for v in q)
    else:
        q = (0.0, 0.0, 0.0, 1.0)
    return (t[0], t[1], t[2]), (q[0], q[1], q[2], q[3])


def _is_recording(source: str) -> bool:
    p = Path(source)
    return p.suffix.lower() in _RECORDING_SUFFIXES


def open_source(spec: SkinSpec, n_sensors: int) -> FrameSource:
    """The ``FrameSource`` for a spec whose source is not read through the selector loop."""
    src = spec.source
    if isinstance(src, FrameSource):
        return src
    text = str(src)
    if text == "sim" or text.startswith("sim:"):
        from skinloc.sim.skin import SimulatedSkin

        seed = int(text.partition(":")[2] or 0) if text != "sim" else 0
        n_tx, n_rx = spec.n_tx or 8, spec.n_rx or max(n_sensors // (spec.n_tx or 8), 1)
        skin = SimulatedSkin(
            n_tx=n_tx, n_rx=n_rx, random_state=seed, rate_hz=spec.rate_hz, realtime=spec.realtime
        )
        return ScriptedFinger(skin, random_state=seed)
    if _is_recording(text):
        if not Path(text).is_file():
            raise SkinlocError(f"recording not found: {text}")
        if Path(text).suffix.lower() == ".mcap":
            from skinloc.sources.mcap_ros2 import McapReplaySource

            return McapReplaySource(text, skin=spec.name, loop=spec.loop)
        from skinloc.sources.replay import ReplaySource

        return ReplaySource(text, loop=spec.loop)
    from skinloc.hardware.serial import SerialSource, SerialSourceConfig

    return SerialSource(
        SerialSourceConfig(
            text,
            baud=spec.baud,
            n_tx=spec.n_tx or 8,
            n_rx=spec.n_rx or 8,
            tx_mask=spec.tx_mask,
            rx_mask=spec.rx_mask,
            format=spec.wire_format,
        )
    )


# --------------------------------------------------------------------------------------------
# feeds: how frames reach the loop


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


class _ThreadFeed:
    """Any ``FrameSource`` read on a thread of its own; frames are queued for the loop."""

    def __init__(
        self, slot: int, source: FrameSource, runner: Runner, realtime_replay: bool
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


# --------------------------------------------------------------------------------------------
# the runner


class Runner:
    """Run the pipelines of one or many skins from one thread.

    Parameters
    ----------
    skins : sequence of SkinSpec
        The skins; names must be unique. Skins that share a model file share its compiled
        localiser.
    sinks : sequence of str or Sink, optional
        Sinks that receive the contacts of every skin (each skin may add its own).
    callback : callable(Contact), optional
        Called for every contact, on the loop's thread.

    Notes
    -----
    ``run()`` (or iterating) drives the loop in the calling thread; ``start()`` drives it on a
    background thread; ``close()`` stops it and joins every thread the runner started. The loop
    ends by itself when every source has ended (recordings played to the end).
    """

    def __init__(
        self,
        skins: Sequence[SkinSpec],
        sinks: Sequence[str | Sink] = (),
        callback: Callable[[Contact], Any] | None = None,
    ) -> None:
        if not skins:
            raise ValueError("a runner needs at least one skin")
        names = [s.name for s in skins]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"skin names must be unique; repeated: {', '.join(dup)}")
        self.specs = list(skins)
        self.callback = callback
        models: dict[str, Any] = {}
        self.cores: list[SkinCore] = []
        for spec in self.specs:
            key = str(Path(spec.model).resolve()) if isinstance(spec.model, str | Path) else None
            fast = models.get(key) if key else None
            if fast is None:
                fast = load_fast_localizer(spec.model)
                if key:
                    models[key] = fast
            core = SkinCore(
                fast,
                spec.config,
                name=spec.name,
                n_tx=spec.n_tx,
                n_rx=spec.n_rx,
                wire_format=spec.wire_format,
            )
            if spec.baseline is not None:
                from skinloc.data.recording import read_recording

                core.set_baseline(read_recording(spec.baseline).baseline_frames)
            self.cores.append(core)
        self.global_sinks = [make_sink(s) for s in sinks]
        self.skin_sinks = [[make_sink(s) for s in spec.sinks] for spec in self.specs]
        self._stop_event = threading.Event()
        self._queue: collections.deque[tuple[int, Frame, float]] = collections.deque()
        self._wake_r, self._wake_w = -1, -1
        self._wake_pending = False
        self._thread: threading.Thread | None = None
        self._opened = False
        self._closed = False
        self._ports: list[_PortFeed] = []
        self._threads: list[_ThreadFeed] = []
        self._sel: selectors.BaseSelector | None = None
        self._error: BaseException | None = None
        self.n_emitted = 0

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> Runner:
        """Open the sources and sinks (``run``, ``start`` and iteration call it)."""
        if self._opened:
            return self
        if self._closed:
            raise SourceNotConnectedError("this runner was closed; make a new one")
        self._opened = True
        try:
            self._open()
        except BaseException:
            self.close()
            raise
        return self

    def _open(self) -> None:
        self._sel = selectors.DefaultSelector()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._sel.register(self._wake_r, selectors.EVENT_READ, None)
        infos = [self._skin_info(i) for i in range(len(self.specs))]
        for sink in self.global_sinks:
            sink.open(infos)
        for info, sinks in zip(infos, self.skin_sinks, strict=True):
            for sink in sinks:
                sink.open([info])
        for slot, core in enumerate(self.cores):
            recorders = [
                s
                for s in (*self.skin_sinks[slot], *self.global_sinks)
                if getattr(s, "wants_frames", False)
            ]
            if recorders:
                self._record_frames(core, recorders)
        for slot, (spec, core) in enumerate(zip(self.specs, self.cores, strict=True)):
            src = spec.source
            if (
                isinstance(src, str | Path)
                and not _is_recording(str(src))
                and not (str(src) == "sim" or str(src).startswith("sim:"))
            ):
                feed = _PortFeed(slot, spec, core)
                try:
                    feed.open()
                except _NoFileDescriptor:
                    feed = None  # a URL without a file descriptor (loop://): use a thread
                except (OSError, ValueError) as exc:  # serial.SerialException is an OSError
                    raise SourceNotConnectedError(
                        f"cannot open serial port {src}: {exc} (is the board plugged in? "
                        "`skinloc ports` lists the ports)"
                    ) from None
                if feed is not None:
                    self._ports.append(feed)
                    self._sel.register(feed.fd, selectors.EVENT_READ, feed)
                    continue
            source = open_source(spec, core.n_sensors)
            if source.n_sensors != core.n_sensors:
                raise ValueError(
                    f"skin {spec.name!r}: the source {source.name} sends {source.n_sensors} "
                    f"sensors but the model takes {core.n_sensors}"
                )
            feed_t = _ThreadFeed(slot, source, self, spec.realtime)
            self._threads.append(feed_t)
        for feed_t in self._threads:
            feed_t.thread.start()

    @staticmethod
    def _record_frames(core: SkinCore, sinks: list[Sink]) -> None:
        """Hand every raw frame of ``core`` to ``sinks`` (``emit_frame``) before processing.

        The instance's ``process`` is wrapped, so frames parsed from a serial port's bytes
        (``SkinCore.feed``) are recorded as well as frames from thread-fed sources; skins
        without a recording sink keep the unwrapped method.
        """
        process = core.process
        name = core.name

        def recording_process(
            values: np.ndarray, timestamp_s: float, index: int = -1, t_in: float | None = None
        ) -> Contact | None:
            for sink in sinks:
                sink.emit_frame(name, values, timestamp_s, index)
            return process(values, timestamp_s, index, t_in)

        core.process = recording_process  # type: ignore[method-assign]

    def _skin_info(self, i: int) -> SkinInfo:
        fast = self.cores[i].fast
        spec = self.specs[i]
        translation, rotation = spec.mount
        return SkinInfo(
            spec.name,
            fast.spec.vertices,
            fast.spec.faces,
            n_tx=self.cores[i].n_tx,
            n_rx=self.cores[i].n_rx,
            parent_frame=spec.parent_frame,
            translation_m=translation,
            rotation_xyzw=rotation,
        )

    def close(self) -> None:
        """Stop the loop, join every thread, close ports, sources and sinks. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop_event.set()
        self._wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(10.0)
        self._thread = None
        for feed in self._threads:
            feed.close()
        for port in self._ports:
            port.close()
        for sink in [*self.global_sinks, *(s for sinks in self.skin_sinks for s in sinks)]:
            try:
                sink.close()
            except Exception as exc:  # noqa: BLE001 - one sink failing must not keep others open
                log.warning("closing sink %s: %s", sink.name, exc)
        if self._sel is not None:
            self._sel.close()
            self._sel = None
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                os.close(fd)
        self._wake_r = self._wake_w = -1

    def __enter__(self) -> Runner:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ threads -> loop
    def _push(self, slot: int, frame: Frame, t_in: float) -> None:
        self._queue.append((slot, frame, t_in))
        if not self._wake_pending:
            self._wake_pending = True
            self._wake()

    def _wake(self) -> None:
        if self._wake_w >= 0:
            try:
                os.write(self._wake_w, b"x")
            except (BlockingIOError, OSError):
                pass

    # ------------------------------------------------------------------ the loop
    def _emit(self, slot: int, c: Contact, out: list[Contact]) -> None:
        for sink in self.skin_sinks[slot]:
            sink.emit(c)
        for sink in self.global_sinks:
            sink.emit(c)
        if self.callback is not None:
            self.callback(c)
        self.n_emitted += 1
        out.append(c)

    def _port_lost(self, feed: _PortFeed, exc: BaseException | str) -> None:
        feed.last_error = str(exc) or type(exc).__name__
        log.warning("lost %s: %s", feed.port, feed.last_error)
        if self._sel is not None and feed.fd >= 0:
            try:
                self._sel.unregister(feed.fd)
            except (KeyError, ValueError):
                pass
        feed.close()
        feed.core.reset_link()
        feed.n_disconnects += 1
        feed.retry_at = time.monotonic() + 0.1

    def _retry_ports(self, now: float) -> None:
        for feed in self._ports:
            if feed.ser is None and now >= feed.retry_at and not self._stop_event.is_set():
                try:
                    feed.open()
                except Exception:  # noqa: BLE001 - still unplugged: try again later
                    feed.retry_at = now + 0.1
                    continue
                self._sel.register(feed.fd, selectors.EVENT_READ, feed)
                feed.n_reconnects += 1
                log.warning("reconnected to %s", feed.port)

    def _step(self, timeout_s: float) -> list[Contact]:
        """One turn of the loop: wait up to ``timeout_s`` for input, process it all."""
        out: list[Contact] = []
        events = self._sel.select(timeout_s)
        t_in = time.monotonic()
        for key, _ in events:
            feed = key.data
            if feed is None:
                try:
                    while os.read(self._wake_r, 4096):
                        pass
                except BlockingIOError:
                    pass
                continue
            try:
                data = os.read(feed.fd, 65536)
            except BlockingIOError:
                continue
            except OSError as exc:
                self._port_lost(feed, exc)
                continue
            if not data:
                self._port_lost(feed, "end of file")
                continue
            feed.n_bytes += len(data)
            for c in feed.core.feed(data, t_in):
                self._emit(feed.slot, c, out)
        self._wake_pending = False
        q = self._queue
        cores = self.cores
        while q:
            slot, frame, t_arr = q.popleft()
            c = cores[slot].process(frame.values, frame.timestamp_s, frame.index, t_arr)
            if c is not None:
                self._emit(slot, c, out)
        now = time.monotonic()
        if self._ports:
            self._retry_ports(now)
        for slot, core in enumerate(cores):
            if core.touching:
                c = core.link_lost(now)
                if c is not None:
                    self._emit(slot, c, out)
        return out

    @property
    def finished(self) -> bool:
        """Whether every source has ended (only recordings end)."""
        return not self._ports and all(f.finished for f in self._threads) and not self._queue

    def __iter__(self) -> Iterator[Contact]:
        """Run the loop in this thread, yielding every contact, until closed or finished."""
        self.open()
        while not self._stop_event.is_set():
            yield from self._step(0.05)
            if self.finished:
                yield from self._step(0.0)
                for slot, core in enumerate(self.cores):  # end touches still open
                    c = core.link_lost(math.inf)
                    if c is not None:
                        out: list[Contact] = []
                        self._emit(slot, c, out)
                        yield from out
                break
        self._raise_feed_errors()

    def _raise_feed_errors(self) -> None:
        errors = [f.error for f in self._threads if f.error is not None]
        if errors and not self._stop_event.is_set():
            raise errors[0]

    def run(self, duration_s: float | None = None) -> int:
        """Run in this thread for ``duration_s`` (or until finished/closed); returns contacts."""
        end = math.inf if duration_s is None else time.monotonic() + duration_s
        n = 0
        for _ in self:
            n += 1
            if time.monotonic() >= end:
                break
        if duration_s is not None:
            while time.monotonic() < end and not self._stop_event.is_set() and not self.finished:
                n += len(self._step(min(0.05, max(end - time.monotonic(), 0.0))))
        return n

    def start(self, callback: Callable[[Contact], Any] | None = None) -> Runner:
        """Run the loop on a background thread (contacts go to the sinks and ``callback``)."""
        if callback is not None:
            self.callback = callback
        if self._thread is not None:
            raise RuntimeError("this runner is already running")
        self.open()

        def loop() -> None:
            try:
                for _ in self:
                    pass
            except BaseException as exc:  # noqa: BLE001 - kept for the caller
                self._error = exc
                log.error("runner stopped: %s", exc)

        self._thread = threading.Thread(target=loop, name="skinloc-runner", daemon=True)
        self._thread.start()
        return self

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait for a started runner to finish; True if it did. Re-raises its error."""
        if self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                return False
        if self._error is not None:
            raise self._error
        return True

    # ------------------------------------------------------------------ state
    def stats(self) -> list[dict[str, Any]]:
        """Per skin: frames, contacts, touches, link state and wire counters."""
        out = []
        ports = {f.slot: f for f in self._ports}
        threads = {f.slot: f for f in self._threads}
        for slot, (spec, core) in enumerate(zip(self.specs, self.cores, strict=True)):
            d: dict[str, Any] = {
                "skin": spec.name,
                "frames": core.n_frames,
                "contacts": core.n_contacts,
                "touches": core.n_touches,
                "calibrated": core.calibrated,
            }
            if slot in ports:
                f = ports[slot]
                d.update(
                    port=f.port,
                    link_up=f.ser is not None,
                    disconnects=f.n_disconnects,
                    reconnects=f.n_reconnects,
                    bytes=f.n_bytes,
                    wire=core.parser_stats,
                )
            elif slot in threads:
                src = threads[slot].source
                d["source"] = src.name
                if hasattr(src, "stats"):
                    d["wire"] = src.stats().as_dict()
            out.append(d)
        return out


class Pipeline(Runner):
    """The live pipeline of one skin, as an object a robot program embeds.

    Parameters
    ----------
    model : str, Path, ContactLocalizer or Engine
        The localiser.
    source : str or FrameSource, default="sim"
        ``sim``, a serial port or URL, a recording, or any ``FrameSource``.
    sinks : sequence of str or Sink
        Where contacts go besides the iterator and the callback.
    config : PipelineConfig, optional
        Detection, drift and filter settings.
    callback : callable(Contact), optional
        Called for every contact (with ``start``, on the pipeline's thread).
    **source_options
        Further ``SkinSpec`` fields: ``name``, ``baud``, ``wire_format``, ``n_tx``, ``n_rx``,
        ``realtime``, ``loop``, ``rate_hz``, ``baseline``.

    Examples
    --------
    >>> with Pipeline("model.h5", "sim") as pipeline:  # doctest: +SKIP
    ...     for contact in pipeline:
    ...         print(contact.state, contact.position_m)
    """

    def __init__(
        self,
        model: Any,
        source: Any = "sim",
        *,
        sinks: Sequence[str | Sink] = (),
        config: PipelineConfig | None = None,
        callback: Callable[[Contact], Any] | None = None,
        **source_options: Any,
    ) -> None:
        spec = SkinSpec(
            model=model,
            source=source,
            config=PipelineConfig() if config is None else config,
            **source_options,
        )
        super().__init__([spec], sinks=sinks, callback=callback)

    @property
    def core(self) -> SkinCore:
        """The skin's processing chain (baseline, detector, filter, localiser)."""
        return self.cores[0]

    def recalibrate(self) -> None:
        """Capture a fresh baseline from the next frames (keep the skin untouched)."""
        self.core.recalibrate()
