"""A publisher thread behind a bounded queue: the pipeline enqueues, the thread sends.

The pipeline's thread must not pay for encoding and network writes (the ROS 2 sink's CDR
encoding and DDS writes cost about 14 µs of loop CPU per frame at 100 skins). ``put`` appends an
item under a short lock and returns: it never blocks on the sending side, and when the queue is
full the oldest item is dropped and counted (``n_dropped``). The thread takes what is queued at
each wake-up as one batch (at most ``max_batch`` items), hands it to ``handle``, then sleeps
``gather_s``: the next batch gathers instead of the thread waking once per frame, and the
pipeline's thread never waits long for the interpreter lock behind a long batch. ``close`` lets
the thread send what is queued, then joins it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["PublisherThread"]


class PublisherThread:
    """Send items on a thread of their own, from a bounded drop-oldest queue.

    Parameters
    ----------
    handle : callable
        ``handle(batch)`` with ``batch`` a list of queued items, oldest first; runs on the
        thread. An exception is logged (the first one with its traceback) and counted in
        ``n_errors``; the thread goes on with the next batch.
    name : str
        The thread's name.
    maxsize : int, default=4096
        Queue bound, items; 4096 is 0.4 s of 100 skins at 100 Hz.
    gather_s : float, default=0.001
        Pause after each batch, s: a bound on the wake-ups per second (and the latency it adds).
    max_batch : int, default=64
        Items per batch at most: the longest the thread holds the interpreter lock in one go
        (about 1 ms for 64 ROS 2 frames).

    Attributes
    ----------
    n_put, n_dropped, n_sent, n_batches, n_errors : int
        Items queued, dropped from a full queue (the oldest), handed to ``handle``; batches;
        batches whose ``handle`` raised.
    cpu_s : float
        CPU time the thread spent in ``handle``, s (``time.thread_time``).
    """

    def __init__(
        self,
        handle: Callable[[list[Any]], None],
        *,
        name: str = "skinloc-publisher",
        maxsize: int = 4096,
        gather_s: float = 0.001,
        max_batch: int = 64,
    ) -> None:
        if maxsize < 1:
            raise ValueError(f"a publisher queue holds at least 1 item, not {maxsize}")
        self._handle = handle
        self.maxsize = int(maxsize)
        self.gather_s = float(gather_s)
        self.max_batch = max(int(max_batch), 1)
        self._q: deque[Any] = deque()
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._idle = False
        self._closing = False
        self.n_put = self.n_dropped = self.n_sent = self.n_batches = self.n_errors = 0
        self.cpu_s = 0.0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, item: Any) -> None:
        """Queue ``item``; never blocks (a full queue drops its oldest item)."""
        with self._lock:
            if self._closing:  # after close: nothing sends it any more
                self.n_dropped += 1
                return
            if len(self._q) >= self.maxsize:
                self._q.popleft()
                self.n_dropped += 1
            self._q.append(item)
            self.n_put += 1
            wake = self._idle
            self._idle = False
        if wake:  # only when the thread sleeps on an empty queue: no signal per item
            self._wake.set()

    @property
    def pending(self) -> int:
        """Items queued and not yet taken by the thread."""
        return len(self._q)

    def _run(self) -> None:
        while True:
            with self._lock:
                q = self._q
                if len(q) <= self.max_batch:
                    batch = list(q)
                    q.clear()
                else:
                    batch = [q.popleft() for _ in range(self.max_batch)]
                if not batch:
                    if self._closing:
                        return
                    self._idle = True
                    self._wake.clear()
            if not batch:
                self._wake.wait()
                continue
            t0 = time.thread_time()
            try:
                self._handle(batch)
            except Exception:  # noqa: BLE001 - the thread must outlive one failed batch
                if not self.n_errors:
                    log.exception("%s: publishing failed", self._thread.name)
                else:
                    log.debug("%s: publishing failed again", self._thread.name, exc_info=True)
                self.n_errors += 1
            self.cpu_s += time.thread_time() - t0
            self.n_sent += len(batch)
            self.n_batches += 1
            if self.gather_s > 0 and not self._closing:
                time.sleep(self.gather_s)

    def flush(self, timeout_s: float = 10.0) -> bool:
        """Wait until every item queued so far is handled (or dropped); False on timeout."""
        end = time.monotonic() + timeout_s
        while self.n_sent + self.n_dropped < self.n_put:
            if time.monotonic() > end or not self._thread.is_alive():
                return False
            time.sleep(0.001)
        return True

    def close(self, timeout_s: float = 10.0) -> bool:
        """Send what is queued, stop and join the thread; False if it did not end in time.

        Idempotent. A thread stuck in ``handle`` past ``timeout_s`` is left behind (it is a
        daemon, so it never keeps the process alive) and a warning is logged.
        """
        with self._lock:
            self._closing = True
        self._wake.set()
        if self._thread is threading.current_thread():
            return False
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            log.warning(
                "%s did not finish within %.0f s; %d items not sent",
                self._thread.name,
                timeout_s,
                len(self._q),
            )
            return False
        return True

    def stats(self) -> dict[str, Any]:
        """Counters, as a JSON-ready dict."""
        return {
            "queued": self.n_put,
            "dropped": self.n_dropped,
            "sent": self.n_sent,
            "batches": self.n_batches,
            "errors": self.n_errors,
            "pending": self.pending,
            "cpu_s": self.cpu_s,
        }
