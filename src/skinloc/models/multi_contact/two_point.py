"""The skin's two-point threshold: how far apart two fingers must be to be read as two.

As for human skin: the smallest separation from which two simultaneous touches of similar
strength are counted two at least 90 % of the time (``counted_two_mm``, what the recogniser
needs) and, stricter, also have each finger placed within 15 mm (``threshold_mm``). Measured
per 10 mm bin of separation; a threshold is the lower edge of the first bin from which every
bin with enough pairs reaches the share (``None``: no separation does).

``fit`` measures it at calibration (``rule_calibration``: held-out pairs of the training
touches, summed); ``bench/multitouch_eval.py`` on sums of other recordings' touches and
``bench/two_point_sim.py`` on the simulator's physical two-finger images use the same
``threshold_from_pairs``. It is stored in the model's contact rule (``"two_point"``); models
saved before it have none (unknown).

The gesture recogniser uses it as the separation below which two tracks may be one finger
(``recogniser_mm``): the full threshold where it exists, else the count's, ``counted_two_mm``.
The count's is what the recogniser's question is (one finger or two), and on the real and
simulated skins measured so far the full threshold exists at no separation (placement is
bounded by the single touch's own error, docs/multitouch.md).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = [
    "EDGES_MM",
    "MIN_PAIRS",
    "SHARE",
    "WITHIN_MM",
    "describe",
    "placed_both",
    "recogniser_mm",
    "threshold_from_pairs",
    "two_point_of",
]

#: Bin edges of separation, mm: 10 mm wide from 10 mm, the last open.
EDGES_MM = (10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0, np.inf)
#: Share of pairs a bin must reach.
SHARE = 0.9
#: Largest distance of a finger's contact from the finger, mm.
WITHIN_MM = 15.0
#: Fewest pairs for a bin to count (fewer: reported, but it decides nothing).
MIN_PAIRS = 5


def placed_both(pred: np.ndarray, true: np.ndarray, within_mm: float = WITHIN_MM) -> bool:
    """Whether two contacts ``pred (2, 3)`` m lie each within ``within_mm`` of ``true (2, 3)``.

    Under the better of the two assignments; fewer than two contacts: ``False``.
    """
    if len(pred) < 2:
        return False
    d = 1e3 * np.linalg.norm(pred[:2, None, :] - true[None, :2, :], axis=2)
    return bool(min(max(d[0, 0], d[1, 1]), max(d[0, 1], d[1, 0])) <= within_mm)


def threshold_from_pairs(
    sep_mm: np.ndarray,
    counted_two: np.ndarray,
    placed: np.ndarray,
    share: float = SHARE,
    min_pairs: int = MIN_PAIRS,
) -> dict[str, Any]:
    """The two-point threshold of pairs ``(n,)``: separations (mm), counted two, both placed.

    Returns ``{"bins": {"lo-hi": {"lo_mm", "n", "counted_two", "all_within_15mm"}},
    "counted_two_mm", "threshold_mm", "n_pairs"}``; the thresholds are ``None`` when no
    separation reaches ``share``. Bins of fewer than ``min_pairs`` pairs are listed but decide
    nothing.
    """
    sep = np.asarray(sep_mm, dtype=np.float64)
    two = np.asarray(counted_two, dtype=bool)
    both = np.asarray(placed, dtype=bool) & two
    bins: dict[str, dict[str, float]] = {}
    for lo, hi in zip(EDGES_MM, EDGES_MM[1:], strict=False):
        sel = (sep >= lo) & (sep < hi)
        if sel.any():
            bins[f"{lo:.0f}-{hi:.0f}"] = {
                "lo_mm": lo,
                "n": int(sel.sum()),
                "counted_two": float(two[sel].mean()),
                "all_within_15mm": float(both[sel].mean()),
            }
    rows = [b for b in bins.values() if b["n"] >= min_pairs]

    def first(ok: Any) -> float | None:
        for i, b in enumerate(rows):
            if all(ok(c) for c in rows[i:]):
                return b["lo_mm"]
        return None

    return {
        "bins": bins,
        "counted_two_mm": first(lambda c: c["counted_two"] >= share),
        "threshold_mm": first(
            lambda c: c["counted_two"] >= share and c["all_within_15mm"] >= share
        ),
        "n_pairs": int(len(sep)),
    }


def two_point_of(contact_rule: dict[str, Any] | None) -> dict[str, Any] | None:
    """The two-point threshold stored in a model's contact rule (``None``: not measured)."""
    if not contact_rule:
        return None
    tp = contact_rule.get("two_point")
    return tp if isinstance(tp, dict) and "counted_two_mm" in tp else None


def recogniser_mm(tp: dict[str, Any] | None) -> tuple[float | None, str]:
    """The separation, mm, below which the recogniser cannot tell two fingers from one.

    Returns ``(mm, basis)``: ``threshold_mm`` (basis ``"placed"``) when the skin has the full
    threshold, else ``counted_two_mm`` (``"counted"``); ``math.inf`` (``"none"``) when no
    separation is counted two 90 % of the time (two fingers are never sure by their
    separation alone); ``None`` (``"unknown"``) when it was not measured.
    """
    if tp is None:
        return None, "unknown"
    for key, basis in (("threshold_mm", "placed"), ("counted_two_mm", "counted")):
        v = tp.get(key)
        if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v > 0:
            return float(v), basis
    return math.inf, "none"


def describe(tp: dict[str, Any] | None) -> str:
    """The threshold in words, as a person reads a two-point threshold."""
    if tp is None:
        return (
            "two-point threshold: unknown (not measured: a network model, a model saved before "
            "it, or too few calibration touches)"
        )
    count, both = tp.get("counted_two_mm"), tp.get("threshold_mm")
    if count is None:
        return (
            "two-point threshold: none: two touches are not counted two 90 % of the time at "
            "any separation"
        )
    read = (
        f"two touches closer than {count:.0f} mm are read as one (counted two >= 90 % from "
        f"{count:.0f} mm)"
    )
    if both is None:
        return (
            f"two-point threshold: none (two fingers are counted but not both placed within "
            f"{WITHIN_MM:.0f} mm at any separation); {read}"
        )
    return (
        f"two-point threshold: {both:.0f} mm (from there two touches are counted two and each "
        f"placed within {WITHIN_MM:.0f} mm >= 90 % of the time); {read}"
    )
