"""The sensor map from the line fields (``sensors.line_fields``), chosen by held-out fit.

``skinloc sensors`` has two estimates of the crossings: the per-crossing fit (each sensor's
own column of responses, ``sensors.crossing_fit``) and the separable line-field model (every line's
field pooled over its 8 crossings). Which one describes a recording is decided on touches
the fits did not see: K-fold cross-validation over the touches, each held-out touch's image
predicted at its label (one free pressure each, the same for both) and scored in units of
the expected error (``fields.heldout_score``). The same check picks the fields' complexity
(bumps per field) within the recording. Lengths are mm inside.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from skinloc.sensors import line_fields as FM

__all__ = [
    "COMPLEXITIES",
    "FieldMap",
    "field_map",
    "heldout_comparison",
    "per_crossing_predictor",
]

#: Bumps per field tried by the cross-validation (the fields' complexity).
COMPLEXITIES = (16, 24, 32, 48, 64, 96)
_FOLDS = 5


@dataclass
class FieldMap:
    """Crossings from the line fields (mm, counts).

    Attributes
    ----------
    positions_mm : (n_sensors, 3) float
        Where each ``f_i * g_j`` peaks on the surface.
    uncertainty_mm : (n_sensors,) float
        RMS bootstrap spread of each position (nan without resamples).
    peak : (n_sensors,) float
        Peak unit-pressure response of each crossing, counts.
    footprint_mm : (n_sensors,) float
        Half-maximum radius of each crossing's response.
    model : FieldModel
        The fitted fields.
    n_centres : int
        Their complexity.
    """

    positions_mm: np.ndarray
    uncertainty_mm: np.ndarray
    peak: np.ndarray
    footprint_mm: np.ndarray
    model: FM.FieldModel
    n_centres: int


def _folds(n: int, random_state: int) -> np.ndarray:
    return np.random.default_rng(random_state).permutation(n) % min(_FOLDS, n)


def per_crossing_predictor(
    cands_mm: np.ndarray, tree: Any, n_tx: int, n_rx: int, label_mm: float
) -> Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]:
    """The per-crossing fit as a predictor of held-out images (for ``heldout_comparison``).

    Fits steps 1-3 of ``sensors.sensor_map`` on the training touches, then each sensor's
    ``a / (1 + d^2 / w^2) + c`` at its final crossing and footprint (``a``, ``c`` by least
    squares on the training labels), and predicts at the test labels ``(n_test, 3)`` mm.
    """
    from skinloc.sensors.crossing_fit import fit_per_crossing

    def predict(train_mm: np.ndarray, train_y: np.ndarray, test_mm: np.ndarray) -> np.ndarray:
        pos, width, *_ = fit_per_crossing(
            1e-3 * train_mm, train_y, 1e-3 * cands_mm, tree, n_tx, n_rx, True, label_mm
        )
        K = 1.0 / (1.0 + ((train_mm[:, None] - pos[None]) ** 2).sum(-1) / width**2)
        a, c = np.zeros(len(pos)), np.zeros(len(pos))
        for k in range(len(pos)):
            D = np.stack([K[:, k], np.ones(len(train_mm))], 1)
            a[k], c[k] = np.linalg.lstsq(D, train_y[:, k], rcond=None)[0]
        return a / (1.0 + ((test_mm[:, None] - pos[None]) ** 2).sum(-1) / width**2) + c

    return predict


def heldout_comparison(
    labels_mm: np.ndarray,
    images: np.ndarray,
    n_tx: int,
    n_rx: int,
    cands_mm: np.ndarray,
    tree: Any,
    per_crossing_predict: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
    label_mm: float,
    complexities: tuple[int, ...] = COMPLEXITIES,
    random_state: int = 0,
) -> dict[str, Any]:
    """Held-out misfit of the per-crossing fit and of the fields at each complexity.

    Parameters
    ----------
    labels_mm : (n_touch, 3) float
        Prompted touch points, mm.
    images : (n_touch, n_sensors) float
        Mean images, counts.
    per_crossing_predict : callable
        ``(train_labels_mm, train_images, test_labels_mm) -> (n_test, n_sensors)`` images
        predicted by the per-crossing fit on the training touches.
    complexities : tuple of int
        Bumps per field to try.

    Returns
    -------
    dict
        ``{"per_crossing": score, "fields": {n_centres: score}, "best_centres": n,
        "fields_better": bool}``, scores the mean held-out misfit per touch (lower is better).
    """
    n = len(labels_mm)
    fold = _folds(n, random_state)
    snapped = cands_mm[tree.query(labels_mm)[1]]
    per = np.zeros(n)
    sc = {m: np.zeros(n) for m in complexities}
    for f in np.unique(fold):
        tr, te = fold != f, fold == f
        pred = per_crossing_predict(labels_mm[tr], images[tr], labels_mm[te])
        per[te] = FM.heldout_score(pred, images[te])
        for m in complexities:
            model = FM.fit_fields(
                labels_mm[tr], images[tr], n_tx, n_rx, cands_mm, tree, n_centres=m,
                label_mm=label_mm,
            )  # fmt: skip
            sc[m][te] = FM.heldout_score(FM.predict_images(model, snapped[te]), images[te])
    means = {m: float(v.mean()) for m, v in sc.items()}
    best = min(means, key=lambda m: means[m])
    return {
        "per_crossing": float(per.mean()),
        "fields": means,
        "best_centres": int(best),
        "fields_better": bool(means[best] < per.mean()),
    }


def field_map(
    labels_mm: np.ndarray,
    images: np.ndarray,
    n_tx: int,
    n_rx: int,
    cands_mm: np.ndarray,
    tree: Any,
    n_centres: int,
    label_mm: float,
    n_boot: int = 8,
    random_state: int = 0,
) -> FieldMap:
    """Fit the fields on every touch, read the crossings off them, bootstrap the touches.

    Each bootstrap resample refits the fields from the full fit's (a quicker refit of the
    same estimator) and reads its crossings again; the uncertainty is the RMS distance of a
    crossing from the full fit's over the resamples.
    """
    model = FM.fit_fields(labels_mm, images, n_tx, n_rx, cands_mm, tree, n_centres, label_mm)
    pos, peak, foot = FM.crossings(model, cands_mm)
    rng = np.random.default_rng(random_state)
    boots = []
    for _ in range(n_boot):
        pick = rng.choice(len(labels_mm), len(labels_mm), replace=True)
        init = FM.FieldModel(
            model.basis_fn, model.tx_weights, model.rx_weights,
            model.touches_mm[pick], model.pressure[pick], model.gain,
        )  # fmt: skip
        b = FM.fit_fields(
            labels_mm[pick], images[pick], n_tx, n_rx, cands_mm, tree, n_centres, label_mm,
            passes=1, iters=4, init=init,
        )  # fmt: skip
        boots.append(FM.crossings(b, cands_mm)[0])
    if boots:
        B = np.stack(boots)
        unc = np.sqrt(((B - pos[None]) ** 2).sum(-1).mean(0))
    else:
        unc = np.full(len(pos), np.nan)
    return FieldMap(pos, unc, peak, foot, model, n_centres)
