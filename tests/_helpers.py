"""Helpers shared by the tests: bounded waits that stretch with the machine's load, one-line
errors, and reading what a subprocess prints without blocking.

A test waits on what it can observe (a line printed, a file grown, a state reached), never a
fixed sleep; every wait is bounded, and the bound is multiplied by :func:`load_factor` so the
suite passes on a machine shared with other CPU-heavy jobs.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import queue
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
#: Set to a number (``2``, ``5``) to stretch every bound by that much on a slow machine.
SCALE_ENV = "SKINLOC_TEST_TIMEOUT_SCALE"
#: However loaded the machine, a wait ends: at most this many times its nominal bound.
MAX_FACTOR = 8.0


def load_factor() -> float:
    """How many times longer than on an idle machine a wait may take, 1 to ``MAX_FACTOR``.

    ``SKINLOC_TEST_TIMEOUT_SCALE`` when set, else the one-minute load average per core (runnable
    processes per core: 2 means each gets about half the time it would alone).
    """
    env = os.environ.get(SCALE_ENV)
    if env:
        return min(max(float(env), 1.0), MAX_FACTOR)
    try:
        load = os.getloadavg()[0]
    except (OSError, AttributeError):  # not available on this platform
        return 1.0
    return min(max(load / (os.cpu_count() or 1), 1.0), MAX_FACTOR)


def scaled(timeout_s: float) -> float:
    """``timeout_s`` stretched by the machine's current load (:func:`load_factor`)."""
    return timeout_s * load_factor()


def wait_until(
    check: Callable[[], Any],
    what: str | Callable[[], str],
    timeout_s: float = 30.0,
    interval_s: float = 0.02,
    proc: subprocess.Popen | None = None,
) -> Any:
    """Poll ``check()`` until it returns something true and return that.

    Fails naming ``what`` (a string, or a function giving one, for the state at the time) once
    ``timeout_s`` scaled by the load has passed; the load is read again at every poll, so a
    machine that gets busier meanwhile gets a longer bound. With ``proc``, fails at once if the
    process ends first.
    """
    t0 = time.monotonic()
    while True:
        got = check()
        if got:
            return got
        waited = time.monotonic() - t0
        ended = proc is not None and proc.poll() is not None
        if ended or waited > scaled(timeout_s):
            text = what() if callable(what) else what
            why = f"the process ended (exit code {proc.returncode})" if ended else (
                f"timed out after {waited:.0f} s"
            )  # fmt: skip
            pytest.fail(f"{why} waiting for {text}")
        time.sleep(interval_s)


def one_line_error(res: Any, *needles: str) -> str:
    """A ``CliRunner`` result that failed with one line ``error: ...`` holding every needle."""
    assert res.exit_code not in (0, None), res.output
    assert "Traceback" not in res.output
    err = res.output.strip()
    assert err.startswith("error:") and err.count("\n") == 0, err
    for n in needles:
        assert n in err, err
    return err


def start_skinloc(
    *args: object, env: dict[str, str] | None = None, **popen: Any
) -> subprocess.Popen:
    """``python -m skinloc ARGS`` (this checkout's code) started as a shell starts a foreground job
    (``popen_foreground``)."""
    env = {**os.environ, **(env or {})}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(SRC), env.get("PYTHONPATH")) if p)
    cmd = [sys.executable, "-m", "skinloc", *(str(a) for a in args)]
    return popen_foreground(cmd, env=env, **popen)


def popen_foreground(cmd: list[str], **popen: Any) -> subprocess.Popen:
    """``subprocess.Popen(cmd, **popen)`` with SIGINT at its default in the child, as a
    terminal's foreground job has it.

    A job started in the background by a non-interactive shell (``make test &`` in a script)
    inherits SIGINT *ignored*, and so does every process it starts: a CI run launched that way
    would send Ctrl-C to commands that rightly keep ignoring it (one hung so beside two busy
    loops). The parent's disposition is restored at once.
    """
    ignored = signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    if ignored:  # a caught signal is reset to its default in the child at exec
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        return subprocess.Popen(cmd, **popen)
    finally:
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)


