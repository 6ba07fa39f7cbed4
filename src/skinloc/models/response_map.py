"""Response maps: each sensor's normalised response as a smooth function on the skin surface.

A touch at surface point ``p`` produces an image whose *shape* depends on ``p`` (which sensors
respond, and how much relative to each other) and whose *scale* depends on pressure. A
response map predicts the shape anywhere on the surface from the calibration touches by
Gaussian-process regression in 3D (one GP per feature, with shared hyperparameters fitted by
marginal likelihood). A new image is then localised by matching its shape against the map at
every candidate surface point (maximum likelihood under the GP's residual noise): that is the
engine's work (``skinloc.models.map_engine``), from the table and search cells built here.

Interpolating 64 smooth scalar fields on a 2D surface needs far fewer touches than learning
the inverse 64 -> 3 mapping, and it recalibrates naturally: a new session's touches fit a
correction layer on top of the old map (see ``ResponseMap.refined``).

Units: positions in metres in the API; the GP works in millimetres internally so that its
length scale reads in mm.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from skinloc._typing import Points
from skinloc.models.map_prior import HYPERPARAMETERS

if TYPE_CHECKING:
    from skinloc.models.map_engine import MapSpec
    from skinloc.models.map_prior import MapPrior

__all__ = ["AmplitudeMap", "MapLayer", "ResponseMap", "shape_features", "unit_images"]


def shape_features(X: np.ndarray, clip_negative: bool = True) -> np.ndarray:
    """Pressure-invariant image shape, ``(n, n_sensors)``.

    Negative deltas (noise, common-mode dips) are clipped to zero, then each image is divided
    by its L2 norm; the norm is floored at one count so an empty frame stays near zero
    instead of being blown up into noise.
    """
    Z = np.asarray(X, dtype=np.float64)
    if clip_negative:
        Z = np.maximum(Z, 0.0)
    return Z / np.maximum(np.linalg.norm(Z, axis=1, keepdims=True), 1.0)


def unit_images(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Touch images divided by their strength, and the strengths.

    The strength of an image is the L2 norm of its positive part, counts (floored at one);
    the unit image keeps the negative deltas, so that the images of two fingers add up.
    Returns ``(U (n, k), strength (n,) counts)``.
    """
    Z = np.asarray(X, dtype=np.float64)
    a = np.maximum(np.linalg.norm(np.maximum(Z, 0.0), axis=1), 1.0)
    return Z / a[:, None], a


def rbf(A_mm: np.ndarray, B_mm: np.ndarray, length_scale_mm: float) -> np.ndarray:
    """Squared-exponential kernel matrix without amplitude, ``(len(A), len(B))``."""
    d2 = (A_mm**2).sum(1)[:, None] + (B_mm**2).sum(1)[None, :] - 2.0 * A_mm @ B_mm.T
    return np.exp(-0.5 * np.maximum(d2, 0.0) / length_scale_mm**2)


@dataclass(frozen=True)
class MapLayer:
    """One GP posterior mean: ``f(q) = k(q, points) @ alpha``.

    Attributes
    ----------
    points_mm : (n, 3) float
        Training positions, mm.
    alpha : (n, k) float
        Dual coefficients (kernel amplitude folded in).
    length_scale_mm : float
        RBF length scale, mm.
    noise : float
        Fitted residual variance per feature (white-noise level of the GP).
    """

    points_mm: np.ndarray
    alpha: np.ndarray
    length_scale_mm: float
    noise: float

    def __call__(self, q_mm: np.ndarray) -> np.ndarray:
        """Layer value at query points ``q_mm (m, 3)`` mm -> ``(m, k)``."""
        return rbf(q_mm, self.points_mm, self.length_scale_mm) @ self.alpha


def fit_gp(
    points_mm: np.ndarray,
    R: np.ndarray,
    length_scale_mm: float | None,
    bounds_mm: tuple[float, float],
    noise: float | None,
    prior: MapPrior | None = None,
) -> Any:
    """A zero-mean GP fitted to residuals ``R (n, k)`` at ``points_mm (n, 3)``.

    With ``length_scale_mm`` and ``noise`` both given the hyperparameters stay fixed (used for
    recalibration from a handful of touches, too few to fit them); otherwise they are chosen
    by maximising the marginal likelihood, starting from the given values, or with a
    ``prior`` the marginal likelihood times the prior (maximum a posteriori), starting from
    the prior's median. Returns scikit-learn's ``GaussianProcessRegressor``, whose
    ``kernel_.theta`` are the log amplitude, length scale (mm) and noise.
    """
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, WhiteKernel
    from sklearn.gaussian_process.kernels import ConstantKernel as C

    fixed = length_scale_mm is not None and noise is not None
    amp0 = float(max(np.mean(R**2), 1e-6))
    optimizer: Any = "fmin_l_bfgs_b"
    if prior is not None and not fixed:
        amp0, length_scale_mm, noise = (prior.typical[k] for k in HYPERPARAMETERS)
        optimizer = _map_optimizer(prior)
    kernel = C(amp0, "fixed" if fixed else (1e-6, 10.0)) * RBF(
        length_scale_mm or 20.0, "fixed" if fixed else bounds_mm
    ) + WhiteKernel(noise or 1e-3, "fixed" if fixed else (1e-6, 1.0))
    gp = GaussianProcessRegressor(kernel, normalize_y=False, random_state=0, optimizer=optimizer)
    with warnings.catch_warnings():
        # A bound reached by the optimiser is a fact about the data, not an error.
        warnings.simplefilter("ignore", ConvergenceWarning)
        gp.fit(points_mm, R)
    return gp


