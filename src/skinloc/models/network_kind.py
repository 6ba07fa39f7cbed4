"""The ``network`` model kind: an ensemble of fully connected networks trained in PyTorch.

Registered in ``models.kinds``; the localiser, the model file and the exports reach it only
through the ``ModelKind`` methods here. Training needs the ``nets`` extra, prediction does not.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from skinloc._lazy import resolve
from skinloc.models.network_training import fit_network

__all__ = ["ACTIVATIONS", "NetworkConfig", "NetworkKind"]

#: Hidden activations a network may use.
ACTIVATIONS = ("relu", "tanh", "gelu")


@dataclass(frozen=True)
class NetworkConfig:
    """A network ensemble's hyperparameters (``ContactLocalizer``'s documents them)."""

    hidden: tuple[int, ...]
    activation: str
    n_members: int
    epochs: int
    lr: float
    weight_decay: float
    noise_std: float

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> NetworkConfig:
        """The network's settings of a localiser's config, checked (``ValueError`` naming one)."""

        def bad(name: str, allowed: str) -> ValueError:
            return ValueError(
                f"the {name!r} parameter of ContactLocalizer must be {allowed}; got {cfg[name]!r}"
            )

        if not cfg["hidden"] or any(h < 1 for h in cfg["hidden"]):
            raise bad("hidden", "a non-empty tuple of positive ints")
        if cfg["activation"] not in ACTIVATIONS:
            raise bad("activation", f"one of {', '.join(ACTIVATIONS)}")
        if not (isinstance(cfg["n_members"], int) and cfg["n_members"] >= 1):
            raise bad("n_members", "an int >= 1")
        if not (isinstance(cfg["epochs"], int) and cfg["epochs"] >= 1):
            raise bad("epochs", "an int >= 1")
        if not cfg["lr"] > 0:
            raise bad("lr", "a float > 0")
        if not cfg["weight_decay"] >= 0:
            raise bad("weight_decay", "a float >= 0")
        if not cfg["noise_std"] >= 0:
            raise bad("noise_std", "a float >= 0")
        return cls(
            tuple(int(h) for h in cfg["hidden"]),
            cfg["activation"],
            cfg["n_members"],
            cfg["epochs"],
            float(cfg["lr"]),
            float(cfg["weight_decay"]),
            float(cfg["noise_std"]),
        )


class NetworkKind:
    """The ``network`` kind (see ``models.kinds.ModelKind``)."""

    name = "network"
    config_type = NetworkConfig
    fitted_attrs = ("coefs_", "intercepts_")
    needs_surface_points = False
    train_extra = "torch"  # the nets extra
    quick_fit = False  # an ensemble trains for minutes
    summary = "an ensemble of fully connected networks, outputs snapped to the surface"

    def fit(
        self,
        model: Any,
        X: np.ndarray,
        y: np.ndarray,
        frames: tuple[np.ndarray, np.ndarray | None],
        groups: np.ndarray | None,
        progress: Callable[[int, int], None] | None,
    ) -> None:
        """Standardise features and targets, then train the ensemble."""
        cfg = model.config_
        F = model._features(X, cfg)
        model.feature_mean_ = F.mean(axis=0)
        model.feature_scale_ = np.maximum(F.std(axis=0), 1e-6 * max(F.std(), 1e-12))
        model.target_mean_ = y.mean(axis=0)
        model.target_scale_ = float(np.maximum(y.std(axis=0).max(), 1e-6))
        fit_network(model, X, y, cfg["epochs"], cfg["lr"], progress)

    def recalibrate(
        self,
        model: Any,
        new: Any,
        X: np.ndarray,
        y: np.ndarray,
        groups: np.ndarray | None,
        progress: Callable[[int, int], None] | None,
    ) -> None:
        """Fine-tune from the weights with a short, gentle schedule."""
        from skinloc.models.localizer import group_means

        if model.config_["train_on"] == "means" and groups is not None:
            X, y = group_means(X, y, groups)
        epochs = max(50, model.config_["epochs"] // 4)
        fit_network(new, X, y, epochs, model.config_["lr"] / 10, progress)
        new.recalibration_ = {
            "method": "fine-tuned",
            "n_touches": int(len(np.unique(groups)) if groups is not None else len(X)),
            "summary": f"fine-tuned the network on the new touches ({epochs} epochs)",
        }

    def spec(self, model: Any, common: dict[str, Any]) -> Any:
        """The ensemble's ``NetworkSpec``."""
        from skinloc.models.network_engine import NetworkSpec

        cfg = model.config_
        return NetworkSpec(
            **common,
            constraint=cfg["constraint"],
            surface_points=model.surface_points_,
            normalise=cfg["normalise"],
            activation=cfg["activation"],
            feature_mean=np.asarray(model.feature_mean_, dtype=np.float64),
            feature_scale=np.asarray(model.feature_scale_, dtype=np.float64),
            weights=[np.asarray(W, dtype=np.float64) for W in model.coefs_],
            biases=[np.asarray(b, dtype=np.float64) for b in model.intercepts_],
            target_mean=np.asarray(model.target_mean_, dtype=np.float64).reshape(3),
            target_scale=float(model.target_scale_),
        )

    def write(self, model: Any, f: Any) -> None:
        """The ``preprocessing`` and ``network`` groups."""
        f.attrs["description"] = (
            "x: baseline-subtracted counts (n_features_in,). features: clip/normalise per "
            "config, then (x - feature_mean) / feature_scale. layers: h = act(h @ W + b) "
            "per member; output * target_scale + target_mean is metres; ensemble mean."
        )
        p = f.create_group("preprocessing")
        p["feature_mean"], p["feature_scale"] = model.feature_mean_, model.feature_scale_
        p["target_mean"] = model.target_mean_
        p.attrs["target_scale"] = model.target_scale_
        net = f.create_group("network")
        for i, (W, b) in enumerate(zip(model.coefs_, model.intercepts_, strict=True)):
            net[f"layer{i}/weight"], net[f"layer{i}/bias"] = W, b

    def read(self, model: Any, f: Any) -> None:
        """The preprocessing arrays and every layer's weights."""
        p = f["preprocessing"]
        model.feature_mean_ = p["feature_mean"][()]
        model.feature_scale_ = p["feature_scale"][()]
        model.target_mean_ = p["target_mean"][()]
        model.target_scale_ = float(p.attrs["target_scale"])
        net = f["network"]
        model.coefs_ = [net[f"layer{i}/weight"][()] for i in range(len(net))]
        model.intercepts_ = [net[f"layer{i}/bias"][()] for i in range(len(net))]

    def onnx(self, spec: Any, include_surface: bool, opset: int) -> Any:
        """The ensemble as ONNX (``models.export.network_onnx``)."""
        return resolve("skinloc.models.export:network_onnx")(spec, include_surface, opset)

    def c_header(self, spec: Any, include_surface: bool, prefix: str) -> str:
        """The ensemble as a C99 header (``models.export.network_c_header``)."""
        return resolve("skinloc.models.export:network_c_header")(spec, include_surface, prefix)
