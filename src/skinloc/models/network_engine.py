"""The network engine: an ensemble of fully connected networks, compiled per frame, BLAS per batch.

Prediction for baseline-subtracted counts ``x (n_features,)``::

    z = max(x, 0) if clip_negative else x
    z = z / max(||z||_p, 1)            # p from normalise: none, l1, l2
    h = (z - feature_mean) / feature_scale
    h = act(h @ W[i][m] + b[i][m])     # per member m, every layer but the last
    y_m = (h @ W[-1][m] + b[-1][m]) * target_scale + target_mean     # metres
    raw = mean_m y_m ;  spread_mm = 1e3 * sqrt(mean_m |y_m - raw|^2)   # nan for one network
    point = raw put on the surface by the constraint

The engine folds the standardisation into the first layer and lays the ensemble out so that one
pass over the weights serves every member; per frame the whole chain runs in one compiled
kernel, per batch the layers are float32 matrix products over the whole batch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from skinloc._jit import jit
from skinloc._typing import Points
from skinloc.geometry.snap import constrain_one
from skinloc.models.engine import Engine, ModelSpec, clip_and_norm, norm_code

__all__ = ["NetworkEngine", "NetworkSpec", "activate_inplace"]

_ACTIVATIONS = {"relu": 0, "tanh": 1, "gelu": 2}


@dataclass(kw_only=True)
class NetworkSpec(ModelSpec):
    """A network ensemble as arrays (see the module's docstring for the arithmetic).

    Attributes
    ----------
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
    """

    kind: ClassVar[str] = "network"

    normalise: str
    activation: str
    feature_mean: np.ndarray
    feature_scale: np.ndarray
    weights: list[np.ndarray]
    biases: list[np.ndarray]
    target_mean: np.ndarray
    target_scale: float

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.normalise not in ("none", "l1", "l2"):
            raise ValueError(
                f"NetworkSpec.normalise must be one of none, l1, l2, got {self.normalise!r}"
            )
        if self.activation not in _ACTIVATIONS:
            raise ValueError(
                f"NetworkSpec.activation must be one of relu, tanh, gelu, got {self.activation!r}"
            )
        if not self.weights or len(self.weights) != len(self.biases):
            raise ValueError("NetworkSpec needs as many bias arrays as weight arrays (>= 1)")
        n_in = self.n_features
        for i, (W, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            if W.ndim != 3 or W.shape[1] != n_in or b.shape != (W.shape[0], 1, W.shape[2]):
                raise ValueError(
                    f"NetworkSpec layer {i}: weight {W.shape} and bias {b.shape} do not chain "
                    f"from {n_in} inputs"
                )
            n_in = W.shape[2]
        if n_in != 3:
            raise ValueError(f"NetworkSpec: the last layer must give 3 outputs, got {n_in}")

    @property
    def n_members(self) -> int:
        """Networks in the ensemble."""
        return int(self.weights[0].shape[0])

    @property
    def layer_sizes(self) -> list[int]:
        """Widths from input to output, e.g. ``[64, 128, 128, 3]``."""
        return [self.n_features, *[int(W.shape[2]) for W in self.weights]]

    def engine(self, constraint: str | None = None) -> NetworkEngine:
        """The compiled engine of this network."""
        return NetworkEngine(self, constraint)


# --------------------------------------------------------------------------------------------
# compiled kernels


@jit()
def _act1(h: float, act: int) -> float:  # pragma: no cover - compiled
    if act == 0:
        return h if h > 0.0 else 0.0
    if act == 1:
        return math.tanh(h)
    return 0.5 * h * (1.0 + math.erf(h * 0.7071067811865476))


@jit()
def _layer0(
    z: np.ndarray, inv: float, params: np.ndarray, meta: np.ndarray, cur: np.ndarray
) -> None:  # pragma: no cover - compiled
    """The folded first layer of every member at once: ``cur = act((z @ W0) * inv + b0)``."""
    fin = meta[7]
    fout = meta[8]
    woff = meta[9]
    boff = meta[10]
    act = meta[3]
    hidden = meta[2] > 1
    inv32 = np.float32(inv)
    for j in range(meta[1] * fout):
        acc = np.float32(0.0)
        row = woff + j * fin
        w = params[row : row + fin]  # a row slice: indexing params[row + i] does not vectorise
        for i in range(fin):
            acc += z[i] * w[i]
        h = acc * inv32 + params[boff + j]
        cur[j] = _act1(h, act) if hidden else h


@jit()
def _mlp_one(
    x: np.ndarray,
    params: np.ndarray,
    meta: np.ndarray,
    scratch: np.ndarray,
    members: np.ndarray,
) -> float:  # pragma: no cover - compiled
    """Forward one image through the folded ensemble; fills ``members (E, 3)`` (m).

    Returns the ensemble spread in mm (nan for one network). ``meta`` = [n_in, E, n_layers,
    act, clip, norm, scale_off, (in, out, w_off, b_off) per layer]. Weights are stored
    transposed so that every output is one contiguous dot product (vectorised): layer 0 as
    ``(E*out, in)`` (the members share the input), later layers as ``(E, out, in)``.
    """
    E = meta[1]
    L = meta[2]
    third = scratch.shape[0] // 3
    z = scratch[2 * third :]
    inv = clip_and_norm(x, meta[4], meta[5], z)
    cur = scratch[:third]
    nxt = scratch[third : 2 * third]
    _layer0(z, inv, params, meta, cur)
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
                nxt[e * fout + j] = h if last else _act1(h, meta[3])
        cur, nxt = nxt, cur
    soff = meta[6]
    for e in range(E):
        for k in range(3):
            members[e, k] = cur[e * 3 + k] * params[soff] + params[soff + 1 + k]
    if E == 1:
        return np.nan
    spread = 0.0
    for k in range(3):
        m = 0.0
        for e in range(E):
            m += members[e, k]
        m /= E
        for e in range(E):
            spread += (members[e, k] - m) ** 2
    return 1e3 * math.sqrt(spread / E)


@jit()
def _localise_one(
    x: np.ndarray,
    params: np.ndarray,
    meta: np.ndarray,
    scratch: np.ndarray,
    members: np.ndarray,
    mode: int,
    surf: tuple,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled
    """One image to ``out`` = [raw x, y, z, point x, y, z, spread_mm] (m, mm)."""
    spread = _mlp_one(x, params, meta, scratch, members)
    E = members.shape[0]
    for k in range(3):
        r = 0.0
        for e in range(E):
            r += members[e, k]
        out[k] = r / E
    constrain_one(out[0], out[1], out[2], mode, surf, out[3:6])
    out[6] = spread


def activate_inplace(h: np.ndarray, name: str) -> np.ndarray:
    """The hidden activation ``name`` of ``h`` (in place where NumPy can)."""
    if name == "relu":
        return np.maximum(h, 0.0, out=h)
    if name == "tanh":
        return np.tanh(h, out=h)
    from scipy.special import erf

    return (0.5 * h * (1.0 + erf(h / np.float32(np.sqrt(2.0))))).astype(h.dtype)


# --------------------------------------------------------------------------------------------
# the engine


class NetworkEngine(Engine):
    """The compiled network ensemble of a ``NetworkSpec``."""

    kind: ClassVar[str] = "network"

    def __init__(self, spec: NetworkSpec, constraint: str | None = None) -> None:
        super().__init__(spec, constraint)
        s = spec
        E = s.n_members
        W0 = s.weights[0] / s.feature_scale[None, :, None]  # (E, in, h)
        b0 = s.biases[0][:, 0, :] - np.einsum(
            "i,eih->eh", s.feature_mean / s.feature_scale, s.weights[0]
        )
        # Standardisation folds into layer 0: with n the image norm (1 without normalising),
        # ((z / n - mu) / s) @ W + b = (z @ (W / s)) / n + (b - (mu / s) @ W).
        n_in, h0 = s.n_features, W0.shape[2]
        chunks = [
            np.transpose(W0, (0, 2, 1)).reshape(E * h0, n_in),  # (E*h, in)
            b0.reshape(E * h0),
        ]
        for W, b in zip(s.weights[1:], s.biases[1:], strict=True):
            chunks += [np.transpose(W, (0, 2, 1)), b[:, 0, :]]
        chunks.append(np.concatenate([[s.target_scale], s.target_mean]))
        flat = [np.ascontiguousarray(c, dtype=np.float32).ravel() for c in chunks]
        offsets = np.concatenate([[0], np.cumsum([f.size for f in flat])])
        layer_meta = [n_in, h0, offsets[0], offsets[1]]
        for i, W in enumerate(s.weights[1:], start=1):
            layer_meta += [W.shape[1], W.shape[2], offsets[2 * i], offsets[2 * i + 1]]
        self._meta = np.array(
            [
                n_in,
                E,
                len(s.weights),
                _ACTIVATIONS[s.activation],
                int(s.clip_negative),
                norm_code(s.normalise),
                offsets[-2],
                *layer_meta,
            ],
            dtype=np.int64,
        )
        self._params = np.concatenate(flat)
        widest = max(E * w for w in s.layer_sizes[1:])
        self._scratch = np.zeros(3 * max(widest, n_in), dtype=np.float32)
        self._members = np.zeros((E, 3), dtype=np.float64)
        # float32 folded weights for the batched path
        self._W0 = np.ascontiguousarray(
            np.transpose(W0, (1, 0, 2)).reshape(n_in, E * h0), dtype=np.float32
        )
        self._b0 = b0.reshape(E * h0).astype(np.float32)
        self._Ws = [np.ascontiguousarray(W, dtype=np.float32) for W in s.weights[1:]]
        self._bs = [np.ascontiguousarray(b, dtype=np.float32) for b in s.biases[1:]]

    @property
    def n_members(self) -> int:
        """Networks in the ensemble."""
        return self.spec.n_members

    def localise_into(self, x: np.ndarray, out: np.ndarray) -> None:
        """One image ``x (n_features,)`` float32 counts into ``out (7,)`` (see ``Engine``)."""
        _localise_one(
            x,
            self._params,
            self._meta,
            self._scratch,
            self._members,
            self.surface.mode,
            self.surface.args,
            out,
        )

    def forward_batch(self, X: np.ndarray) -> np.ndarray:
        """Member outputs ``(n_members, n, 3)`` m for ``X (n, n_features)``, float32 BLAS."""
        s = self.spec
        Z = np.asarray(X, dtype=np.float32).reshape(-1, self.n_features)
        if s.clip_negative:
            Z = np.maximum(Z, 0.0)
        h = Z @ self._W0
        if s.normalise != "none":
            nrm = np.linalg.norm(Z, ord=norm_code(s.normalise), axis=1, keepdims=True)
            h /= np.maximum(nrm, 1.0)
        h += self._b0
        L = len(s.weights)
        if L > 1:
            h = activate_inplace(h, s.activation)
        h = h.reshape(len(Z), self.n_members, -1).transpose(1, 0, 2)  # (E, n, h)
        for i, (W, b) in enumerate(zip(self._Ws, self._bs, strict=True)):
            h = np.matmul(h, W)
            h += b
            if i < L - 2:
                h = activate_inplace(h, s.activation)
        return h.astype(np.float64) * s.target_scale + s.target_mean

    def _predict_rows(self, X: np.ndarray) -> tuple[Points, Points, np.ndarray]:
        """The forward pass on BLAS over the whole batch, then the constraint in parallel.

        The batch goes in blocks of 65,536 rows: alternating the two per small block makes
        OpenBLAS's spinning threads and numba's contend for the cores, which halved the
        throughput on this 2-core machine.
        """
        raw = np.empty((len(X), 3))
        spread = np.full(len(X), np.nan)
        for i in range(0, len(X), 65536):
            block = slice(i, i + 65536)
            members = self.forward_batch(X[block])  # (E, rows, 3)
            raw[block] = members.mean(axis=0)
            if self.n_members > 1:
                dev = ((members - raw[block]) ** 2).sum(axis=2)
                spread[block] = 1e3 * np.sqrt(dev.mean(axis=0))
        return self.constrain(raw), raw, spread
