"""A scripted hand on a live virtual skin: a ``GestureScript`` performed in wall-clock time.

``record_gestures`` runs a script on the simulated skin's own clock, for a recording;
``ScriptedHand`` runs the same items (the same ``Stroke.finger_at`` motion, the same felt-touch
rule) on the wall clock, for a ``VirtualSkin`` (``VirtualSkin.hand``): before each frame the
device asks the hand which fingers touch at that moment, so fingers move, land and lift between
frames as they would on the board. Used by the gesture soak (``bench/live_soak.py --gestures``)
and its short test.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from skinloc.sim.fingers import Finger
from skinloc.sim.gesture_stream import make_felt
from skinloc.sim.gestures import GestureScript, ScriptItem

__all__ = ["ScriptedHand", "script_items"]


def script_items(script: GestureScript, duration_s: float, skin=None) -> list[ScriptItem]:
    """The script's items that end before ``duration_s`` (script time, s), made felt on ``skin``.

    Drawn up front, so the device thread never waits for a path to be found.

    Parameters
    ----------
    script : GestureScript
        Enough gestures to fill ``duration_s`` (the rest are not drawn).
    duration_s : float
        Script time at which the hand stops, s.
    skin : SimulatedSkin, optional
        A stroke too light for this skin to feel is pressed harder (``make_felt``).
    """
    out: list[ScriptItem] = []
    for item in script.items():
        if item.end_s > duration_s:
            break
        if skin is not None:
            for s in item.strokes:
                make_felt(skin, s)
        out.append(item)
    return out


class ScriptedHand:
    """Performs script items on the wall clock: ``hand(now)`` gives the fingers down at ``now``.

    Parameters
    ----------
    items : sequence of ScriptItem
        The items, in script time (s after ``t0``), in order.
    t0 : float
        Wall-clock time (``time.monotonic()``, s) of script time 0.
    ramp_s : float
        Pressure ramp at landing and lifting (``Timing.ramp_s``), s.

    Notes
    -----
    ``__call__`` returns None while nothing touches and nothing did at the previous call (the
    skin is left as it is: no image to recompute), else the fingers (``[]`` when they lift).
    """

    def __init__(self, items: Sequence[ScriptItem], t0: float, ramp_s: float) -> None:
        self.items = list(items)
        self.t0 = float(t0)
        self.ramp_s = float(ramp_s)
        self._next = 0  # first item that may still touch
        self._down = False

    @property
    def end_s(self) -> float:
        """Script time of the last lift, s (0 without items)."""
        return self.items[-1].end_s if self.items else 0.0

    def __call__(self, now: float) -> list[Finger] | None:
        """The fingers down at wall-clock ``now`` (monotonic s); None: as before, none."""
        t = now - self.t0
        items = self.items
        while self._next < len(items) and items[self._next].end_s <= t:
            self._next += 1
        fingers: list[Finger] = []
        if self._next < len(items):
            for s in items[self._next].strokes:
                f = s.finger_at(t, self.ramp_s)
                if f is not None:
                    fingers.append(f)
        if not fingers and not self._down:
            return None
        self._down = bool(fingers)
        return fingers

    def truth(self) -> dict[str, list[dict[str, Any]]]:
        """Gestures, other touches and strokes, times on the wall clock (monotonic s).

        ``strokes``: one entry per finger contact, ``{"item", "kind", "slot", "t0_s",
        "t1_s", "start_m", "end_m"}``; the gestures and touches are the items' ``truth``
        records with ``start_s``/``end_s`` shifted to the wall clock and their ``item`` index.
        """
        gestures, touches, strokes = [], [], []
        for i, item in enumerate(self.items):
            rec = {
                **item.truth,
                "item": i,
                "start_s": item.start_s + self.t0,
                "end_s": item.end_s + self.t0,
            }
            (touches if item.kind in ("rest", "drag") else gestures).append(rec)
            for s in item.strokes:
                strokes.append(
                    {
                        "item": i,
                        "kind": item.kind,
                        "slot": s.slot,
                        "t0_s": s.t0_s + self.t0,
                        "t1_s": s.t1_s + self.t0,
                        "start_m": s.path_m[0].tolist(),
                        "end_m": s.path_m[-1].tolist(),
                    }
                )
        return {"truth_gestures": gestures, "truth_touches": touches, "strokes": strokes}
