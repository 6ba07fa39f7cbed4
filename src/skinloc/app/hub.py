"""Fan-out of messages from worker threads to the browser tabs' WebSockets.

Worker threads call ``Hub.publish`` (thread-safe, never blocks). Each tab has its own queue; a
slow tab loses stream messages (frames, live points), never state or events.
"""

from __future__ import annotations

import asyncio
import collections
import json
import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

__all__ = ["Hub", "to_json"]

#: Message types a slow tab may lose, with the queue length past which they are dropped.
DROPPABLE = {"frame": 8, "live": 64, "sensors": 4}


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.integer | np.bool_):
        return obj.item()
    if isinstance(obj, np.floating):
        return None if not np.isfinite(obj) else float(obj)
    raise TypeError(f"cannot send {type(obj).__name__} as JSON")


def _finite(obj: Any) -> Any:
    """Replace non-finite floats (which JSON cannot carry) by None, recursively."""
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    if isinstance(obj, np.ndarray) and obj.dtype.kind == "f":
        return [_finite(v) for v in obj.tolist()]
    return obj


def to_json(msg: Any) -> str:
    """Encode a message (numpy arrays and non-finite floats allowed) as JSON."""
    return json.dumps(_finite(msg), default=_default, separators=(",", ":"))


@dataclass
class _Tab:
    client_id: str
    queue: collections.deque = field(default_factory=collections.deque)
    event: asyncio.Event = field(default_factory=asyncio.Event)


class Hub:
    """Registry of connected tabs and the event loop that serves them."""

    def __init__(self) -> None:
        self._tabs: dict[int, _Tab] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._next = 0

    @property
    def client_ids(self) -> list[str]:
        """Client ids of the connected tabs."""
        return [t.client_id for t in list(self._tabs.values())]

    def attach(self, client_id: str) -> tuple[int, _Tab]:
        """Register a tab (call from the event loop); returns its key and queue."""
        self._loop = asyncio.get_running_loop()
        self._next += 1
        tab = _Tab(client_id)
        self._tabs[self._next] = tab
        return self._next, tab

    def detach(self, key: int) -> None:
        """Forget a tab."""
        self._tabs.pop(key, None)

    def publish(self, msg: dict[str, Any], to: str | None = None) -> None:
        """Queue ``msg`` for every tab (or only the tabs of client ``to``); thread-safe."""
        loop = self._loop
        if loop is None or loop.is_closed() or not self._tabs:
            return
        text = to_json(msg)
        kind = msg.get("type", "")
        try:
            loop.call_soon_threadsafe(self._put, text, kind, to)
        except RuntimeError:  # the loop closed meanwhile
            pass

    def _put(self, text: str, kind: str, to: str | None) -> None:
        limit = DROPPABLE.get(kind)
        for tab in list(self._tabs.values()):
            if to is not None and tab.client_id != to:
                continue
            if limit is not None and len(tab.queue) >= limit:
                continue
            tab.queue.append(text)
            tab.event.set()

    @staticmethod
    async def drain(tab: _Tab) -> list[str]:
        """Wait for messages of ``tab`` and take all of them."""
        await tab.event.wait()
        tab.event.clear()
        out = list(tab.queue)
        tab.queue.clear()
        return out