def stop_and_wait(
    proc: subprocess.Popen,
    sig: int,
    what: str,
    timeout_s: float = 60.0,
    output: Lines | None = None,
) -> None:
    """Send ``sig`` once and wait for ``proc`` to end; kill it and fail naming ``what`` if it
    does not within the bound (scaled by the load).

    ``output``: the process's stderr, read by ``Lines``; on a hang the failure shows its end,
    with every thread's stack when the process runs with ``PYTHONFAULTHANDLER=1`` (it is sent
    SIGABRT first, which makes Python's fault handler print them).
    """
    proc.send_signal(sig)
    t0 = time.monotonic()
    while proc.poll() is None:
        if time.monotonic() - t0 > scaled(timeout_s):
            if output is not None:
                proc.send_signal(signal.SIGABRT)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(10.0)
            proc.kill()
            proc.wait()
            tail = "" if output is None else "\n" + output.rest(10.0)[-6000:]
            pytest.fail(f"{what} did not stop on one {signal.Signals(sig).name}{tail}")
        time.sleep(0.02)


class Lines:
    """What a subprocess writes to a pipe, read line by line on a thread (never blocks a test).

    Parameters
    ----------
    stream : text file
        ``proc.stdout`` or ``proc.stderr`` of a ``subprocess.Popen(..., text=True)``.
    """

    def __init__(self, stream: IO[str]) -> None:
        self.lines: list[str] = []
        self.ended = False
        self._new: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            self._new.put(line)
        self._new.put(None)

    def _drain(self) -> None:
        """Move what arrived into ``lines``; ``ended`` once the stream is closed."""
        while True:
            try:
                line = self._new.get_nowait()
            except queue.Empty:
                return
            if line is None:
                self.ended = True
            else:
                self.lines.append(line)

    @property
    def text(self) -> str:
        """Everything read so far."""
        self._drain()
        return "".join(self.lines)

    def wait_for(self, want: str, what: str, timeout_s: float = 120.0) -> str:
        """The first line holding ``want``; fails (with the text so far) if the stream ends or
        the bound (scaled by the load) passes first."""

        def seen() -> str | None:
            self._drain()
            hit = next((ln for ln in self.lines if want in ln), None)
            if hit is None and self.ended:
                pytest.fail(f"the process ended before {what}; it wrote: {''.join(self.lines)}")
            return hit

        return wait_until(seen, lambda: f"{what}; it wrote: {''.join(self.lines)[-2000:]}",
                          timeout_s)  # fmt: skip

    def rest(self, timeout_s: float = 60.0) -> str:
        """Everything, once the stream ends (the process closed it, usually by exiting)."""
        self._thread.join(scaled(timeout_s))
        return self.text


#: ROS 2 domain ids the tests lease: 1-99, below the ports Linux hands out at random (a
#: domain's DDS ports are 7400 + 250 id + ...; ids above 101 reach 32768 and up), and apart
#: from the benchmarks' 100-199 (``skinloc.bench.sinks.bench_dds``).
ROS_DOMAINS = range(1, 100)


@contextlib.contextmanager
def ros_domain_lease(ids: range = ROS_DOMAINS) -> Iterator[int]:
    """A ROS 2 domain id of ``ids`` that no other test on this machine holds while the block
    runs.

    Tests run side by side (pytest-xdist workers, other runs on the machine), and two on one
    domain hear each other: another test's probe once pressed a test's stand-in arm. Each id
    is an exclusive lock on a file under the temp dir, freed when the block ends or its
    process dies.
    """
    folder = Path(tempfile.gettempdir()) / "skinloc-test-ros-domains"
    folder.mkdir(exist_ok=True)
    order = list(ids)
    random.shuffle(order)  # a run's first tests do not all try id 1 first
    for domain in order:
        fd = os.open(folder / f"{domain}.lock", os.O_CREAT | os.O_RDWR, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            continue
        try:
            yield domain
        finally:
            os.close(fd)  # frees the lock
        return
    raise RuntimeError(f"every ROS 2 domain id in {ids} is held by another test")
