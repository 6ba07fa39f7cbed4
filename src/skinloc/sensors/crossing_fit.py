"""The per-crossing fit behind ``sensors.sensor_map``, and the result every sensor fit gives.

``CrossingFit`` is what the three estimates of the crossings hand to the sensor map: this
module's fit, the whole-image model (``sensors.joint_fit``) and the line fields
(``sensors.line_fields``).

Each sensor's response to a touch is modelled as ``a / (1 + d^2 / w^2) + c``, with ``d`` the
distance from the touch to the crossing, ``w`` the footprint (half-maximum radius), ``a`` the
gain and ``c`` an offset; a touch's whole image scales with its pressure. All lengths are mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from skinloc._jit import jit
from skinloc._typing import Points
from skinloc.sensors.wires import structured_crossings

__all__ = [
    "LABEL_ERROR_MM",
    "CrossingFit",
    "fit_per_crossing",
    "WIDTHS_MM",
    "local_fit",
    "loo_profile",
    "refine_touches",
    "shared_width",
    "touch_pressure",
]


@dataclass(frozen=True)
class CrossingFit:
    """Where each crossing of a skin is and how it responds (mm, counts).

    Attributes
    ----------
    positions_mm : (n_sensors, 3) float
        Each crossing on the surface, mm.
    footprint_mm : (n_sensors,) float
        Half-maximum radius of each crossing's response, mm.
    gain : (n_sensors,) float
        Each crossing's peak response (any common scale: the health rule compares them).
    touches_mm : (n_touch, 3) float or None
        Where the fit placed the touches, mm (None: at their labels).
    """

    positions_mm: np.ndarray
    footprint_mm: np.ndarray
    gain: np.ndarray
    touches_mm: np.ndarray | None = None


#: The person's miss per tangent axis, mm: measured on the real skin's repeated targets
#: (docs/simulator.md); the prior of ``refine_touches``.
LABEL_ERROR_MM = 5.3
_NEAR_MM = 50.0  # touches used by a sensor's local fit
_MIN_NEAR = 8
_SEARCH_MM = 22.0  # candidate positions searched around the strongest touches
WIDTHS_MM = np.geomspace(4.0, 30.0, 14)
_REL_NOISE, _ABS_NOISE, _PROBE_MM = 0.2, 0.05, 2.5
_SHRINK = 0.5  # damping of the pressure estimate (log scale)
_PRESSURE_ITERS = 1
_SHARED_WIDTH = True
#: Passes moving each touch from its label to where its image says the finger was (more
#: passes measured no better on simulated skins).
_REFINE_ITERS = 1


def local_fit(
    targets_mm: np.ndarray,
    r: np.ndarray,
    cands_mm: np.ndarray,
    tree: Any,
    widths: np.ndarray = WIDTHS_MM,
    stride: int = 1,
) -> tuple[int, float, float, float, float]:
    """Fit ``a / (1 + |p - s|^2 / w^2) + c`` to one sensor's responses ``r (n,)``.

    ``s`` runs over the candidate surface points near the strongest touches and ``w`` over a
    log grid; for each pair ``a`` and ``c`` are the (Huber-reweighted) linear least-squares
    solution, so the search has no local minima and ``s`` stays on the surface. ``stride``
    searches every ``stride``-th candidate (a coarse first pass).

    Returns ``(candidate index of s, w_mm, a, c, residual_rms)``.
    """
    top = np.argsort(r)[-3:]
    wt = np.maximum(r[top] - np.median(r), 1e-9)
    centre = (targets_mm[top] * wt[:, None]).sum(0) / wt.sum()
    cidx = np.asarray(tree.query_ball_point(centre, _SEARCH_MM), dtype=int)[::stride]
    if cidx.size == 0:
        cidx = np.array([tree.query(centre)[1]])
    d = np.linalg.norm(targets_mm - centre, axis=1)
    near = np.argsort(d)[: max(_MIN_NEAR, int((d < _NEAR_MM).sum()))]
    P, y = targets_mm[near], r[near]
    d2 = ((cands_mm[cidx][:, None, :] - P[None]) ** 2).sum(-1)  # (C, m)
    K = 1.0 / (1.0 + d2[None] / widths[:, None, None] ** 2)  # (W, C, m)
    # The weighted sums below are matrix-vector products over the touches: the same least
    # squares as summing (a K + c - y)^2 h term by term, without (W, C, m) temporaries.
    K2 = K * K
    h = np.ones_like(y)
    for _ in range(4):
        hs = h / h.sum()
        Km, K2m, Kym = K @ hs, K2 @ hs, K @ (y * hs)  # (W, C) each
        ym, y2m = float(y @ hs), float((y * y) @ hs)
        var = np.maximum(K2m - Km**2, 1e-12)
        a = np.maximum((Kym - Km * ym) / var, 0.0)
        c = ym - a * Km
        sse = a**2 * K2m + 2.0 * a * c * Km - 2.0 * a * Kym + c**2 - 2.0 * c * ym + y2m
        wi, ci = np.unravel_index(np.argmin(sse), sse.shape)
        fit = a[wi, ci] * K[wi, ci] + c[wi, ci]
        res = fit - y
        # Pressure varies from touch to touch, so the error is mostly proportional to the
        # signal: weight by the inverse predicted variance, then damp outliers (Huber).
        # A probing error of ~2.5 mm moves the response by |grad| * 2.5 mm.
        q = d2[ci] / widths[wi] ** 2
        grad = a[wi, ci] * 2.0 * np.sqrt(q) / (widths[wi] * (1.0 + q) ** 2)
        sd = np.sqrt(
            (_REL_NOISE * fit) ** 2 + (_PROBE_MM * grad) ** 2 + (_ABS_NOISE * a[wi, ci]) ** 2
        )
        sd = np.maximum(sd, 1e-9)
        z = res / sd
        h = np.minimum(1.0, 2.0 / np.maximum(np.abs(z), 1e-12)) / sd**2
    rms = float(np.sqrt(np.mean(res**2)))
    return int(cidx[ci]), float(widths[wi]), float(a[wi, ci]), float(c[wi, ci]), rms


def loo_profile(
    targets_mm: np.ndarray, r: np.ndarray, cands_mm: np.ndarray, tree: Any, widths: np.ndarray
) -> np.ndarray:
    """Leave-one-out error of one sensor's fit at each width, ``(len(widths),)``.

    As in ``local_fit`` (every 4th candidate crossing, ``a`` and ``c`` in closed form, no
    reweighting), each nearby touch is predicted from the fit to the others; its squared
    error is scaled by the variance the noise model expects (``_REL_NOISE`` of the signal,
    ``_ABS_NOISE`` of the sensor's peak), so the strong touches do not dominate.
    """
    top = np.argsort(r)[-3:]
    wt = np.maximum(r[top] - np.median(r), 1e-9)
    centre = (targets_mm[top] * wt[:, None]).sum(0) / wt.sum()
    cidx = np.asarray(tree.query_ball_point(centre, _SEARCH_MM), dtype=int)[::4]
    if cidx.size == 0:
        cidx = np.array([tree.query(centre)[1]])
    d = np.linalg.norm(targets_mm - centre, axis=1)
    near = np.argsort(d)[: max(_MIN_NEAR, int((d < _NEAR_MM).sum()))]
    P, y = targets_mm[near], np.asarray(r[near], dtype=np.float64)
    d2 = ((cands_mm[cidx][:, None, :] - P[None]) ** 2).sum(-1)  # (C, m)
    K = 1.0 / (1.0 + d2[None] / widths[:, None, None] ** 2)  # (W, C, m)
    peak = max(float(y.max()), 1e-9)
    return _loo_errors(
        np.ascontiguousarray(K, dtype=np.float64), y, _REL_NOISE, (_ABS_NOISE * peak) ** 2
    )


@jit(fastmath=False)  # the comparisons of near-equal fits must not depend on reassociation
def _loo_errors(
    K: np.ndarray, y: np.ndarray, rel: float, abs_var: float
) -> np.ndarray:  # pragma: no cover - compiled
    """``loo_profile``'s mean scaled squared error at each width, ``(W,)``.

    ``K (W, C, m)`` holds each width's and candidate's kernel at the ``m`` touches of
    responses ``y (m,)``. Touch ``j`` is predicted by the fit to the other touches (its terms
    taken out of the sums over all, so one pass per width) at the candidate that fits them
    best; its squared error is divided by ``(rel * max(pred, y_j))^2 + abs_var``.
    """
    W, C, m = K.shape
    n1 = m - 1
    Sy, Sy2 = 0.0, 0.0
    for j in range(m):
        Sy += y[j]
        Sy2 += y[j] * y[j]
    out = np.zeros(W)
    S1, SK2, SKy = np.empty(C), np.empty(C), np.empty(C)
    for w in range(W):
        for c in range(C):
            s1 = s2 = sy = 0.0
            for j in range(m):
                k = K[w, c, j]
                s1 += k
                s2 += k * k
                sy += k * y[j]
            S1[c], SK2[c], SKy[c] = s1, s2, sy
        total = 0.0
        for j in range(m):
            yj = y[j]
            ym, y2m = (Sy - yj) / n1, (Sy2 - yj * yj) / n1
            best, pred = np.inf, 0.0
            for c in range(C):
                k = K[w, c, j]
                km, skk, sky = (S1[c] - k) / n1, (SK2[c] - k * k) / n1, (SKy[c] - k * yj) / n1
                a = max((sky - km * ym) / max(skk - km * km, 1e-12), 0.0)
                b = ym - a * km
                sse = y2m - 2 * a * sky - 2 * b * ym + a * a * skk + 2 * a * b * km + b * b
                if sse < best:  # the first of equal minima, as argmin
                    best, pred = sse, a * k + b
            var = (rel * max(pred, yj)) ** 2 + abs_var
            total += (pred - yj) ** 2 / var
        out[w] = total / m
    return out


def shared_width(profiles: np.ndarray, widths: np.ndarray) -> float:
    """Width (mm) minimising ``sum_k log profile_k(w)``, refined by a parabola in log w.

    ``profiles (n_sensors, n_widths)`` are each sensor's errors at each of ``widths
    (n_widths,)`` mm (a log grid); the log makes every sensor count alike whatever its gain.
    """
    L = np.log(np.maximum(profiles, 1e-300)).sum(axis=0)
    i = int(np.argmin(L))
    if 0 < i < len(widths) - 1:
        # Vertex of the parabola through the three grid points around the minimum.
        x, y = np.log(widths[i - 1 : i + 2]), L[i - 1 : i + 2]
        A, B, _ = np.polyfit(x, y, 2)
        if A > 0:
            return float(np.exp(np.clip(-B / (2 * A), x[0], x[2])))
    return float(widths[i])


def refine_touches(
    T_mm: np.ndarray,
    images: np.ndarray,
    pos_mm: np.ndarray,
    width_mm: np.ndarray,
    amp: np.ndarray,
    offset: np.ndarray,
    rms: np.ndarray,
    C_mm: np.ndarray,
    tree: Any,
    label_mm: float = LABEL_ERROR_MM,
) -> np.ndarray:
    """Where each touch really was, ``(n_touch, 3)`` mm: its label moved to fit its image.

    The label ``T_mm (n_touch, 3)`` is where the person was asked to touch, and they miss by
    ``label_mm`` per axis; the image says where the finger landed. Each touch moves to the
    surface point within 3 misses of its label that maximises the likelihood of its image
    under the sensor model (a free pressure scale, the noise model of ``local_fit`` plus
    each sensor's own misfit) times the Gaussian prior of the miss.
    """
    out = T_mm.copy()
    for i, t in enumerate(T_mm):
        cidx = np.asarray(tree.query_ball_point(t, 3.0 * label_mm), dtype=int)
        if cidx.size == 0:
            continue
        X = C_mm[cidx]
        d2 = ((X[:, None, :] - pos_mm[None]) ** 2).sum(-1)
        shape = amp / (1.0 + d2 / width_mm**2) + offset  # (C, n_sensors)
        y = images[i]
        p0 = (shape * y).sum(1) / np.maximum((shape**2).sum(1), 1e-12)
        sd2 = (_REL_NOISE * p0[:, None] * shape) ** 2 + (_ABS_NOISE * amp) ** 2 + rms**2 + 1e-12
        p = (shape * y / sd2).sum(1) / np.maximum((shape**2 / sd2).sum(1), 1e-12)
        p = np.maximum(p, 0.0)
        nll = 0.5 * ((y - p[:, None] * shape) ** 2 / sd2).sum(1) + 0.5 * np.log(sd2).sum(1)
        nll += 0.5 * ((X - t) ** 2).sum(1) / label_mm**2
        out[i] = X[int(np.argmin(nll))]
    return out


def touch_pressure(
    T_mm: np.ndarray,
    images: np.ndarray,
    pos_mm: np.ndarray,
    width_mm: np.ndarray,
    amp: np.ndarray,
    offset: np.ndarray,
) -> np.ndarray:
    """Relative pressure of each touch, ``(n_touch,)`` (median 1).

    A touch's pressure scales its whole image, so it is the typical ratio of the observed to
    the predicted response over the sensors that respond strongly at that point (the weak
    ones are dominated by noise and by the line coupling the sensor model leaves out).
    """
    d2 = ((T_mm[:, None, :] - pos_mm[None]) ** 2).sum(-1)
    pred = amp / (1.0 + d2 / width_mm**2) + offset  # (n_touch, n_sensors)
    strong = pred >= 0.5 * pred.max(axis=1, keepdims=True)
    ratio = np.where(strong & (images > 0) & (pred > 0), images / np.maximum(pred, 1e-12), np.nan)
    w = np.where(np.isfinite(ratio), pred**2, 0.0)
    logp = (np.nan_to_num(np.log(np.where(ratio > 0, ratio, 1.0))) * w).sum(1) / np.maximum(
        w.sum(1), 1e-12
    )
    p = np.exp(_SHRINK * (logp - np.median(logp)))
    return np.clip(p, 0.3, 3.0)


def fit_per_crossing(
    targets: Points,
    images: np.ndarray,
    candidates: Points,
    tree: Any,
    n_tx: int,
    n_rx: int,
    structure: bool,
    label_mm: float = LABEL_ERROR_MM,
) -> CrossingFit:
    """Steps 1-3 of ``sensors.sensor_map``: each crossing from its own column of responses.

    ``targets (n_touch, 3)`` m, ``images (n_touch, n_sensors)`` counts, ``candidates (P, 3)``
    m with ``tree`` the cKDTree of the candidates in mm. The touches of the result are where
    the fit placed them (the labels when ``label_mm`` is 0).
    """
    T_mm, C_mm = 1e3 * targets, 1e3 * candidates
    T_mm0 = T_mm
    n = images.shape[1]
    pos, width, amp, rms = np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n)
    offset = np.zeros(n)
    pressure = np.ones(len(targets))
    widths = WIDTHS_MM
    for it in range(_PRESSURE_ITERS + 2):
        R = images / pressure[:, None]
        for k in range(n):
            ci, width[k], amp[k], offset[k], rms[k] = local_fit(
                T_mm, R[:, k], C_mm, tree, widths, stride=4 if len(widths) > 1 else 1
            )
            pos[k] = C_mm[ci]
        if it == 0 and _SHARED_WIDTH:
            # One silicone layer and one finger: every crossing has about the same footprint,
            # and fixing it leaves each fit three free parameters instead of four. One
            # sensor's own best width is ill-determined (its crossing is free to sit on its
            # strongest touch, which a narrow bump then fits exactly, while a wide bump and a
            # negative offset fit the rest), so the per-sensor widths scatter over the whole
            # grid and their median is an arbitrary grid value. The shared width is instead
            # the one that best predicts each touch left out of its sensor's fit, summed over
            # the sensors that respond (judged by their strongest touches, not by the fitted
            # amplitude, which is larger for the sensors whose own fit chose a narrow width).
            peak = np.sort(R, axis=0)[-3:].mean(axis=0) - np.median(R, axis=0)
            good = peak >= 0.5 * np.median(peak)
            prof = np.array([loo_profile(T_mm, R[:, k], C_mm, tree, widths) for k in range(n)])
            widths = np.array([shared_width(prof[good], widths)])
        elif it <= _PRESSURE_ITERS:
            pressure = touch_pressure(T_mm, images, pos, width, amp, offset)
    for _ in range(_REFINE_ITERS if label_mm > 0 else 0):
        # The labels carry the person's miss (~5 mm per axis); each touch's image says
        # where the finger really was. Move the touches there (from their labels, with the
        # miss as a prior) and refit the crossings on the moved touches.
        T_mm = refine_touches(T_mm0, images, pos, width, amp, offset, rms, C_mm, tree, label_mm)
        pressure = touch_pressure(T_mm, images, pos, width, amp, offset)
        R = images / pressure[:, None]
        for k in range(n):
            ci, width[k], amp[k], offset[k], rms[k] = local_fit(T_mm, R[:, k], C_mm, tree, widths)
            pos[k] = C_mm[ci]
    if structure:
        pos = structured_crossings(pos, amp / max(float(np.median(amp)), 1e-12), C_mm, n_tx, n_rx)
    return CrossingFit(pos, width, amp, T_mm)
