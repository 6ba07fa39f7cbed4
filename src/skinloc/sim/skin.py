"""A simulated mutual-capacitance skin: TX/RX wires on any mesh, a finger, noise and drift.

The core is the pure function ``sensor_image(layout, params, contact, pressure, radius)``:
the expected baseline-subtracted image of one contact. ``SimulatedSkin`` wraps it in a
``FrameSource`` that adds baselines, noise, drift, integer rounding and a simulated clock.
The model and every default value are described in ``docs/simulator.md``.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from skinloc._typing import Points
from skinloc.errors import FrameTimeoutError
from skinloc.sources.base import Frame, FrameSource

try:
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10 needs the tomli backport
    import tomli as tomllib

log = logging.getLogger(__name__)

__all__ = [
    "MAX_RX",
    "MAX_TX",
    "SimulatedSkin",
    "SkinLayout",
    "SkinParams",
    "sensor_image",
    "silicone_thickness_at",
]

#: Largest grid the Muca board reads.
MAX_TX, MAX_RX = 21, 12
_COUNT_MAX = 65535.0  # 16-bit counts
_WIRE_SAMPLES = 48  # points per wire polyline
# A touch whose second-strongest sensor stays under this many noise stds is not felt by the
# session's touch detector (5 sigma, 2 sensors) with some margin, so the person presses again.
_FELT_SIGMA = 6.0


def _default_toml() -> Path:
    return Path(str(resources.files("skinloc.sim") / "fitted_skin.toml"))


@dataclass(frozen=True)
class SkinParams:
    """Physical parameters of the simulated skin; units are in the names.

    Lengths are metres, signals raw counts, times seconds. ``SkinParams.default()`` loads the
    values fitted to the real recordings from the package file ``sim/fitted_skin.toml``, which
    comments every field; ``dataclasses.replace(params, field=value)`` makes a variant.

    Raises
    ------
    ValueError
        From ``__post_init__``, naming the field and the value, when a value is out of range.
    """

    # wiring
    spacing_jitter: float = 0.3
    wire_wobble: float = 0.15
    edge_margin: float = 0.5
    shuffle_lines: bool = True
    # touch signal
    silicone_thickness_m: float = 0.006
    silicone_thickness_base_m: float = 0.013
    peak_signal_counts: float = 300.0
    falloff_exponent: float = 1.3
    line_coupling: float = 0.12
    common_mode_counts: float = 1.5
    finger_radius_m: float = 0.010
    finger_radius_std_m: float = 0.001
    pressure_std: float = 0.2
    radius_pressure_exponent: float = 0.333
    weak_touch_prob: float = 0.15
    weak_touch_pressure: float = 0.3
    crossing_width_std: float = 0.0
    probe_error_std_m: float = 0.0053
    # per-sensor electronics
    gain_std: float = 0.2
    baseline_mean_counts: float = 9500.0
    baseline_line_std_counts: float = 1000.0
    baseline_sensor_std_counts: float = 500.0
    baseline_min_counts: float = 3000.0
    baseline_max_counts: float = 12000.0
    noise_std_counts: float = 4.8
    noise_std_spread_counts: float = 0.5
    noise_std_min_counts: float = 3.4
    noise_std_max_counts: float = 5.7
    # faults
    weak_rx_lines: tuple[int, ...] = (3,)
    weak_tx_lines: tuple[int, ...] = ()
    weak_line_gain: float = 0.35
    weak_line_offset_counts: float = -8.0
    noisy_sensors: tuple[tuple[int, int], ...] = ((1, 7),)
    noisy_sensor_noise_std_counts: float = 50.0
    # drift
    drift_std_counts: float = 3.0
    drift_time_constant_s: float = 300.0

    def __post_init__(self) -> None:
        # TOML gives lists; store tuples so the dataclass stays hashable and immutable.
        object.__setattr__(self, "weak_rx_lines", tuple(int(i) for i in self.weak_rx_lines))
        object.__setattr__(self, "weak_tx_lines", tuple(int(i) for i in self.weak_tx_lines))
        object.__setattr__(
            self, "noisy_sensors", tuple((int(t), int(r)) for t, r in self.noisy_sensors)
        )
        checks: dict[str, tuple[bool, str]] = {
            "spacing_jitter": (0.0 <= self.spacing_jitter < 0.5, "in [0, 0.5)"),
            "wire_wobble": (0.0 <= self.wire_wobble <= 0.5, "in [0, 0.5]"),
            "edge_margin": (0.0 < self.edge_margin <= 1.0, "in (0, 1]"),
            "silicone_thickness_m": (0.0 < self.silicone_thickness_m < 0.1, "in (0, 0.1) m"),
            "silicone_thickness_base_m": (
                0.0 < self.silicone_thickness_base_m < 0.1,
                "in (0, 0.1) m",
            ),
            "peak_signal_counts": (self.peak_signal_counts >= 0.0, ">= 0 counts"),
            "falloff_exponent": (0.0 < self.falloff_exponent <= 10.0, "in (0, 10]"),
            "line_coupling": (0.0 <= self.line_coupling <= 1.0, "in [0, 1]"),
            "finger_radius_m": (0.0 < self.finger_radius_m < 0.05, "in (0, 0.05) m"),
            "finger_radius_std_m": (0.0 <= self.finger_radius_std_m < 0.02, "in [0, 0.02) m"),
            "pressure_std": (0.0 <= self.pressure_std <= 2.0, "in [0, 2]"),
            "radius_pressure_exponent": (0.0 <= self.radius_pressure_exponent <= 1.0, "in [0, 1]"),
            "weak_touch_prob": (0.0 <= self.weak_touch_prob <= 1.0, "in [0, 1]"),
            "weak_touch_pressure": (0.0 < self.weak_touch_pressure <= 1.0, "in (0, 1]"),
            "crossing_width_std": (0.0 <= self.crossing_width_std <= 1.0, "in [0, 1]"),
            "probe_error_std_m": (0.0 <= self.probe_error_std_m < 0.05, "in [0, 0.05) m"),
            "gain_std": (0.0 <= self.gain_std <= 2.0, "in [0, 2]"),
            "baseline_line_std_counts": (self.baseline_line_std_counts >= 0, ">= 0 counts"),
            "baseline_sensor_std_counts": (self.baseline_sensor_std_counts >= 0, ">= 0 counts"),
            "baseline_min_counts": (
                0.0 <= self.baseline_min_counts <= self.baseline_max_counts <= _COUNT_MAX,
                "with 0 <= baseline_min_counts <= baseline_max_counts <= 65535",
            ),
            "baseline_mean_counts": (
                self.baseline_min_counts <= self.baseline_mean_counts <= self.baseline_max_counts,
                "between baseline_min_counts and baseline_max_counts",
            ),
            "noise_std_counts": (self.noise_std_counts >= 0.0, ">= 0 counts"),
            "noise_std_spread_counts": (self.noise_std_spread_counts >= 0.0, ">= 0 counts"),
            "noise_std_min_counts": (
                0.0 <= self.noise_std_min_counts <= self.noise_std_max_counts,
                "with 0 <= noise_std_min_counts <= noise_std_max_counts",
            ),
            "weak_line_gain": (0.0 <= self.weak_line_gain <= 1.0, "in [0, 1]"),
            "noisy_sensor_noise_std_counts": (
                self.noisy_sensor_noise_std_counts >= 0.0,
                ">= 0 counts",
            ),
            "drift_std_counts": (self.drift_std_counts >= 0.0, ">= 0 counts"),
            "drift_time_constant_s": (self.drift_time_constant_s > 0.0, "> 0 s"),
        }
        for name, (ok, allowed) in checks.items():
            value = getattr(self, name)
            if not (ok and np.all(np.isfinite(value))):
                raise ValueError(f"SkinParams.{name} must be {allowed}, got {value!r}")
        for name in ("weak_rx_lines", "weak_tx_lines"):
            if any(i < 0 for i in getattr(self, name)):
                raise ValueError(
                    f"SkinParams.{name} must hold indices >= 0, got {getattr(self, name)!r}"
                )
        if any(t < 0 or r < 0 for t, r in self.noisy_sensors):
            raise ValueError(
                f"SkinParams.noisy_sensors must hold [tx, rx] >= 0, got {self.noisy_sensors!r}"
            )

    @classmethod
    def from_toml(cls, path: str | Path) -> SkinParams:
        """Load parameters from a TOML file of ``field = value`` lines (unknown keys raise)."""
        with Path(path).open("rb") as fh:
            raw: dict[str, Any] = tomllib.load(fh)
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(raw) - known)
        if unknown:
            raise ValueError(f"unknown SkinParams field(s) in {path}: {', '.join(unknown)}")
        return cls(**raw)

    @classmethod
    def default(cls) -> SkinParams:
        """The parameters fitted to the paper's skin (package file ``sim/fitted_skin.toml``)."""
        return cls.from_toml(_default_toml())


