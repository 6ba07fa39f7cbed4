"""Recalibration of a response map by evidence: how much of the old map the new touches keep.

A later session of a skin may respond almost as before (a correction of the old map is best),
or so differently that the old map misleads (the new touches alone are best, as on the real
cone skin five months later). ``choose_recalibration`` decides from the new touches themselves:
each candidate is scored by cross-validation over the k new touches (fitted on the others,
the left-out touches localised by matching, as the model will), and the best one is fitted on
all k. The candidates:

- ``old map``: the old map untouched (scored on all k touches, nothing fitted);
- ``old map + correction``: a correction layer on the old map (``ResponseMap.refined``);
- ``blend w``: the corrected map and the new map mixed, ``w`` of the new (0.25, 0.5, 0.75);
- ``new touches alone``: a map of the new touches alone, with the prior where it applies.

A fitted candidate is scored on touches it did not see, with one touch fewer per fold than it
will have: the old map, which sees none, wins ties and near-ties. With no touch (a baseline
capture only) the old map is kept; with one, nothing can be cross-validated and the old map is
kept too.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from skinloc._typing import Points
from skinloc.models.response_map import MapLayer, ResponseMap

if TYPE_CHECKING:
    from skinloc.models.map_prior import MapPrior

__all__ = ["BLEND_WEIGHTS", "RecalibrationChoice", "blend_maps", "choose_recalibration"]

#: Shares of the new map in the blends tried (between the corrected map and the new one).
BLEND_WEIGHTS = (0.25, 0.5, 0.75)
#: How many standard errors a candidate keeping more of the old map may lose by and still be
#: chosen (``choose_recalibration``'s ``slack_se``); chosen on simulated session changes.
SLACK_SE = 0.0
#: At most this many folds: each fits the new map once, which takes up to a second.
MAX_FOLDS = 5
OLD, CORRECTED, NEW = "old map", "old map + correction", "new touches alone"


@dataclass(frozen=True)
class RecalibrationChoice:
    """What ``choose_recalibration`` did and why.

    Attributes
    ----------
    method : str
        ``"old map"``, ``"old map + correction"``, ``"blend 0.5"`` (the share of the new map)
        or ``"new touches alone"``.
    n_touches : int
        New touches it had.
    cv_error_mm : dict of str to float
        Cross-validated mean error of each candidate over the new touches, mm (empty when
        nothing could be cross-validated).
    n_folds : int
        Folds of the cross-validation (0: none).
    """

    method: str
    n_touches: int
    cv_error_mm: dict[str, float] = field(default_factory=dict)
    n_folds: int = 0

    def summary(self) -> str:
        """One line: the choice, and the cross-validated errors it was made on."""
        if not self.cv_error_mm:
            why = "no new touch" if self.n_touches == 0 else f"{self.n_touches} touch: too few"
            return f"kept the old map ({why} to judge it by)"
        scores = ", ".join(f"{k} {v:.1f}" for k, v in self.cv_error_mm.items())
        return (
            f"chose {self.method} by {self.n_folds}-fold cross-validation over "
            f"{self.n_touches} new touches (mean error, mm: {scores})"
        )

    def as_meta(self) -> dict:
        """The choice as JSON-ready metadata (the model file's ``training.recalibration``)."""
        return {
            "method": self.method,
            "n_touches": self.n_touches,
            "n_folds": self.n_folds,
            "cv_error_mm": {k: round(v, 2) for k, v in self.cv_error_mm.items()},
            "summary": self.summary(),
        }


def blend_maps(a: ResponseMap, b: ResponseMap, w: float) -> ResponseMap:
    """``(1 - w) a + w b`` as one map (a map is linear in its mean and layers' coefficients).

    ``a``'s candidates, amplitude map and first layer (its noise) are kept.
    """
    if not 0.0 <= w <= 1.0:
        raise ValueError(f"w must be in [0, 1], got {w!r}")

    def scaled(m: ResponseMap, s: float) -> list[MapLayer]:
        return [MapLayer(L.points_mm, s * L.alpha, L.length_scale_mm, L.noise) for L in m.layers]

    return ResponseMap(
        (1.0 - w) * a.mean + w * b.mean,
        [*scaled(a, 1.0 - w), *scaled(b, w)],
        a.candidates,
        a.amplitude,
    )


def _candidates(
    old: ResponseMap,
    positions: Points,
    F: np.ndarray,
    prior: MapPrior | None,
    length_scale_mm: float,
    blend_weights: tuple[float, ...],
) -> dict[str, ResponseMap]:
    """Every candidate fitted to ``positions (n, 3)`` m and features ``F (n, k)``."""
    out = {OLD: old}
    if len(F) < 1:
        return out
    corrected = old.refined(positions, F)
    out[CORRECTED] = corrected
    if len(F) < 2:
        return out
    use = prior if prior is not None and prior.applies(len(F)) else None
    new = ResponseMap.fit(positions, F, old.candidates, length_scale_mm, prior=use)
    new = ResponseMap(new.mean, new.layers, new.candidates, old.amplitude)
    for w in blend_weights:
        out[f"blend {w:g}"] = blend_maps(corrected, new, w)
    out[NEW] = new
    return out


def choose_recalibration(
    old: ResponseMap,
    positions: Points,
    F: np.ndarray,
    prior: MapPrior | None = None,
    *,
    length_scale_mm: float = 20.0,
    random_state: int = 0,
    slack_se: float = SLACK_SE,
    blend_weights: tuple[float, ...] = BLEND_WEIGHTS,
) -> tuple[ResponseMap, RecalibrationChoice]:
    """The map to use in a new session, chosen by cross-validation over its touches.

    Parameters
    ----------
    old : ResponseMap
        The old session's map.
    positions : (n, 3) float
        The new touches' positions, m (n may be 0).
    F : (n, k) float
        Their shape features (``shape_features`` of the touch means).
    prior : MapPrior, optional
        The prior a map of the new touches alone is fitted with (where it applies).
    length_scale_mm : float, default=20.0
        Starting length scale of a new map without prior, mm.
    random_state : int, default=0
        Seed of the folds.
    slack_se : float, default=SLACK_SE
        The candidate kept is the first (in the order above: the most of the old map kept)
        whose cross-validated error is within this many standard errors of the best one's
        (0: the best one).
    blend_weights : tuple of float, default=BLEND_WEIGHTS
        Shares of the new map in the blends tried (``()``: no blend).

    Returns
    -------
    (ResponseMap, RecalibrationChoice)
        The chosen map fitted on all n touches, and what was chosen and why.
    """
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(F, dtype=np.float64)
    n = len(positions)
    if F.shape != (n, len(old.mean)):
        raise ValueError(f"F must have shape ({n}, {len(old.mean)}), got {F.shape}")
    if n < 2:
        return old, RecalibrationChoice(OLD, n)
    n_folds = min(n, MAX_FOLDS)
    fold = np.random.default_rng(random_state).permutation(n) % n_folds
    errors: dict[str, list[np.ndarray]] = {}
    for f in range(n_folds):
        test, train = fold == f, fold != f
        for name, m in _candidates(
            old, positions[train], F[train], prior, length_scale_mm, blend_weights
        ).items():
            miss = 1e3 * np.linalg.norm(m.nearest(F[test]) - positions[test], axis=1)
            errors.setdefault(name, []).append(miss)
    # only the candidates every fold could fit (a fold of 1 training touch fits no new map)
    per_touch = {k: np.concatenate(v) for k, v in errors.items() if len(v) == n_folds}
    cv = {k: float(v.mean()) for k, v in per_touch.items()}
    best = min(cv, key=lambda k: cv[k])  # ties: the first, i.e. the one keeping the most
    bar = cv[best] + slack_se * float(per_touch[best].std()) / np.sqrt(n)
    best = next(k for k in cv if cv[k] <= bar)
    chosen = _candidates(old, positions, F, prior, length_scale_mm, blend_weights)[best]
    return chosen, RecalibrationChoice(best, n, cv, n_folds)
