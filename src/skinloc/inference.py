"""A fast inference path for a trained localiser: one frame in a few microseconds, batches in bulk.

``InferenceSpec`` is the minimal surface the online path needs from a model: the preprocessing
parameters and the layer weights as NumPy arrays, the activation, and the skin surface. It is read
from a ``ContactLocalizer``'s fitted attributes (or straight from the saved HDF5 artifact), so this
module never touches the model's internals beyond what ``save`` writes. If ``ContactLocalizer``
gains an ``inference_spec()`` method, that is used instead (the accessor can move into
``model.py`` as is).

``FastLocalizer`` folds the standardisation into the first layer, lays the ensemble out so that
one pass over the weights serves every member, and runs the whole chain (features, network,
ensemble mean and spread, surface constraint) in one compiled kernel (numba) per frame. Batches
go through BLAS matrix products and a parallel exact nearest-point search. Without numba it falls
back to the same arithmetic in NumPy (and a KD-tree), slower but identical in results.

Units: input images are baseline-subtracted counts, output points metres, spread millimetres.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._typing import Frames, Points

log = logging.getLogger(__name__)

__all__ = ["HAVE_NUMBA", "FastLocalizer", "InferenceSpec", "SnapIndex", "closest_on_triangles"]

try:  # numba is a dependency; the fallback keeps skinloc usable where it cannot be installed
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    numba = None
    HAVE_NUMBA = False

_prange = numba.prange if HAVE_NUMBA else range
_ACTIVATIONS = {"relu": 0, "tanh": 1, "gelu": 2}
_NORMS = {"none": 0, "l1": 1, "l2": 2}
_CONSTRAINTS = {"none": 0, "snap": 1, "project": 2}


def _jit(**kw: Any):
    """``numba.njit(cache=True, fastmath=True, nogil=True, **kw)``, or the plain function."""
    if not HAVE_NUMBA:
        return lambda fn: fn
    return numba.njit(cache=True, fastmath=True, nogil=True, **kw)


# --------------------------------------------------------------------------------------------
# the spec


@dataclass
class InferenceSpec:
    """Everything prediction needs, as plain arrays (the model's public contract for export).

    Prediction for baseline-subtracted counts ``x (n_features,)``::

        z = max(x, 0) if clip_negative else x
        z = z / max(||z||_p, 1)            # p from normalise: none, l1, l2
        h = (z - feature_mean) / feature_scale
        h = act(h @ W[i][m] + b[i][m])     # per member m, every layer but the last
        y_m = (h @ W[-1][m] + b[-1][m]) * target_scale + target_mean     # metres
        raw = mean_m y_m ;  spread_mm = 1e3 * sqrt(mean_m |y_m - raw|^2)

    Attributes
    ----------
    n_features : int
        Sensors per image.
    clip_negative : bool
        Zero negative deltas before normalising.
    normalise : {"none", "l1", "l2"}
        Image norm divided out (with a floor of 1 count).
    activation : {"relu", "tanh", "gelu"}
        Hidden activation.
    feature_mean, feature_scale : (n_features,) float
        Standardisation of the features.
    weights : list of (n_members, in, out) float
        Layer weights.
    biases : list of (n_members, 1, out) float
        Layer biases.
    target_mean : (3,) float
        Output offset, m.
    target_scale : float
        Output scale, m.
    constraint : {"snap", "project", "none"}
        Output constraint.
    surface_points : (P, 3) float or None
        Discretised surface for ``snap``, m.
    vertices : (V, 3) float or None
        Skin mesh vertices, m.
    faces : (F, 3) int or None
        Skin mesh triangles.
    """

    n_features: int
    clip_negative: bool
    normalise: str
    activation: str
    feature_mean: np.ndarray
    feature_scale: np.ndarray
    weights: list[np.ndarray]
    biases: list[np.ndarray]
    target_mean: np.ndarray
    target_scale: float
    constraint: str = "snap"
    surface_points: np.ndarray | None = None
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    kind: str = "network"
    map_table: np.ndarray | None = None
    map_coarse: np.ndarray | None = None
    map_cells: np.ndarray | None = None
    map_noise: float = 0.0
    map_n_cells: int = 8

    def __post_init__(self) -> None:
        if self.kind == "map":
            if self.map_table is None or self.surface_points is None:
                raise ValueError("a response-map InferenceSpec needs map_table and surface_points")
            return
        if self.kind != "network":
            raise ValueError(f"InferenceSpec.kind must be network or map, got {self.kind!r}")
        if self.normalise not in _NORMS:
            raise ValueError(
                f"InferenceSpec.normalise must be one of none, l1, l2, got {self.normalise!r}"
            )
        if self.activation not in _ACTIVATIONS:
            raise ValueError(
                f"InferenceSpec.activation must be one of relu, tanh, gelu, got {self.activation!r}"
            )
        if self.constraint not in _CONSTRAINTS:
            raise ValueError(
                f"InferenceSpec.constraint must be one of snap, project, none, got "
                f"{self.constraint!r}"
            )
        if not self.weights or len(self.weights) != len(self.biases):
            raise ValueError("InferenceSpec needs as many bias arrays as weight arrays (>= 1)")
        n_in = self.n_features
        for i, (W, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            if W.ndim != 3 or W.shape[1] != n_in or b.shape != (W.shape[0], 1, W.shape[2]):
                raise ValueError(
                    f"InferenceSpec layer {i}: weight {W.shape} and bias {b.shape} do not chain "
                    f"from {n_in} inputs"
                )
            n_in = W.shape[2]
        if n_in != 3:
            raise ValueError(f"InferenceSpec: the last layer must give 3 outputs, got {n_in}")

    @property
    def n_members(self) -> int:
        """Networks in the ensemble (1 for a response map)."""
        return int(self.weights[0].shape[0]) if self.weights else 1

    @property
    def layer_sizes(self) -> list[int]:
        """Widths from input to output, e.g. ``[64, 128, 128, 3]``."""
        return [self.n_features, *[int(W.shape[2]) for W in self.weights]]

    @classmethod
    def _from_map(cls, model: Any) -> InferenceSpec:
        """Spec of a response-map model: its table at every candidate and its search cells."""
        rmap = model.map_
        cfg = model.config_
        table = np.ascontiguousarray(rmap.table, dtype=np.float32)
        coarse, cells = rmap.search_cells()
        return cls(
            n_features=int(model.n_features_in_),
            clip_negative=bool(cfg.get("clip_negative", True)),
            normalise="l2",
            activation="relu",
            feature_mean=np.zeros(int(model.n_features_in_)),
            feature_scale=np.ones(int(model.n_features_in_)),
            weights=[],
            biases=[],
            target_mean=np.zeros(3),
            target_scale=1.0,
            constraint="snap",
            surface_points=np.asarray(rmap.candidates, dtype=np.float64),
            vertices=getattr(model, "mesh_vertices_", None),
            faces=getattr(model, "mesh_faces_", None),
            meta={"arch": cfg.get("arch", "?")},
            kind="map",
            map_table=table,
            map_coarse=np.asarray(coarse, dtype=np.int64),
            map_cells=np.ascontiguousarray(cells, dtype=np.int64),
            map_noise=float(rmap.noise),
        )

    @classmethod
    def from_localizer(cls, model: Any) -> InferenceSpec:
        """Read the spec off a fitted ``ContactLocalizer``.

        Uses ``model.inference_spec()`` when the model provides it; otherwise the fitted
        attributes that ``ContactLocalizer.save`` writes (``feature_mean_``, ``coefs_``, ...).
        """
        if hasattr(model, "inference_spec"):
            spec = model.inference_spec()
            return spec if isinstance(spec, InferenceSpec) else cls(**spec)
        if getattr(model, "config_", {}).get("kind") == "map" or hasattr(model, "map_"):
            try:
                return cls._from_map(model)
            except (AttributeError, KeyError, TypeError) as exc:
                raise ValueError(f"cannot read the response map off this localiser: {exc}") from exc
        try:
            cfg = model.config_
            spec = cls(
                n_features=int(model.n_features_in_),
                clip_negative=bool(cfg["clip_negative"]),
                normalise=str(cfg["normalise"]),
                activation=str(cfg["activation"]),
                feature_mean=np.asarray(model.feature_mean_, dtype=np.float64),
                feature_scale=np.asarray(model.feature_scale_, dtype=np.float64),
                weights=[np.asarray(W, dtype=np.float64) for W in model.coefs_],
                biases=[np.asarray(b, dtype=np.float64) for b in model.intercepts_],
                target_mean=np.asarray(model.target_mean_, dtype=np.float64).reshape(3),
                target_scale=float(model.target_scale_),
                constraint=str(cfg.get("constraint", "snap")),
                surface_points=getattr(model, "surface_points_", None),
                vertices=getattr(model, "mesh_vertices_", None),
                faces=getattr(model, "mesh_faces_", None),
                meta={"arch": cfg.get("arch", "?")},
            )
        except (AttributeError, KeyError, TypeError) as exc:
            raise ValueError(f"cannot read the network off this localiser: {exc}") from exc
        if spec.constraint == "snap" and spec.surface_points is None and spec.vertices is not None:
            from skinloc.geometry import mesh_from_arrays, surface_points

            spec.surface_points = surface_points(mesh_from_arrays(spec.vertices, spec.faces))
        return spec

    @classmethod
    def load(cls, path: str | Path) -> InferenceSpec:
        """The spec of a saved model file (through ``ContactLocalizer.load``)."""
        from skinloc.model import ContactLocalizer

        return cls.from_localizer(ContactLocalizer.load(path))

    # ------------------------------------------------------------------ reference forward pass
    def forward(self, X: Frames) -> np.ndarray:
        """Member outputs ``(n_members, n, 3)`` m for ``X (n, n_features)``, in float64.

        The plain reference implementation the fast paths and exports are checked against.
        """
        Z = np.asarray(X, dtype=np.float64).reshape(-1, self.n_features)
        if self.clip_negative:
            Z = np.maximum(Z, 0.0)
        if self.normalise != "none":
            order = 1 if self.normalise == "l1" else 2
            Z = Z / np.maximum(np.linalg.norm(Z, ord=order, axis=1, keepdims=True), 1.0)
        h = (Z - self.feature_mean) / self.feature_scale
        h = np.broadcast_to(h, (self.n_members, *h.shape))
        for i, (W, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = np.matmul(h, W) + b
            if i < len(self.weights) - 1:
                h = _act_np(h, self.activation)
        return h * self.target_scale + self.target_mean


def _act_np(h: np.ndarray, name: str) -> np.ndarray:
    if name == "relu":
        return np.maximum(h, 0.0)
    if name == "tanh":
        return np.tanh(h)
    from scipy.special import erf

    return 0.5 * h * (1.0 + erf(h / np.sqrt(2.0)))


# --------------------------------------------------------------------------------------------
# compiled kernels


@_jit()
def _act1(h: float, act: int) -> float:  # pragma: no cover - compiled
    if act == 0:
        return h if h > 0.0 else 0.0
    if act == 1:
        return math.tanh(h)
    return 0.5 * h * (1.0 + math.erf(h * 0.7071067811865476))


@_jit()
def _mlp_one(
    x: np.ndarray,
    params: np.ndarray,
    meta: np.ndarray,
    scratch: np.ndarray,
    members: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """Forward one image through the folded ensemble; fills ``members (E, 3)`` (m).

    Returns the ensemble spread in mm (nan for one network). ``meta`` = [n_in, E, n_layers,
    act, clip, norm, scale_off, (in, out, w_off, b_off) per layer, constraint]. Weights are
    stored transposed so that every output is one contiguous dot product (vectorised): layer 0
    as ``(E*out, in)`` (the members share the input), later layers as ``(E, out, in)``.
    """
    n_in = meta[0]
    E = meta[1]
    L = meta[2]
    act = meta[3]
    clip = meta[4]
    norm = meta[5]
    third = scratch.shape[0] // 3
    z = scratch[2 * third :]
    nrm = 0.0
    for i in range(n_in):
        v = x[i]
        if clip and v < 0.0:
            v = 0.0
        z[i] = v
        if norm == 1:
            nrm += abs(v)
        elif norm == 2:
            nrm += v * v
    if norm == 2:
        nrm = math.sqrt(nrm)
    inv = np.float32(1.0)
    if norm != 0 and nrm > 1.0:
        inv = np.float32(1.0 / nrm)
    fin = meta[7]
    fout = meta[8]
    woff = meta[9]
    boff = meta[10]
    cur = scratch[:third]
    nxt = scratch[third : 2 * third]
    for j in range(E * fout):
        acc = np.float32(0.0)
        row = woff + j * fin
        w = params[row : row + fin]  # a row slice: indexing params[row + i] does not vectorise
        for i in range(fin):
            acc += z[i] * w[i]
        h = acc * inv + params[boff + j]
        cur[j] = _act1(h, act) if L > 1 else h
    for layer in range(1, L):
        base = 7 + 4 * layer
        fin = meta[base]
        fout = meta[base + 1]
        woff = meta[base + 2]
        boff = meta[base + 3]
        last = layer == L - 1
        for e in range(E):
            c = cur[e * fin : (e + 1) * fin]
            for j in range(fout):
                acc = np.float32(0.0)
                row = woff + (e * fout + j) * fin
                w = params[row : row + fin]
                for i in range(fin):
                    acc += c[i] * w[i]
                h = acc + params[boff + e * fout + j]
                nxt[e * fout + j] = h if last else _act1(h, act)
        cur, nxt = nxt, cur
    soff = meta[6]
    tscale = params[soff]
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    for e in range(E):
        a = cur[e * 3] * tscale + params[soff + 1]
        b = cur[e * 3 + 1] * tscale + params[soff + 2]
        c = cur[e * 3 + 2] * tscale + params[soff + 3]
        members[e, 0] = a
        members[e, 1] = b
        members[e, 2] = c
        m0 += a
        m1 += b
        m2 += c
    if E == 1:
        return np.nan
    m0 /= E
    m1 /= E
    m2 /= E
    spread = 0.0
    for e in range(E):
        d0 = members[e, 0] - m0
        d1 = members[e, 1] - m1
        d2 = members[e, 2] - m2
        spread += d0 * d0 + d1 * d1 + d2 * d2
    return 1e3 * math.sqrt(spread / E)


@_jit()
def _snap_one(
    q0: float,
    q1: float,
    q2: float,
    pts: np.ndarray,
    start: np.ndarray,
    items: np.ndarray,
    grid: np.ndarray,
    dims: np.ndarray,
) -> int:  # pragma: no cover - compiled
    """Index of the point of ``pts (P, 3)`` nearest to ``q``, exactly, by growing shells of cells.

    ``grid`` = [origin x, y, z, cell size]; ``dims`` = cells per axis; ``start``/``items`` the
    cells' point lists (CSR).
    """
    ox = grid[0]
    oy = grid[1]
    oz = grid[2]
    hsz = grid[3]
    nx = dims[0]
    ny = dims[1]
    nz = dims[2]
    cx = int(np.floor((q0 - ox) / hsz))
    cy = int(np.floor((q1 - oy) / hsz))
    cz = int(np.floor((q2 - oz) / hsz))
    cx = min(max(cx, 0), nx - 1)
    cy = min(max(cy, 0), ny - 1)
    cz = min(max(cz, 0), nz - 1)
    best = -1
    bestd = np.inf
    rmax = max(nx, max(ny, nz))
    for r in range(rmax + 1):
        x0 = cx - r
        x1 = cx + r
        y0 = cy - r
        y1 = cy + r
        z0 = cz - r
        z1 = cz + r
        for ix in range(max(x0, 0), min(x1, nx - 1) + 1):
            ex = ix == x0 or ix == x1
            for iy in range(max(y0, 0), min(y1, ny - 1) + 1):
                ey = ex or iy == y0 or iy == y1
                for iz in range(max(z0, 0), min(z1, nz - 1) + 1):
                    if not (ey or iz == z0 or iz == z1):
                        continue
                    cell = (ix * ny + iy) * nz + iz
                    k0 = start[cell]
                    k1 = start[cell + 1]
                    if k0 == k1:
                        continue
                    if best >= 0:  # skip a cell whose box is farther than the best point
                        gx = max(ox + ix * hsz - q0, q0 - (ox + (ix + 1) * hsz), 0.0)
                        gy = max(oy + iy * hsz - q1, q1 - (oy + (iy + 1) * hsz), 0.0)
                        gz = max(oz + iz * hsz - q2, q2 - (oz + (iz + 1) * hsz), 0.0)
                        if gx * gx + gy * gy + gz * gz > bestd:
                            continue
                    for k in range(k0, k1):
                        p = items[k]
                        d0 = pts[p, 0] - q0
                        d1 = pts[p, 1] - q1
                        d2 = pts[p, 2] - q2
                        d = d0 * d0 + d1 * d1 + d2 * d2
                        if d < bestd or (d == bestd and p < best):
                            bestd = d
                            best = p
        # Every point not yet seen lies outside the searched block: bound its distance.
        lb = np.inf
        if x0 > 0:
            lb = min(lb, q0 - (ox + x0 * hsz))
        if x1 < nx - 1:
            lb = min(lb, ox + (x1 + 1) * hsz - q0)
        if y0 > 0:
            lb = min(lb, q1 - (oy + y0 * hsz))
        if y1 < ny - 1:
            lb = min(lb, oy + (y1 + 1) * hsz - q1)
        if z0 > 0:
            lb = min(lb, q2 - (oz + z0 * hsz))
        if z1 < nz - 1:
            lb = min(lb, oz + (z1 + 1) * hsz - q2)
        if lb == np.inf:
            break  # the block covers the whole grid
        if best >= 0 and lb > 0.0 and lb * lb >= bestd:
            break
    return best


@_jit()
def _closest_on_triangles(
    q0: float, q1: float, q2: float, tris: np.ndarray, out: np.ndarray
) -> int:  # pragma: no cover - compiled
    """Exact closest point to ``q`` on triangles ``tris (F, 3, 3)``; writes ``out (3,)``.

    Ericson's closest-point-on-triangle, brute force over the faces. Returns the face index.
    """
    bestd = np.inf
    bestf = -1
    for f in range(tris.shape[0]):
        ax = tris[f, 0, 0]
        ay = tris[f, 0, 1]
        az = tris[f, 0, 2]
        abx = tris[f, 1, 0] - ax
        aby = tris[f, 1, 1] - ay
        abz = tris[f, 1, 2] - az
        acx = tris[f, 2, 0] - ax
        acy = tris[f, 2, 1] - ay
        acz = tris[f, 2, 2] - az
        apx = q0 - ax
        apy = q1 - ay
        apz = q2 - az
        d1 = abx * apx + aby * apy + abz * apz
        d2 = acx * apx + acy * apy + acz * apz
        px = 0.0
        py = 0.0
        pz = 0.0
        if d1 <= 0.0 and d2 <= 0.0:
            px, py, pz = ax, ay, az
        else:
            bpx = q0 - tris[f, 1, 0]
            bpy = q1 - tris[f, 1, 1]
            bpz = q2 - tris[f, 1, 2]
            d3 = abx * bpx + aby * bpy + abz * bpz
            d4 = acx * bpx + acy * bpy + acz * bpz
            cpx = q0 - tris[f, 2, 0]
            cpy = q1 - tris[f, 2, 1]
            cpz = q2 - tris[f, 2, 2]
            d5 = abx * cpx + aby * cpy + abz * cpz
            d6 = acx * cpx + acy * cpy + acz * cpz
            vc = d1 * d4 - d3 * d2
            vb = d5 * d2 - d1 * d6
            va = d3 * d6 - d5 * d4
            if d3 >= 0.0 and d4 <= d3:
                px, py, pz = tris[f, 1, 0], tris[f, 1, 1], tris[f, 1, 2]
            elif d6 >= 0.0 and d5 <= d6:
                px, py, pz = tris[f, 2, 0], tris[f, 2, 1], tris[f, 2, 2]
            elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
                v = d1 / (d1 - d3)
                px, py, pz = ax + v * abx, ay + v * aby, az + v * abz
            elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
                w = d2 / (d2 - d6)
                px, py, pz = ax + w * acx, ay + w * acy, az + w * acz
            elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
                w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
                bx = tris[f, 1, 0]
                by = tris[f, 1, 1]
                bz = tris[f, 1, 2]
                px = bx + w * (tris[f, 2, 0] - bx)
                py = by + w * (tris[f, 2, 1] - by)
                pz = bz + w * (tris[f, 2, 2] - bz)
            else:
                denom = 1.0 / (va + vb + vc)
                v = vb * denom
                w = vc * denom
                px = ax + abx * v + acx * w
                py = ay + aby * v + acy * w
                pz = az + abz * v + acz * w
        dx = px - q0
        dy = py - q1
        dz = pz - q2
        d = dx * dx + dy * dy + dz * dz
        if d < bestd:
            bestd = d
            bestf = f
            out[0] = px
            out[1] = py
            out[2] = pz
    return bestf


@_jit()
def _constrain_one(
    q0: float,
    q1: float,
    q2: float,
    mode: int,
    pts: np.ndarray,
    start: np.ndarray,
    items: np.ndarray,
    grid: np.ndarray,
    dims: np.ndarray,
    tris: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Put ``q`` on the surface by ``mode`` (0 none, 1 snap, 2 project); writes ``out (3,)``."""
    if mode == 1:
        k = _snap_one(q0, q1, q2, pts, start, items, grid, dims)
        out[0] = pts[k, 0]
        out[1] = pts[k, 1]
        out[2] = pts[k, 2]
    elif mode == 2:
        _closest_on_triangles(q0, q1, q2, tris, out)
    else:
        out[0] = q0
        out[1] = q1
        out[2] = q2


@_jit()
def _localise_one(
    x: np.ndarray,
    params: np.ndarray,
    meta: np.ndarray,
    scratch: np.ndarray,
    members: np.ndarray,
    pts: np.ndarray,
    start: np.ndarray,
    items: np.ndarray,
    grid: np.ndarray,
    dims: np.ndarray,
    tris: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """One image to ``out`` = [raw x, y, z, point x, y, z, spread_mm] (m, mm)."""
    spread = _mlp_one(x, params, meta, scratch, members)
    E = members.shape[0]
    r0 = 0.0
    r1 = 0.0
    r2 = 0.0
    for e in range(E):
        r0 += members[e, 0]
        r1 += members[e, 1]
        r2 += members[e, 2]
    r0 /= E
    r1 /= E
    r2 /= E
    out[0] = r0
    out[1] = r1
    out[2] = r2
    _constrain_one(r0, r1, r2, meta[-1], pts, start, items, grid, dims, tris, out[3:6])
    out[6] = spread


@_jit(parallel=True)
def _constrain_many(
    q: np.ndarray,
    mode: int,
    pts: np.ndarray,
    start: np.ndarray,
    items: np.ndarray,
    grid: np.ndarray,
    dims: np.ndarray,
    tris: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``_constrain_one`` over the rows of ``q (n, 3)``, in parallel, into ``out (n, 3)``."""
    for i in _prange(q.shape[0]):
        _constrain_one(q[i, 0], q[i, 1], q[i, 2], mode, pts, start, items, grid, dims, tris, out[i])


@_jit()
def _match_one(
    x: np.ndarray,
    clip: int,
    tt: np.ndarray,
    sqp: np.ndarray,
    candp: np.ndarray,
    ct: np.ndarray,
    csq: np.ndarray,
    off: np.ndarray,
    pad_n: np.ndarray,
    pad_pos: np.ndarray,
    n_best: int,
    noise: float,
    f: np.ndarray,
    buf: np.ndarray,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """Response-map matching of one image (as ``ResponseMap.match``) into ``out (7,)``.

    ``tt (P, k)`` is the map table with candidates grouped by coarse cell (cell c is rows
    ``off[c]:off[c+1]``, each candidate once), ``ct (C, k)`` the coarse candidates (contiguous);
    ``sqp``/``csq`` their squared norms, ``candp`` the grouped candidate points (m). ``pad_n``
    and ``pad_pos`` reproduce the padding of ``ResponseMap`` cells (the coarse point repeated),
    which weighs in the spread. ``out`` = [point (3), point (3), spread_mm]: a map's raw output
    already lies on the surface.
    """
    n = x.shape[0]
    nrm = 0.0
    for i in range(n):
        v = x[i]
        if clip and v < 0.0:
            v = 0.0
        nrm += v * v
    nrm = math.sqrt(nrm)
    if nrm < 1.0:
        nrm = 1.0
    ff = 0.0
    for i in range(n):
        v = x[i]
        if clip and v < 0.0:
            v = 0.0
        fv = np.float32(v / nrm)
        f[i] = fv
        ff += float(fv) * float(fv)
    C = ct.shape[0]
    acc = buf[:C]
    for c in range(C):
        a = np.float32(0.0)
        for i in range(n):
            a += f[i] * ct[c, i]
        acc[c] = a
    nb = min(n_best, C)
    best_c = np.empty(nb, dtype=np.int64)
    best_v = np.empty(nb, dtype=np.float64)
    for k in range(nb):
        best_v[k] = np.inf
        best_c[k] = 0
    for c in range(C):
        v = csq[c] - 2.0 * acc[c]
        if v < best_v[nb - 1]:
            k = nb - 1
            while k > 0 and best_v[k - 1] > v:
                best_v[k] = best_v[k - 1]
                best_c[k] = best_c[k - 1]
                k -= 1
            best_v[k] = v
            best_c[k] = c
    # fine: the chosen cells in full, distances into a scratch row per cell
    total = 0
    for b in range(nb):
        c = best_c[b]
        total += off[c + 1] - off[c]
    d = np.empty(total, dtype=np.float64)
    idx = np.empty(total, dtype=np.int64)
    dmin = np.inf
    best = -1
    j = 0
    for b in range(nb):
        c = best_c[b]
        s0 = off[c]
        m = off[c + 1] - s0
        for r in range(m):
            a = np.float32(0.0)
            for i in range(n):
                a += f[i] * tt[s0 + r, i]
            dv = float(sqp[s0 + r] - np.float32(2.0) * a) + ff
            if dv < 0.0:
                dv = 0.0
            d[j] = dv
            idx[j] = s0 + r
            if dv < dmin:
                dmin = dv
                best = s0 + r
            j += 1
    scale = max(dmin, 2.0 * noise)
    inv_scale = 1.0 / scale
    b0 = candp[best, 0]
    b1 = candp[best, 1]
    b2 = candp[best, 2]
    wsum = 0.0
    acc2 = 0.0
    j = 0
    for b in range(nb):
        c = best_c[b]
        m = off[c + 1] - off[c]
        for r in range(m):
            t = j + r
            e = (d[t] - dmin) * inv_scale
            if e > 50.0:  # weight below 2e-22: nothing to add
                continue
            w = math.exp(-e)
            if r == pad_pos[c]:
                w *= 1.0 + pad_n[c]
            p = idx[t]
            e0 = candp[p, 0] - b0
            e1 = candp[p, 1] - b1
            e2 = candp[p, 2] - b2
            wsum += w
            acc2 += w * (e0 * e0 + e1 * e1 + e2 * e2)
        j += m
    out[0] = b0
    out[1] = b1
    out[2] = b2
    out[3] = b0
    out[4] = b1
    out[5] = b2
    out[6] = 1e3 * math.sqrt(acc2 / wsum)


@_jit(parallel=True)
def _match_many(
    X: np.ndarray,
    clip: int,
    tt: np.ndarray,
    sqp: np.ndarray,
    candp: np.ndarray,
    ct: np.ndarray,
    csq: np.ndarray,
    off: np.ndarray,
    pad_n: np.ndarray,
    pad_pos: np.ndarray,
    n_best: int,
    noise: float,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """``_match_one`` over the rows of ``X (n, k)`` into ``out (n, 7)``, in parallel."""
    n = X.shape[1]
    width = ct.shape[0]
    for r in _prange(X.shape[0]):
        f = np.empty(n, dtype=np.float32)
        buf = np.empty(width, dtype=np.float32)
        _match_one(
            X[r],
            clip,
            tt,
            sqp,
            candp,
            ct,
            csq,
            off,
            pad_n,
            pad_pos,
            n_best,
            noise,
            f,
            buf,
            out[r],
        )


# --------------------------------------------------------------------------------------------
# exact nearest point among many


class SnapIndex:
    """Exact nearest neighbour among surface points, answered by a uniform grid of cells.

    Parameters
    ----------
    points : (P, 3) float
        The discretised surface, m.
    points_per_cell : float, default=128
        Target number of points in an occupied cell. Cells about 11 point spacings wide suit
        network outputs, which lie a median 8 mm and a 90th percentile 19 mm off the surface
        on the simulated skin: smaller cells make far queries scan many empty cells (128 ran
        1.3 times faster than 64 and 17 times faster than 8 on such outputs).

    Notes
    -----
    A query looks at the query's cell, then at growing shells of cells around it, and stops once
    no unseen cell can hold a closer point; ties go to the lower index, as in ``cKDTree``. For
    points near the surface that is a few dozen distance computations.
    """

    def __init__(self, points: Points, points_per_cell: float = 128.0) -> None:
        from scipy.spatial import cKDTree

        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
            raise ValueError(f"snap points must have shape (P, 3) with P >= 1, got {pts.shape}")
        self.points = pts
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if len(pts) > 1:
            nn = cKDTree(pts).query(pts[: min(len(pts), 2000)], k=2)[0][:, 1]
            spacing = float(np.median(nn))
        else:
            spacing = 1e-3
        size = max(spacing * np.sqrt(points_per_cell), float((hi - lo).max()) / 256, 1e-6)
        dims = np.maximum(np.floor((hi - lo) / size).astype(np.int64) + 1, 1)
        cell = np.floor((pts - lo) / size).astype(np.int64)
        cell = np.minimum(cell, dims - 1)
        flat = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
        order = np.argsort(flat, kind="stable")
        counts = np.bincount(flat, minlength=int(np.prod(dims)))
        self.start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.items = order.astype(np.int64)
        self.grid = np.array([lo[0], lo[1], lo[2], size], dtype=np.float64)
        self.dims = dims.astype(np.int64)

    def query(self, q: Points) -> np.ndarray:
        """Indices ``(n,)`` of the nearest points to ``q (n, 3)`` m."""
        q = np.ascontiguousarray(np.asarray(q, dtype=np.float64).reshape(-1, 3))
        return np.array(
            [
                _snap_one(
                    r[0], r[1], r[2], self.points, self.start, self.items, self.grid, self.dims
                )
                for r in q
            ],
            dtype=np.int64,
        )


def closest_on_triangles(q: Points, triangles: np.ndarray) -> Points:
    """Exact closest points ``(n, 3)`` on ``triangles (F, 3, 3)`` to ``q (n, 3)``, m."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 3)
    tris = np.ascontiguousarray(triangles, dtype=np.float64)
    out = np.empty_like(q)
    for i, r in enumerate(q):
        _closest_on_triangles(r[0], r[1], r[2], tris, out[i])
    return out


# --------------------------------------------------------------------------------------------
# the fast localiser


class FastLocalizer:
    """A compiled localiser built from an ``InferenceSpec``.

    Parameters
    ----------
    spec : InferenceSpec
        The network, preprocessing and surface.
    constraint : {"snap", "project", "none"}, optional
        Override the spec's output constraint.

    Examples
    --------
    >>> fast = FastLocalizer.from_model(model)  # doctest: +SKIP
    >>> point, raw, spread_mm = fast.predict_one(delta)  # doctest: +SKIP
    """

    def __init__(self, spec: InferenceSpec, constraint: str | None = None) -> None:
        self.spec = spec
        self.constraint = spec.constraint if constraint is None else constraint
        if self.constraint not in _CONSTRAINTS:
            raise ValueError(
                f"unknown output constraint {self.constraint!r}; choose one of: snap, project, none"
            )
        if self.constraint != "none" and spec.vertices is None and spec.surface_points is None:
            self.constraint = "none"
        self.n_features = spec.n_features
        self.n_members = spec.n_members
        self.kind = spec.kind
        if self.kind == "map":
            self.constraint = "snap"
            self._build_map()
        else:
            self._build_params()
        self._build_surface()
        self._x = np.zeros(self.n_features, dtype=np.float32)
        self._members = np.zeros((self.n_members, 3), dtype=np.float64)
        self._out = np.zeros(7, dtype=np.float64)

    @classmethod
    def from_model(cls, model: Any, constraint: str | None = None) -> FastLocalizer:
        """From a fitted ``ContactLocalizer`` or a path to a saved one."""
        if isinstance(model, str | Path):
            spec = InferenceSpec.load(model)
        else:
            spec = InferenceSpec.from_localizer(model)
        return cls(spec, constraint)

    # ------------------------------------------------------------------ layout
    def _build_params(self) -> None:
        s = self.spec
        E = s.n_members
        W0 = s.weights[0] / s.feature_scale[None, :, None]  # (E, in, h)
        b0 = s.biases[0][:, 0, :] - np.einsum(
            "i,eih->eh", s.feature_mean / s.feature_scale, s.weights[0]
        )
        # Standardisation folds into layer 0: with n the image norm (1 without normalising),
        # ((z / n - mu) / s) @ W + b = (z @ (W / s)) / n + (b - (mu / s) @ W).
        chunks: list[np.ndarray] = []
        pos = 0

        def add(a: np.ndarray) -> int:
            nonlocal pos
            flat = np.ascontiguousarray(a, dtype=np.float32).ravel()
            chunks.append(flat)
            off = pos
            pos += flat.size
            return off

        n_in, h0 = s.n_features, W0.shape[2]
        w0_off = add(np.transpose(W0, (0, 2, 1)).reshape(E * h0, n_in))  # (E*h, in)
        b0_off = add(b0.reshape(E * h0))
        layer_meta = [n_in, h0, w0_off, b0_off]
        for W, b in zip(s.weights[1:], s.biases[1:], strict=True):
            layer_meta += [W.shape[1], W.shape[2], add(np.transpose(W, (0, 2, 1))), add(b[:, 0, :])]
        scale_off = add(np.concatenate([[s.target_scale], s.target_mean]))
        L = len(s.weights)
        self._meta = np.array(
            [
                n_in,
                E,
                L,
                _ACTIVATIONS[s.activation],
                int(s.clip_negative),
                _NORMS[s.normalise],
                scale_off,
                *layer_meta,
                _CONSTRAINTS[self.constraint],
            ],
            dtype=np.int64,
        )
        self._params = np.concatenate(chunks).astype(np.float32)
        widest = max(E * w for w in s.layer_sizes[1:])
        self._scratch = np.zeros(3 * max(widest, n_in), dtype=np.float32)
        # float32 folded weights for the batched path
        self._W0 = np.ascontiguousarray(
            np.transpose(W0, (1, 0, 2)).reshape(n_in, E * h0), dtype=np.float32
        )
        self._b0 = b0.reshape(E * h0).astype(np.float32)
        self._Ws = [np.ascontiguousarray(W, dtype=np.float32) for W in s.weights[1:]]
        self._bs = [np.ascontiguousarray(b, dtype=np.float32) for b in s.biases[1:]]

    def _build_map(self) -> None:
        s = self.spec
        table = np.asarray(s.map_table, dtype=np.float32)
        sq = (table**2).sum(axis=1)
        coarse = np.asarray(s.map_coarse, dtype=np.int64)
        cells = np.asarray(s.map_cells, dtype=np.int64)
        perm, off, pad_n, pad_pos = [], [0], [], []
        for c, row in enumerate(cells):
            members = list(dict.fromkeys(row.tolist()))  # unique, in order
            pad_n.append(len(row) - len(members))
            pad_pos.append(members.index(int(coarse[c])) if coarse[c] in members else -1)
            if pad_n[-1] and pad_pos[-1] < 0:
                raise ValueError("response-map cell padding without its coarse point")
            perm += members
            off.append(len(perm))
        perm_a = np.asarray(perm, dtype=np.int64)
        self._tt = np.ascontiguousarray(table[perm_a])  # (P', k), grouped by cell
        self._sqp = sq[perm_a]
        self._candp = np.ascontiguousarray(np.asarray(s.surface_points)[perm_a], dtype=np.float64)
        self._ct = np.ascontiguousarray(table[coarse])  # (C, k)
        self._csq = sq[coarse]
        self._off = np.asarray(off, dtype=np.int64)
        self._pad_n = np.asarray(pad_n, dtype=np.int64)
        self._pad_pos = np.asarray(pad_pos, dtype=np.int64)
        self._f = np.zeros(self.n_features, dtype=np.float32)
        self._buf = np.zeros(len(self._ct), dtype=np.float32)
        self._clip = int(s.clip_negative)

    def _map_args(self) -> tuple:
        return (
            self._clip,
            self._tt,
            self._sqp,
            self._candp,
            self._ct,
            self._csq,
            self._off,
            self._pad_n,
            self._pad_pos,
            self.spec.map_n_cells,
            self.spec.map_noise,
        )

    def _build_surface(self) -> None:
        s = self.spec
        self._pts = np.zeros((1, 3))
        self._index: SnapIndex | None = None
        self._tris = np.zeros((1, 3, 3))
        if self.constraint == "snap":
            pts = s.surface_points
            if pts is None:
                from skinloc.geometry import mesh_from_arrays, surface_points

                pts = surface_points(mesh_from_arrays(s.vertices, s.faces))
            self._index = SnapIndex(pts)
            self._pts = self._index.points
        elif self.constraint == "project":
            v = np.asarray(s.vertices, dtype=np.float64)
            self._tris = np.ascontiguousarray(v[np.asarray(s.faces, dtype=np.int64)])
        idx = self._index
        self._start = idx.start if idx else np.zeros(2, dtype=np.int64)
        self._items = idx.items if idx else np.zeros(1, dtype=np.int64)
        self._grid = idx.grid if idx else np.array([0.0, 0.0, 0.0, 1.0])
        self._dims = idx.dims if idx else np.ones(3, dtype=np.int64)
        self._mode = _CONSTRAINTS[self.constraint]

    # ------------------------------------------------------------------ single frame
    def localise_into(self, x: np.ndarray, out: np.ndarray) -> None:
        """One image ``x (n_features,)`` float32 counts into ``out (7,)`` float64.

        ``out`` = [raw x, y, z (m), point x, y, z (m, on the surface), spread (mm)]. The
        allocation-free call the pipeline uses per frame.
        """
        if self.kind == "map":
            _match_one(x, *self._map_args(), self._f, self._buf, out)
            return
        _localise_one(
            x,
            self._params,
            self._meta,
            self._scratch,
            self._members,
            self._pts,
            self._start,
            self._items,
            self._grid,
            self._dims,
            self._tris,
            out,
        )

    def constrain_into(self, q0: float, q1: float, q2: float, out: np.ndarray) -> None:
        """Put the point ``(q0, q1, q2)`` m on the surface by this model's constraint."""
        _constrain_one(
            q0,
            q1,
            q2,
            self._mode,
            self._pts,
            self._start,
            self._items,
            self._grid,
            self._dims,
            self._tris,
            out,
        )

    def predict_one(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``(point (3,) m, raw (3,) m, spread_mm)`` for one image ``x (n_features,)``."""
        xx = np.ascontiguousarray(x, dtype=np.float32).reshape(-1)
        if xx.shape != (self.n_features,):
            raise ValueError(
                f"sensor image must have shape ({self.n_features},), got {np.shape(x)}"
            )
        out = np.empty(7)
        self.localise_into(xx, out)
        return out[3:6].copy(), out[:3].copy(), float(out[6])

    # ------------------------------------------------------------------ batches
    def forward_batch(self, X: Frames) -> np.ndarray:
        """Member outputs ``(n_members, n, 3)`` m for ``X (n, n_features)``, float32 BLAS."""
        s = self.spec
        Z = np.asarray(X, dtype=np.float32).reshape(-1, self.n_features)
        if s.clip_negative:
            Z = np.maximum(Z, 0.0)
        h = Z @ self._W0
        if s.normalise != "none":
            order = 1 if s.normalise == "l1" else 2
            nrm = np.linalg.norm(Z, ord=order, axis=1, keepdims=True)
            h /= np.maximum(nrm, 1.0)
        h += self._b0
        E = self.n_members
        L = len(s.weights)
        if L > 1:
            h = _act_inplace(h, s.activation)
        h = h.reshape(len(Z), E, -1).transpose(1, 0, 2)  # (E, n, h)
        for i, (W, b) in enumerate(zip(self._Ws, self._bs, strict=True)):
            h = np.matmul(h, W)
            h += b
            if i < L - 2:
                h = _act_inplace(h, s.activation)
        return h.astype(np.float64) * s.target_scale + s.target_mean

    def predict_batch(self, X: Frames) -> tuple[Points, Points, np.ndarray]:
        """``(points (n, 3) m, raw (n, 3) m, spread_mm (n,))`` for ``X (n, n_features)``.

        A network's forward pass runs on BLAS over the whole batch (in blocks of 65,536 rows)
        before the constraint's parallel loop starts: alternating the two per small block makes
        OpenBLAS's spinning threads and numba's contend for the cores, which halved the
        throughput on this 2-core machine.
        """
        Xc = np.ascontiguousarray(np.asarray(X, dtype=np.float32).reshape(-1, self.n_features))
        if self.kind == "map":
            out = np.empty((len(Xc), 7))
            _match_many(Xc, *self._map_args(), out)
            return out[:, 3:6].copy(), out[:, :3].copy(), out[:, 6].copy()
        raw = np.empty((len(Xc), 3))
        spread = np.full(len(Xc), np.nan)
        for i in range(0, len(Xc), 65536):
            block = slice(i, i + 65536)
            members = self.forward_batch(Xc[block])  # (E, rows, 3)
            raw[block] = members.mean(axis=0)
            if self.n_members > 1:
                dev = ((members - raw[block]) ** 2).sum(axis=2)
                spread[block] = 1e3 * np.sqrt(dev.mean(axis=0))
        return self.constrain(raw), raw, spread

    def constrain(self, q: Points) -> Points:
        """Constrain ``q (n, 3)`` m onto the surface; returns ``(n, 3)`` m."""
        q = np.ascontiguousarray(np.asarray(q, dtype=np.float64).reshape(-1, 3))
        if self._mode == 0:
            return q.copy()
        out = np.empty_like(q)
        _constrain_many(
            q,
            self._mode,
            self._pts,
            self._start,
            self._items,
            self._grid,
            self._dims,
            self._tris,
            out,
        )
        return out

    def warm_up(self) -> FastLocalizer:
        """Compile the kernels now (numba caches them on disk) rather than on the first frame."""
        self.localise_into(self._x, self._out)
        self.predict_batch(np.zeros((2, self.n_features), dtype=np.float32))
        return self


def _act_inplace(h: np.ndarray, name: str) -> np.ndarray:
    if name == "relu":
        return np.maximum(h, 0.0, out=h)
    if name == "tanh":
        return np.tanh(h, out=h)
    from scipy.special import erf

    return (0.5 * h * (1.0 + erf(h / np.float32(np.sqrt(2.0))))).astype(h.dtype)


def check_against(fast: FastLocalizer, model: Any, n: int = 16, random_state: int = 0) -> float:
    """Largest difference (m) between ``fast`` and ``model.predict_full`` raw outputs.

    A self-check run when a pipeline loads a model: the fast path is only used when it agrees
    with the model's own prediction (the model's internals may change under it).
    """
    rng = np.random.default_rng(random_state)
    X = np.abs(rng.normal(0.0, 60.0, (n, fast.n_features))).astype(np.float32)
    X[:, : fast.n_features // 4] += 150.0
    ref = model.predict_full(X.astype(np.float64)).raw
    out = np.empty(7)
    got = np.empty_like(ref)
    for i, x in enumerate(X):
        fast.localise_into(x, out)
        got[i] = out[:3]
    err = np.abs(got - ref).max(axis=1)
    if fast.kind == "map":
        # Candidates a float rounding apart in match distance may swap: allow one neighbour.
        return float(np.sort(err)[-2]) if len(err) > 1 else float(err.max())
    return float(err.max())
