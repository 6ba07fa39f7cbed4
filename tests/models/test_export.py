"""Exports: ONNX through onnxruntime within 1e-5 m; the C header through gcc within 1e-4 m."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from skinloc.models.export import c_header_source, export_c_header, export_onnx
from skinloc.models.localizer import ContactLocalizer
from tests._live import calibration, model_path

_MAIN = r"""
#include <stdio.h>
#include "model.h"
int main(void) {
    float x[SKINLOC_N_INPUTS], raw[3], point[3];
    int i;
    for (;;) {
        for (i = 0; i < SKINLOC_N_INPUTS; i++)
            if (scanf("%f", &x[i]) != 1) return 0;
        float s = skinloc_predict(x, raw, point);
        printf("%.9g %.9g %.9g %.9g %.9g %.9g %.9g\n",
               raw[0], raw[1], raw[2], point[0], point[1], point[2], s);
    }
}
"""


def _frames() -> np.ndarray:
    return calibration().deltas.reshape(-1, 64)[::2].astype(np.float32)


@pytest.mark.parametrize("kind", ["map", "mlp", "paper", "gelu"])
def test_onnx_matches_python(kind, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    model = ContactLocalizer.load(model_path(kind))
    X = _frames()
    ref = model.engine().predict(X)  # the one implementation of prediction
    path = export_onnx(model, tmp_path / "m.onnx")
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    points, raw, spread = sess.run(None, {"frames": X})
    np.testing.assert_allclose(raw, ref.raw, atol=1e-5)
    # snapped points: identical, except where two surface points are equally near in float32
    same = np.abs(points - ref.points).max(axis=1) < 1e-5
    assert same.mean() > 0.99
    want = np.nan_to_num(ref.uncertainty_mm, nan=0.0)
    np.testing.assert_allclose(spread, want, atol=1e-2)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="gcc not found")
@pytest.mark.parametrize("kind", ["mlp", "paper", "gelu"])
def test_c_header_compiled_with_gcc_matches_python(kind, tmp_path):
    model = ContactLocalizer.load(model_path(kind))
    export_c_header(model, tmp_path / "model.h")
    (tmp_path / "main.c").write_text(_MAIN)
    exe = tmp_path / "predict"
    subprocess.run(
        ["gcc", "-std=c99", "-O2", "-Wall", "-Wextra", "-Werror", "-o", str(exe),
         str(tmp_path / "main.c"), "-lm"],
        check=True,
        capture_output=True,
    )  # fmt: skip
    X = _frames()
    text = "\n".join(" ".join(f"{v:.9g}" for v in row) for row in X)
    out = subprocess.run([str(exe)], input=text, capture_output=True, text=True, check=True)
    got = np.array([[float(v) for v in ln.split()] for ln in out.stdout.strip().splitlines()])
    ref = model.engine().predict(X)  # the one implementation of prediction
    np.testing.assert_allclose(got[:, :3], ref.raw, atol=1e-4)
    assert (np.abs(got[:, 3:6] - ref.points).max(axis=1) < 1e-4).mean() > 0.99


def test_c_header_refuses_a_response_map_and_bad_prefix():
    with pytest.raises(ValueError, match="too big for a microcontroller"):
        c_header_source(model_path("map"))
    with pytest.raises(ValueError, match="identifier"):
        c_header_source(model_path("paper"), prefix="not an id")
    text = c_header_source(model_path("paper"), include_surface=False, prefix="left")
    assert "left_predict" in text and "#define LEFT_N_SURFACE" not in text
