"""The model file: one self-describing HDF5 file per trained ``ContactLocalizer``.

Format version 2 (written since response maps): attributes ``format`` ("skinloc-model"),
``format_version``, ``config`` and ``meta`` (JSON), ``n_features_in``, ``description``; the
groups of the model's kind, which its ``ModelKind`` writes and reads (``models.kinds``): a
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
from skinloc.models.kinds import model_kind

__all__ = ["MODEL_FORMAT_VERSION", "model_summary", "read_model", "write_model"]

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
            model_kind(model.config_["kind"]).write(model, f)
            if model.mesh_vertices_ is not None:
                f["surface/vertices"], f["surface/faces"] = (
                    model.mesh_vertices_,
                    model.mesh_faces_,
                )
            if model.surface_points_ is not None:
                f["surface/points"] = model.surface_points_
            _write_contacts(model, f)

    atomic_write(path, write)


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
            kind = model_kind(cfg["kind"])  # a kind not registered here: one clear line
            kind.read(model, f)
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


def model_summary(path: Path) -> dict[str, Any]:
    """What a model file holds, read from its attributes and group sizes (``skinloc info``).

    No engine is built, so a model of a kind this install cannot run is still described.
    Keys: ``file``, ``format``, ``format_version``, ``kind``, ``n_sensors``, ``config``,
    ``training`` (recordings, point logs, grid), ``created``, ``skinloc_version``,
    ``mesh_vertices``/``mesh_faces``/``surface_points`` (counts), ``multi_contact`` (whether a
    count rule is stored), ``description``, ``meta`` (the rest). ``ModelFileError`` when
    ``path`` is not a readable skinloc model.
    """
    import h5py

    try:
        with h5py.File(path, "r") as f:
            check_kind(f, path, MODEL, ModelFileError)
            cfg = json.loads(f.attrs["config"])
            meta = json.loads(f.attrs.get("meta", "{}"))
            surf = f.get("surface")

            def rows(name: str) -> int:
                return int(len(surf[name])) if surf is not None and name in surf else 0

            contacts = f.get("contacts")
            summary = {
                "file": str(path),
                "format": MODEL,
                "format_version": int(f.attrs["format_version"]),
                "kind": cfg.get("kind", "network"),
                "n_sensors": int(f.attrs["n_features_in"]),
                "config": cfg,
                "training": meta.pop("training", None),
                "created": meta.pop("created", None),
                "skinloc_version": meta.pop("skinloc_version", None),
                "mesh_vertices": rows("vertices"),
                "mesh_faces": rows("faces"),
                "surface_points": rows("points"),
                "multi_contact": contacts is not None
                and json.loads(contacts.attrs.get("rule", "null")) is not None,
                "description": str(f.attrs.get("description", "")),
                "meta": meta,
            }
    except ModelFileError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise ModelFileError(f"cannot read model {path}: {exc}") from None
    return summary
