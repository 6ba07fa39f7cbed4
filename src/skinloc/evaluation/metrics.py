"""Sensor and localisation metrics: the paper's per-sensor SNR and error statistics in mm."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "ErrorStats",
    "error_stats",
    "localisation_errors_mm",
    "mean_interval",
    "mean_snr_db",
    "snr_db",
]


def snr_db(touch_means: np.ndarray, baseline_frames: np.ndarray) -> np.ndarray:
    """Per-sensor SNR, the paper's Eq. 1.

    ``SNR_i = 20 log10((max_touch(S_i) - S_i0) / sigma_i0)``, where the maximum runs over the
    mean images of the point logs.

    Parameters
    ----------
    touch_means : (n, n_sensors) float
        Mean image of each touch, baseline-subtracted (``S - S_0``), counts.
    baseline_frames : (m, n_sensors) float
        No-touch frames, counts; their standard deviation is ``sigma_0``.

    Returns
    -------
    (n_sensors,) float
        SNR in dB; ``nan`` for a sensor whose largest touch signal is not positive.

    Examples
    --------
    >>> base = np.array([[0.0, 0.0], [2.0, 2.0]])  # std 1 count
    >>> snr_db(np.array([[10.0, 100.0]]), base).round(1)
    array([20., 40.])
    """
    touch_means = np.atleast_2d(np.asarray(touch_means, dtype=np.float64))
    sigma = np.asarray(baseline_frames, dtype=np.float64).std(axis=0)
    peak = touch_means.max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = peak / sigma
        return np.where(ratio > 0, 20.0 * np.log10(np.where(ratio > 0, ratio, 1.0)), np.nan)


def mean_snr_db(touch_means: np.ndarray, baseline_frames: np.ndarray) -> float:
    """Mean of ``snr_db`` over the sensors with a defined SNR, dB."""
    return float(np.nanmean(snr_db(touch_means, baseline_frames)))


def localisation_errors_mm(predicted: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Euclidean distances between ``predicted (n, 3)`` and ``true (n, 3)`` metres, in mm."""
    predicted, true = np.asarray(predicted, float), np.asarray(true, float)
    if predicted.shape != true.shape or predicted.ndim != 2 or predicted.shape[1] != 3:
        raise ValueError(
            f"points must both have shape (n, 3), got {predicted.shape} and {true.shape}"
        )
    return 1e3 * np.linalg.norm(predicted - true, axis=1)


@dataclass(frozen=True)
class ErrorStats:
    """Summary of localisation errors, mm."""

    n: int
    mean_mm: float
    std_mm: float
    median_mm: float
    p95_mm: float
    max_mm: float

    def as_dict(self) -> dict[str, float | int]:
        """The fields as a plain dict (for JSON)."""
        return asdict(self)

    def __str__(self) -> str:
        return (
            f"{self.mean_mm:.1f} +- {self.std_mm:.1f} mm (median {self.median_mm:.1f}, "
            f"p95 {self.p95_mm:.1f}, n={self.n})"
        )


def error_stats(errors_mm: np.ndarray) -> ErrorStats:
    """Mean, std, median, 95th percentile and max of errors in mm.

    Examples
    --------
    >>> error_stats(np.array([1.0, 2.0, 3.0])).mean_mm
    2.0
    """
    e = np.asarray(errors_mm, dtype=np.float64).ravel()
    if e.size == 0:
        raise ValueError("no errors to summarise")
    return ErrorStats(
        n=int(e.size),
        mean_mm=float(e.mean()),
        std_mm=float(e.std()),
        median_mm=float(np.median(e)),
        p95_mm=float(np.percentile(e, 95)),
        max_mm=float(e.max()),
    )


def mean_interval(
    errors_mm: np.ndarray, level: float = 0.95, n_boot: int = 2000, random_state: int = 0
) -> tuple[float, float]:
    """Bootstrap percentile interval of the mean error, mm: ``(low, high)``.

    The touches are resampled with replacement ``n_boot`` times; the interval holds the
    central ``level`` of the resampled means. Cross-validated errors of one session are not
    quite independent (the folds share training touches), so read it as the spread the
    touches alone give, not an exact confidence interval.

    Examples
    --------
    >>> lo, hi = mean_interval(np.array([1.0, 2.0, 3.0, 4.0]))
    >>> 1.0 <= lo < 2.5 < hi <= 4.0
    True
    """
    e = np.asarray(errors_mm, dtype=np.float64).ravel()
    if e.size == 0:
        raise ValueError("no errors to summarise")
    if not 0 < level < 1:
        raise ValueError(f"level must be between 0 and 1, got {level}")
    rng = np.random.default_rng(random_state)
    means = e[rng.integers(0, e.size, size=(n_boot, e.size))].mean(axis=1)
    tail = 100 * (1 - level) / 2
    return float(np.percentile(means, tail)), float(np.percentile(means, 100 - tail))
