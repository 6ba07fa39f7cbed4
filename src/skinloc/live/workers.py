"""The skins of one run spread over worker processes (``skinloc run --workers N``).

One ``Runner`` is one thread on one core. With ``workers`` > 1 the skins are cut into that many
consecutive shares (``partition``), and each share runs a ``Runner`` of its own in a worker
process, with its own sinks: the parent process starts the workers, watches them, and merges
their statistics when they end.

Decisions (docs/live.md, "Workers"):

* **One ROS 2 node per worker.** Worker ``w`` of ``--sink ros2[:NODE]`` is the node
  ``NODE_w`` (``skinloc_0``, ``skinloc_1``...), serving the parameters, ``tare`` and
  ``reset_tracks`` services, ``/diagnostics`` statuses and ``/tf_static`` transforms of its own
  skins. The topics and services keep their absolute names (``/skinloc/<skin>/...``) and
  ``/diagnostics`` and ``/tf_static`` take many publishers, so only the node that holds a skin's
  parameters changes. One node fed by every worker would keep a single name, but every
  parameter set, tare and diagnostics round would then cross two processes, and the node's
  process would be one more writer that all workers wait on; a worker and its node also live
  and die together, so a restarted worker brings its node back whole.
* **A worker that dies is restarted.** One that stops without its goodbye (a crash in native
  code, the out-of-memory killer, ``kill -9``) is reported on stderr and started again after a
  wait that doubles from ``RESTART_WAIT_S`` up to ``RESTART_WAIT_MAX_S``; its skins' statistics
  then count from the restart, and ``worker_restarts`` says how often. A worker that cannot
  start in the first place (a model that does not load, a port missing with ``--no-wait``)
  fails the run, with its one-line error.
* **Sinks.** Each worker opens its own: only those that several processes can share are
  allowed, ``jsonl`` on stdout (one write per line), ``udp`` (one datagram per message) and
  ``ros2`` (a node per worker); a file or a server port would be opened twice.
* **Stopping.** Workers ignore ``SIGINT`` (a Ctrl-C in a terminal reaches the whole process
  group): the parent asks each to stop and waits for its statistics, so every sink is closed
  and every open touch ended once; a worker whose parent is gone stops by itself.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import multiprocessing as mp
import os
import signal
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from skinloc.live.sinks.base import SinkSpec
from skinloc.live.skin_config import SkinConfig

log = logging.getLogger(__name__)

__all__ = [
    "RESTART_WAIT_MAX_S",
    "RESTART_WAIT_S",
    "WorkerError",
    "WorkerPool",
    "partition",
    "worker_sinks",
]

#: the first wait before a dead worker is started again, s (doubled for each death in a row)
RESTART_WAIT_S = 0.5
#: the longest wait before a restart, s
RESTART_WAIT_MAX_S = 30.0
#: how long a stopping worker may take to close its sinks and send its statistics, s
STOP_WAIT_S = 40.0
#: sinks that several processes can share (``Sink`` schemes); ``jsonl`` only on stdout
SHARED_SINKS = ("jsonl", "udp", "ros2")


class WorkerError(RuntimeError):
    """A worker could not start: the run cannot go on without its skins."""


def partition(n_skins: int, workers: int) -> list[range]:
    """Consecutive shares of ``n_skins`` skins for ``workers`` processes, sizes within one.

    Parameters
    ----------
    n_skins : int
        Skins of the run (at least 1).
    workers : int
        Worker processes, 1 .. ``n_skins``.

    Returns
    -------
    list of range
        The skins' indices of each worker, in order; together ``range(n_skins)``.
    """
    if n_skins < 1:
        raise ValueError(f"n_skins must be at least 1, got {n_skins}")
    if not 1 <= workers <= n_skins:
        raise ValueError(f"workers must be 1..{n_skins} (one skin each at least), got {workers}")
    base, extra = divmod(n_skins, workers)
    out, start = [], 0
    for w in range(workers):
        size = base + (1 if w < extra else 0)
        out.append(range(start, start + size))
        start += size
    return out


def worker_sinks(specs: Sequence[Any], index: int) -> list[str]:
    """Worker ``index``'s copies of the sink specs ``specs``.

    ``ros2[:NODE]`` becomes ``ros2:NODE_<index>`` (one node per worker, ``NODE`` defaulting to
    ``skinloc``); ``jsonl`` (stdout) and ``udp`` stay as they are; anything else is refused
    with a ``ValueError`` naming it (a file or a port would be opened by every worker).
    """
    out = []
    for spec in specs:
        if not isinstance(spec, str):
            raise ValueError(f"with workers, sinks are given as specs (text), not {spec!r}")
        parsed = SinkSpec.parse(spec)
        if parsed.scheme not in SHARED_SINKS or (
            parsed.scheme == "jsonl" and parsed.argument not in (None, "-")
        ):
            raise ValueError(
                f"sink {spec!r}: every worker would open it; with --workers use "
                "jsonl (stdout), udp://HOST:PORT or ros2[:NODE]"
            )
        if parsed.scheme == "ros2":
            out.append(f"ros2:{parsed.label('skinloc')}_{index}")
        else:
            out.append(spec)
    return out


@dataclass
class _Worker:
    """The parent's view of one worker."""

    index: int
    skins: list[SkinConfig]
    sinks: list[str]
    proc: Any = None
    conn: Any = None
    ready: bool = False  # said it runs (this incarnation)
    started_once: bool = False  # some incarnation ran
    final: dict[str, Any] | None = None  # its goodbye: statistics
    restarts: int = 0
    deaths_in_row: int = 0
    restart_at: float = math.inf
    exit_codes: list[int] = field(default_factory=list)

    @property
    def names(self) -> str:
        return ", ".join(s.name for s in self.skins)