# --------------------------------------------------------------------------------------------
# wiring


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
        _check_grid(n_tx, n_rx)
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


def _check_grid(n_tx: int, n_rx: int) -> None:
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
            out[todo[ray]] = hits
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


# --------------------------------------------------------------------------------------------
# the signal model


def _kernel(d2: np.ndarray, width2: float, exponent: float) -> np.ndarray:
    """``(1 + d^2 / w^2)^-exponent``: 1 right above a point, falling off with distance."""
    return (1.0 + d2 / width2) ** (-exponent)


def _polyline_distance2(point: np.ndarray, wires: np.ndarray) -> np.ndarray:
    """Squared distance from ``point (3,)`` to each polyline of ``wires (w, m, 3)``, m^2."""
    a, b = wires[:, :-1], wires[:, 1:]
    ab = b - a
    t = np.clip(
        np.einsum("wsk,wsk->ws", point - a, ab)
        / np.maximum(np.einsum("wsk,wsk->ws", ab, ab), 1e-18),
        0.0,
        1.0,
    )
    closest = a + t[..., None] * ab
    return ((closest - point) ** 2).sum(axis=-1).min(axis=1)


def sensor_image(
    layout: SkinLayout,
    params: SkinParams,
    contact: np.ndarray,
    pressure: float,
    finger_radius_m: float,
) -> np.ndarray:
    """Expected baseline-subtracted image of one finger contact, without noise.

    With ``d_k`` the distance from the contact to sensor k, ``h`` the silicone thickness over
    the contact (``silicone_thickness_at``), ``a`` the finger radius, ``w^2 = h^2 + a^2`` and
    ``K(d; w) = (1 + d^2 / w^2)^-gamma``::

        s_k = P * g_k * [A * (h0 / h) * (K(d_k; r_k w) + c * (K(D_tx(k); w) + K(D_rx(k); w))) + C]

    where ``D_tx(k)``, ``D_rx(k)`` are the distances to the nearest point of the sensor's TX and
    RX wires, ``A`` is ``peak_signal_counts``, ``h0`` ``silicone_thickness_m`` (the top's),
    ``r_k`` the crossing's own width (``layout.width_scales``), ``c`` ``line_coupling``, ``C``
    ``common_mode_counts`` and ``P`` the pressure. Sensors on weak lines respond with
    ``weak_line_gain`` times that, plus ``P * weak_line_offset_counts``.

    Parameters
    ----------
    layout : SkinLayout
        Wiring and per-sensor gains.
    params : SkinParams
        Physical parameters.
    contact : (3,) float
        Contact point on the surface, m.
    pressure : float
        Relative pressure, 1 is a typical touch; 0 gives a zero image.
    finger_radius_m : float
        Contact radius, m.

    Returns
    -------
    (n_tx * n_rx,) float
        Signal in counts (positive: a finger lowers the mutual capacitance).

    Examples
    --------
    >>> from skinloc.geometry.mesh import cone_skin
    >>> layout = SkinLayout.generate(cone_skin(), 8, 8, random_state=0)
    >>> img = sensor_image(layout, SkinParams.default(), layout.sensor_positions[9], 1.0, 0.006)
    >>> int(np.argmax(img))
    9
    """
    contact = np.asarray(contact, dtype=np.float64)
    if contact.shape != (3,):
        raise ValueError(f"contact must have shape (3,), got {contact.shape}")
    if not (np.isfinite(pressure) and pressure >= 0):
        raise ValueError(f"pressure must be a finite value >= 0, got {pressure!r}")
    if not (np.isfinite(finger_radius_m) and finger_radius_m > 0):
        raise ValueError(f"finger_radius_m must be > 0, got {finger_radius_m!r}")
    h = silicone_thickness_at(layout, params, contact)
    width2 = h**2 + finger_radius_m**2
    gamma = params.falloff_exponent
    d2 = ((layout.sensor_positions - contact) ** 2).sum(axis=1)
    scales = np.ones(layout.n_sensors) if layout.width_scales is None else layout.width_scales
    local = _kernel(d2, width2 * scales**2, gamma)
    k_tx = _kernel(_polyline_distance2(contact, layout.tx_wires), width2, gamma)
    k_rx = _kernel(_polyline_distance2(contact, layout.rx_wires), width2, gamma)
    along = (k_tx[:, None] + k_rx[None, :]).ravel()
    # Parallel-plate coupling through the dielectric: the signal falls as 1 / thickness.
    amplitude = params.peak_signal_counts * params.silicone_thickness_m / h
    signal = amplitude * (local + params.line_coupling * along)
    signal = pressure * layout.gains * (signal + params.common_mode_counts)
    weak = np.zeros((layout.n_tx, layout.n_rx), dtype=bool)
    weak[[i for i in params.weak_tx_lines if i < layout.n_tx], :] = True
    weak[:, [j for j in params.weak_rx_lines if j < layout.n_rx]] = True
    weak = weak.ravel()
    signal[weak] = params.weak_line_gain * signal[weak] + pressure * params.weak_line_offset_counts
    return signal


