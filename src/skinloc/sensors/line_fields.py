"""Separable line-sensitivity model: one smooth field per TX line and per RX line.

A touch's image is nearly rank one (a TX profile times an RX profile; 98 % of its energy on
the real cone), so the response of crossing (i, j) to a touch at ``x`` is modelled as::

    y_tij = P_t * K_ij * f_i(x_t) * g_j(x_t)

with ``P_t`` the touch's pressure, ``K_ij`` the crossing's own factor (median 1), ``f_i`` the
sensitivity field of TX line i and ``g_j`` that of RX line j over the surface. Each field
is a non-negative sum of Gaussian bumps centred on ``n_centres`` surface points spread evenly
over the skin, plus a constant (the field far from the wire: common mode, coupling). The
fields are fitted by alternating non-negative weighted least squares over all touches: each
TX field pools the responses of its 8 crossings, so it is far less noisy than one crossing's
own fit from the same 20-80 touches. Nothing assumes where the wires run or that they
cross: crossing (i, j) is where ``f_i * g_j`` peaks.

Whether the fields describe a recording better than the per-crossing fit
(``sensors.crossing_fit``) is decided on touches neither saw (``heldout_comparison``: K-fold
cross-validation over the touches, each held-out touch's image predicted at its label with
one free pressure, scored in units of the expected error); the same check picks the fields'
complexity (bumps per field). ``field_map`` gives the crossings of the chosen fields.

The touches may carry the person's miss (``label_mm`` per tangent axis): between field fits
each touch moves to the surface point near its label that best explains its whole image under
the current fields, with the miss as a Gaussian prior. Lengths are mm inside.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import nnls

from skinloc.sensors.crossing_fit import CrossingFit

__all__ = [
    "COMPLEXITIES",
    "FieldMap",
    "FieldModel",
    "centres",
    "crossings",
    "field_map",
    "fit_fields",
    "heldout_comparison",
    "heldout_score",
    "locate_touches",
    "make_basis",
    "per_crossing_predictor",
    "predict_images",
]

_REL_SD = 0.15  # model error proportional to the response
_ABS_SD = 3.0  # counts: error floor of a mean response
_RIDGE = 1e-2  # ridge on the field weights, relative to the mean diagonal of the normal matrix
_SIGMA_FACTOR = 0.8  # bump width relative to the spacing of the centres


@dataclass
class FieldModel:
    """Fitted line fields (mm, counts).

    Attributes
    ----------
    basis_fn : callable
        ``(n, 3) mm -> (n, M + 1)``: the non-negative basis functions at surface points
        (``make_basis``), the last a constant.
    tx_weights : (M + 1, n_tx) float
        Non-negative weights of each TX field (last row: the constant).
    rx_weights : (M + 1, n_rx) float
        The same for each RX field.
    touches_mm : (n_touch, 3) float
        Where the fit placed the touches (the labels when ``label_mm`` is 0), mm.
    pressure : (n_touch,) float
        Relative pressure of each touch (median 1).
    gain : (n_tx, n_rx) float
        Each crossing's own factor on ``f_i * g_j`` (median 1; ones when not fitted).
    """

    basis_fn: Callable[[np.ndarray], np.ndarray]
    tx_weights: np.ndarray
    rx_weights: np.ndarray
    touches_mm: np.ndarray
    pressure: np.ndarray
    gain: np.ndarray  # (n_tx, n_rx) each crossing's own factor, median 1 (ones without it)

    def basis(self, x_mm: np.ndarray) -> np.ndarray:
        """Basis ``(n, M + 1)`` at points ``x_mm (n, 3)``: the bumps and a constant."""
        return self.basis_fn(np.asarray(x_mm, float))

    def fields(self, x_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TX fields ``(n, n_tx)`` and RX fields ``(n, n_rx)`` at ``x_mm (n, 3)``."""
        B = self.basis(x_mm)
        return B @ self.tx_weights, B @ self.rx_weights

    def response(self, x_mm: np.ndarray) -> np.ndarray:
        """Unit-pressure response ``(n, n_tx * n_rx)`` of every sensor to touches at ``x_mm``."""
        F, G = self.fields(x_mm)
        return (self.gain[None] * F[:, :, None] * G[:, None, :]).reshape(len(x_mm), -1)