def fit_layer(
    points_mm: np.ndarray,
    R: np.ndarray,
    length_scale_mm: float | None,
    bounds_mm: tuple[float, float],
    noise: float | None,
    prior: MapPrior | None = None,
) -> MapLayer:
    """The posterior mean of ``fit_gp`` (same arguments) as a ``MapLayer``."""
    gp = fit_gp(points_mm, R, length_scale_mm, bounds_mm, noise, prior)
    k = gp.kernel_
    amp, ls, white = (
        float(k.k1.k1.constant_value),
        float(k.k1.k2.length_scale),
        float(k.k2.noise_level),
    )
    alpha = amp * np.asarray(gp.alpha_).reshape(len(points_mm), -1)
    return MapLayer(points_mm.copy(), alpha, ls, white)


def _map_optimizer(prior: MapPrior) -> Any:
    """An optimiser for scikit-learn's GP that maximises the marginal likelihood times ``prior``.

    scikit-learn passes the negative log marginal likelihood and its gradient over the
    kernel's log hyperparameters (amplitude, length scale, noise: ``HYPERPARAMETERS``).
    """
    from scipy.optimize import minimize

    def optimise(obj: Any, theta0: np.ndarray, bounds: np.ndarray) -> tuple[np.ndarray, float]:
        def neg_post(theta: np.ndarray) -> tuple[float, np.ndarray]:
            nll, grad = obj(theta, eval_gradient=True)
            lp, dlp = prior.log_density(theta)
            return nll - lp, grad - dlp

        res = minimize(neg_post, theta0, jac=True, method="L-BFGS-B", bounds=bounds)
        return res.x, float(res.fun)

    return optimise


@dataclass(frozen=True)
class AmplitudeMap:
    """The un-normalised response on the surface: unit image and typical strength per point.

    A touch of strength ``s`` counts at ``p`` gives about ``s * unit(p)``, negative deltas
    included; several fingers give the sum of their images (what multi-contact localisation,
    ``skinloc.models.multi_contact``, searches for). One GP posterior mean with the shape map's
    hyperparameters predicts ``[unit image, log strength]`` jointly.

    Attributes
    ----------
    mean : (k + 1,) float
        Mean of ``[unit image, log strength]`` over the calibration touches.
    layer : MapLayer
        GP layer on the residuals.
    """

    mean: np.ndarray
    layer: MapLayer

    @classmethod
    def fit(
        cls, positions: Points, X: np.ndarray, length_scale_mm: float, noise: float
    ) -> AmplitudeMap:
        """Fit to touch positions ``(n, 3)`` m and baseline-subtracted means ``X (n, k)``."""
        U, a = unit_images(X)
        T = np.concatenate([U, np.log(a)[:, None]], axis=1)
        mean = T.mean(axis=0)
        q = 1e3 * np.asarray(positions, dtype=np.float64)
        layer = fit_layer(q, T - mean, length_scale_mm, (2.0, 300.0), max(noise, 1e-6))
        return cls(mean, layer)

    def evaluate(self, points: Points) -> tuple[np.ndarray, np.ndarray]:
        """``(unit (m, k), strength (m,) counts)`` at ``points (m, 3)`` m."""
        out = []
        for i in range(0, len(points), 4096):
            q = 1e3 * np.asarray(points[i : i + 4096], dtype=np.float64)
            out.append(self.mean + self.layer(q))
        T = np.concatenate(out) if out else np.zeros((0, len(self.mean)))
        return T[:, :-1], np.exp(T[:, -1])