def silicone_thickness_at(layout: SkinLayout, params: SkinParams, point: np.ndarray) -> float:
    """Silicone thickness over ``point (3,)`` m: linear in y from the top to the base, m.

    A skin moulded on a standing cone is thicker at its base; ``silicone_thickness_m`` is the
    thickness at the highest y of the mesh and ``silicone_thickness_base_m`` at the lowest.
    """
    top, base = params.silicone_thickness_m, params.silicone_thickness_base_m
    if layout.height_range_m is None or base == top:
        return top
    lo, hi = layout.height_range_m
    depth = 0.0 if hi <= lo else float(np.clip((hi - point[1]) / (hi - lo), 0.0, 1.0))
    return top + (base - top) * depth


# --------------------------------------------------------------------------------------------
# the frame source


class SimulatedSkin(FrameSource):
    """A simulated skin that streams integer-count frames like the Muca board.

    Parameters
    ----------
    mesh : trimesh.Trimesh, optional
        Skin surface, m; the paper's semi-cone (``geometry.cone_skin()``) by default.
    n_tx, n_rx : int, default=8
        Grid, at most 21 x 12.
    params : SkinParams, optional
        Physical parameters; ``SkinParams.default()`` by default.
    random_state : int or None, default=0
        Seed of the wiring, electronics, noise, drift and touch variation.
    rate_hz : float, default=100.0
        Frame rate of the simulated clock, Hz.
    realtime : bool, default=False
        Sleep so frames arrive at ``rate_hz`` in wall-clock time.

    Examples
    --------
    >>> with SimulatedSkin(random_state=0) as skin:
    ...     skin.press(skin.sensor_positions[0], pressure=1.0)
    ...     frame = skin.read()
    >>> frame.values.shape
    (64,)
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh | None = None,
        *,
        n_tx: int = 8,
        n_rx: int = 8,
        params: SkinParams | None = None,
        random_state: int | None = 0,
        rate_hz: float = 100.0,
        realtime: bool = False,
    ) -> None:
        _check_grid(n_tx, n_rx)
        if not (np.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        if mesh is None:
            from skinloc.geometry.mesh import cone_skin

            mesh = cone_skin()
        self.mesh = mesh
        self.n_tx, self.n_rx = int(n_tx), int(n_rx)
        self.params = SkinParams.default() if params is None else params
        self.random_state = random_state
        self.rate_hz = float(rate_hz)
        self.realtime = realtime
        layout_seed, self._noise_seed = np.random.SeedSequence(random_state).spawn(2)
        self.layout = SkinLayout.generate(
            mesh, self.n_tx, self.n_rx, self.params, np.random.default_rng(layout_seed)
        )
        self._rng = np.random.default_rng(self._noise_seed)
        self._connected = False
        self._index = 0
        self._time_s = 0.0
        self._wall_start: float | None = None
        self._drift = self.params.drift_std_counts * self._rng.standard_normal(self.n_sensors)
        self._signal = np.zeros(self.n_sensors)
        self.contact: np.ndarray | None = None

    # -- FrameSource -------------------------------------------------------------------------
    @property
    def name(self) -> str:
        """``sim`` plus the grid and seed."""
        return f"sim({self.n_tx}x{self.n_rx}, seed={self.random_state})"

    @property
    def is_connected(self) -> bool:
        """Whether ``read`` may be called."""
        return self._connected

    def _connect(self) -> None:
        self._connected = True
        self._wall_start = time.monotonic() - self._time_s

    def _disconnect(self) -> None:
        self._connected = False

    def _read(self, timeout_s: float) -> Frame:
        if self.realtime and self._wall_start is not None:
            wait = self._wall_start + self._time_s - time.monotonic()
            if wait > timeout_s:
                raise FrameTimeoutError(f"{self.name}: no frame within {timeout_s} s")
            if wait > 0:
                time.sleep(wait)
        values = self._frame()
        frame = Frame(values=values, timestamp_s=self._time_s, index=self._index)
        self._index += 1
        self._advance_drift(1.0 / self.rate_hz)
        return frame

    # -- simulation --------------------------------------------------------------------------
    @property
    def sensor_positions(self) -> Points:
        """Where the wire crossings lie, ``(n_sensors, 3)`` m (unknown to any model)."""
        return self.layout.sensor_positions

    @property
    def time_s(self) -> float:
        """The simulated clock, s."""
        return self._time_s

    def _frame(self) -> np.ndarray:
        layout = self.layout
        noise = layout.noise_std_counts * self._rng.standard_normal(self.n_sensors)
        raw = layout.baselines_counts + self._drift + self._signal + noise
        return np.clip(np.rint(raw), 0.0, _COUNT_MAX).astype(np.float32)

    def _advance_drift(self, dt_s: float) -> None:
        """Move the clock by ``dt_s`` and the Ornstein-Uhlenbeck drift exactly with it."""
        self._time_s += dt_s
        p = self.params
        if p.drift_std_counts > 0:
            decay = np.exp(-dt_s / p.drift_time_constant_s)
            step = p.drift_std_counts * np.sqrt(1.0 - decay**2)
            self._drift = decay * self._drift + step * self._rng.standard_normal(self.n_sensors)

    def advance(self, dt_s: float) -> None:
        """Let ``dt_s`` seconds pass without reading frames (the baselines keep drifting)."""
        if not dt_s >= 0:
            raise ValueError(f"dt_s must be >= 0, got {dt_s!r}")
        self._advance_drift(float(dt_s))
        self._index += int(round(dt_s * self.rate_hz))

    def reseed(self, seed: int | None) -> None:
        """Restart the noise, drift and touch randomness from ``seed``, keeping the wiring.

        Two sessions on the same skin (same ``random_state``) then see different noise.
        """
        self._rng = np.random.default_rng(
            np.random.SeedSequence([self._noise_seed.entropy, seed or 0])
        )

    def draw_touch(
        self, rng: np.random.Generator | None = None, weak: bool = True
    ) -> tuple[float, float]:
        """Pressure and finger radius (m) of one touch, drawn from the touch-to-touch spread.

        With ``weak=False`` the touch is never one of the light ones (``weak_touch_prob``).
        """
        rng = self._rng if rng is None else rng
        p = self.params
        pressure = float(np.exp(p.pressure_std * rng.standard_normal() - 0.5 * p.pressure_std**2))
        # A few touches are light (the finger barely lands): a pressure well below the rest.
        if weak and p.weak_touch_prob > 0 and rng.uniform() < p.weak_touch_prob:
            pressure *= p.weak_touch_pressure
        radius = max(
            p.finger_radius_m + p.finger_radius_std_m * rng.standard_normal(),
            0.25 * p.finger_radius_m,
        )
        # A harder press flattens the fingertip: Hertz contact gives a ~ F^(1/3).
        radius *= pressure**p.radius_pressure_exponent
        return pressure, float(radius)

    def press(
        self,
        point: np.ndarray,
        *,
        pressure: float | None = None,
        finger_radius_m: float | None = None,
    ) -> None:
        """Put the finger down at ``point (3,)`` m until ``release``.

        ``pressure`` (1 is a typical touch) and ``finger_radius_m`` not given are drawn from the
        touch-to-touch variation in ``params``.
        """
        point = np.asarray(point, dtype=np.float64).reshape(-1)
        if point.shape != (3,):
            raise ValueError(f"point must have shape (3,), got {point.shape}")
        drawn_p, drawn_r = self.draw_touch()
        pressure = drawn_p if pressure is None else float(pressure)
        radius = drawn_r if finger_radius_m is None else float(finger_radius_m)
        self._signal = sensor_image(self.layout, self.params, point, pressure, radius)
        self.contact = point
        log.debug(
            "press at %s mm, pressure %.2f, radius %.1f mm",
            np.round(point * 1e3, 1),
            pressure,
            radius * 1e3,
        )

    def release(self) -> None:
        """Lift the finger."""
        self._signal = np.zeros(self.n_sensors)
        self.contact = None

    def touch_near(self, target: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """Press near ``target (3,)`` m as a person asked to touch it would.

        The finger lands ``probe_error_std_m`` (per axis, Gaussian) away from the target in the
        surface's tangent plane, projected back onto the mesh. Pressure and finger radius are
        drawn from the touch-to-touch variation.

        Returns
        -------
        (3,) float
            The actual contact point, m (the label stays the target).
        """
        rng = self._rng if rng is None else rng
        target = np.asarray(target, dtype=np.float64).reshape(-1)
        if target.shape != (3,):
            raise ValueError(f"target must have shape (3,), got {target.shape}")
        _, _, face = trimesh.proximity.closest_point(self.mesh, target[None])
        normal = self.mesh.face_normals[face[0]]
        e1 = np.cross(normal, [1.0, 0.0, 0.0])
        if np.linalg.norm(e1) < 1e-6:
            e1 = np.cross(normal, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(normal, e1)
        offset = self.params.probe_error_std_m * rng.standard_normal(2)
        moved = target + offset[0] * e1 + offset[1] * e2
        contact = trimesh.proximity.closest_point(self.mesh, moved[None])[0][0]
        pressure, radius = self.draw_touch(rng)
        felt = _FELT_SIGMA * self.layout.noise_std_counts
        for _ in range(3):
            image = sensor_image(self.layout, self.params, contact, pressure, radius)
            if np.count_nonzero(image > felt) >= 2:
                break
            # Too light for the prompt to register: the person presses again, normally.
            pressure, radius = self.draw_touch(rng, weak=False)
        else:
            # Still not felt (a dull spot): they press harder until it registers.
            pressure *= 1.1 / max(float(np.sort(image / felt)[-2]), 1e-3)
        self.press(contact, pressure=pressure, finger_radius_m=radius)
        return contact
