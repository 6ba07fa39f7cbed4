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
    "LeaveOneOutMap",
    "TouchInfluence",
    "cross_validated_errors",
    "fold_of",
    "leave_one_out_residuals",
    "touch_influence",
]

#: Fits a model on a recording (``train_localizer`` with the caller's options).
Fit = Callable[[Recording], Any]
#: ``progress(done, total)``, called after each fit.
Progress = Callable[[int, int], None]


def fold_of(n: int, n_folds: int, random_state: int = 0) -> np.ndarray:
    """Fold of each of ``n`` touches, ``(n,)`` int: a shuffled, balanced split.

    ``min(n_folds, n // 2)`` folds, at least 2 (each fold at least 2 touches).
    """
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
    folds = fold_of(n, n_folds, random_state)
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


@dataclass
class LeaveOneOutMap:
    """The response map of a session's touches, each touch left out of its own prediction.

    The map is the GP of ``skinloc.models.response_map`` on the image shapes (``F``, mm
    positions ``q_mm``) with the package's map prior; its hyperparameters are fitted once
    (maximum a posteriori) and kept by ``with_excluded``. Touch ``i``'s leave-one-out map
    comes in closed form from the whole map (a rank-one downdate of ``K^-1``), so no model is
    fitted per touch.
    """

    q_mm: np.ndarray
    F: np.ndarray
    mu: np.ndarray
    amp: float
    length_scale_mm: float
    noise: float
    exclude: np.ndarray

    @classmethod
    def fit(
        cls,
        positions: np.ndarray,
        touch_means: np.ndarray,
        exclude=None,
        *,
        power: float = 1.0,
    ) -> LeaveOneOutMap:
        """Fit the map's hyperparameters on the touches not in ``exclude``.

        ``power`` compresses each image before its shape is taken (``shape_features`` of the
        positive counts to that power): below 1 the weaker sensors around the peak count
        more, so the map follows the image's whole footprint rather than its peak sensor.
        """
        from skinloc.models.map_prior import load_prior

        if not 0.0 < power <= 1.0:
            raise ValueError(f"power must be in (0, 1], got {power!r}")
        q = 1e3 * np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        X = np.asarray(touch_means, dtype=np.float64)
        F = shape_features(X if power == 1.0 else np.maximum(X, 0.0) ** power)
        skip = np.zeros(len(q), bool) if exclude is None else np.asarray(exclude, dtype=bool)
        use = ~skip
        # The prior at every size (the default model drops it past a few touches): its pull
        # keeps an off-target touch from bending the hyperparameters (a shorter length scale,
        # more noise) into explaining itself.
        prior = load_prior(None)
        mu = prior.mean(F[use])
        kern = fit_gp(q[use], F[use] - mu, None, (2.0, 300.0), None, prior).kernel_
        return cls(
            q,
            F,
            mu,
            float(kern.k1.k1.constant_value),
            float(kern.k1.k2.length_scale),
            float(kern.k2.noise_level),
            skip,
        )

    def with_excluded(self, exclude: np.ndarray) -> LeaveOneOutMap:
        """The same hyperparameters, other touches left out of the map."""
        return LeaveOneOutMap(
            self.q_mm,
            self.F,
            self.mu,
            self.amp,
            self.length_scale_mm,
            self.noise,
            np.asarray(exclude, dtype=bool).copy(),
        )

    def _solve(self):
        use = np.flatnonzero(~self.exclude)
        q = self.q_mm[use]
        K_inv = np.linalg.inv(
            self.amp * rbf(q, q, self.length_scale_mm) + self.noise * np.eye(len(use))
        )
        alpha = K_inv @ (self.F[use] - self.mu)
        return use, K_inv, alpha, np.diag(K_inv)

    def residuals(self) -> np.ndarray:
        """``(n,)`` each touch's image at its position against the others' map.

        Mean squared difference over the features divided by the predictive variance (closed
        form: ``y_i - [K^-1 y]_i / [K^-1]_ii``, variance ``1 / [K^-1]_ii``): about 1 for a
        touch the map expects, large for an image recorded elsewhere.
        """
        use, K_inv, alpha, diag = self._solve()
        out = np.empty(len(self.q_mm))
        out[use] = ((alpha / diag[:, None]) ** 2).mean(axis=1) * diag
        skip = np.flatnonzero(self.exclude)
        if len(skip):
            kx = self.amp * rbf(self.q_mm[skip], self.q_mm[use], self.length_scale_mm)
            resid = self.F[skip] - self.mu - kx @ alpha
            var = self.amp + self.noise - np.einsum("ij,jk,ik->i", kx, K_inv, kx)
            out[skip] = (resid**2).mean(axis=1) / var
        return out

    def located(self, surface_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the others' map puts each touch, and how much better its image fits there.

        Parameters
        ----------
        surface_points : (P, 3) float
            Candidate places on the skin, m.

        Returns
        -------
        distance_mm : (n,) float
            From each touch's position to the candidate its image fits best, mm.
        gain : (n,) float
            The image's per-feature Gaussian negative log-likelihood at its position minus at
            that candidate (variance included, so a place far from every touch does not win
            on its large variance alone): near 0 for a touch made where it says, large for
            one made elsewhere.
        """
        P = 1e3 * np.asarray(surface_points, dtype=np.float64).reshape(-1, 3)
        use, K_inv, alpha, diag = self._solve()
        ls = self.length_scale_mm
        n = len(self.q_mm)
        at_own = np.empty(n)
        at_own[use] = ((alpha / diag[:, None]) ** 2).mean(axis=1) * diag - np.log(diag)
        kP = self.amp * rbf(P, self.q_mm[use], ls)
        mP = self.mu + kP @ alpha
        varP = self.amp + self.noise - np.einsum("ij,jk,ik->i", kP, K_inv, kP)
        C = kP @ K_inv
        where, best = np.empty((n, 3)), np.empty(n)
        for j, i in enumerate(use):  # the map without touch i: a rank-one downdate
            m_i = mP - np.outer(C[:, j], alpha[j] / diag[j])
            v_i = varP + C[:, j] ** 2 / diag[j]
            nll = ((self.F[i] - m_i) ** 2).mean(axis=1) / v_i + np.log(v_i)
            k = int(np.argmin(nll))
            where[i], best[i] = P[k], nll[k]
        skip = np.flatnonzero(self.exclude)
        if len(skip):
            kx = self.amp * rbf(self.q_mm[skip], self.q_mm[use], ls)
            var = self.amp + self.noise - np.einsum("ij,jk,ik->i", kx, K_inv, kx)
            resid = self.F[skip] - self.mu - kx @ alpha
            at_own[skip] = (resid**2).mean(axis=1) / var + np.log(var)
            nll_all = ((self.F[skip][:, None, :] - mP[None]) ** 2).mean(axis=2) / varP + np.log(
                varP
            )
            k = np.argmin(nll_all, axis=1)
            where[skip], best[skip] = P[k], nll_all[np.arange(len(skip)), k]
        return np.linalg.norm(where - self.q_mm, axis=1), at_own - best


def leave_one_out_residuals(
    positions: np.ndarray, touch_means: np.ndarray, *, exclude: np.ndarray | None = None
) -> np.ndarray:
    """How badly the other touches' response map predicts each touch's image at its position.

    ``LeaveOneOutMap.residuals`` of a map fitted on the touches not in ``exclude``.

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
    return LeaveOneOutMap.fit(positions, touch_means, exclude).residuals()