@dataclass
class ResponseMap:
    """Feature mean plus a stack of GP layers, evaluated on a set of candidate surface points.

    Attributes
    ----------
    mean : (k,) float
        Mean feature vector of the first calibration.
    layers : list of MapLayer
        The base map, then one correction layer per recalibration.
    candidates : (P, 3) float
        Surface points the matcher chooses among, m.
    amplitude : AmplitudeMap or None
        The un-normalised response (maps saved before multi-contact have none).
    """

    mean: np.ndarray
    layers: list[MapLayer]
    candidates: Points
    amplitude: AmplitudeMap | None = None
    _table: np.ndarray | None = field(default=None, repr=False)
    _sq: np.ndarray | None = field(default=None, repr=False)
    _coarse: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    @classmethod
    def fit(
        cls,
        positions: Points,
        F: np.ndarray,
        candidates: Points,
        length_scale_mm: float = 20.0,
        bounds_mm: tuple[float, float] = (2.0, 300.0),
        prior: MapPrior | None = None,
    ) -> ResponseMap:
        """Fit the base map to touch positions ``(n, 3)`` m and their features ``F (n, k)``.

        With a ``prior`` (``skinloc.models.map_prior``) the mean is shrunk towards the
        skins' common level and the hyperparameters are a posteriori; without, the mean is
        the touches' and the hyperparameters maximise the marginal likelihood.
        """
        mean = F.mean(axis=0) if prior is None else prior.mean(F)
        layer = fit_layer(1e3 * positions, F - mean, length_scale_mm, bounds_mm, None, prior)
        return cls(mean, [layer], np.asarray(candidates, dtype=np.float64))

    def with_amplitude(self, positions: Points, X: np.ndarray) -> ResponseMap:
        """A copy with an amplitude map fitted to the touch means ``X (n, k)`` counts.

        The amplitude map takes the base layer's length scale and noise (fitted on the shapes)
        rather than its own: the same touches, the same smoothness.
        """
        base = self.layers[0]
        amp = AmplitudeMap.fit(positions, X, base.length_scale_mm, base.noise)
        return ResponseMap(self.mean, self.layers, self.candidates, amp)

    def refined(self, positions: Points, F: np.ndarray) -> ResponseMap:
        """A copy corrected by new touches (e.g. a new session), keeping what still holds.

        The correction is a GP on the residual between the new features and this map, with
        the base layer's length scale and noise, so a few touches pull the map locally
        towards the new response and leave it unchanged far from them.
        """
        q = 1e3 * np.asarray(positions, dtype=np.float64)
        R = F - self.evaluate_mm(q)
        base = self.layers[0]
        layer = fit_layer(q, R, base.length_scale_mm, (2.0, 300.0), base.noise)
        # the amplitude map keeps the first session's response: the count rule needs its scale
        return ResponseMap(
            self.mean.copy(), [*self.layers, layer], self.candidates.copy(), self.amplitude
        )

    @property
    def noise(self) -> float:
        """Residual feature variance of the base map (per feature)."""
        return self.layers[0].noise

    def evaluate_mm(self, q_mm: np.ndarray) -> np.ndarray:
        """Map value (predicted features) at ``q_mm (m, 3)`` mm -> ``(m, k)``."""
        out = np.broadcast_to(self.mean, (len(q_mm), len(self.mean))).copy()
        for layer in self.layers:
            out += layer(q_mm)
        return out

    @property
    def table(self) -> np.ndarray:
        """The map at every candidate point, ``(P, k)`` float32 (computed once)."""
        if self._table is None:
            chunks = [
                self.evaluate_mm(1e3 * self.candidates[i : i + 4096])
                for i in range(0, len(self.candidates), 4096)
            ]
            self._table = np.concatenate(chunks).astype(np.float32)
            self._sq = (self._table**2).sum(axis=1)
        return self._table

    def nearest(self, F: np.ndarray) -> Points:
        """The candidate whose map value is nearest each of ``F (m, k)``: ``(m, 3)`` m.

        An exhaustive search of the table, without the engine's coarse level, noise model or
        output constraint: what scoring a map on touch means needs.
        """
        table = self.table.astype(np.float64)
        d = (table**2).sum(1)[None, :] - 2.0 * np.asarray(F, dtype=np.float64) @ table.T
        return self.candidates[d.argmin(axis=1)]

    def spec(self, **common: Any) -> MapSpec:
        """The map as its engine's arrays; ``common`` are the ``ModelSpec`` fields.

        ``n_features`` and ``clip_negative`` are required; ``spec(...).engine()`` matches
        images against the map (``predict_batch``).
        """
        from skinloc.models.map_engine import MapSpec

        coarse, cells = self.search_cells()
        amp = self.amplitude
        return MapSpec(
            **common,
            surface_points=self.candidates,
            table=self.table,
            coarse=coarse,
            cells=cells,
            noise=float(self.noise),
            unit_table=None if amp is None else amp.evaluate(self.candidates)[0],
        )

    def search_cells(self) -> tuple[np.ndarray, np.ndarray]:
        """A coarse level for the search: every 16th candidate, and the candidates nearest each.

        Returns ``(coarse (C,) int, cells (C, m) int)``, each cell padded by repeating its
        coarse point.
        """
        if getattr(self, "_coarse", None) is None:
            from scipy.spatial import cKDTree

            coarse = np.arange(0, len(self.candidates), 16)
            owner = cKDTree(self.candidates[coarse]).query(self.candidates)[1]
            order = np.argsort(owner, kind="stable")
            counts = np.bincount(owner, minlength=len(coarse))
            cells = np.repeat(coarse[:, None], counts.max(), axis=1)
            starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
            for c, (s0, n) in enumerate(zip(starts, counts, strict=True)):
                cells[c, :n] = order[s0 : s0 + n]
            self._coarse = (coarse, cells)
        return self._coarse
