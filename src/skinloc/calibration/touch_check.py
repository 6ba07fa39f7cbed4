"""The quality checks of a calibration's touches: which to retake or leave out, and why.

One touch by itself is ``weak`` (its image is no touch, or far below the session's), ``short``
(the finger lifted during the capture) or ``saturated`` (a sensor clipped); among the others
it is ``off_target`` when the map of the other touches puts it far from its target and its
image fits there much better than at the target (the finger pressed elsewhere). The app's gate
(``skinloc app``), ``skinloc check`` and the benchmarks use these functions and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skinloc.calibration.capture import CapturedTouch, TouchDetector
from skinloc.data.recording import Recording

__all__ = [
    "COUNTS_MAX",
    "COUNTS_MIN",
    "OffTarget",
    "baseline_drift_sigma",
    "check_recording",
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


@dataclass
class OffTarget:
    """The off-target check of a session's touches.

    Attributes
    ----------
    flags : (n,) bool
        Touches pressed elsewhere than their target (all False with too few touches).
    distance_mm : (n,) float
        From each target to where the other touches' map puts the touch's image, mm.
    gain : (n,) float
        How much better the image fits there than at its target (nats per feature).
    threshold : float
        The gain above which a touch located more than ``floor_mm`` away is flagged.
    """

    flags: np.ndarray
    distance_mm: np.ndarray
    gain: np.ndarray
    threshold: float


def _gain_threshold(gain: np.ndarray, good: np.ndarray, floor: float, k: float) -> float:
    """Median + ``k`` scaled MAD of the good touches' gains, at least ``floor``."""
    med = float(np.median(gain[good]))
    spread = max(1.4826 * float(np.median(np.abs(gain[good] - med))), 0.05)
    return max(floor, med + k * spread)


def off_target(
    targets: np.ndarray,
    touch_means: np.ndarray,
    surface_points: np.ndarray,
    *,
    floor_mm: float = 20.0,
    gain_floor: float = 0.8,
    k: float = 3.0,
    min_touches: int = 6,
) -> OffTarget:
    """Flag touches pressed far from their target, on evidence from the other touches.

    For each touch, the response map of the *other* touches (``LeaveOneOutMap``) locates its
    image on the skin; the touch is off-target when that place is more than ``floor_mm`` from
    its target and the image fits there better than at the target by more than the session's
    own spread allows (median + ``k`` scaled MAD of the unflagged touches' gains, at least
    ``gain_floor``). The worst such touch is left out of the map before looking again, so
    several bad touches do not hide each other, and a flagged touch that no longer stands out
    once the others are left out is put back (it was a neighbour of a bad touch).

    Parameters
    ----------
    targets : (n, 3) float
        Prompted positions, m.
    touch_means : (n, n_sensors) float
        Baseline-subtracted mean image of each touch, counts.
    surface_points : (P, 3) float
        Candidate places on the skin, m (``geometry.mesh.surface_points(mesh, 2000)``).

    Returns
    -------
    OffTarget
        Measured on 1-3 touches pressed 40-100 mm off per session (docs/app.md, "Touch
        quality"; ``bench/off_target_eval.py``).
    """
    from skinloc.evaluation.influence import LeaveOneOutMap

    targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
    n = len(targets)
    if n < min_touches:
        nan = np.full(n, np.nan)
        return OffTarget(np.zeros(n, dtype=bool), nan, nan.copy(), float("nan"))
    flags = np.zeros(n, dtype=bool)
    fitted = LeaveOneOutMap.fit(targets, touch_means)
    for _ in range(max(2, n // 2)):
        distance, gain = fitted.with_excluded(flags).located(surface_points)
        threshold = _gain_threshold(gain, ~flags, gain_floor, k)
        put_back = None
        for j in np.flatnonzero(flags):
            trial = flags.copy()
            trial[j] = False
            d_j, g_j = fitted.with_excluded(trial).located(surface_points)
            if not (d_j[j] > floor_mm and g_j[j] > _gain_threshold(g_j, ~trial, gain_floor, k)):
                put_back = j
                break
        if put_back is not None:
            flags[put_back] = False
            continue
        over = np.where(flags | (distance <= floor_mm), -np.inf, gain - threshold)
        worst = int(np.argmax(over))
        if over[worst] <= 0:
            break
        flags[worst] = True
        # the hyperparameters again without the touch just flagged: it bent them
        fitted = LeaveOneOutMap.fit(targets, touch_means, flags)
    return OffTarget(flags, distance, gain, threshold)


def baseline_drift_sigma(frames: np.ndarray, baseline: np.ndarray, noise: np.ndarray) -> float:
    """How far no-touch ``frames (m, n)`` sit from the baseline: median |shift| / noise."""
    shift = np.asarray(frames, dtype=np.float64).mean(axis=0) - baseline
    return float(np.median(np.abs(shift) / np.maximum(noise, 1.0)))


def check_recording(
    rec: Recording, *, threshold_sigma: float | None = None, min_active: int | None = None
) -> tuple[list[list[str]], OffTarget]:
    """Every touch's flags in a recording, as the app's gate gives them (it calls this).

    Each point log is one touch: ``short`` counts its frames the calibration's touch rule
    (``TouchDetector`` with ``threshold_sigma`` and ``min_active``, on the recording's own
    baseline and noise) does not see as a touch; the reference peak of ``weak`` is the
    median peak of the recording. ``threshold_sigma`` and ``min_active`` default to the
    session's settings stored in the recording (``meta["session"]``), else 5.0 and 2.

    Returns
    -------
    flags : list of list of str
        One list per point log: ``off_target``, ``weak``, ``short``, ``saturated``.
    OffTarget
        The off-target check's figures.
    """
    from skinloc.geometry.mesh import surface_points

    session = rec.meta.get("session") or {}
    if threshold_sigma is None:
        threshold_sigma = float(session.get("threshold_sigma", 5.0))
    if min_active is None:
        min_active = int(session.get("min_active", 2))
    baseline = rec.baseline
    detector = TouchDetector(baseline, rec.noise, threshold_sigma, min_active)
    peaks = (rec.touch_means.astype(np.float64)).max(axis=1) if rec.n_point_logs else []
    reference = float(np.median(peaks)) if len(peaks) else None
    out: list[list[str]] = []
    for frames in rec.frames:
        untouched = sum(not detector.is_touched(f) for f in frames)
        touch = CapturedTouch(frames, np.zeros(len(frames)), untouched, False)
        out.append(touch_flags(touch, baseline, detector, reference)[0])
    check = off_target(rec.targets, rec.touch_means, surface_points(rec.mesh, 2000))
    for f, bad in zip(out, check.flags, strict=True):
        if bad:
            f.insert(0, "off_target")
    return out, check
