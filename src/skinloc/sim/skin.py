"""A simulated mutual-capacitance skin: TX/RX wires on any mesh, a finger, noise and drift.

The parts live in their own modules: ``params`` (``SkinParams``), ``layout`` (``SkinLayout``, the
wiring), ``signal`` (``sensor_image``, the pure function that gives the expected
baseline-subtracted image of one contact). ``SimulatedSkin`` here wraps them in a
``FrameSource`` that adds baselines, noise, drift, integer rounding and a simulated clock;
the names above stay importable from this module. The model and every default value are
described in ``docs/simulator.md``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Sequence

import numpy as np
import trimesh

from skinloc._typing import Points
from skinloc.errors import FrameTimeoutError
from skinloc.sim.fingers import Finger, multi_touch_image
from skinloc.sim.layout import MAX_RX, MAX_TX, SkinLayout, check_grid
from skinloc.sim.params import COUNT_MAX, SkinParams
from skinloc.sim.signal import sensor_image, silicone_thickness_at
from skinloc.sources.base import Frame, FrameSource, SourceOptions

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

# A touch whose second-strongest sensor stays under this many noise stds is not felt by the
# session's touch detector (5 sigma, 2 sensors) with some margin, so the person presses again.
_FELT_SIGMA = 6.0


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
        check_grid(n_tx, n_rx)
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
        # The pressure and finger radius (m) of the press in progress, kept while it slides.
        self._pressed: tuple[float, float] | None = None
        # Finger moves queued by ``follow``: (monotonic time s, point (3,) m or None to lift).
        self._moves: deque[tuple[float, np.ndarray | None]] = deque()
        self._moves_lock = threading.Lock()

    # -- FrameSource -------------------------------------------------------------------------
    @property
    def name(self) -> str:
        """``sim`` plus the grid and seed."""
        return f"sim({self.n_tx}x{self.n_rx}, seed={self.random_state})"

    @property
    def is_connected(self) -> bool:
        """Whether ``read`` may be called."""
        return self._connected

    @classmethod
    def from_options(
        cls, options: SourceOptions, mesh: trimesh.Trimesh | None = None
    ) -> SimulatedSkin:
        """The skin ``options`` name (``skinloc.sources.base.make_source``), on ``mesh``."""
        return cls(
            mesh,
            n_tx=options.n_tx,
            n_rx=options.n_rx,
            random_state=options.sim_seed,
            rate_hz=options.rate_hz,
            realtime=options.realtime,
        )

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
        if self._moves:
            # the finger where it was at this frame's time (a reader that is behind still sees
            # the path as it was drawn); a skin that is not paced: where it is now
            paced = self.realtime and self._wall_start is not None
            self._apply_moves(self._wall_start + self._time_s if paced else time.monotonic())
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

    def uncovered_share(self, max_spacings: float = 2.0, n_samples: int = 3000) -> float:
        """Share of the surface farther than ``max_spacings`` sensor spacings from any crossing.

        A planar chart lays the wires on one side of a mesh, so on a closed shell (a whole
        sphere) about half the surface has no sensor near it: a touch there is never felt.
        The spacing is the median distance from a crossing to its nearest neighbour.

        Parameters
        ----------
        max_spacings : float, default=2.0
            How far from the nearest crossing a point may be, in sensor spacings.
        n_samples : int, default=3000
            Surface points sampled evenly (fixed seed: the answer is deterministic).

        Returns
        -------
        float
            In [0, 1]: 0.01 on the paper's cone, 0.46 on a whole sphere.
        """
        from scipy.spatial import cKDTree

        tree = cKDTree(self.sensor_positions)
        spacing = float(np.median(tree.query(self.sensor_positions, k=2)[0][:, 1]))
        points, _ = trimesh.sample.sample_surface_even(self.mesh, n_samples, seed=0)
        dist, _ = tree.query(points)
        return float(np.mean(dist > max_spacings * spacing))

    @property
    def time_s(self) -> float:
        """The simulated clock, s."""
        return self._time_s

    def _frame(self) -> np.ndarray:
        layout = self.layout
        noise = layout.noise_std_counts * self._rng.standard_normal(self.n_sensors)
        raw = layout.baselines_counts + self._drift + self._signal + noise
        return np.clip(np.rint(raw), 0.0, COUNT_MAX).astype(np.float32)

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
        weak: bool = True,
    ) -> None:
        """Put the finger down at ``point (3,)`` m until ``release``.

        ``pressure`` (1 is a typical touch) and ``finger_radius_m`` not given are drawn from the
        touch-to-touch variation in ``params``; ``weak=False``: never one of the light touches
        (a person pressing until the skin responds, as with the app's mouse).
        """
        point = np.asarray(point, dtype=np.float64).reshape(-1)
        if point.shape != (3,):
            raise ValueError(f"point must have shape (3,), got {point.shape}")
        drawn_p, drawn_r = self.draw_touch(weak=weak)
        pressure = drawn_p if pressure is None else float(pressure)
        radius = drawn_r if finger_radius_m is None else float(finger_radius_m)
        self._signal = sensor_image(self.layout, self.params, point, pressure, radius)
        self.contact = point
        self._pressed = (pressure, radius)
        log.debug(
            "press at %s mm, pressure %.2f, radius %.1f mm",
            np.round(point * 1e3, 1),
            pressure,
            radius * 1e3,
        )

    def slide(self, point: np.ndarray) -> None:
        """Move the finger that is down to ``point (3,)`` m, pressing as it did (a drag).

        A finger sliding on the skin keeps its pressure and contact radius; without a finger
        down this is ``press`` (a new touch, its pressure and radius drawn).
        """
        if self.contact is None or self._pressed is None:
            self.press(point)
            return
        pressure, radius = self._pressed
        self.press(point, pressure=pressure, finger_radius_m=radius)

    def follow(self, moves: Sequence[tuple[float, np.ndarray | None]]) -> None:
        """Queue finger moves, each made by the first frame at or after its time.

        ``moves`` are ``(t, point)`` in time order: ``t`` on this machine's ``time.monotonic``
        clock, s; ``point (3,)`` m on the skin presses there (never a light touch, as a person
        pressing until the skin responds) or slides the finger that is down, ``None`` lifts
        it. A paced skin's frame of simulated time ``s`` belongs to wall time ``s`` after its
        start, so a path drawn with the mouse keeps its pace however late frames are read.
        """
        with self._moves_lock:
            for t, point in moves:
                p = None if point is None else np.asarray(point, dtype=np.float64).reshape(3)
                self._moves.append((float(t), p))

    @property
    def moves_pending(self) -> int:
        """Finger moves queued by ``follow`` and not yet made (0: the path has been played)."""
        with self._moves_lock:  # a move is popped and made under this lock: 0 means made
            return len(self._moves)

    def _apply_moves(self, now: float) -> None:
        """Make the queued moves due at ``now`` (monotonic s), oldest first."""
        with self._moves_lock:
            while self._moves and self._moves[0][0] <= now:
                _, point = self._moves.popleft()
                if point is None:
                    self.release()
                elif self.contact is not None and self._pressed is not None:
                    self.slide(point)
                else:
                    self.press(point, weak=False)

    def touch(self, fingers: Sequence[Finger]) -> None:
        """Put ``fingers`` on the skin at once, replacing any (``[]`` lifts them all).

        The image is ``fingers.multi_touch_image``: several fingers interact (shared line
        fields, body re-transmission); one finger gives exactly ``press``'s image.
        """
        fingers = tuple(fingers)
        self._signal = multi_touch_image(self.layout, self.params, fingers)
        self.contact = np.asarray(fingers[0].position_m, dtype=np.float64) if fingers else None
        self._pressed = None

    def release(self) -> None:
        """Lift the finger (every finger)."""
        self._signal = np.zeros(self.n_sensors)
        self.contact = None
        self._pressed = None

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
