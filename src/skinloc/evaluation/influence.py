"""Which touch of a calibration hurts the held-out error most: cross-validated influence.

Every touch is predicted by a model that did not see it (K-fold cross-validation over the
touches). A suspect touch's influence is how much the cross-validated error of the *other*
touches falls when it is also left out of every training fold: the same folds, the same
touches scored, only that one touch missing from the training sets. A touch recorded at the
wrong place teaches the model a wrong image-to-position pair and raises the error of its
neighbours; its own large error alone would not prove that (a touch at a hard place is
missed too, and leaving it out helps nobody).

``leave_one_out_residuals`` is the quick form used while touches are captured: each touch's
image predicted at its position by the response map of the other touches, in closed form
(one hyperparameter fit, no model per fold).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skinloc.data.recording import Recording
from skinloc.evaluation.scoring import evaluate
from skinloc.models.response_map import fit_gp, rbf, shape_features

__all__ = [
    "TouchInfluence",
    "cross_validated_errors",
    "leave_one_out_residuals",
    "touch_influence",
]

#: Fits a model on a recording (``train_localizer`` with the caller's options).
Fit = Callable[[Recording], Any]
#: ``progress(done, total)``, called after each fit.
Progress = Callable[[int, int], None]


def _folds(n: int, n_folds: int, random_state: int) -> np.ndarray:
    """Fold of each of ``n`` touches, ``(n,)`` int: a shuffled, balanced split."""
    k = max(2, min(n_folds, n // 2))
    return np.random.default_rng(random_state).permutation(n) % k


def cross_validated_errors(
    rec: Recording,
    fit: Fit,
    *,
    folds: np.ndarray,
    leave_out: int | None = None,
    skip_fold: int | None = None,
    base: np.ndarray | None = None,
    progress: Callable[[], None] | None = None,
) -> np.ndarray:
    """Error of each touch predicted by the model of the folds it is not in, ``(n,)`` mm.

    ``leave_out`` also removes that touch from every training set; ``skip_fold`` keeps the
    errors of ``base`` for that fold (its model never saw ``leave_out`` anyway).
    """
    n = rec.n_point_logs
    errors = np.full(n, np.nan) if base is None else base.copy()
    index = np.arange(n)
    for f in np.unique(folds):
        if f == skip_fold:
            continue
        train = (folds != f) & (index != leave_out)
        test = np.flatnonzero(folds == f)
        model = fit(rec.subset(np.flatnonzero(train)))
        errors[test] = evaluate(model, [rec.subset(test)]).errors_mm
        if progress is not None:
            progress()
    return errors


@dataclass
class TouchInfluence:
    """What the cross-validation says of each touch.

    Attributes
    ----------
    errors_mm : (n,) float
        Cross-validated error of each touch, mm.
    n_folds : int
        Folds of the cross-validation.
    suspects : list of dict
        Each examined touch: ``index``, its own ``error_mm``, the mean cross-validated error
        of the other touches ``others_with_mm`` (it in the training sets) and
        ``others_without_mm`` (left out), and ``gain_mm``, the fall from one to the other.
        Largest gain first.
    """

    errors_mm: np.ndarray
    n_folds: int
    suspects: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """For JSON: means in mm, rounded to 0.01 mm."""
        return {
            "cv_mean_mm": round(float(np.mean(self.errors_mm)), 2),
            "cv_errors_mm": np.round(self.errors_mm, 2).tolist(),
            "n_folds": self.n_folds,
            "suspects": self.suspects,
        }


def touch_influence(
    rec: Recording,
    fit: Fit,
    *,
    suspects: Sequence[int] = (),
    max_suspects: int = 2,
    n_folds: int = 4,
    random_state: int = 0,
    progress: Progress | None = None,
) -> TouchInfluence:
    """Cross-validated errors, and the influence of the most suspect touches.

    The suspects examined are ``suspects`` (e.g. the touches the capture flagged) first,
    then the touches with the largest cross-validated error, ``max_suspects`` in all. Each
    costs ``n_folds - 1`` fits, the cross-validation ``n_folds``.

    Parameters
    ----------
    rec : Recording
        The calibration (``n >= 4`` touches).
    fit : callable
        ``fit(recording) -> model`` with ``predict_full``.
    suspects : sequence of int
        Touches to examine first, indices into ``rec``.
    """
    n = rec.n_point_logs
    folds = _folds(n, n_folds, random_state)
    k = int(folds.max()) + 1
    chosen: list[int] = []
    total = k + max_suspects * (k - 1)
    done = 0

    def step() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    base = cross_validated_errors(rec, fit, folds=folds, progress=step)
    for i in [*suspects, *np.argsort(-base).tolist()]:
        if len(chosen) >= max_suspects:
            break
        if 0 <= int(i) < n and int(i) not in chosen:
            chosen.append(int(i))
    out = []
    for i in chosen:
        without = cross_validated_errors(
            rec, fit, folds=folds, leave_out=i, skip_fold=int(folds[i]), base=base, progress=step
        )
        others = np.arange(n) != i
        with_i, without_i = float(base[others].mean()), float(without[others].mean())
        out.append(
            {
                "index": i,
                "error_mm": round(float(base[i]), 2),
                "others_with_mm": round(with_i, 2),
                "others_without_mm": round(without_i, 2),
                "gain_mm": round(with_i - without_i, 2),
            }
        )
    out.sort(key=lambda s: -s["gain_mm"])
    return TouchInfluence(base, k, out)


def leave_one_out_residuals(
    positions: np.ndarray, touch_means: np.ndarray, *, exclude: np.ndarray | None = None
) -> np.ndarray:
    """How badly the other touches' response map predicts each touch's image at its position.

    The map is the GP of ``skinloc.models.response_map`` on the image shapes with the
    package's map prior, its hyperparameters fitted once (maximum a posteriori);
    each touch's shape is predicted at its own position by the map of the others (closed
    form: ``y_i - [K^-1 y]_i / [K^-1]_ii``, variance ``1 / [K^-1]_ii``). The residual is the
    mean squared difference over the features divided by that predictive variance: about 1
    for a touch the map expects, large for an image recorded elsewhere.

    Parameters
    ----------
    positions : (n, 3) float
        Touch positions, m.
    touch_means : (n, n_sensors) float
        Baseline-subtracted mean images, counts.
    exclude : (n,) bool, optional
        Touches kept out of the map; each is predicted by the map of the others.

    Returns
    -------
    (n,) float
        Standardised residual of each touch (dimensionless).
    """
    from skinloc.models.map_prior import load_prior

    q = 1e3 * np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    F = shape_features(touch_means)
    n = len(q)
    skip = np.zeros(n, dtype=bool) if exclude is None else np.asarray(exclude, dtype=bool)
    use = np.flatnonzero(~skip)
    # The prior at every size (the default model drops it past a few touches): its pull keeps
    # an off-target touch from bending the hyperparameters (a shorter length scale, more
    # noise) into explaining itself.
    prior = load_prior(None)
    mu = prior.mean(F[use])
    kern = fit_gp(q[use], F[use] - mu, None, (2.0, 300.0), None, prior).kernel_
    amp, ls = float(kern.k1.k1.constant_value), float(kern.k1.k2.length_scale)
    noise = float(kern.k2.noise_level)
    K_inv = np.linalg.inv(amp * rbf(q[use], q[use], ls) + noise * np.eye(len(use)))
    alpha = K_inv @ (F[use] - mu)
    out = np.empty(n)
    diag = np.diag(K_inv)
    out[use] = ((alpha / diag[:, None]) ** 2).mean(axis=1) * diag
    if skip.any():
        kx = amp * rbf(q[skip], q[use], ls)
        resid = F[skip] - mu - kx @ alpha
        var = amp + noise - np.einsum("ij,jk,ik->i", kx, K_inv, kx)
        out[skip] = (resid**2).mean(axis=1) / var
    return out
