"""Export a trained localiser: ONNX for a robot computer, a C header for the microcontroller.

Both exports are built from the model's spec (``models.engine``: the weights, the map table and
the preprocessing as arrays), the arrays its engine predicts from, and are tested against that
engine:

* ``export_onnx``: input ``frames (n, n_features)`` float32 baseline-subtracted counts; outputs
  ``points (n, 3)`` m (snapped to the model's surface points when its constraint is ``snap``,
  otherwise the raw output), ``raw (n, 3)`` m and ``uncertainty_mm (n,)`` (0 for one network).
  Opset 17; checked against onnxruntime in the tests (within 1e-5 m).
* ``export_c_header``: one self-contained C99 header with the weights as ``const float`` arrays
  (in flash: ``PROGMEM`` on AVR) and ``skinloc_predict(x, raw, point)``; checked on the host with
  gcc in the tests (within 1e-4 m).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._lazy import require_extra
from skinloc.models.engine import ModelSpec
from skinloc.models.kinds import model_kind

log = logging.getLogger(__name__)

__all__ = [
    "c_header_source",
    "export_c_header",
    "export_onnx",
    "map_onnx",
    "network_c_header",
    "network_onnx",
    "onnx_model",
]


def _spec(model: Any) -> ModelSpec:
    if isinstance(model, ModelSpec):
        return model
    if isinstance(model, str | Path):
        return ModelSpec.load(model)
    return model.spec()


# --------------------------------------------------------------------------------------------
# ONNX


def onnx_model(model: Any, *, include_surface: bool = True, opset: int = 17) -> Any:
    """The localiser as an ``onnx.ModelProto``.

    Parameters
    ----------
    model : ContactLocalizer, ModelSpec or path
        The trained model.
    include_surface : bool, default=True
        Snap ``points`` to the model's surface points (an exact nearest-point search over all
        of them); otherwise ``points`` equals ``raw``.
    opset : int, default=17
        ONNX opset.
    """
    require_extra("onnx", "ONNX export")
    s = _spec(model)
    return model_kind(s.kind).onnx(s, include_surface, opset)


def network_onnx(s: Any, include_surface: bool, opset: int) -> Any:
    """A network ensemble's spec as ONNX (the ``network`` kind's export, ``onnx_model``)."""
    from onnx import helper, numpy_helper

    f32 = np.float32
    inits: list[Any] = []
    nodes: list[Any] = []

    def const(name: str, arr: Any) -> str:
        inits.append(numpy_helper.from_array(np.asarray(arr, dtype=f32), name))
        return name

    def const_i64(name: str, arr: Any) -> str:
        inits.append(numpy_helper.from_array(np.asarray(arr, dtype=np.int64), name))
        return name

    def node(op: str, inputs: list[str], output: str, **attrs: Any) -> str:
        nodes.append(helper.make_node(op, inputs, [output], **attrs))
        return output

    h = "frames"
    if s.clip_negative:
        h = node("Relu", [h], "clipped")
    if s.normalise != "none":
        op = "ReduceL1" if s.normalise == "l1" else "ReduceL2"
        n = node(op, [h], "norm", axes=[1], keepdims=1)
        n = node("Max", [n, const("one", [1.0])], "norm_floor")
        h = node("Div", [h, n], "normalised")
    h = node("Sub", [h, const("feature_mean", s.feature_mean)], "centred")
    h = node("Div", [h, const("feature_scale", s.feature_scale)], "features")
    h = node("Unsqueeze", [h, const_i64("axis0", [0])], "features_e")  # (1, n, F)
    L = len(s.weights)
    for i, (W, b) in enumerate(zip(s.weights, s.biases, strict=True)):
        h = node("MatMul", [h, const(f"W{i}", W)], f"mm{i}")  # (E, n, out)
        h = node("Add", [h, const(f"b{i}", b)], f"lin{i}")
        if i < L - 1:
            if s.activation == "relu":
                h = node("Relu", [h], f"act{i}")
            elif s.activation == "tanh":
                h = node("Tanh", [h], f"act{i}")
            else:
                e = node("Mul", [h, const(f"inv_sqrt2_{i}", [1 / np.sqrt(2.0)])], f"gs{i}")
                e = node("Erf", [e], f"ge{i}")
                e = node("Add", [e, const(f"g1_{i}", [1.0])], f"g1p{i}")
                e = node("Mul", [h, e], f"gm{i}")
                h = node("Mul", [e, const(f"ghalf_{i}", [0.5])], f"act{i}")
    y = node("Mul", [h, const("target_scale", [s.target_scale])], "scaled")
    y = node("Add", [y, const("target_mean", s.target_mean)], "members")  # (E, n, 3)
    node("ReduceMean", [y], "raw", axes=[0], keepdims=0)
    d = node("Sub", [y, "raw"], "member_dev")
    d = node("Mul", [d, d], "member_dev2")
    d = node("ReduceSum", [d, const_i64("axis2", [2])], "member_d2", keepdims=0)
    d = node("ReduceMean", [d], "member_var", axes=[0], keepdims=0)
    d = node("Sqrt", [d], "member_sd")
    node("Mul", [d, const("to_mm", [1e3])], "uncertainty_mm")
    if include_surface and s.constraint == "snap" and s.surface_points is not None:
        P = np.asarray(s.surface_points, dtype=f32)
        q = node("Unsqueeze", [("raw"), const_i64("axis1", [1])], "raw_q")  # (n, 1, 3)
        diff = node("Sub", [q, const("surface_points", P[None])], "snap_diff")  # (n, P, 3)
        d2 = node("Mul", [diff, diff], "snap_diff2")
        d2 = node("ReduceSum", [d2, const_i64("axis2b", [2])], "snap_d2", keepdims=0)
        idx = node("ArgMin", [d2], "snap_idx", axis=1, keepdims=0, select_last_index=0)
        node("Gather", ["surface_points_flat", idx], "points", axis=0)
        inits.append(numpy_helper.from_array(P, "surface_points_flat"))
    else:
        node("Identity", ["raw"], "points")
    return _finish_onnx(
        nodes,
        inits,
        "skinloc_localizer",
        s.n_features,
        opset,
        doc=(
            "frames: baseline-subtracted counts (n, n_features). points: contact on the skin, m "
            f"(constraint: {s.constraint if include_surface else 'none'}). raw: network output, "
            "m. uncertainty_mm: ensemble spread."
        ),
        props={
            "skinloc.constraint": s.constraint if include_surface else "none",
            "skinloc.units": "m",
            "skinloc.n_members": str(s.n_members),
        },
    )


def _finish_onnx(
    nodes: list[Any],
    inits: list[Any],
    name: str,
    n_features: int,
    opset: int,
    doc: str,
    props: dict[str, str],
) -> Any:
    """The checked model of a graph from ``frames (n, n_features)`` to the three outputs."""
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph(
        nodes,
        name,
        [helper.make_tensor_value_info("frames", TensorProto.FLOAT, ["n", n_features])],
        [
            helper.make_tensor_value_info("points", TensorProto.FLOAT, ["n", 3]),
            helper.make_tensor_value_info("raw", TensorProto.FLOAT, ["n", 3]),
            helper.make_tensor_value_info("uncertainty_mm", TensorProto.FLOAT, ["n"]),
        ],
        inits,
    )
    m = helper.make_model(
        graph,
        opset_imports=[helper.make_opsetid("", opset)],
        producer_name="skinloc",
        doc_string=doc,
    )
    m.ir_version = min(m.ir_version, 9)
    helper.set_model_props(m, props)
    onnx.checker.check_model(m)
    return m


def map_onnx(s: Any, opset: int) -> Any:
    """A response map's spec as ONNX: the coarse-to-fine search of ``ResponseMap.match``."""
    from onnx import helper, numpy_helper

    table = np.asarray(s.table, dtype=np.float32)
    sq = (table**2).sum(axis=1).astype(np.float32)
    coarse = np.asarray(s.coarse, dtype=np.int64)
    cells = np.asarray(s.cells, dtype=np.int64)
    n_best = min(int(s.n_cells), len(coarse))
    inits = [
        numpy_helper.from_array(table, "table"),
        numpy_helper.from_array(sq, "table_sq"),
        numpy_helper.from_array(np.ascontiguousarray(table[coarse].T), "coarse_table_t"),
        numpy_helper.from_array(sq[coarse], "coarse_sq"),
        numpy_helper.from_array(cells, "cells"),
        numpy_helper.from_array(np.asarray(s.surface_points, dtype=np.float32), "candidates"),
        numpy_helper.from_array(np.array([n_best], dtype=np.int64), "n_best"),
        numpy_helper.from_array(np.array([0, -1], dtype=np.int64), "flat_shape"),
        numpy_helper.from_array(np.array([1], dtype=np.int64), "ax1"),
        numpy_helper.from_array(np.array([2], dtype=np.int64), "ax2"),
        numpy_helper.from_array(np.array([-1], dtype=np.int64), "ax_last"),
        numpy_helper.from_array(np.array([1.0], dtype=np.float32), "one"),
        numpy_helper.from_array(np.array([-2.0], dtype=np.float32), "minus_two"),
        numpy_helper.from_array(np.array([0.0], dtype=np.float32), "zero"),
        numpy_helper.from_array(np.array([2.0 * s.noise], dtype=np.float32), "two_noise"),
        numpy_helper.from_array(np.array([1e3], dtype=np.float32), "to_mm"),
    ]
    N: list[Any] = []

    def node(op: str, inputs: list[str], output: str | list[str], **attrs: Any) -> Any:
        outs = [output] if isinstance(output, str) else output
        N.append(helper.make_node(op, inputs, outs, **attrs))
        return output

    h = "frames"
    if s.clip_negative:
        h = node("Relu", [h], "clipped")
    nrm = node("ReduceL2", [h], "norm", axes=[1], keepdims=1)
    nrm = node("Max", [nrm, "one"], "norm_floor")
    F = node("Div", [h, nrm], "features")  # (n, k)
    ff = node("Mul", [F, F], "f2")
    ff = node("ReduceSum", [ff, "ax1"], "ff", keepdims=1)  # (n, 1)
    dc = node("MatMul", [F, "coarse_table_t"], "coarse_dot")  # (n, C)
    dc = node("Mul", [dc, "minus_two"], "coarse_m2")
    dc = node("Add", [dc, "coarse_sq"], "coarse_d")
    neg = node("Neg", [dc], "coarse_neg")
    node("TopK", [neg, "n_best"], ["best_val", "best_cells"], axis=1, largest=1, sorted=1)
    idx = node("Gather", ["cells", "best_cells"], "fine_idx3", axis=0)  # (n, b, m)
    idx = node("Reshape", [idx, "flat_shape"], "fine_idx")  # (n, b*m)
    rows = node("Gather", ["table", idx], "fine_rows", axis=0)  # (n, b*m, k)
    fcol = node("Unsqueeze", [F, "ax_last"], "f_col")  # (n, k, 1)
    dot = node("MatMul", [rows, fcol], "fine_dot3")
    dot = node("Squeeze", [dot, "ax_last"], "fine_dot")  # (n, b*m)
    fsq = node("Gather", ["table_sq", idx], "fine_sq", axis=0)
    d = node("Mul", [dot, "minus_two"], "fine_m2")
    d = node("Add", [d, fsq], "fine_d0")
    d = node("Add", [d, ff], "fine_d1")
    d = node("Max", [d, "zero"], "fine_d")
    am = node("ArgMin", [d], "fine_am", axis=1, keepdims=1, select_last_index=0)
    best = node("GatherElements", [idx, am], "best_idx2", axis=1)  # (n, 1)
    best = node("Squeeze", [best, "ax1"], "best_idx")
    node("Gather", ["candidates", best], "points", axis=0)
    node("Identity", ["points"], "raw")
    dmin = node("ReduceMin", [d], "dmin", axes=[1], keepdims=1)
    scale = node("Max", [dmin, "two_noise"], "scale")
    e = node("Sub", [d, dmin], "d_rel")
    e = node("Div", [e, scale], "d_scaled")
    e = node("Neg", [e], "d_neg")
    w = node("Exp", [e], "w")
    cand = node("Gather", ["candidates", idx], "fine_cand", axis=0)  # (n, b*m, 3)
    pcol = node("Unsqueeze", ["points", "ax1"], "points_col")  # (n, 1, 3)
    diff = node("Sub", [cand, pcol], "cand_diff")
    diff = node("Mul", [diff, diff], "cand_diff2")
    dist2 = node("ReduceSum", [diff, "ax2"], "cand_d2", keepdims=0)  # (n, b*m)
    num = node("Mul", [w, dist2], "w_d2")
    num = node("ReduceSum", [num, "ax1"], "w_d2_sum", keepdims=0)
    den = node("ReduceSum", [w, "ax1"], "w_sum", keepdims=0)
    v = node("Div", [num, den], "spread2")
    v = node("Sqrt", [v], "spread")
    node("Mul", [v, "to_mm"], "uncertainty_mm")
    return _finish_onnx(
        N,
        inits,
        "skinloc_response_map",
        s.n_features,
        opset,
        doc=(
            "frames: baseline-subtracted counts (n, n_features). points = raw: the surface "
            "candidate whose response-map value best matches the image's shape, m. "
            "uncertainty_mm: likelihood-weighted spread of the searched candidates."
        ),
        props={"skinloc.kind": "map", "skinloc.units": "m"},
    )


