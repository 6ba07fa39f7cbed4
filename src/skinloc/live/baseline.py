"""Baseline subtraction with drift tracking: the first compiled step of every frame."""

from __future__ import annotations

import numpy as np

from skinloc._jit import jit

__all__ = ["subtract_baseline"]


@jit()
def subtract_baseline(
    values: np.ndarray,
    baseline: np.ndarray,
    inv_sigma: np.ndarray,
    delta: np.ndarray,
    alpha: float,
    quiet_z: float,
    mode: int,
) -> float:  # pragma: no cover - compiled
    """``delta = values - baseline``; returns the peak ``delta / sigma``.

    Drift tracking moves the baseline ``alpha`` of the way towards ``values``: ``mode`` 0 not
    at all; 1 every sensor if the peak is below ``quiet_z``; 2 every sensor; 3 only sensors
    below ``quiet_z`` (during a touch: those away from the finger).
    """
    n = values.shape[0]
    peak = -np.inf
    for i in range(n):
        d = values[i] - baseline[i]
        delta[i] = d
        z = d * inv_sigma[i]
        if z > peak:
            peak = z
    if alpha > 0.0:
        if mode == 2 or (mode == 1 and peak < quiet_z):
            for i in range(n):
                baseline[i] += alpha * (values[i] - baseline[i])
        elif mode == 3:
            for i in range(n):
                if delta[i] * inv_sigma[i] < quiet_z:
                    baseline[i] += alpha * (values[i] - baseline[i])
    return peak