def _describe_exit(code: int | None) -> str:
    if code is None:
        return "no exit code"
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


class WorkerPool:
    """Run ``skins`` over ``workers`` processes, one ``Runner`` each (see the module's notes).

    Parameters
    ----------
    skins : sequence of SkinConfig
        Every skin of the run (each must pickle: a model given as a path, a source as text).
    sinks : sequence of str
        Sink specs of every skin (``worker_sinks`` adapts them per worker).
    workers : int
        Worker processes, 2 .. ``len(skins)`` (1 is allowed: one worker process).
    report : callable(str), optional
        Told what happens to the workers (started, died, restarted), one line each.
    """

    def __init__(
        self,
        skins: Sequence[SkinConfig],
        sinks: Sequence[str],
        workers: int,
        report: Callable[[str], None] | None = None,
    ) -> None:
        names = [s.name for s in skins]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"skin names must be unique; repeated: {', '.join(dup)}")
        shares = partition(len(skins), workers)
        self.workers = []
        for w, share in enumerate(shares):
            # a skin's own sinks go with it to its worker (copies: the caller's stay as given)
            mine = [
                dataclasses.replace(skins[i], sinks=worker_sinks(skins[i].sinks, w)) for i in share
            ]
            self.workers.append(_Worker(w, mine, worker_sinks(sinks, w)))
        self.report = report or (lambda line: log.info("%s", line))
        self._ctx = mp.get_context("spawn")
        self._stop = threading.Event()
        self._deadline = math.inf

    # ------------------------------------------------------------------ lifecycle
    def stop(self) -> None:
        """Ask every worker to end (safe from a signal handler: sets a flag the loop reads)."""
        self._stop.set()

    def _spawn(self, wk: _Worker) -> None:
        left = None if math.isinf(self._deadline) else max(self._deadline - time.monotonic(), 0)
        parent, child = self._ctx.Pipe()
        wk.proc = self._ctx.Process(
            target=_worker_main,
            args=(child, wk.index, wk.skins, wk.sinks, left),
            name=f"skinloc-worker-{wk.index}",
        )
        wk.proc.start()
        child.close()
        wk.conn, wk.ready, wk.final = parent, False, None

    def run(self, duration_s: float | None = None) -> list[dict[str, Any]]:
        """Start the workers, wait until they end (or ``stop``), and merge their statistics.

        Returns the statistics of every skin (``Runner.stats``), in the order given, each with
        ``worker`` (its worker's index) and ``worker_restarts``. Raises ``WorkerError`` when a
        worker cannot start.
        """
        if duration_s is not None:
            self._deadline = time.monotonic() + duration_s
        try:
            for wk in self.workers:
                self._spawn(wk)
            while True:
                if self._stop.is_set():
                    self._stop_all()
                    break
                live = [wk for wk in self.workers if wk.proc is not None]
                if not live and all(wk.final is not None for wk in self.workers):
                    break
                if not live:  # every worker waits for its restart
                    time.sleep(0.05)
                self._serve(live, 0.1)
                now = time.monotonic()
                for wk in self.workers:
                    if wk.proc is None and wk.final is None and now >= wk.restart_at:
                        self._restart(wk)
        except WorkerError:
            self._stop.set()  # the others stop cleanly (their errors add nothing)
            with contextlib.suppress(WorkerError):
                self._stop_all()
            self._kill_all()
            raise
        except BaseException:
            self._kill_all()
            raise
        return self.stats()

    def _serve(self, live: list[_Worker], timeout_s: float) -> None:
        """Wait up to ``timeout_s`` for the running workers' messages and ends; handle them."""
        from multiprocessing.connection import wait

        owner = {id(x): wk for wk in live for x in (wk.conn, wk.proc.sentinel)}
        for ready in wait([x for wk in live for x in (wk.conn, wk.proc.sentinel)], timeout_s):
            wk = owner[id(ready)]
            if wk.proc is not None:  # not reaped by an earlier event of this batch
                self._receive(wk, ready)

    def _receive(self, wk: _Worker, ready: Any) -> None:
        """``ready`` (``wk``'s pipe or process sentinel) said something: read or reap it."""
        if ready is wk.conn:
            try:
                msg = wk.conn.recv()
            except (EOFError, OSError):  # its end closed: the process is ending
                self._ended(wk)
                return
            self._message(wk, msg)
        elif not wk.conn.poll():  # gone, with nothing left unread
            self._ended(wk)

    def _message(self, wk: _Worker, msg: dict[str, Any]) -> None:
        if "ready" in msg:
            wk.ready = wk.started_once = True
            self.report(
                f"worker {wk.index} (pid {msg['ready']}): {wk.names}"
                + (f"; ROS 2 node {', '.join(msg['nodes'])}" if msg.get("nodes") else "")
            )
        elif "error" in msg:
            if not wk.started_once:
                raise WorkerError(f"worker {wk.index} ({wk.names}) could not start: {msg['error']}")
            self.report(f"worker {wk.index} ({wk.names}): {msg['error']}")
        elif "final" in msg:
            wk.final = msg["final"]
            wk.deaths_in_row = 0

    def _ended(self, wk: _Worker) -> None:
        """Worker ``wk``'s process is gone: done, or dead (restart it)."""
        while True:  # its last words first
            try:
                if not wk.conn.poll():
                    break
                msg = wk.conn.recv()
            except (EOFError, OSError):
                break
            self._message(wk, msg)
        wk.proc.join(5.0)
        code = wk.proc.exitcode
        wk.proc = None
        wk.conn.close()
        if wk.final is not None:
            return
        if not wk.started_once:
            raise WorkerError(
                f"worker {wk.index} ({wk.names}) ended before it started ({_describe_exit(code)})"
            )
        wk.exit_codes.append(code if code is not None else -1)
        if self._stop.is_set() or time.monotonic() >= self._deadline:
            wk.final = {"stats": [], "elapsed_s": 0.0}
            self.report(f"worker {wk.index} ({wk.names}) ended ({_describe_exit(code)})")
            return
        wait_s = min(RESTART_WAIT_S * 2**wk.deaths_in_row, RESTART_WAIT_MAX_S)
        wk.deaths_in_row += 1
        wk.restart_at = time.monotonic() + wait_s
        self.report(
            f"worker {wk.index} ({wk.names}) died ({_describe_exit(code)}); "
            f"restarting it in {wait_s:.1f} s"
        )

    def _restart(self, wk: _Worker) -> None:
        wk.restart_at = math.inf
        wk.restarts += 1
        self._spawn(wk)
        self.report(f"worker {wk.index} ({wk.names}) restarted ({wk.restarts} so far)")

    def _stop_all(self) -> None:
        """Ask every worker to end, wait for their statistics (bounded), then kill stragglers."""
        for wk in self.workers:
            if wk.proc is not None:
                try:
                    wk.conn.send("stop")
                except (OSError, ValueError):
                    wk.proc.terminate()
            elif wk.final is None:  # waiting for a restart: nothing to stop
                wk.final = {"stats": [], "elapsed_s": 0.0}
        end = time.monotonic() + STOP_WAIT_S
        while any(wk.proc is not None for wk in self.workers) and time.monotonic() < end:
            self._serve([wk for wk in self.workers if wk.proc is not None], 0.1)
        self._kill_all()

    def _kill_all(self) -> None:
        for wk in self.workers:
            if wk.proc is not None and wk.proc.is_alive():
                self.report(f"worker {wk.index} ({wk.names}) did not stop; killed")
                wk.proc.kill()
            if wk.proc is not None:
                wk.proc.join(5.0)
                wk.proc = None

    # ------------------------------------------------------------------ state
    def stats(self) -> list[dict[str, Any]]:
        """Every skin's statistics, in the skins' order, with ``worker`` and ``worker_restarts``.

        A skin whose worker left no statistics (killed while stopping) has its name, its
        worker and ``lost: true`` only.
        """
        out = []
        for wk in self.workers:
            got = {d["skin"]: d for d in (wk.final or {}).get("stats", [])}
            for skin in wk.skins:
                d = dict(got.get(skin.name) or {"skin": skin.name, "lost": True})
                d.update(worker=wk.index, worker_restarts=wk.restarts)
                out.append(d)
        return out

    def elapsed(self) -> float:
        """The longest time a worker ran, s."""
        return max(
            (float((wk.final or {}).get("elapsed_s", 0.0)) for wk in self.workers), default=0
        )


