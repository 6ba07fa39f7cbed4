"""A second finger in time: the image's change of shape while a touch lands and lifts.

Two fingers of one hand land (and lift) tens of milliseconds apart. A single finger's image
grows and shrinks with its pressure but keeps its shape; when a second finger lands beside
it, the image gains the second finger's image, which the earlier frame (the first finger
alone) cannot explain. So each frame is compared with the frame ``lag`` frames before it:
the earlier image is scaled to fit the later one (least squares) and what is left, in noise
levels, is the *change*::

    e = |z_t - s z_{t-lag}|^2 / ((1 + s^2) n),   s = (z_t . z_{t-lag}) / |z_{t-lag}|^2

where ``z = x * w`` are whitened images (``w = 1 / sensor noise``) of ``n`` sensors. For a
finger that keeps its shape, ``e`` is the noise alone, about 1 whatever the finger's
strength; a second finger landing or lifting adds its share of the image. A touch's change is
the largest ``e`` over its frames and over ``LAGS``. It needs no separation between the
fingers: it finds them below the pair search's minimum separation, and it misses fingers
that land and lift together (within a frame or so).

The threshold of one skin (``CountRule.landing_change``) is calibrated in ``fit`` from the
skin's own calibration touches (``calibrate_landing``): each touch's mean image ramped up,
held and ramped down, with that touch's own frame-to-frame noise added, is a single finger;
two touches summed with their ramps shifted by 1-4 frames are two fingers. The threshold is
the least that calls at most ``rate`` of the single fingers two.

Units: counts in, noise levels out; frames (at the skin's rate) for lags.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skinloc._jit import jit

__all__ = ["LAGS", "calibrate_landing", "frame_change", "landing_sets", "touch_change"]

#: Frames between the two images compared (20 and 30 ms at 100 Hz: a finger's image grows
#: over about 20 ms as it lands).
LAGS = (2, 3)
#: Frames of a synthetic touch held at full strength, between its ramps.
_HOLD = 8
#: A calibration touch ramps up (and down) over these fractions of its strength.
_RAMP = (0.25, 0.5, 0.75)


@jit()
def frame_change(z: np.ndarray, ref: np.ndarray) -> float:  # pragma: no cover - compiled
    """The change ``e`` of whitened image ``z (n,)`` from the earlier ``ref (n,)``, noise levels.

    About 1 when ``z`` is ``ref`` scaled plus noise; more when the shape changed.
    """
    n = z.shape[0]
    rr = 0.0
    zr = 0.0
    zz = 0.0
    for j in range(n):
        rr += ref[j] * ref[j]
        zr += z[j] * ref[j]
        zz += z[j] * z[j]
    if rr <= 0.0:
        return 0.0
    s = zr / rr
    # |z - s ref|^2 = |z|^2 - 2 s z.ref + s^2 |ref|^2
    return max(zz - 2.0 * s * zr + s * s * rr, 0.0) / ((1.0 + s * s) * n)


def touch_change(zs: np.ndarray, lags: tuple[int, ...] = LAGS) -> float:
    """The largest change over a touch's whitened frames ``zs (T, n)`` and ``lags``."""
    zs = np.ascontiguousarray(zs, dtype=np.float64)
    best = 0.0
    for lag in lags:
        for t in range(lag, zs.shape[0]):
            best = max(best, frame_change(zs[t], zs[t - lag]))
    return best


def _ramp(n_hold: int, land: int = 0, lift: int = 0) -> np.ndarray:
    """A finger's strength over a synthetic touch, frame by frame.

    0 for ``land`` frames, a ramp up, held, a ramp down (``lift`` frames later than a finger
    held ``n_hold``).
    """
    up = np.asarray(_RAMP)
    hold = max(n_hold - land + lift, 1)
    return np.concatenate([np.zeros(land), up, np.ones(hold), up[::-1]])


def _sequence(
    touches: list[np.ndarray], rng: np.random.Generator, shifts: list[tuple[int, int]]
) -> np.ndarray:
    """Frames ``(T, n)`` of fingers ``touches`` (each its frames ``(m, n)``) with ramps.

    Finger ``i`` lands ``shifts[i][0]`` frames after the first and lifts ``shifts[i][1]``
    frames later than it would; each frame has each finger's own frame-to-frame noise (its
    recorded frames in a row less their mean).
    """
    profs = [_ramp(_HOLD, a, b) for a, b in shifts]
    T = max(len(p) for p in profs)
    n = touches[0].shape[1]
    out = np.zeros((T, n))
    for F, p in zip(touches, profs, strict=True):
        mean = F.mean(axis=0)
        # consecutive frames, as a live touch's: a touch that creeps over its recording does
        # not creep within a tap
        start = int(rng.integers(0, max(F.shape[0] - T, 0) + 1))
        rows = (start + np.arange(T)) % F.shape[0]
        p = np.concatenate([p, np.zeros(T - len(p))])
        out += p[:, None] * mean[None, :] + (F[rows] - mean[None, :])
    return out


