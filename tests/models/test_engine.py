"""The engine: one implementation per model kind; model files of main; no PyTorch by default."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from skinloc.errors import MissingExtraError
from skinloc.models.engine import Engine, ModelSpec, load_engine
from skinloc.models.localizer import ContactLocalizer
from tests._live import calibration, model_path

GOLDEN = Path(__file__).parents[1] / "golden"


@pytest.mark.parametrize("arch", ["default", "paper", "mlp"])
def test_model_files_written_by_main_load_and_predict_as_before(arch):
    # written by skinloc at commit 780f4d6 (tests/golden/make_model_main.py), before the engine
    want = np.load(GOLDEN / "model_main_predictions.npz")
    model = ContactLocalizer.load(GOLDEN / f"model_main_{arch}.h5")
    got = model.predict_full(want["frames"])
    np.testing.assert_allclose(got.raw, want[f"{arch}_raw"], atol=1e-6)
    assert np.mean(np.abs(got.points - want[f"{arch}_points"]).max(axis=1) < 1e-9) >= 0.95
    np.testing.assert_allclose(
        got.uncertainty_mm, want[f"{arch}_uncertainty_mm"], atol=1e-3, equal_nan=True
    )


@pytest.mark.parametrize("kind", ["map", "mlp"])
def test_a_frame_alone_and_in_a_batch_gets_the_same_answer(kind):
    engine = load_engine(model_path(kind))
    X = calibration().deltas.reshape(-1, 64).astype(np.float32)
    points, raw, spread = engine.predict_batch(X)
    assert len(X) > 128  # a map's batch path (chunks of 128 rows), not its few-rows path
    few = engine.predict_batch(X[:5])
    np.testing.assert_allclose(few[1], raw[:5], atol=1e-6 if kind == "mlp" else 0)
    out = np.empty(7)
    for i in range(0, len(X), 7):
        engine.localise_into(X[i], out)
        np.testing.assert_allclose(out[:3], raw[i], atol=1e-6 if kind == "mlp" else 0)
        np.testing.assert_array_equal(out[3:6], points[i]) if kind == "map" else None
        assert np.isclose(out[6], spread[i], atol=1e-4)


def test_every_path_to_an_engine_gives_the_same_kind_and_answer():
    path = model_path("map")
    model = ContactLocalizer.load(path)
    X = calibration().touch_means.astype(np.float32)
    engines = [
        model.engine(),
        Engine.from_model(path),
        Engine.from_model(ModelSpec.load(path)),
        load_engine(model),
    ]
    assert {e.kind for e in engines} == {"map"}
    ref = engines[0].predict_batch(X)[0]
    for e in engines[1:]:
        np.testing.assert_array_equal(e.predict_batch(X)[0], ref)
    assert load_engine(engines[0]) is engines[0]


def test_engine_rejects_images_of_the_wrong_width():
    engine = load_engine(model_path("paper"))
    with pytest.raises(ValueError, match=r"shape \(n, 64\)"):
        engine.predict_batch(np.zeros((3, 63)))
    with pytest.raises(ValueError, match=r"shape \(64,\)"):
        engine.predict_one(np.zeros(65))


def test_recalibrated_model_predicts_with_its_own_engine():
    model = ContactLocalizer.load(model_path("map"))
    cal = calibration()
    before = model.predict(cal.touch_means)
    new = model.recalibrate(cal.touch_means[:5] * 0.5, cal.targets[:5])
    assert new.engine() is not model.engine()
    np.testing.assert_array_equal(model.predict(cal.touch_means), before)


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=Path(__file__).parents[2],
    )


def test_the_default_path_never_imports_torch(tmp_path):
    res = _run(
        f"""
        import sys
        from pathlib import Path
        import skinloc
        from skinloc.calibration.session import SessionConfig, simulate_session
        from skinloc.data.recording import read_recording
        from skinloc.evaluation.scoring import evaluate, train_localizer
        from skinloc.geometry.mesh import cone_skin
        from skinloc.models.localizer import ContactLocalizer
        from skinloc.live.core import SkinCore
        from skinloc.sim.skin import SimulatedSkin

        mesh = cone_skin()
        out = Path({str(tmp_path)!r})
        with SimulatedSkin(mesh, random_state=0) as skin:
            cal = simulate_session(skin, mesh, out / "cal.h5",
                SessionConfig(n_points=12, mode="even", samples_per_touch=3, random_state=0))
        model = train_localizer([read_recording(out / "cal.h5")])
        model.save(out / "m.h5")
        loaded = ContactLocalizer.load(out / "m.h5")
        loaded.predict(cal.touch_means)
        evaluate(loaded, [cal])
        SkinCore(out / "m.h5")
        print("torch" in sys.modules)
        """
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip().splitlines()[-1] == "False"


def test_a_network_predicts_without_torch_and_training_one_names_the_extra():
    path = model_path("paper")
    res = _run(
        f"""
        import sys
        sys.modules["torch"] = None  # as if PyTorch were not installed
        import numpy as np
        from skinloc.errors import MissingExtraError
        from skinloc.models.localizer import ContactLocalizer

        model = ContactLocalizer.load({str(path)!r})
        print(model.predict(np.zeros((2, 64))).shape)
        try:
            model.recalibrate(np.ones((4, 64)), np.zeros((4, 3)))
        except MissingExtraError as exc:
            print(exc)
        """
    )
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    assert lines[0] == "(2, 3)"
    assert "pip install 'skinloc[nets]'" in lines[1] and "'paper' network" in lines[1]


def test_missing_extra_is_a_skinloc_error_the_cli_reports_in_one_line():
    from skinloc.errors import SkinlocError

    assert issubclass(MissingExtraError, SkinlocError) and issubclass(
        MissingExtraError, ImportError
    )


def test_training_a_network_without_torch_is_one_line_naming_the_extra(monkeypatch, tmp_path):
    # the message holds brackets, which the CLI's console must print as they are
    from typer.testing import CliRunner

    from skinloc.cli.main import app

    monkeypatch.setitem(sys.modules, "torch", None)  # as if PyTorch were not installed
    res = CliRunner().invoke(
        app, ["train", str(calibration_path()), "--arch", "paper", "--out", str(tmp_path / "m.h5")]
    )
    assert res.exit_code == 1
    assert "error: training the 'paper' network needs PyTorch: pip install 'skinloc[nets]'" in (
        res.output
    )
    assert "Traceback" not in res.output and not (tmp_path / "m.h5").exists()


def calibration_path() -> Path:
    calibration()
    from tests._live import _DIR

    return _DIR / "cal.h5"


def test_one_model_predicts_from_several_threads_at_once():
    # the app predicts from its server and its device threads with one model
    from concurrent.futures import ThreadPoolExecutor

    model = ContactLocalizer.load(model_path("map"))
    X = calibration().deltas.reshape(-1, 64)
    want = model.predict(X)
    rows = [X[i : i + 3] for i in range(0, 120, 3)]
    with ThreadPoolExecutor(4) as pool:
        got = list(pool.map(model.predict, rows + [X, X]))
    np.testing.assert_array_equal(np.concatenate(got[: len(rows)]), want[:120])
    np.testing.assert_array_equal(got[-1], want)


def test_a_spec_with_a_mesh_but_no_snap_points_samples_them_in_the_engine():
    # the sampling moved from geometry.snap (which no longer imports geometry.mesh) to here
    from dataclasses import replace

    from skinloc.geometry.snap import Surface

    spec = ModelSpec.load(model_path("mlp"))
    assert spec.constraint == "snap" and spec.vertices is not None
    bare = replace(spec, surface_points=None)
    X = calibration().deltas.reshape(-1, 64)[:20].astype(np.float32)
    points = bare.engine().predict(X).points
    np.testing.assert_allclose(points, spec.engine().predict(X).points, atol=1e-6)
    with pytest.raises(ValueError, match="needs its surface points"):
        Surface("snap", None, spec.vertices, spec.faces)