def export_onnx(model: Any, path: str | Path, *, include_surface: bool = True) -> Path:
    """Write the localiser as an ONNX file; returns the path."""
    proto = onnx_model(model, include_surface=include_surface)  # says which extra is missing
    import onnx

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(proto, str(path))
    return path


# --------------------------------------------------------------------------------------------
# C header


def _c_array(name: str, arr: np.ndarray, per_line: int = 8) -> str:
    flat = np.asarray(arr, dtype=np.float32).ravel()
    vals = [f"{v:.9g}f" if np.isfinite(v) else "0.0f" for v in flat.tolist()]
    lines = [", ".join(vals[i : i + per_line]) for i in range(0, len(vals), per_line)]
    body = ",\n    ".join(lines)
    return f"static SKINLOC_CONST float {name}[{len(flat)}] = {{\n    {body}\n}};\n"


def c_header_source(model: Any, *, include_surface: bool = True, prefix: str = "skinloc") -> str:
    """The C header text for ``model`` (see ``export_c_header``); its kind's, or a ValueError."""
    if not prefix.isidentifier():
        raise ValueError(f"the C prefix must be an identifier, got {prefix!r}")
    s = _spec(model)
    return model_kind(s.kind).c_header(s, include_surface, prefix)


def network_c_header(s: Any, include_surface: bool, prefix: str) -> str:
    """A network ensemble's spec as a C99 header (the ``network`` kind's export)."""
    from skinloc import __version__

    P = prefix
    U = prefix.upper()
    E = s.n_members
    sizes = s.layer_sizes
    widest = max(E * w for w in sizes)
    snap = include_surface and s.constraint == "snap" and s.surface_points is not None
    n_params = sum(W.size + b.size for W, b in zip(s.weights, s.biases, strict=True))
    out = [
        f"/* {P}: contact localiser exported by skinloc {__version__}.",
        f" * Network {'-'.join(map(str, sizes))}, {E} member(s), activation {s.activation},",
        f" * normalise {s.normalise}, clip_negative {int(s.clip_negative)}; {n_params} weights"
        f" ({4 * n_params} bytes)" + (f" + {len(s.surface_points)} snap points." if snap else "."),
        " *",
        f" * float {P}_predict(const float x[{U}_N_INPUTS], float raw[3], float point[3]);",
        " *   x: baseline-subtracted sensor counts, TX-major.",
        " *   raw: network output (ensemble mean), m, in the skin mesh frame.",
        " *   point: raw snapped to the nearest surface point, m (= raw without surface).",
        " *   returns the ensemble spread in mm (0 for a single network).",
        " * Weights live in flash (PROGMEM on AVR); RAM use is two scratch buffers of",
        f" * {widest} floats. Define {U}_NO_SURFACE before including to leave the snap out.",
        " */",
        f"#ifndef {U}_MODEL_H",
        f"#define {U}_MODEL_H",
        "#include <math.h>",
        "#if defined(__AVR__)",
        "#include <avr/pgmspace.h>",
        "#define SKINLOC_CONST const PROGMEM",
        "#define SKINLOC_READ(a, i) pgm_read_float(&(a)[i])",
        "#else",
        "#define SKINLOC_CONST const",
        "#define SKINLOC_READ(a, i) ((a)[i])",
        "#endif",
        f"#define {U}_N_INPUTS {s.n_features}",
        f"#define {U}_N_MEMBERS {E}",
        f"#define {U}_N_LAYERS {len(s.weights)}",
        f"#define {U}_WIDEST {widest}",
        f"#define {U}_ACT_{s.activation.upper()} 1",
        "",
        _c_array(f"{P}_feature_mean", s.feature_mean),
        _c_array(f"{P}_feature_scale", s.feature_scale),
        _c_array(f"{P}_target", np.concatenate([[s.target_scale], s.target_mean])),
    ]
    for i, (W, b) in enumerate(zip(s.weights, s.biases, strict=True)):
        out.append(f"/* layer {i}: (members, in, out) = {W.shape} */")
        out.append(_c_array(f"{P}_w{i}", W))
        out.append(_c_array(f"{P}_b{i}", b))
    if snap:
        out.append(f"#ifndef {U}_NO_SURFACE")
        out.append(f"#define {U}_N_SURFACE {len(s.surface_points)}")
        out.append(_c_array(f"{P}_surface", s.surface_points, per_line=6))
        out.append("#endif")
    out.append(f"static const int {P}_sizes[{len(sizes)}] = {{{', '.join(map(str, sizes))}}};")
    act = {
        "relu": "v > 0.0f ? v : 0.0f",
        "tanh": "tanhf(v)",
        "gelu": "0.5f * v * (1.0f + erff(v * 0.70710678f))",
    }[s.activation]
    norm = {
        "none": "",
        "l1": "nrm += fabsf(v);",
        "l2": "nrm += v * v;",
    }[s.normalise]
    weights = ", ".join(f"{P}_w{i}" for i in range(len(s.weights)))
    biases = ", ".join(f"{P}_b{i}" for i in range(len(s.weights)))
    out.append(
        f"""
static float {P}_act(float v) {{ return {act}; }}

static float {P}_predict(const float *x, float raw[3], float point[3]) {{
    static float buf_a[{U}_WIDEST], buf_b[{U}_WIDEST], feat[{U}_N_INPUTS];
    const float *ws[{U}_N_LAYERS] = {{{weights}}};
    const float *bs[{U}_N_LAYERS] = {{{biases}}};
    float members[{U}_N_MEMBERS][3];
    float nrm = 0.0f, inv = 1.0f;
    int i, j, e, k, layer;
    for (i = 0; i < {U}_N_INPUTS; i++) {{
        float v = x[i];
        {"if (v < 0.0f) v = 0.0f;" if s.clip_negative else ""}
        {norm}
        feat[i] = v;
    }}
    {"nrm = sqrtf(nrm);" if s.normalise == "l2" else ""}
    {"if (nrm > 1.0f) inv = 1.0f / nrm;" if s.normalise != "none" else "(void)nrm;"}
    for (i = 0; i < {U}_N_INPUTS; i++)
        feat[i] = (feat[i] * inv - SKINLOC_READ({P}_feature_mean, i))
                  / SKINLOC_READ({P}_feature_scale, i);
    for (e = 0; e < {U}_N_MEMBERS; e++) {{
        const float *in = feat;
        for (layer = 0; layer < {U}_N_LAYERS; layer++) {{
            int fin = {P}_sizes[layer], fout = {P}_sizes[layer + 1];
            const float *W = ws[layer] + (long)e * fin * fout;
            const float *B = bs[layer] + (long)e * fout;
            float *dst = (layer % 2 == 0) ? buf_a : buf_b;
            for (j = 0; j < fout; j++) {{
                float acc = SKINLOC_READ(B, j);
                for (i = 0; i < fin; i++) acc += in[i] * SKINLOC_READ(W, (long)i * fout + j);
                dst[j] = (layer < {U}_N_LAYERS - 1) ? {P}_act(acc) : acc;
            }}
            in = dst;
        }}
        for (k = 0; k < 3; k++)
            members[e][k] = in[k] * SKINLOC_READ({P}_target, 0) + SKINLOC_READ({P}_target, k + 1);
    }}
    float spread = 0.0f;
    for (k = 0; k < 3; k++) {{
        float m = 0.0f;
        for (e = 0; e < {U}_N_MEMBERS; e++) m += members[e][k];
        raw[k] = m / {U}_N_MEMBERS;
    }}
    for (e = 0; e < {U}_N_MEMBERS; e++)
        for (k = 0; k < 3; k++) {{
            float d = members[e][k] - raw[k];
            spread += d * d;
        }}
    spread = 1000.0f * sqrtf(spread / {U}_N_MEMBERS);
    point[0] = raw[0]; point[1] = raw[1]; point[2] = raw[2];
#if defined({U}_N_SURFACE)
    {{
        float best = 3.4e38f;
        long p;
        for (p = 0; p < {U}_N_SURFACE; p++) {{
            float d0 = SKINLOC_READ({P}_surface, 3 * p) - raw[0];
            float d1 = SKINLOC_READ({P}_surface, 3 * p + 1) - raw[1];
            float d2 = SKINLOC_READ({P}_surface, 3 * p + 2) - raw[2];
            float d = d0 * d0 + d1 * d1 + d2 * d2;
            if (d < best) {{
                best = d;
                point[0] = SKINLOC_READ({P}_surface, 3 * p);
                point[1] = SKINLOC_READ({P}_surface, 3 * p + 1);
                point[2] = SKINLOC_READ({P}_surface, 3 * p + 2);
            }}
        }}
    }}
#endif
    return spread;
}}

#endif /* {U}_MODEL_H */
"""
    )
    return "\n".join(out)


def export_c_header(
    model: Any, path: str | Path, *, include_surface: bool = True, prefix: str = "skinloc"
) -> Path:
    """Write a self-contained C header with the weights and ``<prefix>_predict``.

    Parameters
    ----------
    model : ContactLocalizer, ModelSpec or path
        The trained model.
    path : str or Path
        Header to write (``.h``).
    include_surface : bool, default=True
        Include the snap points (``P x 3`` floats; leave them out on small boards).
    prefix : str, default="skinloc"
        Prefix of every C name, so two models can live in one sketch.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(c_header_source(model, include_surface=include_surface, prefix=prefix))
    return path
