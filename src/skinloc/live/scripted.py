"""A simulated skin touched by a scripted finger: the ``sim`` source of ``skinloc run``."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from skinloc.sources.base import Frame, FrameSource

__all__ = ["ScriptedFinger"]


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
