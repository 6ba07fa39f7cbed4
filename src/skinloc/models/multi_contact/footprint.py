"""A second finger in the image's footprint: wider and fuller than one finger's at that place.

Two fingers a couple of sensor pitches apart make one blob to the pair search, but a blob
unlike one finger's: more sensors lit, more signal on the flanks and outside the finger's own
footprint, more total signal for its peak, more signal overall. Each is measured against the
model's own prediction for one finger at the place the one-contact fit found (the amplitude
map's unit image there, scaled to the image), so that what is typical of the skin's single
touches cancels and the statistics transfer across recordings of one skin. For a whitened
image ``z`` (``x * w``, noise levels) and the prediction ``q = s u`` (``u`` the whitened unit
image at the one-contact fit's row, ``s`` the least-squares scale), with ``z+`` and ``q+``
their parts above ``FLOOR`` noise levels, the features are:

0. ``log`` of total over peak, ``(sum z+ / max z) / (sum q+ / max q)``;
1. ``log`` of the participation ratio ``(sum z+)^2 / sum z+^2``, over the prediction's;
2. ``log`` of the sensors above a quarter of the peak, over the prediction's;
3. ``log`` of flank over core (the signal where ``q`` is 5-50 % of its peak against where it
   is above half), over the prediction's;
4. the share of ``z+`` where ``q`` is under 5 % of its peak (outside the finger's footprint);
5. the share of the image's energy the prediction leaves, ``|z - q|^2 / |z|^2``;
6. the positive residual outside the core, ``sum max(z - q, 0)`` there, over ``sum z+``;
7. ``log`` of the peak signal, noise levels (more fingers, more signal).

No one of them separates two fingers 20-40 mm apart from the skin's single touches at a 2 %
false rate (real single touches misfit the map as much), but a linear combination of all does:
the *footprint score* ``f . a``, its weights ``a`` a linear discriminant between held-out single
touches and held-out pairs 15-50 mm apart, fitted in the count rule's cross-validation in
``fit`` (``rule_calibration``) on the skin's own calibration touches; its threshold
(``CountRule.footprint_two``) calls at most 2 % of the held-out single touches (touch means and
single frames alike) two, and its hold level (``footprint_hold``) lies above 95 % of them.
The peak signal makes the score depend on pressure: calibrated on held touches it finds sums of
held touches across recordings, but not the lighter taps of a gesture (docs/multitouch.md, "A
second finger in the footprint"), so no count uses it yet.

Units: counts in, noise levels inside; the score has none.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skinloc._jit import jit

__all__ = [
    "FEATURES",
    "N_FEATURES",
    "calibrate_footprint",
    "features_of",
    "footprint_features",
    "footprint_score",
]

#: The features' names, in order.
FEATURES = (
    "total_over_peak",
    "participation",
    "lit",
    "flank_over_core",
    "outside",
    "misfit",
    "residual_outside_core",
    "peak",
)
N_FEATURES = len(FEATURES)
#: Whitened signal under which a sensor counts as unlit (noise levels).
FLOOR = 2.0
#: Share of the prediction's peak above which a sensor is in the finger's core, and under
#: which it is outside its footprint.
CORE, OUTSIDE = 0.5, 0.05
#: Share of the peak above which a sensor is lit.
LIT = 0.25
#: Least separation (mm) of the calibration's pairs, and the largest: the footprint is for
#: the fingers the pair search cannot separate.
PAIR_MM = (15.0, 50.0)
#: Share of held-out single touches the threshold may call two, and above the hold level.
RATE, HOLD_RATE = 0.02, 0.05
#: Fewest held-out single touches and pairs to calibrate on (fewer: the cue is off).
MIN_SETS = 40
#: The features the score weighs (the others get weight 0).
USED = tuple(range(N_FEATURES))


@jit()
def footprint_features(z: np.ndarray, u: np.ndarray, out: np.ndarray) -> bool:  # pragma: no cover
    """The features of whitened image ``z (k,)`` against whitened unit image ``u (k,)``.

    Writes ``out (N_FEATURES,)``; returns False (``out`` untouched) when either has no signal.
    """
    k = z.shape[0]
    zu = 0.0
    uu = 0.0
    zz = 0.0
    zmax = 0.0
    umax = 0.0
    for j in range(k):
        zu += float(z[j]) * float(u[j])
        uu += float(u[j]) * float(u[j])
        zz += float(z[j]) * float(z[j])
        zmax = max(zmax, float(z[j]))
        umax = max(umax, float(u[j]))
    if zu <= 0.0 or uu <= 0.0 or zmax <= 0.0 or umax <= 0.0:
        return False
    s = zu / uu
    qmax = s * umax
    zs = zs2 = qs = qs2 = 0.0
    zlit = qlit = 0
    zcore = zflank = qcore = qflank = 0.0
    zout = 0.0
    rr = 0.0
    rpos = 0.0
    for j in range(k):
        v = float(z[j])
        q = s * float(u[j])
        r = v - q
        rr += r * r
        vp = v if v > FLOOR else 0.0
        qp = q if q > FLOOR else 0.0
        zs += vp
        zs2 += vp * vp
        qs += qp
        qs2 += qp * qp
        if v > LIT * zmax:
            zlit += 1
        if q > LIT * qmax:
            qlit += 1
        if q > CORE * qmax:
            zcore += vp
            qcore += qp
        else:
            if r > 0.0:
                rpos += r
            if q > OUTSIDE * qmax:
                zflank += vp
                qflank += qp
            else:
                zout += vp
    tiny = 1e-9
    out[0] = np.log(max(zs / zmax, tiny) / max(qs / qmax, tiny))
    out[1] = np.log(max(zs * zs / max(zs2, tiny), tiny) / max(qs * qs / max(qs2, tiny), tiny))
    out[2] = np.log(max(zlit, 1) / max(qlit, 1))
    out[3] = np.log(max(zflank / max(zcore, tiny), tiny) / max(qflank / max(qcore, tiny), tiny))
    out[4] = zout / max(zs, tiny)
    out[5] = rr / zz
    out[6] = rpos / max(zs, tiny)
    out[7] = np.log(zmax)
    return True


@jit()
def footprint_score(
    z: np.ndarray, u: np.ndarray, weights: np.ndarray, f: np.ndarray
) -> float:  # pragma: no cover - compiled
    """The footprint score ``f . weights`` of ``z`` against ``u`` (``f``: scratch); nan if none."""
    if not footprint_features(z, u, f):
        return np.nan
    acc = 0.0
    for i in range(f.shape[0]):
        acc += f[i] * weights[i]
    return acc


def features_of(z: np.ndarray, u: np.ndarray) -> np.ndarray:
    """``footprint_features`` of ``z (n, k)`` against ``u (n, k)``: ``(n, N_FEATURES)``.

    Rows without signal are nan.
    """
    z = np.ascontiguousarray(z, dtype=np.float32)
    u = np.ascontiguousarray(u, dtype=np.float32)
    out = np.full((len(z), N_FEATURES), np.nan)
    f = np.zeros(N_FEATURES)
    for i in range(len(z)):
        if footprint_features(z[i], u[i], f):
            out[i] = f
    return out


def calibrate_footprint(
    singles: list[np.ndarray], pairs: np.ndarray, rate: float = RATE, hold_rate: float = HOLD_RATE
) -> tuple[np.ndarray, float, float, dict[str, Any]]:
    """The footprint score's weights, threshold and hold level from held-out sets.

    Parameters
    ----------
    singles : list of (n_i, N_FEATURES) float
        Features of held-out single touches (touch means; single frames): each set keeps
        under ``rate`` above the threshold.
    pairs : (m, N_FEATURES) float
        Features of held-out pairs ``PAIR_MM`` apart (summed images).

    Returns
    -------
    weights : (N_FEATURES,) float
        The linear discriminant (empty: too few sets, the cue is off).
    threshold, hold : float
        Scores from which an image is two fingers, and no longer surely one.
    report : dict
        ``singles``, ``pairs`` (how many), ``pairs_found`` (their share at the threshold),
        ``single_called_two`` (the worst set's share), ``singles_held``.
    """
    singles = [s[np.all(np.isfinite(s), axis=1)] for s in singles]
    singles = [s for s in singles if len(s) >= MIN_SETS]
    pairs = pairs[np.all(np.isfinite(pairs), axis=1)] if len(pairs) else pairs
    n_s = sum(len(s) for s in singles)
    if not singles or len(pairs) < MIN_SETS:
        return np.zeros(0), 0.0, 0.0, {"singles": n_s, "pairs": int(len(pairs))}
    use = list(USED)
    S, P = np.concatenate(singles)[:, use], pairs[:, use]
    cov = np.cov(S.T).reshape(len(use), -1) + np.cov(P.T).reshape(len(use), -1)
    # a ridge of 1e-3 of the mean variance: the features are few but correlated
    cov += 1e-3 * float(np.trace(cov)) / len(cov) * np.eye(len(cov))
    weights = np.zeros(N_FEATURES)
    weights[use] = np.linalg.solve(cov, P.mean(axis=0) - S.mean(axis=0))
    scores = [s @ weights for s in singles]
    threshold = max(float(np.quantile(v, 1.0 - rate)) for v in scores) + 1e-9
    hold = min(max(float(np.quantile(v, 1.0 - hold_rate)) for v in scores), threshold)
    p = pairs @ weights
    return (
        weights,
        threshold,
        hold,
        {
            "singles": n_s,
            "pairs": int(len(pairs)),
            "pairs_found": float(np.mean(p >= threshold)),
            "single_called_two": max(float(np.mean(v >= threshold)) for v in scores),
            "singles_held": max(float(np.mean(v >= hold)) for v in scores),
        },
    )
