"""The contact localiser: sensor image (n_sensors,) counts -> contact point (3,) m on the skin.

``ContactLocalizer`` follows the scikit-learn conventions: ``__init__`` stores
hyperparameters, ``fit`` learns (attributes with a trailing ``_``) and returns ``self``.

Every kind of model shares the class (each kind registered once, ``models.kinds``):

- ``kind="map"`` (the default): a response map of the skin (``skinloc.models.response_map``), fitted
  by Gaussian-process regression on the surface in well under a second; prediction matches
  the image's shape against the map at every candidate surface point.
- ``kind="network"`` (``paper``, ``mlp``): fully connected networks trained in PyTorch (the
  ``skinloc[nets]`` extra); prediction needs no PyTorch.

Prediction is not here: a fitted model is described by a spec (``spec()``, plain arrays) and
predicted by the engine of its kind (``skinloc.models.engine``), the one implementation that the
pipeline, the benchmarks, the app and the exports share.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._typing import Frames, Points
from skinloc.errors import NotFittedError
from skinloc.models.engine import Engine, ModelSpec, Prediction
from skinloc.models.kinds import ModelKind, model_kind
from skinloc.models.model_file import MODEL_FORMAT_VERSION
from skinloc.models.multi_contact.rule_calibration import sensor_noise_from_frames

log = logging.getLogger(__name__)

__all__ = [
    "ARCHITECTURES",
    "ContactLocalizer",
    "MODEL_FORMAT_VERSION",
    "Prediction",
    "architecture_kind",
]


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
        # the response map's prior learned from simulated skins (models.map_prior):
        # "package" (the one shipped), "none", or a prior file's path
        prior="package",
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

#: Hyperparameters a user may override (each an ``__init__`` argument).
_TUNABLE = (
    "length_scale_mm",
    "prior",
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


def architecture_kind(arch: str) -> ModelKind | None:
    """The kind of the configuration ``arch`` of ``ARCHITECTURES``; None when there is none."""
    cfg = ARCHITECTURES.get(arch)
    return None if cfg is None else model_kind(cfg["kind"])


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
    prior : str, optional
        The response map's prior, learned from simulated skins (``skinloc.models.map_prior``):
        ``"package"`` (the one shipped, the default), ``"none"`` (maximum likelihood, no
        prior) or the path of a prior file (``skinloc prior build --out``).
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
    count_rule : bool, default=True
        Calibrate the multi-contact count rule (a response map's). False keeps the default
        rule: for a model that is only scored on single touches (cross-validation folds,
        learning curves), whose predictions it does not change, at a fraction of the fit.
    """

    def __init__(
        self,
        *,
        arch: str = "default",
        length_scale_mm: float | None = None,
        prior: str | None = None,
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
        count_rule: bool = True,
    ) -> None:
        self.arch = arch
        self.length_scale_mm = length_scale_mm
        self.prior = prior
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
        self.count_rule = count_rule

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
        model_kind(cfg["kind"]).config_type.from_config(cfg)  # the kind's own parameters

    @property
    def kind(self) -> ModelKind:
        """The model's kind (``models.kinds``), which fits, saves and exports it."""
        cfg = getattr(self, "config_", None) or self.get_config()
        return model_kind(cfg["kind"])

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
        frames = (X, groups)  # before averaging: the noise and the count rule's calibration
        if cfg["train_on"] == "means" and groups is not None:
            X, y = group_means(X, y, groups)
        t0 = time.perf_counter()
        kind = model_kind(cfg["kind"])
        for attr in (*kind.fitted_attrs, "contact_rule_"):  # a new fit: afresh
            self.__dict__.pop(attr, None)
        self.n_features_in_ = X.shape[1]
        self.config_ = cfg
        self._set_surface(mesh, surface_points)
        self.sensor_noise_ = sensor_noise_from_frames(*frames)
        kind.fit(self, X, y, frames, groups, progress)
        self.fit_time_s_ = time.perf_counter() - t0
        log.info("trained %s in %.2f s", cfg["arch"], self.fit_time_s_)
        return self

    def map_prior(self):  # -> MapPrior | None
        """The response map's prior this configuration names (``None``: no prior).

        ``fit`` applies it to a calibration of at most ``max_touches`` touches (the prior's
        own measure of where it helps) and sets ``prior_used_`` to say whether it did.
        """
        from skinloc.models.map_prior import load_prior

        cfg = getattr(self, "config_", None) or self.get_config()
        name = cfg.get("prior", "none")  # models saved before the prior have none
        if name == "none":
            return None
        return load_prior(None if name == "package" else name)

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
        enough, and none (a baseline capture only) gives the model unchanged. A response map
        keeps, corrects, blends or replaces its map as cross-validation over the new touches
        decides (``models.recalibration``); a network is fine-tuned from its weights with a
        short, gentle schedule. ``recalibration_`` says what was done.
        """
        import copy

        self._check_fitted()
        X = self._check_X(X) if len(X) else np.zeros((0, self.n_features_in_))
        y = np.asarray(y, dtype=np.float64)
        if len(X) == 0 and y.size == 0:
            y = y.reshape(0, 3)
        if y.shape != (len(X), 3):
            raise ValueError(f"touch positions must have shape ({len(X)}, 3), got {y.shape}")
        new = copy.deepcopy(self)
        new._engine = None
        t0 = time.perf_counter()
        if len(X) == 0:
            new.recalibration_ = {
                "method": "old map" if self.kind.name == "map" else "old model",
                "n_touches": 0,
                "summary": "kept the old model (no new touch to judge it by)",
            }
        else:
            n = int(len(np.unique(groups)) if groups is not None else len(X))
            new.recalibration_ = {  # a kind that says more replaces it
                "method": "adapted",
                "n_touches": n,
                "summary": f"adapted the {self.kind.name} model to {n} new touches",
            }
            self.kind.recalibrate(self, new, X, y, groups, progress)
        new.fit_time_s_ = time.perf_counter() - t0
        return new

    # ---------------------------------------------------------------- surface
    def _set_surface(self, mesh: Any, surface_points: Points | None) -> None:
        self.mesh_vertices_ = None if mesh is None else np.asarray(mesh.vertices, dtype=np.float64)
        self.mesh_faces_ = None if mesh is None else np.asarray(mesh.faces, dtype=np.int64)
        self.surface_points_ = surface_points
        needs_points = self.constraint == "snap" or self.kind.needs_surface_points
        if mesh is not None and surface_points is None and needs_points:
            from skinloc.geometry.mesh import surface_points as make_points

            self.surface_points_ = make_points(mesh)
        self._engine = None

    @property
    def mesh(self):  # -> trimesh.Trimesh | None
        """The skin surface the model constrains its output to, if any."""
        self._check_fitted()
        if self.mesh_vertices_ is None:
            return None
        from skinloc.geometry.mesh import mesh_from_arrays

        return mesh_from_arrays(self.mesh_vertices_, self.mesh_faces_)

    # ---------------------------------------------------------------- prediction
    def _check_fitted(self) -> None:
        cfg = getattr(self, "config_", None)
        if cfg is None or not all(hasattr(self, a) for a in model_kind(cfg["kind"]).fitted_attrs):
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
            sensor_noise=getattr(self, "sensor_noise_", None),
            contact_rule=getattr(self, "contact_rule_", None),
        )
        return model_kind(cfg["kind"]).spec(self, common)

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
        """Write the model to one self-describing HDF5 file, atomically (``models.model_file``).

        The file holds the configuration (JSON), the preprocessing arrays, every layer's
        weights as ``(n_members, in, out)`` datasets or the response map's layers, the skin
        mesh and the snap points.
        """
        from skinloc.models.model_file import write_model

        self._check_fitted()
        write_model(self, Path(path), extra_meta)

    @classmethod
    def load(cls, path: str | Path) -> ContactLocalizer:
        """Read a model written by ``save``; raises ``ModelFileError`` when it cannot."""
        from skinloc.models.model_file import read_model

        model = read_model(cls, Path(path))
        model._engine = None
        return model