def _basis(x: np.ndarray, c: np.ndarray, sigma: float) -> np.ndarray:
    d2 = ((x[:, None, :] - c[None]) ** 2).sum(-1)
    return np.hstack([np.exp(-0.5 * d2 / sigma**2), np.ones((len(x), 1))])


def make_basis(cands_mm: np.ndarray, n: int) -> Callable[[np.ndarray], np.ndarray]:
    """Gaussian bumps at ``n`` evenly spread surface points (``centres``) and a constant.

    (Cubic B-splines on a grid of the unrolled cone, whose rows and columns follow rings and
    rulings, predicted held-out touches no better on simulated skins and placed the crossings
    no better; docs/sensors.md.)
    """
    cen, sigma = centres(cands_mm, n)
    return lambda x: _basis(x, cen, sigma)


def centres(cands_mm: np.ndarray, n: int) -> tuple[np.ndarray, float]:
    """``n`` evenly spread surface points (farthest-point sampling) and the bump width, mm.

    Deterministic: starts from the candidate nearest the surface's centroid. The width is
    ``_SIGMA_FACTOR`` times the median distance from a centre to its nearest neighbour.
    """
    sub = cands_mm[:: max(1, len(cands_mm) // 3000)]
    pick = [int(np.argmin(((sub - sub.mean(0)) ** 2).sum(1)))]
    d = ((sub - sub[pick[0]]) ** 2).sum(1)
    for _ in range(n - 1):
        k = int(np.argmax(d))
        pick.append(k)
        d = np.minimum(d, ((sub - sub[k]) ** 2).sum(1))
    C = sub[pick]
    dc = np.sqrt(((C[:, None] - C[None]) ** 2).sum(-1))
    np.fill_diagonal(dc, np.inf)
    return C, float(_SIGMA_FACTOR * np.median(dc.min(1)))


def _sd(pred: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Expected error of a mean response: a floor plus a share of the signal, counts."""
    return np.sqrt(_ABS_SD**2 + (_REL_SD * np.maximum(np.maximum(pred, y), 0.0)) ** 2)


def _nnls_ridge(A: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Non-negative weighted least squares with a small ridge (rows of ``A``, weights ``w``)."""
    sw = np.sqrt(w)
    Aw, bw = A * sw[:, None], b * sw
    lam = _RIDGE * max(float(np.mean((Aw**2).sum(0))), 1e-12)
    m = A.shape[1]
    Aa = np.vstack([Aw, np.sqrt(lam) * np.eye(m)])
    ba = np.concatenate([bw, np.zeros(m)])
    return nnls(Aa, ba, maxiter=50 * m)[0]


def _pressure(Y: np.ndarray, M: np.ndarray, W: np.ndarray) -> np.ndarray:
    """Weighted least-squares scale of each touch's image against its prediction ``(n,)``."""
    return np.maximum((W * Y * M).sum(1) / np.maximum((W * M * M).sum(1), 1e-12), 1e-3)


def _fit_at(
    B: np.ndarray, Y: np.ndarray, n_tx: int, n_rx: int, A0: np.ndarray, C0: np.ndarray,
    K0: np.ndarray, iters: int, crossing_gains: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Alternating fit with the touches fixed (basis ``B (nt, M + 1)``).

    Returns TX weights, RX weights, pressures ``(nt,)`` and crossing gains ``(n_tx, n_rx)``.
    """
    nt = len(Y)
    Y3 = Y.reshape(nt, n_tx, n_rx)
    A, C, K = A0.copy(), C0.copy(), K0.copy()
    P = np.ones(nt)
    for _ in range(iters):
        F, G = B @ A, B @ C
        pred = P[:, None, None] * K[None] * F[:, :, None] * G[:, None, :]
        W3 = 1.0 / _sd(pred, Y3) ** 2
        # Robust: a response far off the model (a glitch, a touch the model cannot place)
        # weighs as if its error grew linearly (Huber at 2.5 sd).
        z = np.abs(pred - Y3) * np.sqrt(W3)
        W3 = W3 * np.minimum(1.0, 2.5 / np.maximum(z, 1e-12))
        for i in range(n_tx):
            # y_tij = (B_t . a_i) * P_t K_ij G_tj: linear in a_i over the rows (t, j).
            D = (B[:, None, :] * (P[:, None] * K[i][None] * G)[:, :, None]).reshape(nt * n_rx, -1)
            A[:, i] = _nnls_ridge(D, Y3[:, i, :].ravel(), W3[:, i, :].ravel())
        F = B @ A
        for j in range(n_rx):
            Fj = P[:, None] * K[:, j][None] * F
            D = (B[:, None, :] * Fj[:, :, None]).reshape(nt * n_tx, -1)
            C[:, j] = _nnls_ridge(D, Y3[:, :, j].ravel(), W3[:, :, j].ravel())
        G = B @ C
        M3 = P[:, None, None] * F[:, :, None] * G[:, None, :]
        if crossing_gains:
            # Each crossing's own factor (an electrical fault, a crossing's coupling), the
            # part of its response the two line fields cannot carry; median 1.
            K = (W3 * Y3 * M3).sum(0) / np.maximum((W3 * M3 * M3).sum(0), 1e-12)
            K = np.clip(K / max(float(np.median(K)), 1e-12), 0.0, 5.0)
        M = (K[None] * F[:, :, None] * G[:, None, :]).reshape(nt, -1)
        P = _pressure(Y, M, W3.reshape(nt, -1))
        # Scale ambiguities: pressures median 1, TX and RX fields of equal size.
        s = float(np.median(P))
        P, A = P / s, A * s
        r = np.sqrt(max(float(np.abs(A).max()), 1e-12) / max(float(np.abs(C).max()), 1e-12))
        A, C = A / r, C * r
    return A, C, P, K


def fit_fields(
    labels_mm: np.ndarray,
    images: np.ndarray,
    n_tx: int,
    n_rx: int,
    cands_mm: np.ndarray,
    tree: Any,
    n_centres: int = 24,
    label_mm: float = 5.3,
    passes: int = 2,
    iters: int = 8,
    init: FieldModel | None = None,
    crossing_gains: bool = True,
) -> FieldModel:
    """Fit the line fields to calibration touches.

    Parameters
    ----------
    labels_mm : (n_touch, 3) float
        Prompted touch points, mm.
    images : (n_touch, n_tx * n_rx) float
        Mean baseline-subtracted image of each touch, counts.
    n_tx, n_rx : int
        Grid; sensor k is TX ``k // n_rx``, RX ``k % n_rx``.
    cands_mm : (P, 3) float
        Surface points, mm; ``tree`` their cKDTree.
    n_centres : int
        Bumps per field (the model's complexity; chosen by held-out fit).
    label_mm : float
        The person's miss per tangent axis, mm; 0 keeps the touches at their labels.
    passes : int
        Moves of the touches (each followed by a refit of the fields).
    iters : int
        Alternating sweeps per fit.
    init : FieldModel, optional
        Start from these fields, gains and touches (``touches_mm (n_touch, 3)``, one per
        row of ``images``: a bootstrap resample of the same skin).
    crossing_gains : bool
        Fit each crossing's own factor on ``f_i * g_j`` (else ones).

    Returns
    -------
    FieldModel

    Raises
    ------
    ValueError
        If the images do not match the touches and the grid, or there are too few touches.
    """
    Y = np.asarray(images, float)
    nt = len(np.asarray(labels_mm).reshape(-1, 3))
    if Y.shape != (nt, n_tx * n_rx):
        raise ValueError(f"images must be ({nt}, {n_tx * n_rx}), got {Y.shape}")
    if nt < 5 or n_centres < 1:
        raise ValueError(f"need at least 5 touches and 1 bump per field, got {nt}, {n_centres}")
    labels = cands_mm[tree.query(np.asarray(labels_mm, float))[1]]
    K0 = np.ones((n_tx, n_rx))
    if init is None:
        bfn = make_basis(cands_mm, n_centres)
        B = bfn(labels)
        # Start: each field follows its line's total response (rank-one start).
        Y3 = np.maximum(Y.reshape(len(Y), n_tx, n_rx), 0.0)
        u, v = np.sqrt(Y3.sum(2) + 1.0), np.sqrt(Y3.sum(1) + 1.0)
        A0 = np.stack([_nnls_ridge(B, u[:, i], np.ones(len(Y))) for i in range(n_tx)], 1)
        C0 = np.stack([_nnls_ridge(B, v[:, j], np.ones(len(Y))) for j in range(n_rx)], 1)
        A0, C0 = A0 + 1e-3, C0 + 1e-3
        X = labels
    else:
        bfn, A0, C0 = init.basis_fn, init.tx_weights, init.rx_weights
        K0 = init.gain if crossing_gains else K0
        X = cands_mm[tree.query(init.touches_mm)[1]] if label_mm > 0 else labels
    fit = _fit_at(bfn(X), Y, n_tx, n_rx, A0, C0, K0, iters, crossing_gains)
    model = FieldModel(bfn, fit[0], fit[1], X, fit[2], fit[3])
    for _ in range(passes if label_mm > 0 else 0):
        X = locate_touches(model, Y, labels, cands_mm, tree, label_mm)
        fit = _fit_at(
            model.basis(X), Y, n_tx, n_rx, model.tx_weights, model.rx_weights, model.gain,
            max(2, iters // 2), crossing_gains,
        )  # fmt: skip
        model = FieldModel(bfn, fit[0], fit[1], X, fit[2], fit[3])
    return model


def locate_touches(
    model: FieldModel,
    images: np.ndarray,
    labels_mm: np.ndarray,
    cands_mm: np.ndarray,
    tree: Any,
    label_mm: float,
) -> np.ndarray:
    """Where each touch was, ``(n_touch, 3)`` mm: the likeliest surface point near its label.

    Searches the surface points within 3 misses of the label; each point's likelihood is that
    of the whole image under the fields (pressure free, in closed form) times the Gaussian
    prior of the miss.
    """
    out = np.asarray(labels_mm, float).copy()
    for t, lab in enumerate(out.copy()):
        idx = np.asarray(tree.query_ball_point(lab, 3.0 * label_mm), dtype=int)[::2]
        if idx.size == 0:
            continue
        X = cands_mm[idx]
        M = model.response(X)
        y = images[t][None]
        W = 1.0 / _sd(M * np.median(model.pressure), y) ** 2
        p = _pressure(np.broadcast_to(y, M.shape), M, W)
        W = 1.0 / _sd(p[:, None] * M, y) ** 2
        nll = 0.5 * (W * (y - p[:, None] * M) ** 2).sum(1) - 0.5 * np.log(W).sum(1)
        nll += 0.5 * ((X - lab) ** 2).sum(1) / label_mm**2
        out[t] = X[int(np.argmin(nll))]
    return out


def predict_images(model: FieldModel, x_mm: np.ndarray) -> np.ndarray:
    """Unit-pressure images ``(n, n_sensors)`` at ``x_mm``, counts."""
    return model.response(np.asarray(x_mm, float))


def heldout_score(pred: np.ndarray, images: np.ndarray) -> np.ndarray:
    """Misfit of predicted images to observed ones, one value per touch ``(n,)``.

    Each prediction ``(n, n_sensors)`` is first scaled to its image (one free pressure per
    touch, weighted least squares), then the mean squared error in units of the expected
    error (``_sd`` of the observed response): lower is better, about 1 for a model as good
    as the noise model says.
    """
    Y = np.asarray(images, float)
    W = 1.0 / _sd(np.zeros_like(Y), Y) ** 2
    p = _pressure(Y, pred, W)
    return (W * (Y - p[:, None] * pred) ** 2).mean(1)


def crossings(model: FieldModel, cands_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each crossing where ``f_i * g_j`` peaks on the surface, its peak and footprint.

    Returns positions ``(n_sensors, 3)`` mm (surface points), peak unit-pressure responses
    ``(n_sensors,)`` counts above the fields' far-off floor (the constant terms' product),
    times the crossing's own factor, and footprints ``(n_sensors,)`` mm: the radius of a disc
    of the same area as the surface where the response is above half its peak, within 40 mm
    of the peak.
    """
    F, G = model.fields(cands_mm)
    n_tx, n_rx = F.shape[1], G.shape[1]
    floor = np.outer(model.tx_weights[-1], model.rx_weights[-1]).ravel()
    # Surface area per candidate point (an even sampling): from its nearest-neighbour spacing.
    area_per_point = _area_per_point(cands_mm)
    pos = np.zeros((n_tx * n_rx, 3))
    peak = np.zeros(n_tx * n_rx)
    foot = np.zeros(n_tx * n_rx)
    for i in range(n_tx):
        prod = F[:, i, None] * G  # (P, n_rx)
        for j in range(n_rx):
            k = i * n_rx + j
            c = int(np.argmax(prod[:, j]))
            pos[k] = cands_mm[c]
            peak[k] = model.gain[i, j] * max(float(prod[c, j] - floor[k]), 0.0)
            near = ((cands_mm - pos[k]) ** 2).sum(1) < 40.0**2
            above = near & (prod[:, j] - floor[k] >= 0.5 * (prod[c, j] - floor[k]))
            foot[k] = np.sqrt(above.sum() * area_per_point / np.pi)
    return pos, peak, foot


def _area_per_point(cands_mm: np.ndarray) -> float:
    """Surface area per candidate point, mm^2 (from the median nearest-neighbour spacing)."""
    from scipy.spatial import cKDTree

    sub = cands_mm[:: max(1, len(cands_mm) // 4000)]
    s = float(np.median(cKDTree(cands_mm).query(sub, k=2)[0][:, 1]))
    return s * s


# ---------------------------------------------------------- the fields against the per-crossing fit

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
    model: FieldModel
    n_centres: int

    def crossings(self) -> CrossingFit:
        """The crossings (touches at their labels)."""
        return CrossingFit(self.positions_mm, self.footprint_mm, self.peak)


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
        fit = fit_per_crossing(
            1e-3 * train_mm, train_y, 1e-3 * cands_mm, tree, n_tx, n_rx, True, label_mm
        )
        pos, width = fit.positions_mm, fit.footprint_mm
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
        per[te] = heldout_score(pred, images[te])
        for m in complexities:
            model = fit_fields(
                labels_mm[tr], images[tr], n_tx, n_rx, cands_mm, tree, n_centres=m,
                label_mm=label_mm,
            )  # fmt: skip
            sc[m][te] = heldout_score(predict_images(model, snapped[te]), images[te])
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
    model = fit_fields(labels_mm, images, n_tx, n_rx, cands_mm, tree, n_centres, label_mm)
    pos, peak, foot = crossings(model, cands_mm)
    rng = np.random.default_rng(random_state)
    boots = []
    for _ in range(n_boot):
        pick = rng.choice(len(labels_mm), len(labels_mm), replace=True)
        init = FieldModel(
            model.basis_fn, model.tx_weights, model.rx_weights,
            model.touches_mm[pick], model.pressure[pick], model.gain,
        )  # fmt: skip
        b = fit_fields(
            labels_mm[pick], images[pick], n_tx, n_rx, cands_mm, tree, n_centres, label_mm,
            passes=1, iters=4, init=init,
        )  # fmt: skip
        boots.append(crossings(b, cands_mm)[0])
    if boots:
        B = np.stack(boots)
        unc = np.sqrt(((B - pos[None]) ** 2).sum(-1).mean(0))
    else:
        unc = np.full(len(pos), np.nan)
    return FieldMap(pos, unc, peak, foot, model, n_centres)
