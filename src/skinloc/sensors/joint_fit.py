"""One model of every touch's whole image: crossings, touches, pressures and footprint together.

``sensors.crossing_fit`` locates each crossing from its own column of responses, with the touches at
their labels (or moved once). Here every response of every touch is explained at once::

    y_tk = P_t * (g_k * A(x_t) * [K(|x_t - s_k|; w(x_t)) + c * L_tk] + o_k)

with ``x_t`` where touch t really was (its label plus the person's miss, a Gaussian prior of
``label_mm`` per tangent axis), ``P_t`` its pressure, ``s_k`` crossing k on the surface, ``g_k``
its gain, ``o_k`` its offset (common mode, weak lines), ``K(d; w) = (1 + d^2 / w^2)^-gamma``
one point-spread function shared by all crossings whose width ``w`` and amplitude ``A`` change
smoothly over the skin (log-linear in position: thicker silicone, wider footprint), and ``L_tk``
the coupling along sensor k's TX and RX wires (the same kernel of the distance to the wires, the
smooth paths through the current crossings; held fixed within one solve). A touch's image thus
moves its own position, each crossing is pinned by all 80 touches' images rather than by the
few near it, and the label noise averages down over the touches.

Solved by robust (soft-L1) nonlinear least squares from the per-crossing estimate, with each
point moved in its local tangent plane and snapped back to the surface between passes. Lengths
are mm inside.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from skinloc.sensors.crossing_fit import CrossingFit

__all__ = ["JointFit", "half_max_mm", "joint_fit", "plausible"]

_REL_SD = 0.1  # model error proportional to the predicted response
_ABS_SD = 2.0  # counts: model error floor of a mean response
_GAMMA0 = 1.3
_SCALE_MM = 100.0  # position scale of the log-linear width and amplitude trends
_STEP_MM = 15.0  # largest move of a crossing in one pass (tangent plane), mm
#: Shared parameters: log width, its gradient (3), log amplitude gradient (3), log exponent,
#: line coupling.
_N_GLOBAL = 9


@dataclass
class JointFit:
    """Result of ``joint_fit`` (mm, counts)."""

    positions_mm: np.ndarray  # (n_sensors, 3) on the surface
    touches_mm: np.ndarray  # (n_touch, 3) on the surface
    gain: np.ndarray  # (n_sensors,) peak response at each crossing, counts
    offset: np.ndarray  # (n_sensors,) counts
    pressure: np.ndarray  # (n_touch,)
    width_mm: np.ndarray  # (n_sensors,) half-maximum-ish width w at each crossing
    gamma: float
    coupling: float
    cost: float
    #: (n_sensors,) the crossing's own factor, with the skin-wide amplitude trend (thicker
    #: silicone, ...) taken out: what an electrical fault changes.
    electrical_gain: np.ndarray | None = None

    def crossings(self) -> CrossingFit:
        """The crossings: gains without the skin-wide trend, half-maximum footprints."""
        gain = self.gain if self.electrical_gain is None else self.electrical_gain
        return CrossingFit(self.positions_mm, half_max_mm(self), gain, self.touches_mm)


def _frames(points: np.ndarray, cands: np.ndarray, tree: Any, k: int = 24) -> np.ndarray:
    """Orthonormal tangent basis ``(n, 2, 3)`` of the surface at each point (local PCA)."""
    _, idx = tree.query(points, k=k)
    nb = cands[idx] - cands[idx].mean(axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(nb, full_matrices=False)
    return vt[:, :2, :]


def _wire_distance2(x: np.ndarray, paths: list[np.ndarray]) -> np.ndarray:
    """Squared distance ``(n, n_lines)`` from each point to each polyline path, mm^2."""
    out = np.empty((len(x), len(paths)))
    for i, p in enumerate(paths):
        a, b = p[:-1], p[1:]
        ab = b - a
        L2 = np.maximum((ab**2).sum(1), 1e-12)
        t = np.clip(((x[:, None, :] - a[None]) * ab[None]).sum(-1) / L2[None], 0.0, 1.0)
        q = a[None] + t[..., None] * ab[None]
        out[:, i] = ((x[:, None, :] - q) ** 2).sum(-1).min(1)
    return out


def _extended_path(pts: np.ndarray, w: np.ndarray, extend_mm: float = 40.0) -> np.ndarray:
    """A line's smooth path through its crossings, extended past its ends (wires run on)."""
    from skinloc.sensors.wires import line_path

    p = line_path(pts, w, n=24)
    d0 = p[0] - p[1]
    d1 = p[-1] - p[-2]
    d0 /= max(np.linalg.norm(d0), 1e-9)
    d1 /= max(np.linalg.norm(d1), 1e-9)
    return np.vstack([p[0] + extend_mm * d0, p, p[-1] + extend_mm * d1])


