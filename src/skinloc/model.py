"""The contact localiser: sensor image (n_sensors,) counts -> contact point (3,) m on the skin.

``ContactLocalizer`` follows the scikit-learn conventions: ``__init__`` stores
hyperparameters, ``fit`` learns (attributes with a trailing ``_``) and returns ``self``.

Two kinds of model share the class:

- ``kind="map"`` (the default): a response map of the skin (``skinloc.response_map``), fitted
  by Gaussian-process regression on the surface in well under a second; prediction matches
  the image's shape against the map at every candidate surface point.
- ``kind="network"`` (``paper``, ``mlp``): fully connected networks trained in PyTorch (the
  ``skinloc[nets]`` extra); prediction needs no PyTorch.

Prediction is not here: a fitted model is described by a spec (``spec()``, plain arrays) and
predicted by the engine of its kind (``skinloc.engine``), the one implementation that the
pipeline, the benchmarks, the app and the exports share.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._typing import Frames, Points
from skinloc.engine import Engine, ModelSpec, Prediction
from skinloc.errors import MissingExtraError, ModelFileError, NotFittedError

log = logging.getLogger(__name__)

__all__ = ["ARCHITECTURES", "ContactLocalizer", "MODEL_FORMAT_VERSION", "Prediction"]

#: 2 added response-map models; version 1 files (networks) still load.
MODEL_FORMAT_VERSION = 2

#: Named configurations. ``paper`` is the paper's network exactly (64-32-3, one hidden layer);
#: ``default`` is the most accurate on the real recordings (see docs/accuracy.md); ``mlp`` is
#: the best network found (an ensemble, also the way to an uncertainty from a network).
ARCHITECTURES: dict[str, dict[str, Any]] = {
    "default": dict(
        kind="map",
        normalise="l2",
        clip_negative=True,
        train_on="means",
        length_scale_mm=20.0,
    ),
    "paper": dict(
        kind="network",
        hidden=(32,),
        activation="tanh",
        n_members=1,
        normalise="none",
        clip_negative=False,
        train_on="means",
        epochs=2000,
        lr=1e-2,
        weight_decay=0.0,
        noise_std=0.0,
    ),
    "mlp": dict(
        kind="network",
        hidden=(128, 128),
        activation="relu",
        n_members=5,
        normalise="l2",
        clip_negative=True,
        train_on="frames",
        epochs=100,
        lr=3e-3,
        weight_decay=1e-4,
        noise_std=0.0,
    ),
}

_ACTIVATIONS = ("relu", "tanh", "gelu")
#: Hyperparameters a user may override (each an ``__init__`` argument).
_TUNABLE = (
    "length_scale_mm",
    "hidden",
    "activation",
    "n_members",
    "normalise",
    "clip_negative",
    "train_on",
    "epochs",
    "lr",
    "weight_decay",
    "noise_std",
)


def import_torch(purpose: str) -> Any:
    """``torch``, or a one-line error naming the extra that installs it.

    Only training networks needs PyTorch; the default model and every prediction run without
    it, so it is imported here, on demand, and never at module level.
    """
    try:
        import torch
    except ImportError:
        raise MissingExtraError(
            f"{purpose} needs PyTorch: pip install 'skinloc[nets]' (the default model does not)"
        ) from None
    return torch


def group_means(X: np.ndarray, y: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Average rows of ``X (n, k)`` and ``y (n, 3)`` that share a group label.

    Returns ``(X_mean (g, k), y_mean (g, 3))`` in order of the sorted group labels.
    """
    uniq, inv = np.unique(np.asarray(groups), return_inverse=True)
    counts = np.bincount(inv).astype(np.float64)[:, None]
    Xm = np.zeros((len(uniq), X.shape[1]))
    ym = np.zeros((len(uniq), y.shape[1]))
    np.add.at(Xm, inv, X)
    np.add.at(ym, inv, y)
    return Xm / counts, ym / counts


