"""Several fingers on the simulated skin at once: the physics that is not a sum of images.

One finger's image is ``signal.sensor_image``. With several fingers, three things make the
image differ from the sum of their single images (docs/simulator.md, "Several fingers"):

- **A crossing's fringe field is finite.** Each finger takes a share of the field that is left:
  ``S (1 - prod_f (1 - x_f))`` with ``x_f`` the finger's single-finger local signal over
  ``S = crossing_saturation_counts``.
- **A line's drive is shared.** A finger loads the TX or RX line it sits on (an admittance in
  parallel with the line's own), so the line loses ``M y / (1 + y)`` of its drive with
  ``y = sum_f y_f``, ``y_f = d_f / (1 - d_f)`` and ``d_f`` the finger's single-finger line
  signal over ``M = line_saturation_counts``: two fingers on one line take less than twice one.
- **The body re-transmits.** The hand is one conductor: it picks up the driven TX line under one
  finger and puts that signal back into the RX lines under every other finger, raising the
  mutual coupling there (a negative signal) by ``rho A sum_{f != g} u_f[tx] v_g[rx]``, with
  ``rho = body_retransmission`` and ``u``, ``v`` the fingers' couplings to the lines. The part of
  this with one finger (``f == g``) is in the fitted single-finger image already.

Each formula gives exactly the single-finger image for one finger.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from skinloc.sim.layout import SkinLayout
from skinloc.sim.params import SkinParams
from skinloc.sim.signal import apply_weak_lines, finger_terms, polyline_distance2, sensor_image

__all__ = ["Finger", "multi_touch_image", "nearest_lines", "summed_image"]

_MAX_SHARE = 0.999  # a finger never takes the whole field of a crossing or a line


@dataclass(frozen=True)
class Finger:
    """One finger on the skin.

    Attributes
    ----------
    position_m : (3,) float
        Contact point on the surface, m.
    pressure : float
        Relative pressure, 1 is a typical touch.
    radius_m : float
        Contact radius, m.
    """

    position_m: np.ndarray
    pressure: float = 1.0
    radius_m: float = 0.010


def _share(parts: np.ndarray, scale: float) -> np.ndarray:
    """``scale (1 - prod (1 - parts / scale))`` over axis 0: shares of a finite field, counts."""
    x = np.clip(parts / scale, 0.0, _MAX_SHARE)
    return scale * (1.0 - np.prod(1.0 - x, axis=0))


def _load(parts: np.ndarray, scale: float) -> np.ndarray:
    """Drive lost by a line loaded by several fingers in parallel, counts (axis 0: fingers)."""
    d = np.clip(parts / scale, 0.0, _MAX_SHARE)
    y = (d / (1.0 - d)).sum(axis=0)
    return scale * y / (1.0 + y)


def multi_touch_image(
    layout: SkinLayout, params: SkinParams, fingers: Sequence[Finger]
) -> np.ndarray:
    """Expected baseline-subtracted image of several fingers at once, without noise.

    Parameters
    ----------
    layout : SkinLayout
        Wiring and per-sensor gains.
    params : SkinParams
        Physical parameters (``crossing_saturation_counts``, ``line_saturation_counts`` and
        ``body_retransmission`` set the interaction).
    fingers : sequence of Finger
        The fingers on the skin; none gives a zero image, one gives ``sensor_image``'s.

    Returns
    -------
    (n_tx * n_rx,) float
        Signal in counts.
    """
    if len(fingers) == 0:
        return np.zeros(layout.n_sensors)
    if len(fingers) == 1:
        f = fingers[0]
        return sensor_image(layout, params, f.position_m, f.pressure, f.radius_m)
    terms = [finger_terms(layout, params, f.position_m, f.pressure, f.radius_m) for f in fingers]
    local = _share(np.stack([t.local for t in terms]), params.crossing_saturation_counts)
    m = params.line_saturation_counts
    line_tx = _load(np.stack([t.line_tx for t in terms]), m)
    line_rx = _load(np.stack([t.line_rx for t in terms]), m)
    u = np.stack([t.couple_tx for t in terms])  # (fingers, n_tx)
    v = np.stack([t.couple_rx for t in terms])  # (fingers, n_rx)
    # Cross terms only (f != g): all pairs minus each finger with itself.
    cross = np.outer(u.sum(axis=0), v.sum(axis=0)) - u.T @ v
    retrans = params.body_retransmission * params.peak_signal_counts * cross
    pressure = float(sum(f.pressure for f in fingers))
    signal = (
        local
        + (line_tx[:, None] + line_rx[None, :] - retrans).ravel()
        + pressure * params.common_mode_counts
    )
    return apply_weak_lines(layout, params, layout.gains * signal, pressure)


def summed_image(layout: SkinLayout, params: SkinParams, fingers: Sequence[Finger]) -> np.ndarray:
    """The sum of the fingers' single images, ``(n_sensors,)`` counts: what a sum model assumes."""
    out = np.zeros(layout.n_sensors)
    for f in fingers:
        out += sensor_image(layout, params, f.position_m, f.pressure, f.radius_m)
    return out


def nearest_lines(layout: SkinLayout, point: np.ndarray) -> tuple[int, int]:
    """The TX and RX lines (electrical indices) whose wires pass nearest ``point (3,)`` m."""
    point = np.asarray(point, dtype=np.float64).reshape(3)
    tx = int(np.argmin(polyline_distance2(point, layout.tx_wires)))
    rx = int(np.argmin(polyline_distance2(point, layout.rx_wires)))
    return tx, rx
