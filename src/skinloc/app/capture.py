"""The quality checks of guided capture: they flag touches worth retaking.

A touch is weak, short, saturated or off-target (an image unlike its neighbours'). The touch
rule itself (``TouchCapture``: wait for a steady touch, capture, wait for the release; the
``TouchDetector``) is ``skinloc.calibration.capture``'s, the one rule of every calibration
capture; it is re-exported here for the app.
"""

from __future__ import annotations

import logging

import numpy as np

from skinloc.calibration.capture import (
    CapturedTouch,
    CapturePhase,
    TouchCapture,
    TouchDetector,
)

log = logging.getLogger(__name__)

__all__ = [
    "CapturePhase",
    "CapturedTouch",
    "TouchCapture",
    "baseline_drift_sigma",
    "off_target",
    "touch_flags",
]


#: The range of a sensor's raw counts (16 bits): a value at either end is clipped.
COUNTS_MIN, COUNTS_MAX = 0.0, 65535.0


def touch_flags(
    touch: CapturedTouch,
    baseline: np.ndarray,
    detector: TouchDetector,
    reference_peak: float | None,
    *,
    weak_ratio: float = 0.3,
    short_fraction: float = 0.2,
) -> tuple[list[str], float]:
    """Flags of one touch by itself: ``weak``, ``short``, ``saturated``; and its peak (counts).

    A touch is ``weak`` when its mean image is not a touch for the detector or its peak is below
    ``weak_ratio`` times ``reference_peak`` (the session's median); ``short`` when more than
    ``short_fraction`` of its frames were not touches (the finger lifted during the capture);
    ``saturated`` when a sensor whose baseline is inside the counts' range (0, 65535) reaches
    either end of it in a frame (pressed too hard: its image is clipped).
    """
    mean = touch.frames.astype(np.float64).mean(axis=0)
    peak = float((mean - baseline).max())
    flags = []
    if not detector.is_touched(mean) or (
        reference_peak is not None and peak < weak_ratio * reference_peak
    ):
        flags.append("weak")
    if touch.n_untouched > short_fraction * len(touch.frames):
        flags.append("short")
    inside = (baseline > COUNTS_MIN) & (baseline < COUNTS_MAX)
    clipped = (touch.frames <= COUNTS_MIN) | (touch.frames >= COUNTS_MAX)
    if np.any(clipped[:, inside]):
        flags.append("saturated")
    return flags, peak


def off_target(
    targets: np.ndarray,
    touch_means: np.ndarray,
    *,
    limit: float = 4.0,
    min_touches: int = 6,
) -> tuple[np.ndarray, np.ndarray]:
    """Flag touches whose image the other touches' response map does not expect there.

    Each touch's image is predicted at its target by the response map of the other touches
    (``leave_one_out_residuals``); a residual more than ``limit`` robust standard deviations
    (median and scaled MAD of the other touches' residuals) above the others' median means
    the finger was probably elsewhere. The worst such touch is left out of the map before
    looking again, so one wrong touch does not drag down its neighbours.

    Parameters
    ----------
    targets : (n, 3) float
        Prompted positions, m.
    touch_means : (n, n_sensors) float
        Baseline-subtracted mean image of each touch, counts.

    Returns
    -------
    flags : (n,) bool
        Off-target touches (all False with fewer than ``min_touches``).
    score : (n,) float
        Robust z-score of each touch's residual among the unflagged touches (nan with too
        few touches).
    """
    from skinloc.evaluation.influence import leave_one_out_residuals

    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    n = len(targets)
    if n < min_touches:
        return np.zeros(n, dtype=bool), np.full(n, np.nan)
    # The residual misses a press made far away at a target far from the other touches (the
    # map predicts there only loosely); the image neighbours catch that one.
    flags = _unlike_neighbours(targets, touch_means, factor=4.0, min_touches=min_touches)[0]
    for _ in range(max(1, n // 5)):
        resid = leave_one_out_residuals(targets, touch_means, exclude=flags)
        good = resid[~flags]
        med = float(np.median(good))
        # a floor on the spread: a session of near-identical residuals flags nothing small
        spread = max(1.4826 * float(np.median(np.abs(good - med))), 0.1 * med, 1e-9)
        score = (resid - med) / spread
        over = np.where(flags, -np.inf, score - limit)
        worst = int(np.argmax(over))
        if over[worst] <= 0:
            break
        flags[worst] = True
    return flags, score


def _unlike_neighbours(
    targets: np.ndarray,
    touch_means: np.ndarray,
    *,
    k: int = 3,
    factor: float = 3.0,
    floor_mm: float = 25.0,
    min_touches: int = 6,
) -> tuple[np.ndarray, np.ndarray]:
    """Flag touches whose image looks nothing like the images of their neighbours (coarse).

    Catches a press far from its target (its image resembles touches far away) but with 20
    targets ~50 mm apart its limit is ~100 mm.

    Each touch's position is guessed from the ``k`` other touches with the most similar
    images (cosine similarity of the clipped, baseline-subtracted mean images, weighted); a touch
    whose guess lands more than ``max(floor_mm, factor x median miss)`` from its target is
    off-target: the finger was probably elsewhere.

    Parameters
    ----------
    targets : (n, 3) float
        Prompted positions, m.
    touch_means : (n, n_sensors) float
        Baseline-subtracted mean image of each touch, counts.

    Returns
    -------
    flags : (n,) bool
        Off-target touches (all False with fewer than ``min_touches``).
    miss_mm : (n,) float
        Distance of each guess from its target, mm (nan with too few touches).
    """
    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    n = len(targets)
    if n < max(min_touches, k + 2):
        return np.zeros(n, dtype=bool), np.full(n, np.nan)
    Z = np.maximum(np.asarray(touch_means, dtype=np.float64), 0.0)
    Z = Z / np.maximum(np.linalg.norm(Z, axis=1, keepdims=True), 1e-9)
    S = Z @ Z.T
    np.fill_diagonal(S, -np.inf)
    flags = np.zeros(n, dtype=bool)
    # Flag the worst touch, leave it out of everyone's neighbours, and look again: a touch
    # made at the wrong place must not drag the touches it resembles down with it.
    for _ in range(max(1, n // 5)):
        S_use = np.where(flags[None, :], -np.inf, S)
        nearest = np.argsort(-S_use, axis=1)[:, :k]
        w = np.maximum(np.take_along_axis(S_use, nearest, axis=1), 0.0) ** 4 + 1e-12
        guess = (w[..., None] * targets[nearest]).sum(axis=1) / w.sum(axis=1, keepdims=True)
        miss = 1e3 * np.linalg.norm(guess - targets, axis=1)
        limit = max(floor_mm, factor * float(np.median(miss[~flags])))
        over = np.where(flags, -np.inf, miss - limit)
        worst = int(np.argmax(over))
        if over[worst] <= 0:
            break
        flags[worst] = True
    return flags, miss


def baseline_drift_sigma(frames: np.ndarray, baseline: np.ndarray, noise: np.ndarray) -> float:
    """How far no-touch ``frames (m, n)`` sit from the baseline: median |shift| / noise."""
    shift = np.asarray(frames, dtype=np.float64).mean(axis=0) - baseline
    return float(np.median(np.abs(shift) / np.maximum(noise, 1.0)))
