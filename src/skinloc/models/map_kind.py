"""The ``map`` model kind: a response map of the skin, fitted by GP regression on the surface.

Registered in ``models.kinds``; the localiser, the model file and the exports reach it only
through the ``ModelKind`` methods here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from skinloc._lazy import resolve
from skinloc.models.multi_contact.rule_calibration import fit_contact_model

__all__ = ["MapConfig", "MapKind"]


@dataclass(frozen=True)
class MapConfig:
    """A response map's hyperparameters (``ContactLocalizer``'s documents them).

    Attributes
    ----------
    length_scale_mm : float
        Starting length scale of the GP, mm (> 0).
    prior : str
        ``"package"``, ``"none"`` or a prior file's path.
    """

    length_scale_mm: float
    prior: str = "none"

    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> MapConfig:
        """The map's settings of a localiser's config, checked (``ValueError`` naming one)."""
        ls, prior = cfg["length_scale_mm"], cfg.get("prior", "none")  # older files: no prior
        if not (isinstance(ls, int | float) and ls > 0):
            raise ValueError(
                "the 'length_scale_mm' parameter of ContactLocalizer must be a float > 0; "
                f"got {ls!r}"
            )
        if not isinstance(prior, str):
            raise ValueError(
                "the 'prior' parameter of ContactLocalizer must be 'package', 'none' or a prior "
                f"file's path; got {prior!r}"
            )
        if cfg["normalise"] != "l2" or cfg["train_on"] != "means":
            raise ValueError("a response map matches L2-normalised touch means")
        return cls(float(ls), prior)


class MapKind:
    """The ``map`` kind (see ``models.kinds.ModelKind``)."""

    name = "map"
    config_type = MapConfig
    fitted_attrs = ("map_",)
    needs_surface_points = True
    train_extra = None
    quick_fit = True  # a map fits in seconds
    summary = (
        "a response map (Gaussian-process interpolation of each sensor's normalised "
        "response over the surface, matched by image shape)"
    )

    def fit(
        self,
        model: Any,
        X: np.ndarray,
        y: np.ndarray,
        frames: tuple[np.ndarray, np.ndarray | None],
        groups: np.ndarray | None,
        progress: Callable[[int, int], None] | None,
    ) -> None:
        """Fit the map (and the count rule) on touch means ``X``, ``y``."""
        from skinloc.models.response_map import ResponseMap, shape_features

        if model.surface_points_ is None:
            raise ValueError(
                "a response-map model chooses among surface points: give the skin mesh or "
                "surface_points to fit()"
            )
        cfg = MapConfig.from_config(model.config_)
        F = shape_features(X, model.config_["clip_negative"])
        prior = model.map_prior()
        if prior is not None and not prior.applies(len(F)):
            prior = None
        model.prior_used_ = prior is not None
        rmap = ResponseMap.fit(y, F, model.surface_points_, cfg.length_scale_mm, prior=prior)
        if not getattr(model, "count_rule", True):  # scored on single touches only
            model.map_, model.contact_rule_ = rmap.with_amplitude(y, X), None
            return
        model.map_, model.contact_rule_ = fit_contact_model(
            rmap,
            X,
            y,
            frames[0] if frames[1] is not None else None,
            frames[1],
            model.sensor_noise_,
            model.random_state,
        )

    def recalibrate(
        self,
        model: Any,
        new: Any,
        X: np.ndarray,
        y: np.ndarray,
        groups: np.ndarray | None,
        progress: Callable[[int, int], None] | None,
    ) -> None:
        """The old map kept, corrected, blended or replaced, as the new touches decide.

        Cross-validation over the new touches (their means when grouped) chooses
        (``models.recalibration``); the decision is ``new.recalibration_``.
        """
        from skinloc.models.localizer import group_means
        from skinloc.models.recalibration import choose_recalibration
        from skinloc.models.response_map import shape_features

        if groups is not None:
            X, y = group_means(X, y, groups)
        cfg = MapConfig.from_config(model.config_)
        new.map_, choice = choose_recalibration(
            model.map_,
            y,
            shape_features(X, model.config_["clip_negative"]),
            model.map_prior(),
            length_scale_mm=cfg.length_scale_mm,
            random_state=model.random_state,
        )
        new.recalibration_ = choice.as_meta()

    def spec(self, model: Any, common: dict[str, Any]) -> Any:
        """The map's ``MapSpec``."""
        return model.map_.spec(**common)

    def write(self, model: Any, f: Any) -> None:
        """The ``map`` group: mean, candidates, GP layers and the amplitude map."""
        f.attrs["description"] = (
            "x: baseline-subtracted counts (n_features_in,). features: clip negatives, divide by "
            "max(L2 norm, 1). map(q) = mean + sum over layers of exp(-|q - points_mm|^2 / "
            "(2 length_scale_mm^2)) @ alpha, q in mm. prediction: the row of map/candidates "
            "(metres) whose map value is nearest the features."
        )
        g = f.create_group("map")
        g["mean"], g["candidates"] = model.map_.mean, model.map_.candidates
        for i, layer in enumerate(model.map_.layers):
            lg = g.create_group(f"layer{i}")
            lg["points_mm"], lg["alpha"] = layer.points_mm, layer.alpha
            lg.attrs["length_scale_mm"], lg.attrs["noise"] = layer.length_scale_mm, layer.noise
        amp = model.map_.amplitude
        if amp is not None:
            ag = g.create_group("amplitude")
            ag["mean"], ag["points_mm"] = amp.mean, amp.layer.points_mm
            ag["alpha"] = amp.layer.alpha
            ag.attrs["length_scale_mm"] = amp.layer.length_scale_mm
            ag.attrs["noise"] = amp.layer.noise

    def read(self, model: Any, f: Any) -> None:
        """``map_`` from the ``map`` group."""
        from skinloc.models.response_map import AmplitudeMap, MapLayer, ResponseMap

        g = f["map"]
        layers = [
            MapLayer(
                g[f"layer{i}/points_mm"][()],
                g[f"layer{i}/alpha"][()],
                float(g[f"layer{i}"].attrs["length_scale_mm"]),
                float(g[f"layer{i}"].attrs["noise"]),
            )
            for i in range(sum(1 for k in g if k.startswith("layer")))
        ]
        amp = None
        if "amplitude" in g:
            a = g["amplitude"]
            amp = AmplitudeMap(
                a["mean"][()],
                MapLayer(
                    a["points_mm"][()],
                    a["alpha"][()],
                    float(a.attrs["length_scale_mm"]),
                    float(a.attrs["noise"]),
                ),
            )
        model.map_ = ResponseMap(g["mean"][()], layers, g["candidates"][()], amp)

    def onnx(self, spec: Any, include_surface: bool, opset: int) -> Any:
        """The coarse-to-fine map search as ONNX (``models.export.map_onnx``)."""
        return resolve("skinloc.models.export:map_onnx")(spec, opset)

    def c_header(self, spec: Any, include_surface: bool, prefix: str) -> str:
        """None: a map's table does not fit a microcontroller (``ValueError`` says so)."""
        size_mb = np.asarray(spec.table).nbytes / 2**20
        raise ValueError(
            f"a response-map model carries a {size_mb:.1f} MB table of the skin: too big for a "
            "microcontroller; export it with --onnx, or train a network for the board "
            "(skinloc train --arch paper or --arch mlp)"
        )
