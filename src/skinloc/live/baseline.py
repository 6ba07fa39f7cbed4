"""Baseline subtraction with drift tracking: the first compiled step of every frame."""

from __future__ import annotations

import numpy as np

from skinloc._jit import jit

__all__ = ["BaselineCapture", "subtract_baseline"]


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


class BaselineCapture:
    """A skin's baseline and per-sensor noise, captured from untouched frames.

    Parameters
    ----------
    n_sensors : int
        Sensors per frame.

    Attributes
    ----------
    baseline : (n_sensors,) float64
        The baseline, counts; drift tracking (``subtract_baseline``) moves it in place, so the
        array is never replaced.
    inv_sigma : (n_sensors,) float64
        One over each sensor's noise std (floored), 1/counts; updated in place.
    captured_baseline, captured_sigma : (n_sensors,) float64
        The baseline and noise std (counts) of the last capture; sigma is NaN before one.
    n_frames : int
        Frames summed so far towards the capture in progress.
    """

    __slots__ = (
        "_sum",
        "_sum2",
        "baseline",
        "captured_baseline",
        "captured_sigma",
        "inv_sigma",
        "n_frames",
    )

    def __init__(self, n_sensors: int) -> None:
        self.baseline = np.zeros(n_sensors, dtype=np.float64)
        self.inv_sigma = np.ones(n_sensors, dtype=np.float64)
        self.captured_baseline = np.zeros(n_sensors, dtype=np.float64)
        self.captured_sigma = np.full(n_sensors, np.nan)
        self._sum = np.zeros(n_sensors, dtype=np.float64)
        self._sum2 = np.zeros(n_sensors, dtype=np.float64)
        self.n_frames = 0

    def restart(self) -> None:
        """Forget the frames summed so far: the next ``add`` starts a new capture."""
        self.n_frames = 0
        self._sum[:] = 0.0
        self._sum2[:] = 0.0

    def set_from(self, frames: np.ndarray, noise_floor: float) -> None:
        """Capture from untouched raw frames ``(m, n_sensors)`` at once.

        Raises
        ------
        ValueError
            When ``frames`` is empty or holds a value that is not finite.
        """
        n = self.baseline.shape[0]
        F = np.asarray(frames, dtype=np.float64).reshape(-1, n)
        if len(F) == 0 or not np.all(np.isfinite(F)):
            raise ValueError("baseline frames must be a non-empty array of finite counts")
        self.baseline[:] = F.mean(axis=0)
        self._keep(F.std(axis=0) if len(F) > 1 else np.zeros(n), noise_floor)
        self.n_frames = 0

    def add(self, values: np.ndarray, frames_needed: int, noise_floor: float) -> bool:
        """Sum one untouched frame ``(n_sensors,)``; True when it completes the capture."""
        v = np.asarray(values, dtype=np.float64)
        self._sum += v
        self._sum2 += v * v
        self.n_frames += 1
        m = self.n_frames
        if m < frames_needed:
            return False
        mean = self._sum / m
        var = np.maximum(self._sum2 / m - mean * mean, 0.0) * m / max(m - 1, 1)
        self.baseline[:] = mean
        self._keep(np.sqrt(var), noise_floor)
        return True

    def _keep(self, sigma: np.ndarray, noise_floor: float) -> None:
        self.inv_sigma[:] = 1.0 / np.maximum(sigma, noise_floor)
        self.captured_baseline[:] = self.baseline
        self.captured_sigma[:] = sigma
