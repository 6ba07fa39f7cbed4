"""The quality checks of a calibration's touches: which to retake or leave out, and why.

One touch by itself is ``weak`` (its image is no touch, or far below the session's), ``short``
(the finger lifted during the capture) or ``saturated`` (a sensor clipped); among the others
it is ``off_target`` when the map of the other touches (of the images' square roots) puts it
far from its target, its image fits there better than at the target and badly at the target
(the finger pressed elsewhere).
The app's gate (``skinloc app``), ``skinloc check`` and the benchmarks use these functions and
nothing else.
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
    score : (n,) float
        The evidence against the touch: ``gain`` plus the log of its standardised residual at
        its target (``LeaveOneOutMap.residuals``); about 0 for a good touch.
    threshold : float
        The score above which a touch located more than ``floor_mm`` away is flagged.
    """

    flags: np.ndarray
    distance_mm: np.ndarray
    gain: np.ndarray
    score: np.ndarray
    threshold: float


def _score_threshold(score: np.ndarray, core: np.ndarray, floor: float, k: float) -> float:
    """Median + ``k`` scaled MAD of the core touches' scores, at least ``floor``."""
    med = float(np.median(score[core]))
    spread = max(1.4826 * float(np.median(np.abs(score[core] - med))), 0.05)
    return max(floor, med + k * spread)


def _evidence(fitted, surface_points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(distance_mm, gain, score)`` of every touch against the map of the others."""
    distance, gain = fitted.located(surface_points)
    score = gain + np.log(np.maximum(fitted.residuals(), 1e-6))
    return distance, gain, score


def off_target(
    targets: np.ndarray,
    touch_means: np.ndarray,
    surface_points: np.ndarray,
    *,
    floor_mm: float = 30.0,
    score_floor: float = 0.4,
    k: float = 2.0,
    trim_share: float = 0.2,
    passes: int = 2,
    min_touches: int = 6,
    power: float = 0.5,
) -> OffTarget:
    """Flag touches pressed far from their target, on evidence from the other touches.

    Each touch is scored against the response map of the *other* touches
    (``LeaveOneOutMap``): how much better its image fits where that map locates it than at
    its target (``gain``, nats per feature), plus the log of how badly the map predicts its
    image at its target (standardised residual, about 1 for a good touch). Neither depends on
    the touch itself. Suspects do not vouch for each other: the ``trim_share`` of the touches
    with the highest scores is left out of the map and every touch scored again (the left-out
    ones by the map of the rest), ``passes`` times, the flagged ones and the next highest
    staying out. A touch is flagged when it is located more than ``floor_mm`` from its target
    and its score exceeds the spread of the kept touches (median + ``k`` scaled MADs), at
    least ``score_floor`` (raised as ``20 / n`` below 20 touches, where the map is loose and
    the spread rests on a few touches). The map's hyperparameters are fitted once, on all
    touches, with the package's map prior. The map is of the images' square roots
    (``power``): a raw image's shape is mostly its peak sensor, which changes between touches
    a few mm apart on the real skin; the root lets the weaker sensors around it count, so
    the map is smoother between touches and a touch in a gap between them is judged on more
    than its peak (chosen on the tuning sessions of ``bench/off_target_eval.py``'s docstring).

    Parameters
    ----------
    targets : (n, 3) float
        Prompted positions, m.
    touch_means : (n, n_sensors) float
        Baseline-subtracted mean image of each touch, counts.
    surface_points : (P, 3) float
        Candidate places on the skin, m (``geometry.mesh.surface_points(mesh, 2000)``).
    floor_mm : float
        A touch located closer than this to its target is never flagged, mm.
    score_floor, k : float
        The score threshold: at least ``score_floor`` (x ``20 / n`` below 20 touches), and
        median + ``k`` scaled MADs of the touches kept in the map.
    trim_share, passes : float, int
        The share of highest-scored touches kept out of the map, and how often re-scored.
    min_touches : int
        Below this many touches nothing is flagged (all figures NaN).
    power : float
        Each image's positive counts are raised to it before the map is fitted, in (0, 1].

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
        return OffTarget(np.zeros(n, dtype=bool), nan, nan.copy(), nan.copy(), float("nan"))
    fitted = LeaveOneOutMap.fit(targets, touch_means, power=power)
    n_out = max(1, int(np.ceil(trim_share * n)))
    floor = score_floor * max(1.0, 20.0 / n)
    _, _, score = _evidence(fitted, surface_points)
    out = np.zeros(n, dtype=bool)
    out[np.argsort(-score)[:n_out]] = True
    for _ in range(max(1, passes)):
        distance, gain, score = _evidence(fitted.with_excluded(out), surface_points)
        threshold = _score_threshold(score, ~out, floor, k)
        flags = (score > threshold) & (distance > floor_mm)
        # the flagged touches and the next highest stay out of the map
        again = flags.copy()
        again[np.argsort(-np.where(flags, -np.inf, score))[: max(0, n_out - int(flags.sum()))]] = (
            True
        )
        if np.array_equal(again, out):
            break
        out = again
    return OffTarget(flags, distance, gain, score, threshold)


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
