"""The wires of a TX x RX skin: smooth paths through their crossings (``sensors.sensor_map``).

Crossing (i, j) lies on TX wire i and on RX wire j, and wires are continuous, gently bending
paths. In a 2D chart of the skin the crossings of one line fall on a smooth curve; that ties
each crossing to its seven (or n - 1) line mates in both directions.

Units: mm inside (names say so), metres for the reported paths.
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["CURVE_DEGREE", "line_path", "structured_crossings"]

#: Degree of the polynomial a line's crossings are fitted with, in the chart.
CURVE_DEGREE = 2


def line_path(points: np.ndarray, weights: np.ndarray, n: int = 24) -> np.ndarray:
    """A wire's path: the weighted curve through its crossings, sampled at ``n`` points."""
    c = np.average(points, axis=0, weights=weights)
    _, _, vt = np.linalg.svd((points - c) * np.sqrt(weights)[:, None], full_matrices=False)
    t = (points - c) @ vt[0]
    deg = max(1, min(2, len(points) - 2))
    W = np.sqrt(weights)[:, None]
    coef, *_ = np.linalg.lstsq(np.vander(t, deg + 1) * W, points * W, rcond=None)
    ts = np.linspace(t.min(), t.max(), n)
    return np.vander(ts, deg + 1) @ coef


def _chart(candidates_mm: np.ndarray) -> tuple[Any, np.ndarray]:
    """2D coordinates on the skin in which the wires run roughly straight, mm.

    A cone or cylinder about the y axis (the paper's skin) unrolls to (arc length around the
    axis at the mean radius, y); any other skin uses its two principal directions. Returns
    ``(to_uv, candidates_uv)`` with ``to_uv((k, 3) mm) -> (k, 2) mm``.
    """
    c = candidates_mm
    r = np.hypot(c[:, 0], c[:, 2])
    fit = np.polyfit(c[:, 1], r, 1)
    if np.ptp(c[:, 1]) > 0 and np.abs(np.polyval(fit, c[:, 1]) - r).max() < 0.03 * r.mean():
        r0 = float(r.mean())

        def to_uv(p: np.ndarray) -> np.ndarray:
            return np.stack([r0 * np.arctan2(p[:, 2], p[:, 0]), p[:, 1]], axis=1)

    else:
        centre = c.mean(axis=0)
        axes = np.linalg.svd(c - centre, full_matrices=False)[2][:2]

        def to_uv(p: np.ndarray) -> np.ndarray:
            return (p - centre) @ axes.T

    return to_uv, to_uv(c)


def _curve_constraint(
    uv: np.ndarray, weights: np.ndarray, degree: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """Smooth curve through one line's crossings in the chart.

    Returns the curve point nearest each crossing ``(m, 2)``, the curve's unit normal there
    ``(m, 2)``, and the weighted residual variance across the curve (mm^2).
    """
    c = np.average(uv, axis=0, weights=weights)
    d = np.linalg.svd((uv - c) * np.sqrt(weights)[:, None], full_matrices=False)[2][0]
    nrm = np.array([-d[1], d[0]])
    t, h = (uv - c) @ d, (uv - c) @ nrm
    deg = max(1, min(degree, len(uv) - 3))
    coef = np.polyfit(t, h, deg, w=np.sqrt(weights))
    hf = np.polyval(coef, t)
    slope = np.polyval(np.polyder(coef), t)
    tang = d[None, :] + slope[:, None] * nrm[None, :]
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    normal = np.stack([-tang[:, 1], tang[:, 0]], axis=1)
    dof = max(len(uv) - deg - 1, 1)
    var = float((weights * (h - hf) ** 2).sum() / weights.sum() * len(uv) / dof)
    return c + t[:, None] * d + hf[:, None] * nrm, normal, max(var, 0.25)


def structured_crossings(
    pos_mm: np.ndarray,
    gain: np.ndarray,
    candidates_mm: np.ndarray,
    n_tx: int,
    n_rx: int,
) -> np.ndarray:
    """Combine each crossing's own peak with the smooth paths of its TX and RX wires.

    In the chart, crossing (i, j) must lie on TX curve i and RX curve j; each curve fixes
    the component across it, with the variance of its own fit. The crossing's own peak
    (weighted by its gain squared: weak sensors' peaks are noisier) is the third term of a
    2 x 2 weighted least-squares problem, solved in closed form. Returns ``(n, 3)`` mm, on
    the nearest candidate point.
    """
    from scipy.spatial import cKDTree

    if n_tx < 4 or n_rx < 4:
        return pos_mm
    to_uv, cand_uv = _chart(candidates_mm)
    uv = to_uv(pos_mm).reshape(n_tx, n_rx, 2)
    g2 = np.clip(gain, 0.05, 2.0).reshape(n_tx, n_rx) ** 2
    A = np.zeros((n_tx, n_rx, 2, 2))
    b = np.zeros((n_tx, n_rx, 2))
    own_var = []
    cons = []
    for axis, count in ((0, n_tx), (1, n_rx)):
        for i in range(count):
            sl = (i, slice(None)) if axis == 0 else (slice(None), i)
            p, nrm, var = _curve_constraint(uv[sl], g2[sl], CURVE_DEGREE)
            own_var.append(var)
            cons.append((sl, p, nrm, var))
    s_own = float(np.median(own_var))  # per-axis variance of a typical crossing's own peak
    for sl, p, nrm, var in cons:
        wl = 1.0 / var
        A[sl] += wl * nrm[:, :, None] * nrm[:, None, :]
        b[sl] += wl * nrm * (nrm * p).sum(-1, keepdims=True)
    wo = g2 / s_own
    A += wo[..., None, None] * np.eye(2)
    b += wo[..., None] * uv
    merged = np.linalg.solve(A.reshape(-1, 2, 2), b.reshape(-1, 2)[..., None])[..., 0]
    idx = cKDTree(cand_uv).query(merged)[1]
    return candidates_mm[idx]
