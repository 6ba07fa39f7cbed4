"""Coverage: where on the skin a touch will be located well, from the response map's posterior.

A touch at ``q`` gives features ``f(q) + noise``. The map matches them against its
prediction everywhere; a point ``p`` competes with ``q`` when the map's features there are
close to those at ``q`` relative to the noise and to how unsure the map is at both points
(the Gaussian-process posterior variance, large far from calibration touches). The expected
localisation error at ``q`` is then the likelihood-weighted mean distance to the competitors::

    w(p | q) ~ N(mu(q); mu(p), (s2(p) + s2(q)) I_k)       e(q) = sum_p w(p|q) |p - q|

with ``s2 = noise + posterior variance`` per feature and ``k`` features. Everything works on
an evaluation subset of the surface (a few hundred points). The posterior variance after a
further touch at ``c`` is a rank-one update, which is what ``calibration.active`` uses to choose
the touch that lowers the mean expected error most.

Units: metres in the API, millimetres for errors and inside the kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skinloc._typing import Points

__all__ = [
    "Coverage",
    "GPState",
    "calibrate_temperature",
    "coverage_map",
    "expected_error_mm",
    "gp_state",
]

#: Points whose expected error exceeds this are listed as blind spots.
BLIND_MM = 15.0


def _rbf(A_mm: np.ndarray, B_mm: np.ndarray, ls_mm: float) -> np.ndarray:
    d2 = (A_mm**2).sum(1)[:, None] + (B_mm**2).sum(1)[None, :] - 2.0 * A_mm @ B_mm.T
    return np.exp(-0.5 * np.maximum(d2, 0.0) / ls_mm**2)


@dataclass
class GPState:
    """What the coverage needs of a fitted map: its GP kernel and training points.

    Attributes
    ----------
    train_mm : (n, 3) float
        Calibration touch positions, mm.
    length_scale_mm : float
        RBF length scale, mm.
    amplitude : float
        Prior variance per feature.
    noise : float
        Residual (white) variance per feature.
    """

    train_mm: np.ndarray
    length_scale_mm: float
    amplitude: float
    noise: float

    def _chol(self) -> np.ndarray:
        K = self.amplitude * _rbf(self.train_mm, self.train_mm, self.length_scale_mm)
        return np.linalg.cholesky(K + self.noise * np.eye(len(K)))

    def posterior_cov(self, A_mm: np.ndarray, B_mm: np.ndarray) -> np.ndarray:
        """Posterior covariance between ``A (a, 3)`` and ``B (b, 3)`` mm -> ``(a, b)``."""
        L = self._chol()
        ka = self.amplitude * _rbf(self.train_mm, A_mm, self.length_scale_mm)
        kb = self.amplitude * _rbf(self.train_mm, B_mm, self.length_scale_mm)
        va = np.linalg.solve(L, ka)
        vb = np.linalg.solve(L, kb)
        return self.amplitude * _rbf(A_mm, B_mm, self.length_scale_mm) - va.T @ vb

    def posterior_var(self, A_mm: np.ndarray) -> np.ndarray:
        """Posterior variance per feature at ``A (a, 3)`` mm -> ``(a,)``."""
        L = self._chol()
        v = np.linalg.solve(L, self.amplitude * _rbf(self.train_mm, A_mm, self.length_scale_mm))
        return np.maximum(self.amplitude - (v**2).sum(0), 0.0)


def gp_state(rmap, F: np.ndarray | None = None) -> GPState:
    """The base layer of a ``ResponseMap`` as a ``GPState``; ``F (n, k)`` its training features.

    The prior variance is the features' variance about their mean (the fitted kernel's
    amplitude is folded into the map's coefficients and not kept); without ``F`` (a saved
    model keeps no touches) the map's own values at its training points stand in.
    """
    layer = rmap.layers[0]
    if F is None:
        F = rmap.evaluate_mm(layer.points_mm)
    amp = float(max(np.mean((F - rmap.mean) ** 2), 1e-8))
    return GPState(layer.points_mm.copy(), float(layer.length_scale_mm), amp, float(layer.noise))


def expected_error_mm(
    points_m: Points,
    mu: np.ndarray,
    s2: np.ndarray,
    queries: tuple[Points, np.ndarray, np.ndarray] | None = None,
    chunk: int = 512,
    normalised: bool = True,
    exclude_self: bool = True,
) -> np.ndarray:
    """Expected localisation error at each query point, mm.

    The competitors are the evaluation points other than the query itself (a touch is never
    exactly on the grid), so the error of a well-mapped point is about the grid spacing.

    Parameters
    ----------
    points_m : (E, 3) float
        Evaluation points on the surface, m.
    mu : (E, k) float
        Map features there.
    s2 : (E,) float
        Feature variance there (noise + posterior variance, times the temperature).
    queries : ((Q, 3) m, (Q, k), (Q,)), optional
        Other query points, their features and variances; default: the evaluation points.
    normalised : bool
        Include the Gaussian normaliser. Without it every poorly known point competes with
        every query: a pessimistic score that ``skinloc.calibration.active`` uses to explore.
    exclude_self : bool
        Leave the query's own grid point out of its competitors.

    Returns
    -------
    (Q,) or (E,) float
    """
    P = 1e3 * np.asarray(points_m)
    qP, qmu, qs2 = (P, mu, s2) if queries is None else (1e3 * queries[0], *queries[1:])
    sq, qsq = (mu**2).sum(1), (qmu**2).sum(1)
    out = np.empty(len(qP))
    for i in range(0, len(qP), chunk):
        sl = slice(i, i + chunk)
        d2 = np.maximum(qsq[sl, None] + sq[None, :] - 2.0 * qmu[sl] @ mu.T, 0.0)
        dist = np.linalg.norm(qP[sl, None, :] - P[None, :, :], axis=2)
        var = qs2[sl, None] + s2[None, :]
        # Gaussian likelihood in k features, normaliser included: a point the map knows
        # nothing about (large variance) explains everything a little, nothing well.
        logw = -d2 / (2.0 * var)
        if normalised:
            logw -= 0.5 * mu.shape[1] * np.log(var)
        if exclude_self:
            logw[dist < 1e-6] = -np.inf
        logw -= logw.max(axis=1, keepdims=True)
        w = np.exp(logw)
        out[sl] = (w * dist).sum(1) / w.sum(1)
    return out


def calibrate_temperature(
    targets: Points, F: np.ndarray, candidates: Points, n_folds: int = 5, n_eval: int = 400
) -> float:
    """Scale of the feature variance that makes the expected error match cross-validation.

    The GP's variances leave out what the map gets wrong between touches, so taken as they
    are they promise errors far below the real ones. Folds of the touches are held out; the
    temperature whose expected errors at the held-out touches have the same mean as their
    real errors (map fitted without them) is returned.

    Parameters
    ----------
    targets : (n, 3) float
        Touches, m.
    F : (n, k) float
        Their shape features.
    candidates : (P, 3) float
        Surface points, m.
    """
    from skinloc.geometry.mesh import farthest_point_sampling
    from skinloc.models.response_map import ResponseMap

    n = len(targets)
    folds = np.arange(n) % n_folds
    grid = candidates[farthest_point_sampling(candidates, min(n_eval, len(candidates)))]
    temps = np.geomspace(1.0, 1e4, 25)
    pred = np.zeros((len(temps), n))
    real = np.zeros(n)
    for f in range(n_folds):
        tr, te = folds != f, folds == f
        if tr.sum() < 4 or te.sum() == 0:
            continue
        rmap = ResponseMap.fit(targets[tr], F[tr], candidates)
        # shape features are their own features (clipped, norm <= 1): the engine matches them
        found = rmap.spec(n_features=F.shape[1], clip_negative=True).engine().predict_batch(F[te])
        real[te] = 1e3 * np.linalg.norm(found[0] - targets[te], axis=1)
        gp = gp_state(rmap, F[tr])
        mu_g, mu_q = rmap.evaluate_mm(1e3 * grid), rmap.evaluate_mm(1e3 * targets[te])
        v_g = gp.noise + gp.posterior_var(1e3 * grid)
        v_q = gp.noise + gp.posterior_var(1e3 * targets[te])
        for i, t in enumerate(temps):
            pred[i, te] = expected_error_mm(grid, mu_g, t * v_g, (targets[te], mu_q, t * v_q))
    return float(temps[np.argmin(np.abs(pred.mean(axis=1) - real.mean()))])


@dataclass(frozen=True)
class Coverage:
    """Expected localisation error over the skin.

    Attributes
    ----------
    points_m : (E, 3) float
        Evaluation points, m.
    expected_mm : (E,) float
        Expected error at each, mm.
    blind_m : (b, 3) float
        Points whose expected error exceeds ``threshold_mm``, m.
    threshold_mm : float
        The blind-spot threshold, mm.
    temperature : float
        Scale applied to the GP's feature variance (1: as fitted).
    """

    points_m: Points
    expected_mm: np.ndarray
    blind_m: Points
    threshold_mm: float
    temperature: float = 1.0

    def as_dict(self) -> dict:
        """JSON-ready summary (positions m, errors mm)."""
        e = self.expected_mm
        return {
            "n_points": len(e),
            "expected_error_mm": {
                "mean": round(float(e.mean()), 2),
                "median": round(float(np.median(e)), 2),
                "p90": round(float(np.percentile(e, 90)), 2),
            },
            "blind_threshold_mm": self.threshold_mm,
            "temperature": round(self.temperature, 3),
            "blind_fraction": round(float((e > self.threshold_mm).mean()), 3),
            "blind_spots_m": np.round(self.blind_m, 5).tolist(),
        }


def coverage_map(
    rmap,
    F_train: np.ndarray | None = None,
    n_points: int = 400,
    threshold_mm: float = BLIND_MM,
    temperature: float = 1.0,
) -> Coverage:
    """The coverage of a fitted ``ResponseMap`` (``model.map_``) trained on ``F_train (n, k)``.

    ``n_points`` evaluation points are spread evenly over the map's candidates;
    ``temperature`` scales the feature variance (``calibrate_temperature``).
    """
    from skinloc.geometry.mesh import farthest_point_sampling

    cands = rmap.candidates
    idx = farthest_point_sampling(cands, min(n_points, len(cands)))
    pts = cands[idx]
    gp = gp_state(rmap, F_train)
    mu = rmap.evaluate_mm(1e3 * pts)
    s2 = temperature * (gp.noise + gp.posterior_var(1e3 * pts))
    e = expected_error_mm(pts, mu, s2)
    return Coverage(pts, e, pts[e > threshold_mm], threshold_mm, temperature)
