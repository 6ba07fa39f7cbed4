"""Physical parameters of the simulated skin (``SkinParams``) and their fitted defaults.

Every field, its unit and how it was set are in ``docs/simulator.md`` and the package file
``sim/fitted_skin.toml``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 needs the tomli backport
    import tomli as tomllib

__all__ = ["COUNT_MAX", "SkinParams"]

#: Largest raw count (16-bit).
COUNT_MAX = 65535.0


def _default_toml() -> Path:
    return Path(str(resources.files("skinloc.sim") / "fitted_skin.toml"))


@dataclass(frozen=True)
class SkinParams:
    """Physical parameters of the simulated skin; units are in the names.

    Lengths are metres, signals raw counts, times seconds. ``SkinParams.default()`` loads the
    values fitted to the real recordings from the package file ``sim/fitted_skin.toml``, which
    comments every field; ``dataclasses.replace(params, field=value)`` makes a variant.

    Raises
    ------
    ValueError
        From ``__post_init__``, naming the field and the value, when a value is out of range.
    """

    # wiring
    spacing_jitter: float = 0.3
    wire_wobble: float = 0.15
    edge_margin: float = 0.5
    shuffle_lines: bool = True
    # touch signal
    silicone_thickness_m: float = 0.006
    silicone_thickness_base_m: float = 0.013
    peak_signal_counts: float = 300.0
    falloff_exponent: float = 1.3
    line_coupling: float = 0.12
    common_mode_counts: float = 1.5
    finger_radius_m: float = 0.010
    finger_radius_std_m: float = 0.001
    pressure_std: float = 0.2
    radius_pressure_exponent: float = 0.333
    weak_touch_prob: float = 0.15
    weak_touch_pressure: float = 0.3
    crossing_width_std: float = 0.0
    probe_error_std_m: float = 0.0053
    # several fingers at once (sim/fingers.py)
    crossing_saturation_counts: float = 1900.0
    line_saturation_counts: float = 200.0
    body_retransmission: float = 0.1
    # per-sensor electronics
    gain_std: float = 0.2
    baseline_mean_counts: float = 9500.0
    baseline_line_std_counts: float = 1000.0
    baseline_sensor_std_counts: float = 500.0
    baseline_min_counts: float = 3000.0
    baseline_max_counts: float = 12000.0
    noise_std_counts: float = 4.8
    noise_std_spread_counts: float = 0.5
    noise_std_min_counts: float = 3.4
    noise_std_max_counts: float = 5.7
    # faults
    weak_rx_lines: tuple[int, ...] = (3,)
    weak_tx_lines: tuple[int, ...] = ()
    weak_line_gain: float = 0.35
    weak_line_offset_counts: float = -8.0
    noisy_sensors: tuple[tuple[int, int], ...] = ((1, 7),)
    noisy_sensor_noise_std_counts: float = 50.0
    # drift
    drift_std_counts: float = 3.0
    drift_time_constant_s: float = 300.0

    def __post_init__(self) -> None:
        # TOML gives lists; store tuples so the dataclass stays hashable and immutable.
        object.__setattr__(self, "weak_rx_lines", tuple(int(i) for i in self.weak_rx_lines))
        object.__setattr__(self, "weak_tx_lines", tuple(int(i) for i in self.weak_tx_lines))
        object.__setattr__(
            self, "noisy_sensors", tuple((int(t), int(r)) for t, r in self.noisy_sensors)
        )
        checks: dict[str, tuple[bool, str]] = {
            "spacing_jitter": (0.0 <= self.spacing_jitter < 0.5, "in [0, 0.5)"),
            "wire_wobble": (0.0 <= self.wire_wobble <= 0.5, "in [0, 0.5]"),
            "edge_margin": (0.0 < self.edge_margin <= 1.0, "in (0, 1]"),
            "silicone_thickness_m": (0.0 < self.silicone_thickness_m < 0.1, "in (0, 0.1) m"),
            "silicone_thickness_base_m": (
                0.0 < self.silicone_thickness_base_m < 0.1,
                "in (0, 0.1) m",
            ),
            "peak_signal_counts": (self.peak_signal_counts >= 0.0, ">= 0 counts"),
            "falloff_exponent": (0.0 < self.falloff_exponent <= 10.0, "in (0, 10]"),
            "line_coupling": (0.0 <= self.line_coupling <= 1.0, "in [0, 1]"),
            "finger_radius_m": (0.0 < self.finger_radius_m < 0.05, "in (0, 0.05) m"),
            "finger_radius_std_m": (0.0 <= self.finger_radius_std_m < 0.02, "in [0, 0.02) m"),
            "pressure_std": (0.0 <= self.pressure_std <= 2.0, "in [0, 2]"),
            "radius_pressure_exponent": (0.0 <= self.radius_pressure_exponent <= 1.0, "in [0, 1]"),
            "weak_touch_prob": (0.0 <= self.weak_touch_prob <= 1.0, "in [0, 1]"),
            "weak_touch_pressure": (0.0 < self.weak_touch_pressure <= 1.0, "in (0, 1]"),
            "crossing_width_std": (0.0 <= self.crossing_width_std <= 1.0, "in [0, 1]"),
            "probe_error_std_m": (0.0 <= self.probe_error_std_m < 0.05, "in [0, 0.05) m"),
            "crossing_saturation_counts": (self.crossing_saturation_counts > 0.0, "> 0 counts"),
            "line_saturation_counts": (self.line_saturation_counts > 0.0, "> 0 counts"),
            "body_retransmission": (0.0 <= self.body_retransmission <= 1.0, "in [0, 1]"),
            "gain_std": (0.0 <= self.gain_std <= 2.0, "in [0, 2]"),
            "baseline_line_std_counts": (self.baseline_line_std_counts >= 0, ">= 0 counts"),
            "baseline_sensor_std_counts": (self.baseline_sensor_std_counts >= 0, ">= 0 counts"),
            "baseline_min_counts": (
                0.0 <= self.baseline_min_counts <= self.baseline_max_counts <= COUNT_MAX,
                "with 0 <= baseline_min_counts <= baseline_max_counts <= 65535",
            ),
            "baseline_mean_counts": (
                self.baseline_min_counts <= self.baseline_mean_counts <= self.baseline_max_counts,
                "between baseline_min_counts and baseline_max_counts",
            ),
            "noise_std_counts": (self.noise_std_counts >= 0.0, ">= 0 counts"),
            "noise_std_spread_counts": (self.noise_std_spread_counts >= 0.0, ">= 0 counts"),
            "noise_std_min_counts": (
                0.0 <= self.noise_std_min_counts <= self.noise_std_max_counts,
                "with 0 <= noise_std_min_counts <= noise_std_max_counts",
            ),
            "weak_line_gain": (0.0 <= self.weak_line_gain <= 1.0, "in [0, 1]"),
            "noisy_sensor_noise_std_counts": (
                self.noisy_sensor_noise_std_counts >= 0.0,
                ">= 0 counts",
            ),
            "drift_std_counts": (self.drift_std_counts >= 0.0, ">= 0 counts"),
            "drift_time_constant_s": (self.drift_time_constant_s > 0.0, "> 0 s"),
        }
        for name, (ok, allowed) in checks.items():
            value = getattr(self, name)
            if not (ok and np.all(np.isfinite(value))):
                raise ValueError(f"SkinParams.{name} must be {allowed}, got {value!r}")
        for name in ("weak_rx_lines", "weak_tx_lines"):
            if any(i < 0 for i in getattr(self, name)):
                raise ValueError(
                    f"SkinParams.{name} must hold indices >= 0, got {getattr(self, name)!r}"
                )
        if any(t < 0 or r < 0 for t, r in self.noisy_sensors):
            raise ValueError(
                f"SkinParams.noisy_sensors must hold [tx, rx] >= 0, got {self.noisy_sensors!r}"
            )

    @classmethod
    def from_toml(cls, path: str | Path) -> SkinParams:
        """Load parameters from a TOML file of ``field = value`` lines (unknown keys raise)."""
        with Path(path).open("rb") as fh:
            raw: dict[str, Any] = tomllib.load(fh)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(raw) - known)
        if unknown:
            raise ValueError(f"unknown SkinParams field(s) in {path}: {', '.join(unknown)}")
        return cls(**raw)

    @classmethod
    def default(cls) -> SkinParams:
        """The parameters fitted to the paper's skin (package file ``sim/fitted_skin.toml``)."""
        return cls.from_toml(_default_toml())