def landing_sets(
    per_touch: list[np.ndarray],
    weights: np.ndarray,
    positions_m: np.ndarray,
    *,
    z_on: float = 8.0,
    min_separation_mm: float = 10.0,
    n_draws: int = 4,
    random_state: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The changes of synthetic single fingers and of shifted pairs made of recorded touches.

    Each touch, ramped up, held and ramped down with its own frame-to-frame noise, is a single
    finger (``n_draws`` each); two touches at least ``min_separation_mm`` apart, the second
    landing and lifting 1-4 frames after the first, are a pair (``n_draws`` per touch). Only
    frames whose peak reaches ``z_on / 2`` noise levels count (the live pipeline's touch).

    Returns
    -------
    singles : (n_touches * n_draws,) float
        Their changes, noise levels.
    pairs : (m,) float
        The pairs' changes.
    pair_index : (m, 2) int
        The pairs' touches (indices into ``per_touch``).
    """
    rng = np.random.default_rng(random_state)
    w = np.asarray(weights, dtype=np.float64)
    ok = [len(F) >= 2 for F in per_touch]
    keep = np.flatnonzero(ok)
    touches = [np.asarray(F, dtype=np.float64) for F, k in zip(per_touch, ok, strict=True) if k]
    pos = np.asarray(positions_m, dtype=np.float64)[ok]

    def change(X: np.ndarray) -> float:
        Z = X * w[None, :]
        keep = Z.max(axis=1) >= 0.5 * z_on  # frames the pipeline would see as touched
        return touch_change(Z[keep]) if keep.sum() > max(LAGS) else 0.0

    singles = np.array(
        [change(_sequence([F], rng, [(0, 0)])) for F in touches for _ in range(n_draws)]
    )
    pairs, idx = [], []
    for i, F in enumerate(touches):
        d = np.linalg.norm(pos - pos[i], axis=1)
        far = np.flatnonzero(d >= 1e-3 * min_separation_mm)
        for j in rng.choice(far, size=min(n_draws, len(far)), replace=False):
            d0, d1 = (int(v) for v in rng.integers(1, 5, size=2))
            pairs.append(change(_sequence([F, touches[j]], rng, [(0, 0), (d0, d1)])))
            idx.append((keep[i], keep[j]))
    return singles, np.asarray(pairs), np.asarray(idx, dtype=np.int64).reshape(-1, 2)


def calibrate_landing(
    per_touch: list[np.ndarray],
    weights: np.ndarray,
    positions_m: np.ndarray,
    *,
    z_on: float = 8.0,
    rate: float = 0.01,
    hold_rate: float = 0.10,
    min_separation_mm: float = 10.0,
    n_draws: int = 4,
    random_state: int = 0,
) -> tuple[float, dict[str, Any]]:
    """The change threshold of a skin from its calibration touches, and what it reaches.

    Parameters
    ----------
    per_touch : list of (m_i, n) float
        Each calibration touch's baseline-subtracted frames, counts.
    weights : (n,) float
        ``1 / sensor noise`` (``contacts.noise_weights``).
    positions_m : (len(per_touch), 3) float
        Where each touch was, m (pairs are of touches at least ``min_separation_mm`` apart).
    z_on : float
        Peak signal, noise levels, from which a frame is a touch's (as the live pipeline).
    rate : float
        Share of single fingers the threshold may call two.
    hold_rate : float
        Share of single fingers above ``hold``, the change from which a one-finger tap is
        held back (not surely one finger).
    n_draws : int
        Synthetic touches per calibration touch (and pairs per touch): ``landing_sets``.

    Returns
    -------
    threshold : float
        The least change above which at most ``rate`` of the single fingers lie (0: fewer
        than 10 touches to calibrate on; the cue is then off).
    report : dict
        ``hold``; ``singles`` and ``pairs`` (how many), ``pairs_found`` (share of pairs above
        the threshold), the singles' ``single_p50`` ... ``single_p97`` and ``pair_p50``.
    """
    if sum(len(F) >= 2 for F in per_touch) < 10:
        return 0.0, {"hold": 0.0, "singles": 0, "pairs": 0}
    singles, pairs_arr, _ = landing_sets(
        per_touch,
        weights,
        positions_m,
        z_on=z_on,
        min_separation_mm=min_separation_mm,
        n_draws=n_draws,
        random_state=random_state,
    )
    k = int(np.floor(rate * len(singles)))  # singles allowed above the threshold
    threshold = float(np.sort(singles)[::-1][k]) * 1.0001
    hold = min(float(np.percentile(singles, 100.0 * (1.0 - hold_rate))), threshold)
    return threshold, {
        "hold": hold,
        "singles": int(len(singles)),
        "pairs": int(len(pairs_arr)),
        "pairs_found": float(np.mean(pairs_arr >= threshold)) if len(pairs_arr) else 0.0,
        "single_p50": float(np.median(singles)),
        "single_p90": float(np.percentile(singles, 90)),
        "single_p95": float(np.percentile(singles, 95)),
        "single_p97": float(np.percentile(singles, 97)),
        "pair_p50": float(np.median(pairs_arr)) if len(pairs_arr) else 0.0,
    }