@dataclass
class _Pass:
    """One solve: the fixed quantities and the parameter layout (mm, counts)."""

    labels: np.ndarray  # (nt, 3) prompted points
    Y: np.ndarray  # (nt, ns) images
    X0: np.ndarray  # (nt, 3) touches, start of this pass
    S0: np.ndarray  # (ns, 3) crossings, start of this pass
    Ft: np.ndarray  # (nt, 2, 3) tangent bases at X0
    Fs: np.ndarray  # (ns, 2, 3) tangent bases at S0
    centre: np.ndarray  # (3,) origin of the width and amplitude trends
    label_mm: float

    def __post_init__(self) -> None:
        nt, ns = self.Y.shape
        self.free = self.label_mm > 0
        n_u = 2 * nt if self.free else 0
        self.sl_u = slice(0, n_u)
        self.sl_p = slice(n_u, n_u + nt)
        self.sl_v = slice(self.sl_p.stop, self.sl_p.stop + 2 * ns)
        self.sl_g = slice(self.sl_v.stop, self.sl_v.stop + ns)
        self.sl_o = slice(self.sl_g.stop, self.sl_g.stop + ns)
        self.sl_G = slice(self.sl_o.stop, self.sl_o.stop + _N_GLOBAL)
        self.L = np.zeros_like(self.Y)
        self.sd = np.ones_like(self.Y)

    def unpack(self, th: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nt, ns = self.Y.shape
        X = self.X0
        if self.free:
            X = X + np.einsum("ti,tij->tj", th[self.sl_u].reshape(nt, 2), self.Ft)
        S = self.S0 + np.einsum("ki,kij->kj", th[self.sl_v].reshape(ns, 2), self.Fs)
        return X, S

    def width2_gamma(self, X: np.ndarray, G: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Squared width ``(nt, 1)`` mm^2, amplitude ``(nt, 1)`` and exponent at touches X."""
        z = (X - self.centre) / _SCALE_MM
        w2 = np.exp(2.0 * (G[0] + z @ G[1:4]))[:, None]
        return w2, np.exp(z @ G[4:7])[:, None], float(np.exp(G[7]))

    def predict(self, th: np.ndarray) -> np.ndarray:
        X, S = self.unpack(th)
        G = th[self.sl_G]
        w2, A, gam = self.width2_gamma(X, G)
        K = (1.0 + ((X[:, None, :] - S[None]) ** 2).sum(-1) / w2) ** (-gam)
        P = np.exp(th[self.sl_p])[:, None]
        return P * (th[self.sl_g][None] * A * (K + G[8] * self.L) + th[self.sl_o][None])

    def resid(self, th: np.ndarray) -> np.ndarray:
        parts = [((self.predict(th) - self.Y) / self.sd).ravel()]
        if self.free:
            X, _ = self.unpack(th)
            parts.append(((X - self.labels) / self.label_mm).ravel())
        parts.append(th[self.sl_p] / 0.7)  # pressures: median 1, lognormal spread
        return np.concatenate(parts)

    def sparsity(self) -> Any:
        """Which residual depends on which parameter (for the finite-difference Jacobian)."""
        from scipy.sparse import lil_matrix

        nt, ns = self.Y.shape
        n_pr = 3 * nt if self.free else 0
        J = lil_matrix((nt * ns + n_pr + nt, self.sl_G.stop), dtype=np.int8)
        rows = np.arange(nt * ns).reshape(nt, ns)
        for t in range(nt):
            if self.free:
                J[rows[t][:, None], np.array([2 * t, 2 * t + 1])[None]] = 1
                J[nt * ns + 3 * t : nt * ns + 3 * t + 3, 2 * t : 2 * t + 2] = 1
            J[rows[t], self.sl_p.start + t] = 1
            J[nt * ns + n_pr + t, self.sl_p.start + t] = 1
        for k in range(ns):
            v = self.sl_v.start + 2 * k
            cols = np.array([v, v + 1, self.sl_g.start + k, self.sl_o.start + k])
            J[rows[:, k][:, None], cols[None]] = 1
        J[: nt * ns, self.sl_G] = 1
        return J.tocsr()

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        n = self.sl_G.stop
        lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
        lo[self.sl_u], hi[self.sl_u] = -4.0 * self.label_mm, 4.0 * self.label_mm
        lo[self.sl_v], hi[self.sl_v] = -_STEP_MM, _STEP_MM
        lo[self.sl_g] = 0.0
        g0 = self.sl_G.start
        lo[g0], hi[g0] = np.log(2.0), np.log(60.0)  # width, mm
        lo[g0 + 7], hi[g0 + 7] = np.log(0.4), np.log(4.0)  # exponent
        lo[g0 + 8], hi[g0 + 8] = 0.0, 1.0  # line coupling
        return lo, hi


def _line_term(
    X: np.ndarray, w2: np.ndarray, gam: float, S: np.ndarray, g: np.ndarray, n_tx: int, n_rx: int
) -> np.ndarray:
    """Coupling along the wires, ``(nt, ns)``.

    The kernel of each touch's distance to the sensor's TX wire plus that to its RX wire (the
    paths through the crossings ``S``, weighted by gain).
    """
    Sg, Wg = S.reshape(n_tx, n_rx, 3), np.maximum(g, 1e-6).reshape(n_tx, n_rx)
    Dt = _wire_distance2(X, [_extended_path(Sg[i], Wg[i]) for i in range(n_tx)])
    Dr = _wire_distance2(X, [_extended_path(Sg[:, j], Wg[:, j]) for j in range(n_rx)])
    k = np.arange(n_tx * n_rx)
    return ((1.0 + Dt / w2) ** (-gam))[:, k // n_rx] + ((1.0 + Dr / w2) ** (-gam))[:, k % n_rx]


def joint_fit(
    labels_mm: np.ndarray,
    images: np.ndarray,
    init_pos_mm: np.ndarray,
    cands_mm: np.ndarray,
    tree: Any,
    n_tx: int,
    n_rx: int,
    width0_mm: float,
    noise_counts: np.ndarray | None = None,
    label_mm: float = 5.3,
    passes: int = 3,
    init_touches_mm: np.ndarray | None = None,
) -> JointFit:
    """Fit the whole-image model of the module docstring.

    Parameters
    ----------
    labels_mm : (n_touch, 3) float
        Prompted touch points, mm.
    images : (n_touch, n_sensors) float
        Mean baseline-subtracted image of each touch, counts.
    init_pos_mm : (n_sensors, 3) float
        Starting crossings (the per-crossing estimate), mm.
    cands_mm : (P, 3) float
        Surface points, mm; ``tree`` their cKDTree.
    n_tx, n_rx : int
        Grid.
    width0_mm : float
        Starting footprint, mm.
    noise_counts : (n_sensors,) float, optional
        No-touch noise std per sensor (a noisy sensor's responses weigh less).
    label_mm : float
        Person's miss per tangent axis, mm (0: the labels are exact).
    passes : int
        Solves; between them the points are snapped to the surface, tangent planes and wire
        paths are recomputed.
    init_touches_mm : (n_touch, 3) float, optional
        Starting touch positions (default: the labels).

    Returns
    -------
    JointFit
    """
    from scipy.optimize import least_squares

    Y = np.asarray(images, float)
    nt, ns = Y.shape
    labels = np.asarray(labels_mm, float)
    noise = np.full(ns, 5.0) if noise_counts is None else np.nan_to_num(noise_counts, nan=5.0)
    # A noisy sensor's mean responses scatter more: its residuals weigh less.
    abs_sd = _ABS_SD + 0.3 * np.maximum(noise - np.median(noise), 0.0)
    X0 = labels.copy() if init_touches_mm is None else np.asarray(init_touches_mm, float).copy()
    S0 = np.asarray(init_pos_mm, float).copy()
    g = np.maximum(np.sort(Y, axis=0)[-3:].mean(0), 1.0)  # gains from the strongest touches
    o, logP = np.zeros(ns), np.zeros(nt)
    glob = np.array([np.log(width0_mm), 0, 0, 0, 0, 0, 0, np.log(_GAMMA0), 0.1])
    cost = np.nan
    for _ in range(max(passes, 1)):
        pb = _Pass(
            labels, Y, X0, S0, _frames(X0, cands_mm, tree), _frames(S0, cands_mm, tree),
            labels.mean(axis=0), label_mm,
        )  # fmt: skip
        lo, hi = pb.bounds()
        th0 = np.clip(
            np.concatenate([np.zeros(pb.sl_u.stop), logP, np.zeros(2 * ns), g, o, glob]),
            lo + 1e-9,
            hi - 1e-9,
        )
        # Wire coupling and residual scales from the start of the pass, fixed within it.
        w2, _, gam = pb.width2_gamma(X0, glob)
        pb.L = _line_term(X0, w2, gam, S0, g, n_tx, n_rx)
        pred0 = pb.predict(th0)
        pb.sd = np.sqrt(abs_sd[None] ** 2 + (_REL_SD * np.maximum(np.maximum(pred0, Y), 0)) ** 2)
        sol = least_squares(
            pb.resid,
            th0,
            jac_sparsity=pb.sparsity(),
            bounds=(lo, hi),
            loss="soft_l1",
            f_scale=2.0,
            tr_solver="lsmr",
            x_scale="jac",
            max_nfev=60,
        )
        cost = float(sol.cost)
        X, S = pb.unpack(sol.x)
        # Back onto the surface for the next pass.
        S0 = cands_mm[tree.query(S)[1]]
        X0 = cands_mm[tree.query(X)[1]] if pb.free else X0
        logP, g, o, glob = (sol.x[sl] for sl in (pb.sl_p, pb.sl_g, pb.sl_o, pb.sl_G))
    z = (S0 - labels.mean(axis=0)) / _SCALE_MM
    return JointFit(
        positions_mm=S0,
        touches_mm=X0,
        gain=g * np.exp(z @ glob[4:7]),
        offset=o,
        pressure=np.exp(logP),
        width_mm=np.exp(glob[0] + z @ glob[1:4]),
        gamma=float(np.exp(glob[7])),
        coupling=float(glob[8]),
        cost=cost,
        electrical_gain=g,
    )


def plausible(fit: JointFit, labels_mm: np.ndarray, width_mm: float, label_mm: float) -> bool:
    """Whether the whole-image model fits this skin, judged by its own assumptions.

    The touches must have moved about as far as the person's miss allows (median move at
    most 1.5 x the median of a 2D Gaussian miss, ``1.18 label_mm``), and the shared footprint
    must stay within a factor 2 of the per-crossing fit's ``width_mm`` (half-maximum radius).
    A skin whose responses the model does not describe (the real cone, docs/sensors.md) drives
    the touches far from their labels and the footprint to an extreme instead.
    """
    hm = float(np.median(half_max_mm(fit)))
    if not (0.5 * width_mm <= hm <= 2.0 * width_mm):
        return False
    if label_mm <= 0:
        return True
    moves = np.linalg.norm(fit.touches_mm - labels_mm, axis=1)
    return bool(np.median(moves) <= 1.5 * 1.18 * label_mm)


def half_max_mm(fit: JointFit) -> np.ndarray:
    """Half-maximum radius of each crossing's response, ``(n_sensors,)`` mm."""
    return fit.width_mm * np.sqrt(2.0 ** (1.0 / fit.gamma) - 1.0)