# ------------------------------------------------------------------------------ the worker
def _worker_main(
    conn: Any, index: int, skins: list[SkinConfig], sinks: list[str], duration_s: float | None
) -> None:
    """A worker process: one ``Runner`` over ``skins``, until its duration, the end or "stop"."""
    from skinloc.live.runner import Runner

    # a Ctrl-C in a terminal reaches the whole process group: the parent decides
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        runner = Runner(skins, sinks=sinks)
        runner.open()
    except Exception as exc:  # noqa: BLE001 - said to the parent in one line
        why = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
        conn.send({"error": why})
        conn.close()
        os._exit(1)
    signal.signal(signal.SIGTERM, lambda *_: runner.stop())

    def watch() -> None:
        # "stop", or the parent gone (end of file): end the loop
        try:
            conn.recv()
        except (EOFError, OSError):
            pass
        runner.stop()

    threading.Thread(target=watch, name="skinloc-worker-watch", daemon=True).start()
    nodes = [getattr(s, "node_name", "") for s in runner.all_sinks() if s.name == "ros2"]
    conn.send({"ready": os.getpid(), "nodes": nodes})
    t0 = time.monotonic()
    code = 0
    try:
        runner.run(duration_s)
    except Exception as exc:  # noqa: BLE001 - said to the parent; it restarts the worker
        conn.send({"error": f"{type(exc).__name__}: {exc}"})
        code = 1
    stats = runner.stats()
    runner.close()
    if code == 0:
        conn.send({"final": {"stats": stats, "elapsed_s": time.monotonic() - t0}})
    conn.close()
    if code:
        os._exit(code)
