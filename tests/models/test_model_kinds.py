"""A model kind registered from this test module alone goes train-save-load-predict end to end.

Nothing in ``src`` knows the ``toy`` kind: the localiser, the model file, the engine, the
exports and the live pipeline reach it only through ``models.kinds``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import pytest

from skinloc.errors import ModelFileError
from skinloc.models.engine import Engine, ModelSpec, load_engine
from skinloc.models.kinds import model_kind, register_model_kind, unregister_model_kind
from skinloc.models.localizer import ARCHITECTURES, ContactLocalizer


@dataclass(kw_only=True)
class ToySpec(ModelSpec):
    """Nearest stored image: ``table (g, n_features)`` counts, ``points (g, 3)`` m."""

    kind: ClassVar[str] = "toy"
    table: np.ndarray
    points: np.ndarray

    def engine(self, constraint: str | None = None) -> ToyEngine:
        return ToyEngine(self, constraint)


class ToyEngine(Engine):
    kind: ClassVar[str] = "toy"

    def __init__(self, spec: ToySpec, constraint: str | None = None) -> None:
        super().__init__(spec, constraint)
        self._table = np.asarray(spec.table, dtype=np.float32)
        self._points = np.asarray(spec.points, dtype=np.float64)

    def localise_into(self, x: np.ndarray, out: np.ndarray) -> None:
        p = self._points[int(np.argmin(((self._table - x) ** 2).sum(axis=1)))]
        out[0:3], out[3:6], out[6] = p, p, 0.0

    def _predict_rows(self, X: np.ndarray) -> tuple[Any, Any, np.ndarray]:
        idx = ((X[:, None, :] - self._table[None]) ** 2).sum(axis=2).argmin(axis=1)
        P = self._points[idx]
        return P.copy(), P.copy(), np.zeros(len(X))


@dataclass(frozen=True)
class ToyConfig:
    @classmethod
    def from_config(cls, cfg: dict[str, Any]) -> ToyConfig:
        if cfg["normalise"] != "none":
            raise ValueError("a toy model takes raw images (normalise='none')")
        return cls()


class ToyKind:
    name = "toy"
    config_type = ToyConfig
    fitted_attrs = ("toy_table_", "toy_points_")
    needs_surface_points = False
    train_extra = None
    quick_fit = True
    summary = "the nearest stored image"

    def fit(self, model, X, y, frames, groups, progress) -> None:
        model.toy_table_, model.toy_points_ = np.array(X), np.array(y)

    def recalibrate(self, model, new, X, y, groups, progress) -> None:
        new.toy_table_ = np.vstack([model.toy_table_, X])
        new.toy_points_ = np.vstack([model.toy_points_, y])

    def spec(self, model, common) -> ToySpec:
        return ToySpec(
            **common,
            constraint=model.config_["constraint"],
            table=model.toy_table_,
            points=model.toy_points_,
        )

    def write(self, model, f) -> None:
        f.attrs["description"] = "toy: the nearest stored image's point"
        f["toy/table"], f["toy/points"] = model.toy_table_, model.toy_points_

    def read(self, model, f) -> None:
        model.toy_table_, model.toy_points_ = f["toy/table"][()], f["toy/points"][()]

    def onnx(self, spec, include_surface, opset):
        raise ValueError("a toy model has no ONNX export")

    def c_header(self, spec, include_surface, prefix):
        raise ValueError("a toy model has no C export")


@pytest.fixture
def toy(monkeypatch):
    register_model_kind(ToyKind)
    arch = dict(kind="toy", normalise="none", clip_negative=False, train_on="means")
    monkeypatch.setitem(ARCHITECTURES, "toy", arch)
    yield
    unregister_model_kind("toy")


def _data(n_touches: int = 12, n: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    means = rng.uniform(0, 400, (n_touches, n))
    groups = np.repeat(np.arange(n_touches), 3)
    X = means[groups] + rng.normal(0, 1, (len(groups), n))
    y = rng.uniform(-0.05, 0.05, (n_touches, 3))[groups]
    return X, y, groups


def test_a_toy_kind_trains_saves_loads_and_predicts(toy, tmp_path):
    X, y, groups = _data()
    model = ContactLocalizer(arch="toy", constraint="none").fit(X, y, groups=groups)
    assert model.kind is model_kind("toy") and model.spec().kind == "toy"
    path = tmp_path / "toy.h5"
    model.save(path)
    loaded = ContactLocalizer.load(path)
    assert loaded.config_["kind"] == "toy"
    np.testing.assert_allclose(loaded.predict(X), y, atol=1e-9)  # its own touches, exactly
    engine = load_engine(path)
    assert isinstance(engine, ToyEngine)
    point, _, _ = engine.predict_one(X[4])
    np.testing.assert_allclose(point, y[4], atol=1e-9)
    with pytest.raises(ValueError, match="sensor images must have shape \\(n, 64\\)"):
        loaded.predict(np.zeros((2, 65)))
    # a kind that does not say how it recalibrated gets the common account
    again = model.recalibrate(X[:6], y[:6], groups=groups[:6])
    assert again.recalibration_["method"] == "adapted"
    assert again.recalibration_["summary"] == "adapted the toy model to 2 new touches"
    assert model.recalibrate(X[:0], y[:0]).recalibration_["n_touches"] == 0
    with pytest.raises(ValueError, match="toy model has no ONNX export"):
        from skinloc.models.export import onnx_model

        onnx_model(path)
    # the live pipeline builds on it too: the engine declares what SkinCore reads
    from skinloc.live.core import SkinCore

    core = SkinCore(path)
    core.set_baseline(np.zeros((10, 64)))
    core.process_frame(X[0].astype(np.float32), timestamp_s=0.0, index=0)
    # the kind's typed config refuses what it cannot take
    with pytest.raises(ValueError, match="normalise='none'"):
        ContactLocalizer(arch="toy", normalise="l2").fit(X, y)


def test_a_file_of_a_kind_not_registered_is_one_clear_error(toy, tmp_path):
    X, y, groups = _data()
    path = tmp_path / "toy.h5"
    ContactLocalizer(arch="toy", constraint="none").fit(X, y, groups=groups).save(path)
    unregister_model_kind("toy")
    with pytest.raises(ModelFileError, match="unknown model kind 'toy'; registered: map, network"):
        ContactLocalizer.load(path)


def test_a_kind_is_registered_once_and_must_be_one():
    with pytest.raises(ValueError, match="already registered as 'map'"):
        register_model_kind(type(model_kind("map")))
    with pytest.raises(TypeError, match="not a ModelKind"):
        register_model_kind(object())
