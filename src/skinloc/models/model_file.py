"""The model file: one self-describing HDF5 file per trained ``ContactLocalizer``.

Format version 2 (written since response maps): attributes ``format`` ("skinloc-model"),
``format_version``, ``config`` and ``meta`` (JSON), ``n_features_in``, ``description``; a
``map`` group (the response map's mean, candidates and GP layers) or ``preprocessing`` and
``network`` groups (the ensemble's arrays); a ``surface`` group (mesh and snap points).
Version 1 files (networks only) still load. Since multi-contact localisation, optional: a
``map/amplitude`` group (the amplitude map: ``mean``, ``points_mm``, ``alpha``, its length scale
and noise) and a ``contacts`` group (``sensor_noise`` counts, the count rule as JSON in
``rule``); files without them load, and their engines use the defaults (``models.multi_contact``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.errors import ModelFileError
from skinloc.h5layout import MODEL, check_kind, set_kind

__all__ = ["MODEL_FORMAT_VERSION", "read_model", "write_model"]

#: 2 added response-map models; version 1 files (networks) still load.
MODEL_FORMAT_VERSION = 2


def write_model(model: Any, path: Path, extra_meta: dict[str, Any] | None = None) -> None:
    """Write a fitted ``ContactLocalizer`` to ``path``, atomically."""
    import h5py

    from skinloc import __version__
    from skinloc.files import atomic_write

    meta = {
        "skinloc_version": __version__,
        "numpy_version": np.__version__,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "fit_time_s": getattr(model, "fit_time_s_", None),
        **(extra_meta or {}),
    }
    if hasattr(model, "training_meta_"):
        meta.setdefault("training", model.training_meta_)

    def write(tmp: Path) -> None:
        with h5py.File(tmp, "w") as f:
            set_kind(f, MODEL)
            f.attrs["format_version"] = MODEL_FORMAT_VERSION
            f.attrs["config"] = json.dumps(model.config_)
            f.attrs["meta"] = json.dumps(meta, default=str)
            f.attrs["n_features_in"] = model.n_features_in_
            if model.config_["kind"] == "map":
                _write_map(model, f)
            else:
                _write_network(model, f)
            if model.mesh_vertices_ is not None:
                f["surface/vertices"], f["surface/faces"] = (
                    model.mesh_vertices_,
                    model.mesh_faces_,
                )
            if model.surface_points_ is not None:
                f["surface/points"] = model.surface_points_
            _write_contacts(model, f)

    atomic_write(path, write)


def _write_map(model: Any, f: Any) -> None:
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
        ag["mean"], ag["points_mm"], ag["alpha"] = amp.mean, amp.layer.points_mm, amp.layer.alpha
        ag.attrs["length_scale_mm"], ag.attrs["noise"] = amp.layer.length_scale_mm, amp.layer.noise


def _write_contacts(model: Any, f: Any) -> None:
    noise = getattr(model, "sensor_noise_", None)
    rule = getattr(model, "contact_rule_", None)
    if noise is None and rule is None:
        return
    g = f.create_group("contacts")
    if noise is not None:
        g["sensor_noise"] = np.asarray(noise, dtype=np.float64)
    g.attrs["rule"] = json.dumps(rule, default=float)


def _read_contacts(model: Any, f: Any) -> None:
    g = f.get("contacts")
    model.sensor_noise_ = g["sensor_noise"][()] if g is not None and "sensor_noise" in g else None
    model.contact_rule_ = json.loads(g.attrs.get("rule", "null")) if g is not None else None


def _write_network(model: Any, f: Any) -> None:
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


def _read_map(model: Any, g: Any) -> None:
    from skinloc.models.response_map import AmplitudeMap, MapLayer, ResponseMap

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


def _read_network(model: Any, f: Any) -> None:
    p = f["preprocessing"]
    model.feature_mean_ = p["feature_mean"][()]
    model.feature_scale_ = p["feature_scale"][()]
    model.target_mean_ = p["target_mean"][()]
    model.target_scale_ = float(p.attrs["target_scale"])
    net = f["network"]
    model.coefs_ = [net[f"layer{i}/weight"][()] for i in range(len(net))]
    model.intercepts_ = [net[f"layer{i}/bias"][()] for i in range(len(net))]


def read_model(cls: type, path: Path) -> Any:
    """A ``cls`` (``ContactLocalizer``) read from ``path``; ``ModelFileError`` when it cannot."""
    import h5py

    if not path.is_file():
        raise ModelFileError(f"model not found: {path}")
    try:
        with h5py.File(path, "r") as f:
            check_kind(f, path, MODEL, ModelFileError)
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
                _read_map(model, f["map"])
            else:
                _read_network(model, f)
            surf = f.get("surface")
            model.mesh_vertices_ = surf["vertices"][()] if surf and "vertices" in surf else None
            model.mesh_faces_ = surf["faces"][()] if surf and "faces" in surf else None
            model.surface_points_ = surf["points"][()] if surf and "points" in surf else None
            _read_contacts(model, f)
    except ModelFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise ModelFileError(f"cannot read model {path}: {exc}") from exc
    return model
