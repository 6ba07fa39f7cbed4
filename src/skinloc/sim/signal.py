"""The signal model: the expected baseline-subtracted image of a finger contact.

``sensor_image(layout, params, contact, pressure, radius)`` is the simulator's core, a pure
function; the model is described in ``docs/simulator.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skinloc.sim.layout import SkinLayout
from skinloc.sim.params import SkinParams

__all__ = [
    "apply_weak_lines",
    "finger_terms",
    "FingerTerms",
    "polyline_distance2",
    "sensor_image",
    "silicone_thickness_at",
    "weak_line_mask",
]


def _kernel(d2: np.ndarray, width2: float, exponent: float) -> np.ndarray:
    """``(1 + d^2 / w^2)^-exponent``: 1 right above a point, falling off with distance."""
    return (1.0 + d2 / width2) ** (-exponent)


def polyline_distance2(point: np.ndarray, wires: np.ndarray) -> np.ndarray:
    """Squared distance from ``point (3,)`` to each polyline of ``wires (w, m, 3)``, m^2."""
    a, b = wires[:, :-1], wires[:, 1:]
    ab = b - a
    t = np.clip(
        np.einsum("wsk,wsk->ws", point - a, ab)
        / np.maximum(np.einsum("wsk,wsk->ws", ab, ab), 1e-18),
        0.0,
        1.0,
    )
    closest = a + t[..., None] * ab
    return ((closest - point) ** 2).sum(axis=-1).min(axis=1)


def sensor_image(
    layout: SkinLayout,
    params: SkinParams,
    contact: np.ndarray,
    pressure: float,
    finger_radius_m: float,
) -> np.ndarray:
    """Expected baseline-subtracted image of one finger contact, without noise.

    With ``d_k`` the distance from the contact to sensor k, ``h`` the silicone thickness over
    the contact (``silicone_thickness_at``), ``a`` the finger radius, ``w^2 = h^2 + a^2`` and
    ``K(d; w) = (1 + d^2 / w^2)^-gamma``::

        s_k = P * g_k * [A * (h0 / h) * (K(d_k; r_k w) + c * (K(D_tx(k); w) + K(D_rx(k); w))) + C]

    where ``D_tx(k)``, ``D_rx(k)`` are the distances to the nearest point of the sensor's TX and
    RX wires, ``A`` is ``peak_signal_counts``, ``h0`` ``silicone_thickness_m`` (the top's),
    ``r_k`` the crossing's own width (``layout.width_scales``), ``c`` ``line_coupling``, ``C``
    ``common_mode_counts`` and ``P`` the pressure. Sensors on weak lines respond with
    ``weak_line_gain`` times that, plus ``P * weak_line_offset_counts``.

    Parameters
    ----------
    layout : SkinLayout
        Wiring and per-sensor gains.
    params : SkinParams
        Physical parameters.
    contact : (3,) float
        Contact point on the surface, m.
    pressure : float
        Relative pressure, 1 is a typical touch; 0 gives a zero image.
    finger_radius_m : float
        Contact radius, m.

    Returns
    -------
    (n_tx * n_rx,) float
        Signal in counts (positive: a finger lowers the mutual capacitance).

    Examples
    --------
    >>> from skinloc.geometry.mesh import cone_skin
    >>> layout = SkinLayout.generate(cone_skin(), 8, 8, random_state=0)
    >>> img = sensor_image(layout, SkinParams.default(), layout.sensor_positions[9], 1.0, 0.006)
    >>> int(np.argmax(img))
    9
    """
    terms = finger_terms(layout, params, contact, pressure, finger_radius_m)  # checks them
    along = (terms.line_tx[:, None] + terms.line_rx[None, :]).ravel()
    signal = layout.gains * (terms.local + along + pressure * params.common_mode_counts)
    return apply_weak_lines(layout, params, signal, pressure)


@dataclass(frozen=True)
class FingerTerms:
    """The parts of one finger's image before the sensors' gains, counts.

    Attributes
    ----------
    local : (n_sensors,) float
        ``P A (h0 / h) K(d_k; r_k w)``: the field the finger takes from each crossing.
    line_tx : (n_tx,) float
        ``P A (h0 / h) c K(D_tx; w)``: what it takes from each whole TX line.
    line_rx : (n_rx,) float
        The same for each RX line.
    couple_tx : (n_tx,) float
        ``P (h0 / h) K(D_tx; w)``: the finger's relative capacitive coupling to each TX line.
    couple_rx : (n_rx,) float
        The same for each RX line.
    """

    local: np.ndarray
    line_tx: np.ndarray
    line_rx: np.ndarray
    couple_tx: np.ndarray
    couple_rx: np.ndarray


def finger_terms(
    layout: SkinLayout,
    params: SkinParams,
    contact: np.ndarray,
    pressure: float,
    finger_radius_m: float,
) -> FingerTerms:
    """The parts of one finger's image (``sensor_image`` adds them); see ``FingerTerms``."""
    contact = np.asarray(contact, dtype=np.float64)
    if contact.shape != (3,):
        raise ValueError(f"contact must have shape (3,), got {contact.shape}")
    if not (np.isfinite(pressure) and pressure >= 0):
        raise ValueError(f"pressure must be a finite value >= 0, got {pressure!r}")
    if not (np.isfinite(finger_radius_m) and finger_radius_m > 0):
        raise ValueError(f"finger_radius_m must be > 0, got {finger_radius_m!r}")
    h = silicone_thickness_at(layout, params, contact)
    width2 = h**2 + finger_radius_m**2
    gamma = params.falloff_exponent
    d2 = ((layout.sensor_positions - contact) ** 2).sum(axis=1)
    scales = np.ones(layout.n_sensors) if layout.width_scales is None else layout.width_scales
    local = _kernel(d2, width2 * scales**2, gamma)
    k_tx = _kernel(polyline_distance2(contact, layout.tx_wires), width2, gamma)
    k_rx = _kernel(polyline_distance2(contact, layout.rx_wires), width2, gamma)
    # Parallel-plate coupling through the dielectric: the signal falls as 1 / thickness.
    relative = pressure * params.silicone_thickness_m / h
    amplitude = relative * params.peak_signal_counts
    line = amplitude * params.line_coupling
    return FingerTerms(
        local=amplitude * local,
        line_tx=line * k_tx,
        line_rx=line * k_rx,
        couple_tx=relative * k_tx,
        couple_rx=relative * k_rx,
    )


def weak_line_mask(layout: SkinLayout, params: SkinParams) -> np.ndarray:
    """``(n_sensors,) bool``: the sensors on a weak TX or RX line."""
    weak = np.zeros((layout.n_tx, layout.n_rx), dtype=bool)
    weak[[i for i in params.weak_tx_lines if i < layout.n_tx], :] = True
    weak[:, [j for j in params.weak_rx_lines if j < layout.n_rx]] = True
    return weak.ravel()


def apply_weak_lines(
    layout: SkinLayout, params: SkinParams, signal: np.ndarray, pressure: float
) -> np.ndarray:
    """Sensors on weak lines give ``weak_line_gain`` x their signal + ``pressure`` x offset.

    ``pressure`` is the total over the fingers on the skin; ``signal`` is changed in place.
    """
    weak = weak_line_mask(layout, params)
    signal[weak] = params.weak_line_gain * signal[weak] + pressure * params.weak_line_offset_counts
    return signal


def silicone_thickness_at(layout: SkinLayout, params: SkinParams, point: np.ndarray) -> float:
    """Silicone thickness over ``point (3,)`` m: linear in y from the top to the base, m.

    A skin moulded on a standing cone is thicker at its base; ``silicone_thickness_m`` is the
    thickness at the highest y of the mesh and ``silicone_thickness_base_m`` at the lowest.
    """
    top, base = params.silicone_thickness_m, params.silicone_thickness_base_m
    if layout.height_range_m is None or base == top:
        return top
    lo, hi = layout.height_range_m
    depth = 0.0 if hi <= lo else float(np.clip((hi - point[1]) / (hi - lo), 0.0, 1.0))
    return top + (base - top) * depth
