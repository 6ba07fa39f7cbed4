"""The One-Euro filter (Casiez et al. 2012) of a 3D point, compiled; one state per track."""

from __future__ import annotations

import math

import numpy as np

from skinloc._jit import jit
from skinloc.geometry.snap import constrain_one

__all__ = ["one_euro", "one_euro_onto"]


@jit()
def one_euro(
    state: np.ndarray, p0: float, p1: float, p2: float, t: float, prm: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """One-Euro filter (Casiez et al. 2012) of a 3D point; ``state`` = [init, t, x3, dx3].

    ``prm`` = [min_cutoff_hz, beta, d_cutoff_hz]. Writes the filtered point to ``out (3,)``.
    """
    if state[0] == 0.0:
        state[0] = 1.0
        state[1] = t
        state[2] = p0
        state[3] = p1
        state[4] = p2
        state[5] = 0.0
        state[6] = 0.0
        state[7] = 0.0
        out[0] = p0
        out[1] = p1
        out[2] = p2
        return
    dt = t - state[1]
    if dt <= 0.0:
        dt = 1e-3
    state[1] = t
    ad = 1.0 / (1.0 + 1.0 / (2.0 * math.pi * prm[2] * dt))
    speed = 0.0
    for k in range(3):
        p = p0 if k == 0 else (p1 if k == 1 else p2)
        dx = (p - state[2 + k]) / dt
        state[5 + k] += ad * (dx - state[5 + k])
        speed += state[5 + k] * state[5 + k]
    cutoff = prm[0] + prm[1] * math.sqrt(speed)
    a = 1.0 / (1.0 + 1.0 / (2.0 * math.pi * cutoff * dt))
    for k in range(3):
        p = p0 if k == 0 else (p1 if k == 1 else p2)
        state[2 + k] += a * (p - state[2 + k])
        out[k] = state[2 + k]


@jit()
def one_euro_onto(
    state: np.ndarray,
    p0: float,
    p1: float,
    p2: float,
    t: float,
    prm: np.ndarray,
    tmp: np.ndarray,
    mode: int,
    surf: tuple,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``one_euro`` into ``tmp (3,)``, then that point put on the surface into ``out (3,)``.

    ``mode`` and ``surf`` are a ``Surface``'s (``geometry.snap.constrain_one``): the filter and
    the constraint of a track in one compiled call (two cost about 1.5 us more a contact).
    """
    one_euro(state, p0, p1, p2, t, prm, tmp)
    constrain_one(tmp[0], tmp[1], tmp[2], mode, surf, out)
