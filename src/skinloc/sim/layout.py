"""The wiring of a simulated skin: TX/RX wire polylines on any mesh and per-sensor electronics.

``SkinLayout.generate`` lays the wires along a 2-D chart of the surface (cylindrical for a cone
about the y axis, planar otherwise); see ``docs/simulator.md``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import trimesh

from skinloc._typing import Points
from skinloc.sim.params import SkinParams

log = logging.getLogger(__name__)

__all__ = ["MAX_RX", "MAX_TX", "SkinLayout", "check_grid"]

#: Largest grid the Muca board reads.
MAX_TX, MAX_RX = 21, 12
_WIRE_SAMPLES = 48  # points per wire polyline


@dataclass(frozen=True)
class SkinLayout:
    """The wiring of one simulated skin and its per-sensor electronics.

    Sensor k is TX ``k // n_rx``, RX ``k % n_rx`` (electrical order).

    Attributes
    ----------
    n_tx, n_rx : int
        Grid size.
    sensor_positions : (n_tx * n_rx, 3) float
        Crossings of the wires, on the surface, m.
    tx_wires : (n_tx, m, 3) float
        Polyline of each TX wire on the surface, m.
    rx_wires : (n_rx, m, 3) float
        Polyline of each RX wire on the surface, m.
    gains : (n_tx * n_rx,) float
        Relative sensitivity of each sensor (median 1).
    baselines_counts : (n_tx * n_rx,) float
        No-touch count of each sensor.
    noise_std_counts : (n_tx * n_rx,) float
        Per-frame Gaussian noise std of each sensor, counts.
    parameterisation : str
        ``"cylindrical"`` (TX wires at constant angle about the y axis, i.e. along the cone;
        RX wires at constant y, around it) or ``"planar"`` (TX at constant first principal
        coordinate, RX at constant second one).
    width_scales : (n_tx * n_rx,) float or None
        Each crossing's own response width relative to the common one (median 1): the
        irregularity between neighbouring crossings. ``None`` means all 1.
    height_range_m : (float, float) or None
        Lowest and highest y of the mesh, m: the silicone thickens linearly from the top
        (``silicone_thickness_m``) to the base (``silicone_thickness_base_m``). ``None`` means
        a uniform thickness.
    """

    n_tx: int
    n_rx: int
    sensor_positions: Points
    tx_wires: np.ndarray
    rx_wires: np.ndarray
    gains: np.ndarray
    baselines_counts: np.ndarray
    noise_std_counts: np.ndarray
    parameterisation: str
    width_scales: np.ndarray | None = None
    height_range_m: tuple[float, float] | None = None

    @property
    def n_sensors(self) -> int:
        """``n_tx * n_rx``."""
        return self.n_tx * self.n_rx

    @classmethod
    def generate(
        cls,
        mesh: trimesh.Trimesh,
        n_tx: int = 8,
        n_rx: int = 8,
        params: SkinParams | None = None,
        random_state: int | np.random.Generator | None = 0,
        parameterisation: str = "auto",
    ) -> SkinLayout:
        """Lay out TX and RX wires on ``mesh`` with uneven, seed-randomised spacing.

        Parameters
        ----------
        mesh : trimesh.Trimesh
            Skin surface, m.
        n_tx, n_rx : int
            Grid, at most 21 x 12.
        params : SkinParams, optional
            Defaults to ``SkinParams.default()``.
        random_state : int, Generator or None
            Seed of the wiring and the per-sensor electronics.
        parameterisation : {"auto", "cylindrical", "planar"}
            Surface coordinates the wires follow. ``auto`` takes ``cylindrical`` when the mesh
            is a cone or cylinder about the y axis (like the paper's skin), else ``planar``.

        Returns
        -------
        SkinLayout
        """
        check_grid(n_tx, n_rx)
        params = SkinParams.default() if params is None else params
        rng = np.random.default_rng(random_state)
        if parameterisation == "auto":
            parameterisation = "cylindrical" if _is_y_cone(mesh) else "planar"
        if parameterisation not in ("cylindrical", "planar"):
            raise ValueError(
                "parameterisation must be one of auto, cylindrical, planar; "
                f"got {parameterisation!r}"
            )
        lift, (u_lo, u_hi), (v_lo, v_hi) = _surface_chart(mesh, parameterisation)

        u_tx, du = _uneven(n_tx, u_lo, u_hi, params, rng)
        v_rx, dv = _uneven(n_rx, v_lo, v_hi, params, rng)
        # Each wire meanders sideways: u(v) = u_i + A sin(2 pi f t + phi), t in [0, 1].
        wob_tx = _wobble(n_tx, params.wire_wobble * du, rng)
        wob_rx = _wobble(n_rx, params.wire_wobble * dv, rng)
        t = np.linspace(0.0, 1.0, _WIRE_SAMPLES)
        v_line = v_lo + t * (v_hi - v_lo)
        u_line = u_lo + t * (u_hi - u_lo)
        tx_uv = np.stack(
            [u_tx[:, None] + wob_tx(t), np.broadcast_to(v_line, (n_tx, t.size))], axis=-1
        )
        rx_uv = np.stack(
            [np.broadcast_to(u_line, (n_rx, t.size)), v_rx[:, None] + wob_rx(t)], axis=-1
        )
        # Crossings by fixed-point iteration (the wobble is small, so this converges fast).
        uu = np.broadcast_to(u_tx[:, None], (n_tx, n_rx)).copy()
        vv = np.broadcast_to(v_rx[None, :], (n_tx, n_rx)).copy()
        for _ in range(8):
            tv = (vv - v_lo) / (v_hi - v_lo)
            uu = u_tx[:, None] + wob_tx(tv, diag=True)
            tu = (uu - u_lo) / (u_hi - u_lo)
            vv = v_rx[None, :] + wob_rx(tu.T, diag=True).T

        # Electrical order is a random permutation of the spatial order.
        perm_tx = rng.permutation(n_tx) if params.shuffle_lines else np.arange(n_tx)
        perm_rx = rng.permutation(n_rx) if params.shuffle_lines else np.arange(n_rx)
        tx_uv, rx_uv = tx_uv[perm_tx], rx_uv[perm_rx]
        uu, vv = uu[perm_tx][:, perm_rx], vv[perm_tx][:, perm_rx]

        tx_wires = lift(tx_uv.reshape(-1, 2)).reshape(n_tx, t.size, 3)
        rx_wires = lift(rx_uv.reshape(-1, 2)).reshape(n_rx, t.size, 3)
        sensors = lift(np.stack([uu.ravel(), vv.ravel()], axis=1))

        n = n_tx * n_rx
        gains = np.exp(params.gain_std * rng.standard_normal(n))
        line_level = (
            params.baseline_mean_counts
            + params.baseline_line_std_counts * rng.standard_normal(n_rx)
        )
        baselines = np.tile(
            line_level, n_tx
        ) + params.baseline_sensor_std_counts * rng.standard_normal(n)
        baselines = np.clip(baselines, params.baseline_min_counts, params.baseline_max_counts)
        noise = np.clip(
            params.noise_std_counts + params.noise_std_spread_counts * rng.standard_normal(n),
            params.noise_std_min_counts,
            params.noise_std_max_counts,
        )
        for tx, rx in params.noisy_sensors:
            if tx < n_tx and rx < n_rx:
                noise[tx * n_rx + rx] = params.noisy_sensor_noise_std_counts
        # Drawn last, so the wiring and electronics of a seed stay what they were before.
        widths = np.exp(params.crossing_width_std * rng.standard_normal(n))
        y = np.asarray(mesh.vertices)[:, 1]
        log.debug(
            "laid out %d x %d wires (%s) on a mesh of %d faces",
            n_tx,
            n_rx,
            parameterisation,
            len(mesh.faces),
        )
        return cls(
            n_tx=n_tx,
            n_rx=n_rx,
            sensor_positions=sensors,
            tx_wires=tx_wires,
            rx_wires=rx_wires,
            gains=gains,
            baselines_counts=baselines,
            noise_std_counts=noise,
            parameterisation=parameterisation,
            width_scales=widths,
            height_range_m=(float(y.min()), float(y.max())),
        )


def check_grid(n_tx: int, n_rx: int) -> None:
    """Raise ValueError unless ``n_tx x n_rx`` fits the Muca board (at most 21 x 12)."""
    if not (isinstance(n_tx, int | np.integer) and 1 <= n_tx <= MAX_TX):
        raise ValueError(f"n_tx must be an int in 1-{MAX_TX} (the Muca board limit), got {n_tx!r}")
    if not (isinstance(n_rx, int | np.integer) and 1 <= n_rx <= MAX_RX):
        raise ValueError(f"n_rx must be an int in 1-{MAX_RX} (the Muca board limit), got {n_rx!r}")


def _is_y_cone(mesh: trimesh.Trimesh) -> bool:
    """Whether the mesh is a (part of a) cone or cylinder about the y axis."""
    # Vertices and face centres must both lie on r = a y + b (a box's corners alone could).
    v = np.concatenate([mesh.vertices, mesh.triangles_center])
    r = np.hypot(v[:, 0], v[:, 2])
    if len(mesh.vertices) < 12 or np.ptp(v[:, 1]) <= 1e-9 or r.mean() <= 1e-9:
        return False
    a = np.polyfit(v[:, 1], r, 1)
    return bool(np.abs(np.polyval(a, v[:, 1]) - r).max() < 0.02 * r.mean())


def _surface_chart(mesh: trimesh.Trimesh, kind: str):
    """``lift((k, 2) uv) -> (k, 3)`` points on the surface, and the u and v ranges."""
    v = np.asarray(mesh.vertices, dtype=np.float64)

    def project(points: np.ndarray) -> np.ndarray:
        return trimesh.proximity.closest_point(mesh, points)[0]

    if kind == "cylindrical":
        theta = np.arctan2(v[:, 2], v[:, 0])
        radius_fit = np.polyfit(v[:, 1], np.hypot(v[:, 0], v[:, 2]), 1)

        def lift(uv: np.ndarray) -> np.ndarray:
            r = np.polyval(radius_fit, uv[:, 1])
            pts = np.stack([r * np.cos(uv[:, 0]), uv[:, 1], r * np.sin(uv[:, 0])], axis=1)
            return project(pts)

        return lift, (theta.min(), theta.max()), (v[:, 1].min(), v[:, 1].max())

    centre = v.mean(axis=0)
    _, _, axes = np.linalg.svd(v - centre, full_matrices=False)
    normal = axes[2]
    if mesh.face_normals.mean(axis=0) @ normal < 0:  # lay the skin on the outward side
        normal = -normal
    uv_v = (v - centre) @ axes[:2].T
    height = float(np.ptp(v, axis=0).max())

    def lift(uv: np.ndarray) -> np.ndarray:
        # Drop each point onto the skin from above along -normal (closest points would pile up
        # on the vertices of a coarse convex mesh). Points outside the silhouette are pulled
        # towards the centre until they land.
        out = np.empty((len(uv), 3))
        todo = np.arange(len(uv))
        scale = 1.0
        for _ in range(80):
            origins = centre + scale * uv[todo] @ axes[:2] + height * normal
            hits, ray, _ = mesh.ray.intersects_location(
                origins, np.broadcast_to(-normal, origins.shape), multiple_hits=False
            )
            # trimesh gives (0,) rather than (0, 3) when no ray hits
            out[todo[ray]] = np.reshape(hits, (-1, 3))
            todo = np.setdiff1d(todo, todo[ray])
            if todo.size == 0:
                break
            scale *= 0.97
        if todo.size:
            out[todo] = project(centre + uv[todo] @ axes[:2] + height * normal)
        return project(out)  # exactly on the triangles

    return lift, (uv_v[:, 0].min(), uv_v[:, 0].max()), (uv_v[:, 1].min(), uv_v[:, 1].max())


def _uneven(n: int, lo: float, hi: float, params: SkinParams, rng: np.random.Generator):
    """``n`` sorted wire positions in ``[lo, hi]`` with jittered spacing; and the mean spacing."""
    m = params.edge_margin
    spacing = (hi - lo) / (n - 1 + 2 * m)
    base = lo + spacing * (m + np.arange(n))
    pos = base + spacing * rng.uniform(-params.spacing_jitter, params.spacing_jitter, n)
    return np.sort(pos), spacing


def _wobble(n: int, amplitude: float, rng: np.random.Generator):
    """Sideways meander of ``n`` wires: ``f(t (n, k)) -> (n, k)`` offsets in chart units."""
    freq = rng.uniform(0.5, 1.5, n)[:, None]
    phase = rng.uniform(0.0, 2 * np.pi, n)[:, None]
    amp = amplitude * rng.uniform(0.3, 1.0, n)[:, None]

    def f(t: np.ndarray, diag: bool = False) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        if not diag:
            t = np.broadcast_to(t, (n, t.shape[-1]))
        return amp * np.sin(2 * np.pi * freq * t + phase)

    return f
