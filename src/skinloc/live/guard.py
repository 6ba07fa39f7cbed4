"""What keeps the live loop going when a part of it raises: error counts, logs and back-off.

The runner (``skinloc.live.runner``) never lets one exception stop it. A frame whose processing
raises (the model, the skin's chain) is dropped and counted against its skin (``ErrorLog``); a
sink that raises loses that delivery and is counted per skin it serves (``SinkRoute``); a sink
that keeps failing is left alone for a while that doubles at each failure (``BACKOFF_FIRST_S``
to ``BACKOFF_MAX_S``) and then tried again. Each part's first error of a kind is logged with its
traceback; later ones are counted and summed up in one line at most every ``REPEAT_S``.

Everything here takes the time (``time.monotonic()`` s) as an argument: no clock of its own.
"""

from __future__ import annotations

import logging
import math
from typing import Any

log = logging.getLogger("skinloc.live.runner")

__all__ = [
    "BACKOFF_FIRST_S",
    "BACKOFF_MAX_S",
    "REPEAT_S",
    "ErrorLog",
    "GuardedFrameSink",
    "SinkRoute",
]

#: After the second failure in a row a sink waits this long before it is tried again, s; the
#: wait doubles at each further failure (the first failure is retried at the next delivery).
BACKOFF_FIRST_S = 0.05
#: The longest wait between two tries of a failing sink, s.
BACKOFF_MAX_S = 10.0
#: Repeated errors of one part are summed up in one log line at most this often, s.
REPEAT_S = 10.0
#: Kinds of exception (by type) whose first occurrence is logged with its traceback, per part.
_MAX_KINDS = 8


def _describe(exc: BaseException) -> str:
    text = str(exc)
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


class ErrorLog:
    """The exceptions of one part of the loop (a skin's frames, a sink): counted and logged.

    The first exception of each type is logged with its traceback; the others are counted and
    summed up in one line at most every ``REPEAT_S`` while they go on.

    Parameters
    ----------
    what : str
        The part, as the log names it (``skin 'arm'``, ``sink udp://127.0.0.1:9870``).
    consequence : str
        What happens to the failed item (``the frame is dropped``), for the first log line.
    """

    def __init__(self, what: str, consequence: str) -> None:
        self.what = what
        self.consequence = consequence
        #: Exceptions so far.
        self.n = 0
        #: The last one, ``Type: message``.
        self.last = ""
        self._kinds: set[type] = set()
        self._since = 0  # errors not yet told
        self._next_summary = -math.inf

    def record(self, exc: BaseException, now: float) -> None:
        """Count ``exc`` (raised at ``now``, s) and log it as its turn says."""
        self.n += 1
        self.last = _describe(exc)
        kind = type(exc)
        if kind not in self._kinds and len(self._kinds) < _MAX_KINDS:
            self._kinds.add(kind)
            log.error(
                "%s: %s; %s and the loop goes on (further errors are counted: --stats)",
                self.what,
                self.last,
                self.consequence,
                exc_info=(kind, exc, exc.__traceback__),
            )
            self._next_summary = now + REPEAT_S
            return
        self._since += 1
        if now >= self._next_summary:
            log.warning(
                "%s: %d more error(s) (%d in all); last: %s",
                self.what,
                self._since,
                self.n,
                self.last,
            )
            self._since = 0
            self._next_summary = now + REPEAT_S


class SinkRoute:
    """One sink's deliveries of one skin: its failures, its back-off, what it skipped.

    Parameters
    ----------
    label : str
        The sink as given (its spec, ``udp://127.0.0.1:9870``, or the class's ``name``).
    errors : ErrorLog
        The sink's log, shared by every skin it serves (one traceback per sink, not per skin).
    """

    __slots__ = ("errors", "label", "last_error", "n_errors", "n_failing", "n_skipped", "retry_at")

    def __init__(self, label: str, errors: ErrorLog) -> None:
        self.label = label
        self.errors = errors
        #: Deliveries that raised.
        self.n_errors = 0
        #: Deliveries dropped unsent while the sink was backing off.
        self.n_skipped = 0
        #: Failures in a row (0: healthy).
        self.n_failing = 0
        #: When the sink may be tried again, ``time.monotonic()`` s.
        self.retry_at = -math.inf
        #: The last exception of this route, ``Type: message``.
        self.last_error = ""

    def ready(self, now: float) -> bool:
        """Whether to deliver at ``now``; False (and the delivery counted skipped) while waiting."""
        if now >= self.retry_at:
            return True
        self.n_skipped += 1
        return False

    def failed(self, exc: BaseException, now: float) -> None:
        """A delivery raised ``exc`` at ``now``: count, log, and wait longer before the next."""
        self.n_errors += 1
        self.n_failing += 1
        self.errors.record(exc, now)
        self.last_error = self.errors.last
        if self.n_failing >= 2:
            wait = min(BACKOFF_FIRST_S * 2.0 ** (self.n_failing - 2), BACKOFF_MAX_S)
            self.retry_at = now + wait

    def succeeded(self) -> None:
        """A delivery went through: the sink is healthy again."""
        if self.n_failing >= 2:  # info: a sink that flaps would fill the log
            log.info("%s works again after %d failures", self.errors.what, self.n_failing)
        self.n_failing = 0
        self.retry_at = -math.inf

    def as_dict(self, now: float) -> dict[str, Any]:
        """Counters for ``Runner.stats`` (JSON-ready)."""
        return {
            "sink": self.label,
            "errors": self.n_errors,
            "skipped": self.n_skipped,
            "failing": self.n_failing > 0,
            "retry_in_s": round(max(self.retry_at - now, 0.0), 3),
            "last_error": self.last_error,
        }


class GuardedFrameSink:
    """A sink that records raw frames, as a skin's core calls it, kept from stopping the core.

    ``SkinCore.process_frame`` hands every frame to its ``frame_sinks`` before processing it;
    this wrapper gives a failing recorder a count and back-off of its own (``route``, apart
    from the contacts' route: a sink may take contacts and fail on frames), so that a full
    disk stops the recording, not the skin.
    """

    __slots__ = ("clock", "route", "sink")

    def __init__(self, sink: Any, route: SinkRoute, clock: Any) -> None:
        self.sink = sink
        self.route = route
        self.clock = clock

    def emit_frame(self, skin: str, values: Any, timestamp_s: float, index: int) -> None:
        """Hand the frame to the sink, unless it is backing off; an exception is counted."""
        route = self.route
        if route.n_failing:
            now = self.clock()
            if not route.ready(now):
                return
        try:
            self.sink.emit_frame(skin, values, timestamp_s, index)
        except Exception as exc:  # noqa: BLE001 - a recorder must not stop the skin
            route.failed(exc, self.clock())
        else:
            if route.n_failing:
                route.succeeded()
