"""The response map's prior, learned from simulated skins: what every skin's map shares.

A skin's layout (where its crossings lie) differs from skin to skin, but how a crossing
responds does not: the width of its footprint on the surface (the GP's length scale), the size
of the shape features' variation (the GP's amplitude) and the touch-to-touch scatter (its
noise), and what a feature is worth where no touch has been made (a sensor's share of an image
it took no part in). ``skinloc prior build`` (``skinloc.sim.prior_build``) measures
these on many simulated skins and writes them to a small JSON file shipped in the package
(``map_prior.json``). A response map fitted with the prior then

- chooses its hyperparameters by maximum a posteriori instead of maximum likelihood: the
  marginal likelihood of the touches plus a log-normal prior per hyperparameter, so a handful
  of touches cannot pick a length scale no skin has, while many touches outweigh the prior;
- shrinks its mean feature towards the skins' common level with ``mean_pseudo_touches``
  pseudo-touches, so that far from every touch the map does not predict the average of the
  few images it saw.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.files import atomic_write

__all__ = ["HYPERPARAMETERS", "PRIOR_FORMAT_VERSION", "MapPrior", "load_prior"]

#: Written into every prior file; a file of another version is refused.
PRIOR_FORMAT_VERSION = 1
#: The GP's hyperparameters in the order of its kernel's ``theta`` (all on a log scale).
HYPERPARAMETERS = ("amplitude", "length_scale_mm", "noise")
_PACKAGE_FILE = "map_prior.json"


@dataclass(frozen=True)
class MapPrior:
    """Log-normal priors on the GP's hyperparameters and the mean's shrinkage.

    Attributes
    ----------
    log_mean : (3,) float
        Mean of log amplitude, log length scale (mm) and log noise over the simulated skins.
    log_std : (3,) float
        Their spread over the skins (floored, so that the prior never pins a value).
    common_feature : float
        Mean shape feature of a sensor over every touch of every skin (the level a sensor's
        feature takes where nothing is known), dimensionless.
    mean_pseudo_touches : float
        Weight of ``common_feature`` in the map's mean, in touches.
    max_touches : int
        The prior is applied to calibrations of at most this many touches: the most for
        which it lowered the error on the simulated skins that chose it (beyond, the touches
        determine the map alone and the prior only costs a little).
    provenance : dict
        How the prior was built (command, skins, seeds, time).
    version : int
        ``PRIOR_FORMAT_VERSION``.
    """

    log_mean: tuple[float, float, float]
    log_std: tuple[float, float, float]
    common_feature: float
    mean_pseudo_touches: float
    max_touches: int
    provenance: dict[str, Any] = field(default_factory=dict)
    version: int = PRIOR_FORMAT_VERSION

    def __post_init__(self) -> None:
        if len(self.log_mean) != 3 or len(self.log_std) != 3:
            raise ValueError("a map prior needs 3 log means and 3 log stds")
        if not all(np.isfinite(self.log_mean)) or not all(s > 0 for s in self.log_std):
            raise ValueError("a map prior's log means must be finite and its log stds > 0")
        if not self.mean_pseudo_touches >= 0 or not np.isfinite(self.common_feature):
            raise ValueError("a map prior's mean_pseudo_touches must be >= 0")
        if self.max_touches < 0:
            raise ValueError("a map prior's max_touches must be >= 0")

    def applies(self, n_touches: int) -> bool:
        """Whether a calibration of ``n_touches`` touches is fitted with this prior."""
        return 0 < n_touches <= self.max_touches

    @property
    def typical(self) -> dict[str, float]:
        """The prior's median of each hyperparameter (length scale in mm)."""
        return {k: float(np.exp(m)) for k, m in zip(HYPERPARAMETERS, self.log_mean, strict=True)}

    def log_density(self, theta: np.ndarray) -> tuple[float, np.ndarray]:
        """Log prior of ``theta (3,)`` (log hyperparameters, kernel order) and its gradient."""
        z = (np.asarray(theta) - np.asarray(self.log_mean)) / np.asarray(self.log_std)
        return float(-0.5 * (z**2).sum()), -z / np.asarray(self.log_std)

    def mean(self, F: np.ndarray) -> np.ndarray:
        """The map's mean feature for calibration features ``F (n, k)``: ``(k,)``.

        The touches' mean, shrunk towards ``common_feature`` by ``mean_pseudo_touches``.
        """
        n, w = len(F), self.mean_pseudo_touches
        return (F.sum(axis=0) + w * self.common_feature) / (n + w)

    def save(self, path: str | Path) -> None:
        """Write the prior as JSON, atomically."""
        text = json.dumps(asdict(self), indent=1) + "\n"
        atomic_write(Path(path), lambda tmp: tmp.write_text(text))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> MapPrior:
        """The prior from its JSON fields; ``ValueError`` for another version or bad values."""
        if d.get("version") != PRIOR_FORMAT_VERSION:
            raise ValueError(
                f"map prior of version {d.get('version')!r}; this skinloc reads version "
                f"{PRIOR_FORMAT_VERSION} (rebuild it with `skinloc prior build`)"
            )
        return cls(
            log_mean=tuple(float(v) for v in d["log_mean"]),
            log_std=tuple(float(v) for v in d["log_std"]),
            common_feature=float(d["common_feature"]),
            mean_pseudo_touches=float(d["mean_pseudo_touches"]),
            max_touches=int(d["max_touches"]),
            provenance=dict(d.get("provenance", {})),
        )


def load_prior(path: str | Path | None = None) -> MapPrior:
    """The prior in ``path``, or the one shipped in the package (``path=None``).

    Raises ``ValueError`` with a one-line message for a file that is not a map prior.
    """
    where = "the package's map prior" if path is None else str(path)
    try:
        if path is None:
            text = resources.files("skinloc.models").joinpath(_PACKAGE_FILE).read_text()
        else:
            text = Path(path).read_text()
        data = json.loads(text)
    except (OSError, json.JSONDecodeError) as exc:
        raise ValueError(f"cannot read {where} as a map prior: {exc}") from None
    try:
        return MapPrior.from_dict(data)
    except (KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"cannot read {where} as a map prior: no {exc}") from None
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None
