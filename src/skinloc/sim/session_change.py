"""What changes between two sessions of one simulated skin (weeks apart, or the skin remounted).

``later_session(skin, change, seed)`` gives the same skin (same mesh, wiring seed and physics)
as it responds in a later session: its baselines shifted, each sensor's and each line's gain
scaled, its footprint wider or narrower, the whole skin turned and slid on its shell, and the
crossings' apparent positions moved one by one (a non-rigid change). ``SessionChange`` holds
the sizes; ``SessionChange.preset`` names three:

- ``"real"``: the change between the real cone skin's sessions of 2023-12-10 and 2024-05-23
  (``bench/session_change.py``, ``docs/accuracy.md``, "What changes between the two
  sessions"). Footprint, baseline and rigid move are the measured sizes; the gain spreads and
  the crossings' own move are set so that the same measurement (sensor maps of 130 and 60
  touches) on a simulated pair gives the real figures: 52 % of the gains beyond x0.67-1.5,
  crossings' apparent positions ~33 mm off, not a rigid move;
- ``"mild"``: a small change (a remount the same week);
- ``"none"``: no change at all (the later session is the same skin).

The noise is unchanged (the real ratio is 1.02) and every draw follows the seed alone.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import trimesh

from skinloc.sim.layout import SkinLayout
from skinloc.sim.params import COUNT_MAX, SkinParams
from skinloc.sim.skin import SimulatedSkin

__all__ = ["SESSION_CHANGES", "SessionChange", "change_layout", "change_params", "later_session"]


@dataclass(frozen=True)
class SessionChange:
    """Sizes of the change between two sessions of one skin; units are in the names.

    Attributes
    ----------
    baseline_shift_counts : float
        Standard deviation of each sensor's baseline shift, counts (real: 463, i.e. a median
        absolute shift of 312 counts). A baseline capture measures it; the model never sees it.
    sensor_gain_log_std : float
        Standard deviation of the log of each sensor's own gain factor (real: 0.20).
    tx_line_gain_log_std, rx_line_gain_log_std : float
        Standard deviation of the log of each TX / RX line's gain factor (real: 0.15 and 0.32;
        the real lines changed by 0.75-1.40 and 0.59-2.74).
    footprint_factor : float
        Factor on the width of a touch's footprint (silicone thickness and contact radius
        scaled together; real: 0.90).
    rotation_deg : float
        Turn of the whole skin on its shell, about the surface normal at the crossings'
        centre, degrees (real: 7.6, the rigid fit's 8.8 less the same-day 4.4 in quadrature).
    shift_mm : float
        Slide of the whole skin along the surface, mm (real: 9.7).
    displacement_mm : float
        Median of each crossing's own move along the surface (Rayleigh distributed, on top of
        the rigid move), mm: where a crossing's response peaks, no longer where it was (real:
        60, which a sensor map of 60 touches sees as 33 mm; the real one saw 39 mm). The wires
        keep their course.

    Raises
    ------
    ValueError
        Naming the field, when a size is negative (or the footprint factor not positive).
    """

    baseline_shift_counts: float = 0.0
    sensor_gain_log_std: float = 0.0
    tx_line_gain_log_std: float = 0.0
    rx_line_gain_log_std: float = 0.0
    footprint_factor: float = 1.0
    rotation_deg: float = 0.0
    shift_mm: float = 0.0
    displacement_mm: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"SessionChange.{f.name} must be finite and >= 0, got {value!r}")
        if not 0.2 <= self.footprint_factor <= 5.0:
            raise ValueError(
                f"SessionChange.footprint_factor must be in [0.2, 5], got {self.footprint_factor!r}"
            )

    @classmethod
    def preset(cls, name: str) -> SessionChange:
        """The change ``name`` names: ``"real"``, ``"mild"`` or ``"none"``."""
        try:
            return SESSION_CHANGES[name]
        except KeyError:
            known = ", ".join(SESSION_CHANGES)
            raise ValueError(f"session change must be one of {known}, got {name!r}") from None

    @property
    def is_identity(self) -> bool:
        """Whether this change leaves the skin as it was."""
        return self == SessionChange()


#: The named changes (``SessionChange.preset``); ``docs/simulator.md`` gives their sources.
SESSION_CHANGES: dict[str, SessionChange] = {
    "real": SessionChange(
        baseline_shift_counts=463.0,
        sensor_gain_log_std=0.20,
        tx_line_gain_log_std=0.15,
        rx_line_gain_log_std=0.32,
        footprint_factor=0.90,
        rotation_deg=7.6,
        shift_mm=9.7,
        displacement_mm=60.0,
    ),
    "mild": SessionChange(
        baseline_shift_counts=50.0,
        sensor_gain_log_std=0.1,
        tx_line_gain_log_std=0.05,
        rx_line_gain_log_std=0.05,
        footprint_factor=1.0,
        rotation_deg=1.0,
        shift_mm=2.0,
        displacement_mm=3.0,
    ),
    "none": SessionChange(),
}


def _on_surface(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """``points (n, 3)`` m moved onto the nearest point of ``mesh``."""
    return trimesh.proximity.closest_point(mesh, points)[0]


def change_layout(
    layout: SkinLayout, mesh: trimesh.Trimesh, change: SessionChange, rng: np.random.Generator
) -> SkinLayout:
    """``layout`` as it is in a later session (the footprint is a parameter, not the layout's).

    Gains: each sensor's times its own, its TX line's and its RX line's log-normal factor.
    Baselines: shifted per sensor, kept within the 16-bit count range. Positions: crossings and
    wires turned about the surface normal at the crossings' centre and slid along the surface
    together (rigid), then each crossing moved on its own (non-rigid), all put back on the mesh.
    """
    if change.is_identity:
        return layout
    n_tx, n_rx = layout.n_tx, layout.n_rx
    log_gain = (
        change.sensor_gain_log_std * rng.standard_normal(n_tx * n_rx)
        + np.repeat(change.tx_line_gain_log_std * rng.standard_normal(n_tx), n_rx)
        + np.tile(change.rx_line_gain_log_std * rng.standard_normal(n_rx), n_tx)
    )
    shift = change.baseline_shift_counts * rng.standard_normal(n_tx * n_rx)
    baselines = np.clip(layout.baselines_counts + shift, 0.0, COUNT_MAX)

    # the rigid move: about the centre of the crossings, in the tangent plane there
    centre = layout.sensor_positions.mean(axis=0)
    _, _, face = trimesh.proximity.closest_point(mesh, centre[None])
    normal = np.asarray(mesh.face_normals[face[0]], dtype=np.float64)
    e1 = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    angle = np.radians(change.rotation_deg) * rng.choice([-1.0, 1.0])
    heading = rng.uniform(0.0, 2.0 * np.pi)
    slide = 1e-3 * change.shift_mm * (np.cos(heading) * e1 + np.sin(heading) * e2)
    rot = trimesh.transformations.rotation_matrix(angle, normal, centre)[:3, :3]

    def rigid(points: np.ndarray) -> np.ndarray:
        flat = points.reshape(-1, 3)
        moved = (flat - centre) @ rot.T + centre + slide
        return _on_surface(mesh, moved).reshape(points.shape)

    sensors = rigid(layout.sensor_positions)
    if change.displacement_mm > 0:
        # Rayleigh distributed distance (median = displacement_mm), uniform heading, in the
        # tangent plane of each crossing
        sigma = 1e-3 * change.displacement_mm / np.sqrt(2.0 * np.log(2.0))
        _, _, faces = trimesh.proximity.closest_point(mesh, sensors)
        normals = np.asarray(mesh.face_normals[faces], dtype=np.float64)
        step = sigma * rng.standard_normal(sensors.shape)
        step -= (step * normals).sum(axis=1, keepdims=True) * normals
        sensors = _on_surface(mesh, sensors + step)
    return dataclasses.replace(
        layout,
        sensor_positions=sensors,
        tx_wires=rigid(layout.tx_wires),
        rx_wires=rigid(layout.rx_wires),
        gains=layout.gains * np.exp(log_gain),
        baselines_counts=baselines,
    )


def change_params(params: SkinParams, change: SessionChange) -> SkinParams:
    """``params`` with the footprint's width scaled by ``change.footprint_factor``.

    The width is ``sqrt(h^2 + a^2)`` (silicone thickness, contact radius): both are scaled.
    """
    f = change.footprint_factor
    if f == 1.0:
        return params
    return dataclasses.replace(
        params,
        silicone_thickness_m=params.silicone_thickness_m * f,
        silicone_thickness_base_m=params.silicone_thickness_base_m * f,
        finger_radius_m=params.finger_radius_m * f,
        finger_radius_std_m=params.finger_radius_std_m * f,
    )


def later_session(skin: SimulatedSkin, change: SessionChange | str, seed: int = 0) -> SimulatedSkin:
    """A later session of ``skin`` (a ``SimulatedSkin``): a new skin object, ``skin`` unchanged.

    Parameters
    ----------
    skin : SimulatedSkin
        The skin of the first session.
    change : SessionChange or str
        The sizes, or a preset's name (``SessionChange.preset``).
    seed : int, default=0
        Seed of the change's draws (gains, baselines, moves); the later session's noise and
        touches are reseeded from it too.

    Returns
    -------
    SimulatedSkin
        Same mesh, grid, wiring seed and rate; changed layout and footprint.
    """
    if isinstance(change, str):
        change = SessionChange.preset(change)
    if not (isinstance(seed, int | np.integer) and seed >= 0):
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    rng = np.random.default_rng([int(seed), 35])
    later = SimulatedSkin(
        skin.mesh,
        n_tx=skin.n_tx,
        n_rx=skin.n_rx,
        params=change_params(skin.params, change),
        random_state=skin.random_state,
        rate_hz=skin.rate_hz,
        realtime=skin.realtime,
    )
    later.layout = change_layout(skin.layout, skin.mesh, change, rng)
    later.reseed(int(seed) + 1)
    return later
