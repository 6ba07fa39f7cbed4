"""The label-noise floor: how far a person's touch lands from a prompted point, touch to touch.

A prompted target touched twice (two sessions of one day, or a repeated target within one)
gives two images. One model localises both: what it gets wrong at that place is the same
both times and cancels in the difference, what is left is the scatter of the two touches
(and the sensor noise). With ``d`` the distance between the two predictions, the per-touch
repeatability is ``RMS(d) / sqrt(2)`` (two independent misses of the same spread).

No accuracy figure can be trusted below this floor: the labels themselves are that far off.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["probing_repeatability_mm", "repeated_pairs", "session_repeatability"]


def repeated_pairs(
    recordings: Sequence[Any], tol_mm: float = 0.01
) -> list[tuple[int, int, int, int]]:
    """Point logs with the same target in two recordings (or twice in one).

    Returns
    -------
    list of (recording a, log a, recording b, log b)
        Each pair once, ``(a, log a) < (b, log b)``.
    """
    from scipy.spatial import cKDTree

    owners = [(r, i) for r, rec in enumerate(recordings) for i in range(rec.n_point_logs)]
    pts = 1e3 * np.concatenate([rec.targets for rec in recordings])
    pairs = cKDTree(pts).query_pairs(tol_mm, output_type="ndarray")
    return sorted(
        (*owners[min(a, b)], *owners[max(a, b)]) for a, b in np.asarray(pairs).reshape(-1, 2)
    )


def probing_repeatability_mm(pred_a: np.ndarray, pred_b: np.ndarray) -> dict[str, float]:
    """Per-touch repeatability from two predictions ``(n, 3)`` m of the same targets.

    Returns ``{"rms_mm", "median_pair_mm", "n_pairs"}``: the RMS distance over sqrt(2) (the
    floor), and the median distance between the two touches of a pair.
    """
    d = 1e3 * np.linalg.norm(np.asarray(pred_a) - np.asarray(pred_b), axis=1)
    if d.size == 0:
        return {"rms_mm": float("nan"), "median_pair_mm": float("nan"), "n_pairs": 0}
    return {
        "rms_mm": float(np.sqrt(np.mean(d**2)) / np.sqrt(2.0)),
        "median_pair_mm": float(np.median(d)),
        "n_pairs": int(d.size),
    }


def session_repeatability(recording: Any) -> dict[str, float] | None:
    """Probing repeatability from the repeated targets of one session (``n_repeats``).

    For each repeated target a default map is trained without either of its two touches
    and localises both. Returns ``probing_repeatability_mm``'s dict, or ``None`` when the
    session repeats no target.
    """
    from skinloc.evaluation.scoring import train_localizer

    pairs = repeated_pairs([recording])
    if not pairs:
        return None
    pa, pb = [], []
    for _, i, _, j in pairs:
        rest = np.setdiff1d(np.arange(recording.n_point_logs), [i, j])
        model = train_localizer([recording.subset(rest)], count_rule=False)  # single touches
        pred = model.predict(recording.touch_means[[i, j]])
        pa.append(pred[0])
        pb.append(pred[1])
    return probing_repeatability_mm(np.array(pa), np.array(pb))