class ContactLocalizer:
    """Sensor images to contact points: a response map or a network ensemble.

    Parameters
    ----------
    arch : {"default", "mlp", "paper"}, default="default"
        Named configuration; keyword arguments given explicitly override its values, and
        must be ones that configuration has.
    length_scale_mm : float, optional
        Starting length scale of the response map's GP, mm (fitted by marginal likelihood).
    hidden : tuple of int, optional
        Hidden layer widths.
    activation : {"relu", "tanh", "gelu"}, optional
        Hidden activation.
    n_members : int, optional
        Networks in the ensemble; their spread is the uncertainty.
    normalise : {"none", "l1", "l2"}, optional
        Divide each image by its norm (after clipping) so that touch pressure cancels.
    clip_negative : bool, optional
        Set negative deltas to zero before normalising.
    train_on : {"frames", "means"}, optional
        Train on every frame of a touch, or on its mean image (the paper).
    epochs, lr, weight_decay : optional
        Adam full-batch training schedule (cosine-decayed learning rate).
    noise_std : float, optional
        Gaussian noise added to standardised inputs during training (augmentation).
    constraint : {"snap", "project", "none"}, default="snap"
        How predictions are put on the surface (needs a mesh at ``fit``).
    random_state : int, default=0
        Seed; training is deterministic under it.
    """

    def __init__(
        self,
        *,
        arch: str = "default",
        length_scale_mm: float | None = None,
        hidden: tuple[int, ...] | None = None,
        activation: str | None = None,
        n_members: int | None = None,
        normalise: str | None = None,
        clip_negative: bool | None = None,
        train_on: str | None = None,
        epochs: int | None = None,
        lr: float | None = None,
        weight_decay: float | None = None,
        noise_std: float | None = None,
        constraint: str = "snap",
        random_state: int = 0,
    ) -> None:
        self.arch = arch
        self.length_scale_mm = length_scale_mm
        self.hidden = hidden
        self.activation = activation
        self.n_members = n_members
        self.normalise = normalise
        self.clip_negative = clip_negative
        self.train_on = train_on
        self.epochs = epochs
        self.lr = lr
        self.weight_decay = weight_decay
        self.noise_std = noise_std
        self.constraint = constraint
        self.random_state = random_state

    # ---------------------------------------------------------------- configuration
    def get_config(self) -> dict[str, Any]:
        """Resolved hyperparameters: the named architecture with explicit overrides applied."""
        if self.arch not in ARCHITECTURES:
            raise ValueError(
                f"unknown arch {self.arch!r} of ContactLocalizer; choose one of: "
                f"{', '.join(ARCHITECTURES)}"
            )
        cfg = dict(ARCHITECTURES[self.arch])
        for key in _TUNABLE:
            value = getattr(self, key)
            if value is None:
                continue
            if key not in cfg:
                raise ValueError(
                    f"the {key!r} parameter does not apply to arch {self.arch!r} "
                    f"(a {cfg['kind']} model)"
                )
            cfg[key] = value
        if "hidden" in cfg:
            cfg["hidden"] = tuple(int(h) for h in cfg["hidden"])
        cfg.update(arch=self.arch, constraint=self.constraint, random_state=self.random_state)
        self._validate(cfg)
        return cfg

    @staticmethod
    def _validate(cfg: dict[str, Any]) -> None:
        def bad(name: str, allowed: str) -> ValueError:
            return ValueError(
                f"the {name!r} parameter of ContactLocalizer must be {allowed}; got {cfg[name]!r}"
            )

        if cfg["normalise"] not in ("none", "l1", "l2"):
            raise bad("normalise", "one of none, l1, l2")
        if cfg["train_on"] not in ("frames", "means"):
            raise bad("train_on", "one of frames, means")
        if cfg["constraint"] not in ("snap", "project", "none"):
            raise bad("constraint", "one of snap, project, none")
        if cfg["kind"] == "map":
            if not cfg["length_scale_mm"] > 0:
                raise bad("length_scale_mm", "a float > 0")
            if cfg["normalise"] != "l2" or cfg["train_on"] != "means":
                raise ValueError("a response map matches L2-normalised touch means")
            return
        if not cfg["hidden"] or any(h < 1 for h in cfg["hidden"]):
            raise bad("hidden", "a non-empty tuple of positive ints")
        if cfg["activation"] not in _ACTIVATIONS:
            raise bad("activation", f"one of {', '.join(_ACTIVATIONS)}")
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

    # ---------------------------------------------------------------- preprocessing
    def _features(self, X: np.ndarray, cfg: dict[str, Any]) -> np.ndarray:
        """Pressure-invariant image features, before standardisation. ``(n, n_sensors)``."""
        Z = np.asarray(X, dtype=np.float64)
        if cfg["clip_negative"]:
            Z = np.maximum(Z, 0.0)
        if cfg["normalise"] != "none":
            order = 1 if cfg["normalise"] == "l1" else 2
            norm = np.linalg.norm(Z, ord=order, axis=1, keepdims=True)
            # A floor keeps near-empty images (no touch) from being blown up into noise.
            Z = Z / np.maximum(norm, 1.0)
        return Z

    def _check_X(self, X: Frames) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        if X.ndim == 1:
            X = X[None, :]
        n_expected = getattr(self, "n_features_in_", None)
        if X.ndim != 2 or (n_expected is not None and X.shape[1] != n_expected):
            want = f"(n, {n_expected})" if n_expected is not None else "(n, n_sensors)"
            raise ValueError(
                f"sensor images must have shape {want} ({n_expected} sensors), got {X.shape}"
            )
        if not np.all(np.isfinite(X)):
            raise ValueError("sensor images contain NaN or infinite values")
        return X

    # ---------------------------------------------------------------- training
    def fit(
        self,
        X: Frames,
        y: Points,
        *,
        groups: np.ndarray | None = None,
        mesh: Any = None,
        surface_points: Points | None = None,
        progress: Callable[[int, int], None] | None = None,
    ) -> ContactLocalizer:
        """Train on baseline-subtracted images.

        Parameters
        ----------
        X : (n, n_sensors) float
            Baseline-subtracted sensor images, counts (single frames or touch means).
        y : (n, 3) float
            Touch positions, m.
        groups : (n,) int, optional
            Touch each row belongs to; with ``train_on="means"`` rows are averaged per touch.
        mesh : trimesh.Trimesh, optional
            Skin surface for the output constraint.
        surface_points : (P, 3) float, optional
            Discretised surface for ``constraint="snap"``.
        progress : callable(done, total), optional
            Called during training.

        Returns
        -------
        self
        """
        cfg = self.get_config()
        X = self._check_X(X)
        y = np.asarray(y, dtype=np.float64)
        if y.shape != (len(X), 3):
            raise ValueError(f"touch positions must have shape ({len(X)}, 3), got {y.shape}")
        if len(X) < 2:
            raise ValueError("need at least 2 sensor images to train")
        if cfg["train_on"] == "means" and groups is not None:
            X, y = group_means(X, y, groups)
        t0 = time.perf_counter()
        for attr in ("coefs_", "intercepts_", "map_"):  # a second fit starts afresh
            self.__dict__.pop(attr, None)
        self.n_features_in_ = X.shape[1]
        self.config_ = cfg
        self._set_surface(mesh, surface_points)
        if cfg["kind"] == "map":
            self._fit_map(X, y)
        else:
            F = self._features(X, cfg)
            self.feature_mean_ = F.mean(axis=0)
            self.feature_scale_ = np.maximum(F.std(axis=0), 1e-6 * max(F.std(), 1e-12))
            self.target_mean_ = y.mean(axis=0)
            self.target_scale_ = float(np.maximum(y.std(axis=0).max(), 1e-6))
            self._fit_network(X, y, cfg["epochs"], cfg["lr"], progress)
        self.fit_time_s_ = time.perf_counter() - t0
        log.info("trained %s in %.2f s", cfg["arch"], self.fit_time_s_)
        return self

    def _fit_map(self, X: np.ndarray, y: Points) -> None:
        from skinloc.response_map import ResponseMap, shape_features

        if self.surface_points_ is None:
            raise ValueError(
                "a response-map model chooses among surface points: give the skin mesh or "
                "surface_points to fit()"
            )
        F = shape_features(X, self.config_["clip_negative"])
        self.map_ = ResponseMap.fit(
            y, F, self.surface_points_, length_scale_mm=self.config_["length_scale_mm"]
        )

    def _fit_network(
        self,
        X: np.ndarray,
        y: Points,
        epochs: int,
        lr: float,
        progress: Callable[[int, int], None] | None,
    ) -> None:
        """Train the ensemble with AdamW, cosine-decayed ``lr``, from the current weights if any.

        ``X (n, n_sensors)`` counts and ``y (n, 3)`` m; the preprocessing attributes must be set.
        """
        torch = import_torch(f"training the {self.config_['arch']!r} network")
        cfg = self.config_
        Z = (self._features(X, cfg) - self.feature_mean_) / self.feature_scale_
        T = (y - self.target_mean_) / self.target_scale_
        g = torch.Generator().manual_seed(int(self.random_state))
        E = cfg["n_members"]
        sizes = [Z.shape[1], *cfg["hidden"], 3]
        n_layers = len(sizes) - 1
        params: list[torch.Tensor] = []
        if hasattr(self, "coefs_"):
            for W, b in zip(self.coefs_, self.intercepts_, strict=True):
                params += [torch.tensor(W).requires_grad_(), torch.tensor(b).requires_grad_()]
        else:
            for fan_in, fan_out in zip(sizes[:-1], sizes[1:], strict=True):
                bound = 1.0 / np.sqrt(fan_in)  # the default init of torch.nn.Linear
                shape_w, shape_b = (E, fan_in, fan_out), (E, 1, fan_out)
                W = (torch.rand(shape_w, generator=g, dtype=torch.float64) * 2 - 1) * bound
                b = (torch.rand(shape_b, generator=g, dtype=torch.float64) * 2 - 1) * bound
                params += [W.requires_grad_(), b.requires_grad_()]
        act = {"relu": torch.relu, "tanh": torch.tanh, "gelu": torch.nn.functional.gelu}[
            cfg["activation"]
        ]
        Zt = torch.as_tensor(Z).expand(E, -1, -1)
        Tt = torch.as_tensor(T).expand(E, -1, -1)
        opt = torch.optim.AdamW(params, lr=lr, weight_decay=cfg["weight_decay"])
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=epochs)
        self.loss_curve_ = []
        for epoch in range(epochs):
            h = Zt
            if cfg["noise_std"] > 0:
                h = h + cfg["noise_std"] * torch.randn(h.shape, generator=g, dtype=h.dtype)
            for i in range(n_layers):
                h = torch.baddbmm(params[2 * i + 1], h, params[2 * i])
                if i < n_layers - 1:
                    h = act(h)
            loss = ((h - Tt) ** 2).mean(dim=(1, 2)).sum()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            self.loss_curve_.append(loss.item() / E)
            if progress is not None and (epoch % 25 == 0 or epoch == epochs - 1):
                progress(epoch + 1, epochs)
        coefs = [params[2 * i].detach().numpy().copy() for i in range(n_layers)]
        intercepts = [params[2 * i + 1].detach().numpy().copy() for i in range(n_layers)]
        if not all(np.all(np.isfinite(w)) for w in coefs + intercepts):
            raise ValueError(
                "training diverged (non-finite weights); lower lr or check the input images"
            )
        self.coefs_, self.intercepts_ = coefs, intercepts

    def recalibrate(
        self,
        X: Frames,
        y: Points,
        *,
        groups: np.ndarray | None = None,
        progress: Callable[[int, int], None] | None = None,
    ) -> ContactLocalizer:
        """A copy of this model adapted to a skin whose response has moved (a new session).

        ``X (n, n_sensors)`` are baseline-subtracted images from the new session (with its own
        fresh baseline) and ``y (n, 3)`` their touch positions, m; a handful of touches is
        enough. A response map gains a correction layer fitted to the new touches; a network
        is fine-tuned from its weights with a short, gentle schedule.
        """
        import copy

        self._check_fitted()
        X = self._check_X(X)
        y = np.asarray(y, dtype=np.float64)
        if y.shape != (len(X), 3) or len(X) < 1:
            raise ValueError(f"touch positions must have shape ({len(X)}, 3), got {y.shape}")
        new = copy.deepcopy(self)
        new._engine = None
        t0 = time.perf_counter()
        if self.config_["kind"] == "map":
            from skinloc.response_map import shape_features

            if groups is not None:
                X, y = group_means(X, y, groups)
            F = shape_features(X, self.config_["clip_negative"])
            new.map_ = self.map_.refined(y, F)
        else:
            if self.config_["train_on"] == "means" and groups is not None:
                X, y = group_means(X, y, groups)
            epochs = max(50, self.config_["epochs"] // 4)
            new._fit_network(X, y, epochs, self.config_["lr"] / 10, progress)
        new.fit_time_s_ = time.perf_counter() - t0
        return new

    # ---------------------------------------------------------------- surface
    def _set_surface(self, mesh: Any, surface_points: Points | None) -> None:
        self.mesh_vertices_ = None if mesh is None else np.asarray(mesh.vertices, dtype=np.float64)
        self.mesh_faces_ = None if mesh is None else np.asarray(mesh.faces, dtype=np.int64)
        self.surface_points_ = surface_points
        needs_points = self.constraint == "snap" or self.config_["kind"] == "map"
        if mesh is not None and surface_points is None and needs_points:
            from skinloc.geometry import surface_points as make_points

            self.surface_points_ = make_points(mesh)
        self._engine = None

    @property
    def mesh(self):  # -> trimesh.Trimesh | None
        """The skin surface the model constrains its output to, if any."""
        self._check_fitted()
        if self.mesh_vertices_ is None:
            return None
        from skinloc.geometry import mesh_from_arrays

        return mesh_from_arrays(self.mesh_vertices_, self.mesh_faces_)

    # ---------------------------------------------------------------- prediction
    def _check_fitted(self) -> None:
        if not (hasattr(self, "coefs_") or hasattr(self, "map_")):
            raise NotFittedError(
                "this ContactLocalizer is not fitted yet: call fit() or load a trained model"
            )

    def spec(self) -> ModelSpec:
        """The fitted model as plain arrays: what its engine and the exports are built from."""
        self._check_fitted()
        cfg = self.config_
        common = dict(
            n_features=int(self.n_features_in_),
            clip_negative=bool(cfg["clip_negative"]),
            vertices=self.mesh_vertices_,
            faces=self.mesh_faces_,
            meta={"arch": cfg.get("arch", "?")},
        )
        if cfg["kind"] == "map":
            from skinloc.engine_map import MapSpec

            coarse, cells = self.map_.search_cells()
            return MapSpec(
                **common,
                surface_points=self.map_.candidates,
                table=self.map_.table,
                coarse=coarse,
                cells=cells,
                noise=float(self.map_.noise),
            )
        from skinloc.engine_network import NetworkSpec

        return NetworkSpec(
            **common,
            constraint=cfg["constraint"],
            surface_points=self.surface_points_,
            normalise=cfg["normalise"],
            activation=cfg["activation"],
            feature_mean=np.asarray(self.feature_mean_, dtype=np.float64),
            feature_scale=np.asarray(self.feature_scale_, dtype=np.float64),
            weights=[np.asarray(W, dtype=np.float64) for W in self.coefs_],
            biases=[np.asarray(b, dtype=np.float64) for b in self.intercepts_],
            target_mean=np.asarray(self.target_mean_, dtype=np.float64).reshape(3),
            target_scale=float(self.target_scale_),
        )

    def engine(self) -> Engine:
        """The engine that predicts for this model (built once per fit or load)."""
        if getattr(self, "_engine", None) is None:
            self._engine = self.spec().engine()
        return self._engine

    def predict_full(self, X: Frames) -> Prediction:
        """Predict points, raw outputs and the uncertainty for ``X (n, n_sensors)``."""
        self._check_fitted()
        return self.engine().predict(self._check_X(X))

    def predict(self, X: Frames) -> Points:
        """Contact points ``(n, 3)`` m for baseline-subtracted images ``X (n, n_sensors)``.

        A single image ``(n_sensors,)`` gives ``(1, 3)``.
        """
        return self.predict_full(X).points

    # ---------------------------------------------------------------- persistence
    def save(self, path: str | Path, extra_meta: dict[str, Any] | None = None) -> None:
        """Write the model to one self-describing HDF5 file, atomically.

        The file holds the configuration (JSON), the preprocessing arrays, every layer's
        weights as ``(n_members, in, out)`` datasets, the skin mesh and the snap points.
        """
        import h5py

        from skinloc import __version__
        from skinloc.dataset import _atomic_write

        self._check_fitted()
        meta = {
            "skinloc_version": __version__,
            "numpy_version": np.__version__,
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "fit_time_s": getattr(self, "fit_time_s_", None),
            **(extra_meta or {}),
        }
        if hasattr(self, "training_meta_"):
            meta.setdefault("training", self.training_meta_)

        def write(tmp: Path) -> None:
            with h5py.File(tmp, "w") as f:
                f.attrs["format"] = "skinloc-model"
                f.attrs["format_version"] = MODEL_FORMAT_VERSION
                f.attrs["config"] = json.dumps(self.config_)
                f.attrs["meta"] = json.dumps(meta, default=str)
                f.attrs["n_features_in"] = self.n_features_in_
                if self.config_["kind"] == "map":
                    self._write_map(f)
                else:
                    self._write_network(f)
                if self.mesh_vertices_ is not None:
                    f["surface/vertices"], f["surface/faces"] = (
                        self.mesh_vertices_,
                        self.mesh_faces_,
                    )
                if self.surface_points_ is not None:
                    f["surface/points"] = self.surface_points_

        _atomic_write(Path(path), write)

    def _write_map(self, f: Any) -> None:
        f.attrs["description"] = (
            "x: baseline-subtracted counts (n_features_in,). features: clip negatives, divide by "
            "max(L2 norm, 1). map(q) = mean + sum over layers of exp(-|q - points_mm|^2 / "
            "(2 length_scale_mm^2)) @ alpha, q in mm. prediction: the row of map/candidates "
            "(metres) whose map value is nearest the features."
        )
        g = f.create_group("map")
        g["mean"], g["candidates"] = self.map_.mean, self.map_.candidates
        for i, layer in enumerate(self.map_.layers):
            lg = g.create_group(f"layer{i}")
            lg["points_mm"], lg["alpha"] = layer.points_mm, layer.alpha
            lg.attrs["length_scale_mm"], lg.attrs["noise"] = layer.length_scale_mm, layer.noise

    def _write_network(self, f: Any) -> None:
        f.attrs["description"] = (
            "x: baseline-subtracted counts (n_features_in,). features: clip/normalise per "
            "config, then (x - feature_mean) / feature_scale. layers: h = act(h @ W + b) "
            "per member; output * target_scale + target_mean is metres; ensemble mean."
        )
        p = f.create_group("preprocessing")
        p["feature_mean"], p["feature_scale"] = self.feature_mean_, self.feature_scale_
        p["target_mean"] = self.target_mean_
        p.attrs["target_scale"] = self.target_scale_
        net = f.create_group("network")
        for i, (W, b) in enumerate(zip(self.coefs_, self.intercepts_, strict=True)):
            net[f"layer{i}/weight"], net[f"layer{i}/bias"] = W, b

    def _read_map(self, g: Any) -> None:
        from skinloc.response_map import MapLayer, ResponseMap

        layers = [
            MapLayer(
                g[f"layer{i}/points_mm"][()],
                g[f"layer{i}/alpha"][()],
                float(g[f"layer{i}"].attrs["length_scale_mm"]),
                float(g[f"layer{i}"].attrs["noise"]),
            )
            for i in range(sum(1 for k in g if k.startswith("layer")))
        ]
        self.map_ = ResponseMap(g["mean"][()], layers, g["candidates"][()])

    def _read_network(self, f: Any) -> None:
        p = f["preprocessing"]
        self.feature_mean_ = p["feature_mean"][()]
        self.feature_scale_ = p["feature_scale"][()]
        self.target_mean_ = p["target_mean"][()]
        self.target_scale_ = float(p.attrs["target_scale"])
        net = f["network"]
        self.coefs_ = [net[f"layer{i}/weight"][()] for i in range(len(net))]
        self.intercepts_ = [net[f"layer{i}/bias"][()] for i in range(len(net))]

    @classmethod
    def load(cls, path: str | Path) -> ContactLocalizer:
        """Read a model written by ``save``; raises ``ModelFileError`` when it cannot."""
        import h5py

        path = Path(path)
        if not path.is_file():
            raise ModelFileError(f"model not found: {path}")
        try:
            with h5py.File(path, "r") as f:
                if f.attrs.get("format") != "skinloc-model":
                    raise ModelFileError(f"{path} is not a skinloc model")
                version = int(f.attrs["format_version"])
                if version > MODEL_FORMAT_VERSION:
                    raise ModelFileError(
                        f"{path} uses model format {version}; this skinloc reads up to "
                        f"{MODEL_FORMAT_VERSION}: upgrade skinloc"
                    )
                cfg = json.loads(f.attrs["config"])
                if version == 1:  # version 1 held networks only, under the names of today's mlp
                    cfg["kind"] = "network"
                    cfg["arch"] = "mlp" if cfg["arch"] == "default" else cfg["arch"]
                if "hidden" in cfg:
                    cfg["hidden"] = tuple(cfg["hidden"])
                model = cls(
                    arch=cfg["arch"], constraint=cfg["constraint"], random_state=cfg["random_state"]
                )
                model.config_ = cfg
                model.meta_ = json.loads(f.attrs.get("meta", "{}"))
                model.n_features_in_ = int(f.attrs["n_features_in"])
                if cfg["kind"] == "map":
                    model._read_map(f["map"])
                else:
                    model._read_network(f)
                surf = f.get("surface")
                model.mesh_vertices_ = surf["vertices"][()] if surf and "vertices" in surf else None
                model.mesh_faces_ = surf["faces"][()] if surf and "faces" in surf else None
                model.surface_points_ = surf["points"][()] if surf and "points" in surf else None
                model._engine = None
        except ModelFileError:
            raise
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise ModelFileError(f"cannot read model {path}: {exc}") from exc
        return model
