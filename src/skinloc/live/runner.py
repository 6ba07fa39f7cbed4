"""The live runner: sources in, ``SkinCore`` per skin, sinks out, on one loop.

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
import logging
import math
import os
import selectors
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

from skinloc.errors import SourceNotConnectedError
from skinloc.live.config import PipelineConfig
from skinloc.live.control import SkinControl
from skinloc.live.core import Contact, SkinCore
from skinloc.live.feeds import PortFeed, ThreadFeed, open_port_feed
from skinloc.live.guard import ErrorLog, GuardedFrameSink, SinkRoute
from skinloc.live.scripted import ScriptedFinger
from skinloc.live.sinks.base import Sink, SkinInfo, make_sink
from skinloc.live.skin_config import SkinConfig, skin_info
from skinloc.models.engine import load_engine
from skinloc.sources.base import Frame, FrameSource, SourceKind, make_source, source_kind

log = logging.getLogger(__name__)

#: how often the loop looks for lost ports to reopen and touches gone stale, s (port retries
#: come every 0.1 s, ``stale_s`` is 1 s by default)
_SWEEP_S = 0.01

__all__ = ["Pipeline", "Runner", "ScriptedFinger", "SkinConfig", "open_source"]


# --------------------------------------------------------------------------------------------
# the runner


def open_source(skin: SkinConfig, core: SkinCore) -> FrameSource:
    """The frame source of a skin the loop does not read itself, built by ``make_source``.

    The simulated skin is touched by a scripted finger (``ScriptedFinger``), so that a model
    gives contacts without hardware.
    """
    if isinstance(skin.source, FrameSource):
        return skin.source
    options = skin.source_options(core)
    source = make_source(options)
    if options.kind is SourceKind.SIM:
        return ScriptedFinger(source, random_state=options.sim_seed)
    return source


class Runner:
    """Run the pipelines of one or many skins from one thread.

    Parameters
    ----------
    skins : sequence of SkinConfig
        The skins; names must be unique. Skins that share a model file share its compiled
        localiser.
    sinks : sequence of str or Sink, optional
        Sinks that receive the contacts of every skin (each skin may add its own).
    callback : callable(Contact), optional
        Called for every contact, on the loop's thread.
    gesture_callback : callable(dict), optional
        Called for every gesture event (``skinloc.live.gestures``), on the loop's thread.

    Notes
    -----
    ``run()`` (or iterating) drives the loop in the calling thread; ``start()`` drives it on a
    background thread; ``close()`` stops it and joins every thread the runner started. The loop
    ends by itself when every source has ended (recordings played to the end).

    No exception of a skin's processing (the model included), a sink or a callback stops the
    loop (``skinloc.live.guard``): the frame is dropped, or the sink misses that delivery, and
    the rest goes on; each is logged once with its traceback and counted in ``stats`` (a skin's
    ``errors``, each sink's ``errors`` and ``skipped`` under ``sinks``), and a sink that keeps
    failing is tried again after a wait that doubles up to ``guard.BACKOFF_MAX_S``.
    """

    def __init__(
        self,
        skins: Sequence[SkinConfig],
        sinks: Sequence[str | Sink] = (),
        callback: Callable[[Contact], Any] | None = None,
        gesture_callback: Callable[[dict[str, Any]], Any] | None = None,
    ) -> None:
        if not skins:
            raise ValueError("a runner needs at least one skin")
        names = [s.name for s in skins]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"skin names must be unique; repeated: {', '.join(dup)}")
        self.skins = list(skins)
        self.callback = callback
        self.gesture_callback = gesture_callback
        # The sinks first: a spec they refuse (a bad port, a host that does not resolve) fails
        # before the models load (a fresh install compiles the engines' kernels there, ~25 s).
        self.global_sinks = [make_sink(s) for s in sinks]
        self.skin_sinks = [[make_sink(s) for s in skin.sinks] for skin in self.skins]
        models: dict[str, Any] = {}
        self.cores: list[SkinCore] = []
        for skin in self.skins:
            key = str(Path(skin.model).resolve()) if isinstance(skin.model, str | Path) else None
            engine = models.get(key) if key else None
            if engine is None:
                engine = load_engine(skin.model)
                if key:
                    models[key] = engine
            core = SkinCore(
                engine,
                skin.config,
                name=skin.name,
                n_tx=skin.kept_grid[0],
                n_rx=skin.kept_grid[1],
                wire_format=skin.wire_format,
                up=skin.up,
                gesture_config=skin.gestures,
            )
            if skin.baseline is not None:
                from skinloc.data.recording import read_recording

                core.set_baseline(read_recording(skin.baseline).baseline_frames)
            self.cores.append(core)
        # what keeps the loop going (skinloc.live.guard): per skin, its frames' errors; per
        # skin and sink, the route's failures and back-off (a sink's log is shared by its skins)
        self.frame_errors = [
            ErrorLog(f"skin {core.name!r}", "the frame is dropped") for core in self.cores
        ]
        for core, errors in zip(self.cores, self.frame_errors, strict=True):
            core.on_frame_error = self._frame_error_handler(errors)
        sink_logs: dict[int, ErrorLog] = {}

        def route(spec: str | Sink, sink: Sink) -> tuple[Sink, SinkRoute]:
            label = spec if isinstance(spec, str) else sink.name
            if id(sink) not in sink_logs:
                sink_logs[id(sink)] = ErrorLog(f"sink {label}", "that delivery is lost")
            return sink, SinkRoute(label, sink_logs[id(sink)])

        callback_log = ErrorLog("callback", "that call is lost")
        #: Per skin: its sinks (its own first, then the global ones), each with its route.
        self.routes: list[list[tuple[Sink, SinkRoute]]] = []
        #: Per skin: the route of ``callback`` and ``gesture_callback``.
        self.callback_routes: list[SinkRoute] = []
        shared = list(zip(sinks, self.global_sinks, strict=True))
        for skin, own in zip(self.skins, self.skin_sinks, strict=True):
            pairs = [*zip(skin.sinks, own, strict=True), *shared]
            self.routes.append([route(spec, sink) for spec, sink in pairs])
            self.callback_routes.append(SinkRoute("callback", callback_log))
        #: Per skin: the routes of its raw-frame recorders (filled when the runner opens).
        self.frame_routes: list[list[SinkRoute]] = [[] for _ in self.skins]
        self._stop_event = threading.Event()
        self._queue: collections.deque[tuple[int, Frame, float]] = collections.deque()
        self._wake_r, self._wake_w = -1, -1
        self._wake_pending = False
        self._thread: threading.Thread | None = None
        self._opened = False
        self._closed = False
        self._ports: list[PortFeed] = []
        self._threads: list[ThreadFeed] = []
        self._sel: selectors.BaseSelector | None = None
        self._next_sweep = -math.inf  # when the loop next looks for lost ports and stale touches
        self._error: BaseException | None = None
        self._touches_ended = False  # the ends of the open touches went out (once, at the end)
        self.n_emitted = 0
        #: settings, tare and diagnostics for the sinks that serve them (the ROS 2 node)
        self.control = SkinControl(self)
        #: the sinks that gather a turn's writes (``Sink.end_turn``), with their error log
        self._turn_sinks = [
            (sink, sink_logs[key])
            for key, sink in {id(s): s for s in self.all_sinks()}.items()  # once each
            if getattr(type(sink), "end_turn", Sink.end_turn) is not Sink.end_turn
        ]

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
        infos = [skin_info(s, c) for s, c in zip(self.skins, self.cores, strict=True)]
        for sink in self.global_sinks:
            sink.open(infos)
        for info, sinks in zip(infos, self.skin_sinks, strict=True):
            for sink in sinks:
                sink.open([info])
        for slot, core in enumerate(self.cores):
            recorders = [
                GuardedFrameSink(s, SinkRoute(f"{r.label} (frames)", r.errors), time.monotonic)
                for s, r in self.routes[slot]
                if getattr(s, "wants_frames", False)
            ]
            core.frame_sinks = recorders
            self.frame_routes[slot] = [g.route for g in recorders]
        for slot, (skin, core) in enumerate(zip(self.skins, self.cores, strict=True)):
            src = skin.source
            if isinstance(src, str | Path) and source_kind(str(src)) is SourceKind.SERIAL:
                feed = open_port_feed(slot, skin, core)  # None: a URL read on a thread
                if feed is not None:
                    self._ports.append(feed)
                    if not feed.waiting:  # a missing port waited for is opened by the loop
                        self._sel.register(feed.fd, selectors.EVENT_READ, feed)
                    continue
            source = open_source(skin, core)
            if source.n_sensors != core.n_sensors:
                raise ValueError(
                    f"skin {skin.name!r}: the source {source.name} sends {source.n_sensors} "
                    f"sensors but the model takes {core.n_sensors}"
                )
            feed_t = ThreadFeed(slot, source, self, skin.realtime)
            self._threads.append(feed_t)
        for feed_t in self._threads:
            feed_t.thread.start()

    @staticmethod
    def _frame_error_handler(errors: ErrorLog) -> Callable[[Exception], None]:
        """What a core calls with the exception of a frame it dropped: count and log it."""

        def handle(exc: Exception) -> None:
            errors.record(exc, time.monotonic())

        return handle

    def _skin_info(self, i: int) -> SkinInfo:
        """What the sinks learn of skin ``i`` (``skinloc.live.skin_config.skin_info``)."""
        return skin_info(self.skins[i], self.cores[i])

    def close(self) -> None:
        """Stop the loop, join every thread, close ports, sources and sinks. Idempotent."""
        if self._closed:
            return
        self._closed = True
        self._stop_event.set()
        self._wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(10.0)
        # a loop still running on another thread owns the cores (its join above timed out)
        running = (
            self._thread is not None
            and self._thread.is_alive()
            and self._thread is not threading.current_thread()
        )
        self._thread = None
        for feed in self._threads:
            feed.close()
        for port in self._ports:
            port.close()
        if self._opened and not running:
            self._end_touches(time.monotonic())
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

    def stop(self) -> None:
        """Ask the loop to end after its current turn; ``close`` then closes everything.

        Safe to call from a signal handler or another thread: it only sets the stop flag and
        wakes the loop out of its wait for input.
        """
        self._stop_event.set()
        self._wake()

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
    def _emit(self, slot: int, contacts: Sequence[Contact], out: list[Contact]) -> None:
        """One frame's contacts of skin ``slot`` (and the gestures due) to every consumer."""
        core = self.cores[slot]
        gestures = core.take_gestures() if core.gestures else ()
        if not contacts and not gestures:
            return
        name = core.name
        ts = contacts[0].timestamp_s if contacts else gestures[0]["timestamp_s"]
        for sink, route in self.routes[slot]:
            # a failing sink (route.n_failing) waits out its back-off; a healthy one costs
            # no clock reading
            if route.n_failing and not route.ready(time.monotonic()):
                continue
            try:
                if contacts:
                    sink.emit_contacts(name, ts, contacts)
                for g in gestures:
                    sink.emit_gesture(name, g["timestamp_s"], g)
            except BrokenPipeError:  # stdout closed by its reader (| head): the run ends there
                raise
            except Exception as exc:  # noqa: BLE001 - one sink must not stop the others
                route.failed(exc, time.monotonic())
            else:
                if route.n_failing:
                    route.succeeded()
        if self.callback is not None or self.gesture_callback is not None:
            route = self.callback_routes[slot]
            try:
                if self.callback is not None:
                    for c in contacts:
                        self.callback(c)
                if self.gesture_callback is not None:
                    for g in gestures:
                        self.gesture_callback(g)
            except Exception as exc:  # noqa: BLE001 - a program's callback must not stop it
                route.failed(exc, time.monotonic())
                route.n_failing = 0  # a callback is called again at once: no back-off
        self.n_emitted += len(contacts)
        out += contacts

    def _end_stale(self, slot: int, now: float, out: list[Contact]) -> None:
        """The ends of skin ``slot``'s touch gone stale (a lost link), if due."""
        core = self.cores[slot]
        try:
            ends = core.end_stale(now)
        except Exception as exc:  # noqa: BLE001 - one skin must not stop the others
            self.frame_errors[slot].record(exc, now)
            return
        self._emit(slot, ends, out)

    def _retry_ports(self, now: float) -> None:
        if not self._stop_event.is_set():
            for feed in self._ports:
                feed.retry(self._sel, now)

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
                feed.lost(self._sel, exc)
                continue
            if not data:
                feed.lost(self._sel, "end of file")
                continue
            for contacts in feed.contacts(data, t_in):
                self._emit(feed.slot, contacts, out)
            if feed.core.gestures:  # gestures of frames without contacts
                self._emit(feed.slot, (), out)
        self._wake_pending = False
        q = self._queue
        cores = self.cores
        # only the frames queued by now: a source faster than the loop (a replay --fast, the
        # simulated skin unpaced) refills the queue as it drains, and a turn that drained it
        # to the end never came back to the deadline (`--duration 2` ran for 40 s)
        for _ in range(len(q)):
            slot, frame, t_arr = q.popleft()
            contacts = cores[slot].process_frame(
                frame.values, frame.timestamp_s, frame.index, t_arr
            )
            if contacts or cores[slot].gestures:
                self._emit(slot, contacts, out)
        now = time.monotonic()
        # the sweep visits every skin: once per turn it cost more than the frame itself at
        # 100 skins (a turn per frame on a quiet machine); its deadlines are 0.1 s and more
        if now >= self._next_sweep or timeout_s == 0.0:
            self._next_sweep = now + _SWEEP_S
            if self._ports:
                self._retry_ports(now)
            for slot, core in enumerate(cores):
                if core.touching:
                    self._end_stale(slot, now, out)
            self.control.serve(now)
        self._end_turn()
        return out

    def _end_turn(self) -> None:
        """The turn's deliveries are done: the sinks that gather a turn's writes send them."""
        for sink, errors in self._turn_sinks:
            try:
                sink.end_turn()
            except BrokenPipeError:  # as in _emit: stdout closed by its reader
                raise
            except Exception as exc:  # noqa: BLE001 - one sink must not stop the others
                errors.record(exc, time.monotonic())

    def all_sinks(self) -> list[Sink]:
        """Every sink: those of all skins, then each skin's own."""
        return [*self.global_sinks, *(s for sinks in self.skin_sinks for s in sinks)]

    @property
    def waiting(self) -> list[tuple[str, str]]:
        """``(skin, port)`` of every port missing at start and not yet there."""
        return [(f.name, f.port) for f in self._ports if f.waiting]

    @property
    def finished(self) -> bool:
        """Whether every source has ended (only recordings end)."""
        return not self._ports and all(f.finished for f in self._threads) and not self._queue

    def __iter__(self) -> Iterator[Contact]:
        """Run the loop in this thread, yielding every contact, until closed or finished."""
        for contacts in self._turns(math.inf):
            yield from contacts

    def _turns(self, deadline: float) -> Iterator[list[Contact]]:
        """Turn the loop until closed, finished, or ``deadline`` (``time.monotonic()`` s).

        Yields each turn's contacts, none included: the deadline holds whether contacts come or
        not. At the deadline the touches stay open (``close`` ends them).
        """
        self.open()
        while not self._stop_event.is_set():
            now = time.monotonic()
            if now >= deadline:
                break
            yield self._step(min(0.05, deadline - now))
            if self.finished:
                yield self._step(0.0)
                yield self._end_touches(math.inf)
                break
        self._raise_feed_errors()

    def _end_touches(self, now: float) -> list[Contact]:
        """The loop stops: every open touch and track ends, through the ordinary path.

        Every skin's touch in progress gets the ``end`` of each of its tracks and every gesture
        still waiting is reported, to every sink and callback, so that whoever follows the
        contacts (a ROS 2 node, a websocket client) never keeps a finger that has gone. Called
        once, on every way out: the end of the sources (``now`` = inf: the ends carry the last
        frame's time) and ``close`` (Ctrl-C, SIGTERM, ``--duration``, a program's ``close``).
        """
        out: list[Contact] = []
        if self._touches_ended:
            return out
        self._touches_ended = True
        for slot, core in enumerate(self.cores):
            try:
                ends = core.end_open(now)
                core.flush_gestures()
            except Exception as exc:  # noqa: BLE001 - one skin must not keep others' ends
                self.frame_errors[slot].record(exc, time.monotonic())
                continue
            for route in (*(r for _, r in self.routes[slot]), self.callback_routes[slot]):
                route.retry_at = -math.inf  # the last word: every sink gets its chance
            self._emit(slot, ends, out)
        self._end_turn()
        return out

    def _raise_feed_errors(self) -> None:
        errors = [f.error for f in self._threads if f.error is not None]
        if errors and not self._stop_event.is_set():
            raise errors[0]

    def run(self, duration_s: float | None = None) -> int:
        """Run in this thread for ``duration_s`` (or until finished/closed); returns contacts.

        The duration holds whether contacts come or not (the loop checks it every turn, at
        least every 0.05 s).
        """
        end = math.inf if duration_s is None else time.monotonic() + duration_s
        return sum(len(contacts) for contacts in self._turns(end))

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
                log.exception("runner stopped: %s", exc)

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
    def stats(self, slots: Iterable[int] | None = None) -> list[dict[str, Any]]:
        """Per skin: frames, contacts, touches, errors, sinks' health, link and wire counters.

        ``errors``: frames dropped because their processing raised (``last_error`` the last
        one); ``sink_errors``: deliveries of this skin that a sink (or callback) refused;
        ``sinks``: per sink of this skin, ``errors``, ``skipped`` (deliveries not tried while it
        backed off), ``failing``, ``retry_in_s`` and ``last_error``. ``slots``: only these
        skins (slot indices), in that order; default all.
        """
        out = []
        ports = {f.slot: f for f in self._ports}
        threads = {f.slot: f for f in self._threads}
        now = time.monotonic()
        for slot in range(len(self.skins)) if slots is None else slots:
            skin, core = self.skins[slot], self.cores[slot]
            routes = [*(r for _, r in self.routes[slot]), *self.frame_routes[slot]]
            if self.callback is not None or self.gesture_callback is not None:
                routes.append(self.callback_routes[slot])
            errors = self.frame_errors[slot]
            d: dict[str, Any] = {
                "skin": skin.name,
                "frames": core.n_frames,
                "nonfinite_frames": core.n_nonfinite,
                "contacts": core.n_contacts,
                "touches": core.n_touches,
                "gestures": core.n_gestures,
                "calibrated": core.calibrated,
                "errors": errors.n,
                "last_error": errors.last,
                "sink_errors": sum(r.n_errors for r in routes),
                "sinks": [r.as_dict(now) for r in routes],
            }
            if slot in ports:
                f = ports[slot]
                d.update(
                    port=f.port,
                    link_up=f.ser is not None,
                    waiting=f.waiting,
                    disconnects=f.n_disconnects,
                    reconnects=f.n_reconnects,
                    bytes=f.n_bytes,
                    wire=f.decoder.stats.as_dict(),
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
    gesture_callback : callable(dict), optional
        Called for every gesture event, on the pipeline's thread.
    **source_options
        Further ``SkinConfig`` fields: ``name``, ``baud``, ``wire_format``, ``n_tx``, ``n_rx``,
        ``realtime``, ``loop``, ``rate_hz``, ``baseline``, ``wait`` (a missing port).

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
        gesture_callback: Callable[[dict[str, Any]], Any] | None = None,
        **source_options: Any,
    ) -> None:
        skin = SkinConfig(
            model=model,
            source=source,
            config=PipelineConfig() if config is None else config,
            **source_options,
        )
        super().__init__([skin], sinks=sinks, callback=callback, gesture_callback=gesture_callback)

    @property
    def core(self) -> SkinCore:
        """The skin's processing chain (baseline, detector, filter, localiser)."""
        return self.cores[0]

    def recalibrate(self) -> None:
        """Capture a fresh baseline from the next frames (keep the skin untouched)."""
        self.core.recalibrate()
