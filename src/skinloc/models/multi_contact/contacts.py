"""The multi-contact search's result and count rule (the method: the package docstring).

``ContactSet``: the contacts of one frame; ``CountRule``: how many fingers an image holds;
``noise_weights``: each sensor's weight in the search.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = [
    "PRM_MIN2",
    "PRM_MISFIT",
    "PRM_N_TOP",
    "PRM_TAU2",
    "PRM_TAU3",
    "PRM_Z2_MIN",
    "PRM_Z3_MIN",
    "PRM_Z_ON",
    "PRM_Z_POWER",
    "ContactSet",
    "CountRule",
    "noise_weights",
]

#: Noise per sensor assumed when a model does not know its skin's (counts; the paper skin's
#: median no-touch std is 4.8).
DEFAULT_NOISE_COUNTS = 5.0
#: Columns of a search's output rows: x, y, z (m), strength (counts), uncertainty (mm).
N_COLS = 5


def noise_weights(sensor_noise: np.ndarray | None, k: int) -> np.ndarray:
    """``1 / sigma (k,)`` float32 from the noise per sensor (counts; ``None``: the default).

    Sigma is floored at the median noise: a sensor quieter than the rest is not trusted more
    than them (its quiet is more likely a dead line than a better one).
    """
    if sensor_noise is None:
        return np.full(k, 1.0 / DEFAULT_NOISE_COUNTS, dtype=np.float32)
    noise = np.asarray(sensor_noise, dtype=np.float64).reshape(-1)
    if noise.shape != (k,):
        raise ValueError(f"sensor noise must have shape ({k},), got {noise.shape}")
    sigma = np.maximum(noise, max(float(np.median(noise)), 1.0))
    return (1.0 / sigma).astype(np.float32)


# The compiled search's parameters (``CountRule.params``), by slot.
PRM_Z_ON, PRM_MIN2, PRM_TAU2, PRM_TAU3, PRM_N_TOP = 0, 1, 2, 3, 4
PRM_Z2_MIN, PRM_Z3_MIN, PRM_MISFIT, PRM_Z_POWER = 5, 6, 7, 8


@dataclass(frozen=True)
class CountRule:
    """How many contacts an image holds (see the module's docstring).

    Attributes
    ----------
    z_on : float
        Peak signal, in noise levels, of a contact (the live pipeline's ``touch_on_z``).
    min_separation_mm : float
        Closest two contacts may be, mm (closer ones are one finger to this model).
    tau2, tau3 : float
        Relative residual reduction that a 2nd (3rd) contact must bring.
    z2_min, z3_min : float
        Peak signal, noise levels, that the weakest of 2 (3) contacts must reach (at least
        ``z_on``).
    n_top : int
        Seeds of the pair search.
    misfit : float
        The share of a single touch's (whitened) energy the model leaves unexplained, typical
        of a touch it was not trained on (median over the calibration's held-out touches); the
        residual reduction is measured against the residual plus this much of the image's
        energy, so that a strong touch's own misfit does not pass for a second finger. 0 (rules
        saved before it): against the residual alone.
    calibrated : bool
        Whether tau2 and tau3 come from cross-validation on the training recording.
    z_power : float
        Power of the weakest contact's peak signal that weighs the relative reduction (0, rules
        saved before it: the reduction alone).
    landing_change : float
        The change of a touch's image while it lands and lifts, noise levels, above which a
        touch seen as one finger holds two (``multi_contact.landing``; calibrated in ``fit``
        from the skin's own touches; 0, rules saved before it: the cue is off).
    landing_hold : float
        The change above which a touch is no longer surely one finger (the calibration's
        single fingers' 90th percentile): the recogniser reports no tap of it (0: off).
    footprint_weights : tuple of float
        The footprint score's weights (``multi_contact.footprint``: how much wider and fuller
        than one finger's the image is at its place), calibrated in ``fit``; empty (rules
        saved before it): the cue is off.
    footprint_two : float
        The footprint score from which an image seen as one finger holds two (calls at most
        2 % of the calibration's held-out single touches two).
    footprint_hold : float
        The score from which it is no longer surely one finger (5 % of them).
    """

    z_on: float = 8.0
    min_separation_mm: float = 30.0
    tau2: float = 1.0
    tau3: float = 1.0
    z2_min: float = 8.0
    z3_min: float = 8.0
    n_top: int = 12
    calibrated: bool = False
    misfit: float = 0.0
    z_power: float = 0.0
    landing_change: float = 0.0
    landing_hold: float = 0.0
    footprint_weights: tuple[float, ...] = ()
    footprint_two: float = 0.0
    footprint_hold: float = 0.0

    def __post_init__(self) -> None:
        # JSON gives a list: kept as a tuple, so that the rule stays hashable
        object.__setattr__(
            self, "footprint_weights", tuple(float(v) for v in self.footprint_weights)
        )

    @property
    def footprint_on(self) -> bool:
        """Whether the rule has a calibrated footprint cue."""
        return len(self.footprint_weights) > 0

    def as_dict(self) -> dict[str, Any]:
        """The rule as plain JSON values."""
        d = asdict(self)
        d["footprint_weights"] = list(self.footprint_weights)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> CountRule:
        """The rule of ``as_dict`` (unknown keys ignored; ``None``: the defaults)."""
        if not d:
            return cls()
        names = cls.__dataclass_fields__
        return cls(**{k: v for k, v in d.items() if k in names})

    def params(self) -> np.ndarray:
        """The kernels' parameters, by the ``PRM_*`` slots.

        z_on, min separation^2 (m^2), tau2, tau3, n_top, z2_min, z3_min, misfit, z_power.
        """
        return np.array(
            [
                self.z_on,
                (1e-3 * self.min_separation_mm) ** 2,
                self.tau2,
                self.tau3,
                self.n_top,
                max(self.z2_min, self.z_on),
                max(self.z3_min, self.z_on),
                max(self.misfit, 0.0),
                max(self.z_power, 0.0),
            ],
            dtype=np.float64,
        )


class ContactSet:
    """The contacts of one frame, strongest first.

    Attributes
    ----------
    rows : (k, 5) float64
        Per contact: x, y, z (m), strength (counts), uncertainty (mm).
    positions_m : (k, 3) float64
        Contact points on the skin, m.
    strength : (k,) float64
        Contact strengths, counts (the L2 norm of each contact's image's positive part).
    uncertainty_mm : (k,) float64
        Per-contact uncertainty, mm (nan when the model has none).
    """

    __slots__ = ("rows",)

    def __init__(self, rows: np.ndarray) -> None:
        # one (k, 5) block, its columns viewed on access: one allocation per frame
        self.rows = rows

    @property
    def positions_m(self) -> np.ndarray:
        """``(k, 3)`` contact points, m."""
        return self.rows[:, :3]

    @property
    def strength(self) -> np.ndarray:
        """``(k,)`` strengths, counts."""
        return self.rows[:, 3]

    @property
    def uncertainty_mm(self) -> np.ndarray:
        """``(k,)`` uncertainties, mm."""
        return self.rows[:, 4]

    def __len__(self) -> int:
        return len(self.rows)

    def __repr__(self) -> str:
        return f"ContactSet({len(self)} contacts)"

    def to_json(self) -> list[dict[str, Any]]:
        """``[{"position_m": [x, y, z], "uncertainty_mm": u, "strength": s}, ...]``."""
        return [
            {
                "position_m": [float(v) for v in p],
                "uncertainty_mm": None if not math.isfinite(u) else float(u),
                "strength": None if not math.isfinite(s) else float(s),
            }
            for p, s, u in zip(
                self.positions_m.tolist(),
                self.strength.tolist(),
                self.uncertainty_mm.tolist(),
                strict=True,
            )
        ]
