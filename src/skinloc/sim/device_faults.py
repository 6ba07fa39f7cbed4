"""Faults a virtual skin device injects, and its per-frame ground truth.

``FaultConfig`` sets how often bytes are garbled, dropped, split or merged and how often the
device disconnects; ``Fate`` says what happened to each frame, so a soak test can check that
the host delivered exactly the intact frames.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FaultConfig", "Fate", "Pending", "TruthLog"]


class Fate:
    """What happened to a frame; codes stored in the ground-truth log."""

    SENT = 0  #: written intact while a host listened: must be delivered exactly
    DESTROYED = 1  #: its bytes were altered by a fault: must never be delivered wrong
    UNHEARD = 2  #: generated while no host listened (before connect, during a disconnect)


@dataclass
class FaultConfig:
    """Faults the virtual device injects.

    Attributes
    ----------
    p_garbage, p_drop, p_split, p_merge : float
        Per-frame probability of each fault: 1-32 random bytes before or inside the frame; a run
        of 1-16 bytes removed from inside it; the frame written in 2-4 pieces with pauses of
        1-20 ms (text: sometimes a newline inserted mid-line instead); the frame run together
        with the next one (text: the line end removed; binary: both in one write).
    disconnect_every_s : float
        Mean time between disconnects, s (exponentially distributed); 0 disables them.
    downtime_s : float
        How long the device stays away before its port comes back, s.
    random_state : int
        Seed of the faults.
    """

    p_garbage: float = 0.01
    p_drop: float = 0.01
    p_split: float = 0.01
    p_merge: float = 0.005
    disconnect_every_s: float = 30.0
    downtime_s: float = 0.3
    random_state: int = 1

    def __post_init__(self) -> None:
        ps = (self.p_garbage, self.p_drop, self.p_split, self.p_merge)
        if any(not 0.0 <= p <= 1.0 for p in ps) or sum(ps) > 1.0:
            raise ValueError(f"fault probabilities must be in [0, 1] and sum to <= 1, got {ps}")
        if self.disconnect_every_s < 0 or self.downtime_s < 0:
            raise ValueError("disconnect_every_s and downtime_s must be >= 0")

    def choose(self, rng: np.random.Generator) -> str:
        """The fault of one frame: ``garbage``, ``drop``, ``split``, ``merge`` or ``none``."""
        u = rng.random()
        for name, p in (
            ("garbage", self.p_garbage),
            ("drop", self.p_drop),
            ("split", self.p_split),
            ("merge", self.p_merge),
        ):
            if u < p:
                return name
            u -= p
        return "none"


@dataclass
class Pending:
    """A frame held back to be merged with the next one."""

    index: int
    data: bytes


@dataclass
class TruthLog:
    """Per-frame ground truth: frame index, CRC-32 of its values and its ``Fate``."""

    index: list[int] = field(default_factory=list)
    crc: list[int] = field(default_factory=list)
    fate: list[int] = field(default_factory=list)
