"""A robot's probe calibrates the skin: the interface an arm implements, a simulated one, the loop.

- ``Probe`` is the protocol a user implements for their arm, in the robot's base frame (m):
  ``move_above`` (go to a point above a target, no contact), ``press`` (along a direction to a
  depth or a force, then hold; returns where the tip really was, ``PressReport``), ``lift``
  (back to the point above), ``stop`` (halt now: the safety stop) and ``close``.
- ``SimulatedProbe`` is one over the simulated skin (``sim.skin.SimulatedSkin``, duck-typed as
  ``session.ScriptedFinger`` is): its presses put the skin's finger down, so the skin's own
  frames show the touch, with a Gaussian position error per axis.
- ``ProbeSettings`` holds the press (depth or force), its limits, and the approach height;
  ``check_press`` refuses a press beyond the limits before anything moves.
- ``record_probe_point`` runs one touch of a ``CalibrationSession`` with a probe: move above,
  check that the skin feels no touch there, press, capture on the skin's own touch detection
  (``TouchCapture``, the one touch rule), store the touch with the tip's reported position (put
  on the surface) as its target, lift, wait for the release. Any error or Ctrl-C stops the
  probe first. ``probe_dry_run`` only moves above each target.

The recording keeps, per touch, the tip's reported position in the mesh frame and the press
depth (``meta["probe_tips_m"]``, ``meta["probe_depths_m"]``, ``meta["probe_forces_n"]``) and the
settings in ``meta["probe"]`` (docs/formats.md).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from skinloc._typing import Points
from skinloc.calibration.capture import RELEASE_FRAMES, TouchCapture
from skinloc.calibration.probe_plan import SkinPose
from skinloc.calibration.session import CalibrationSession
from skinloc.errors import SkinlocError
from skinloc.geometry.mesh import nearest_on_surface

__all__ = [
    "CHECK_FRAMES",
    "check_depth",
    "PressReport",
    "Probe",
    "ProbeError",
    "ProbeLinkError",
    "ProbeSafetyError",
    "ProbeSettings",
    "SimulatedProbe",
    "check_press",
    "probe_dry_run",
    "record_probe_point",
]

#: Frames read with the probe above a target (before it presses) that must show no touch.
CHECK_FRAMES = 3


class ProbeError(SkinlocError, RuntimeError):
    """The probe cannot do what it was asked (stopped, refused, or a fault)."""


class ProbeLinkError(ProbeError, ConnectionError):
    """The link to the arm was lost."""


class ProbeSafetyError(ProbeError):
    """A safety rule stopped the probe (a touch where none is planned, a press over a limit)."""


@dataclass(frozen=True)
class PressReport:
    """What the arm reports of one press (base frame).

    Attributes
    ----------
    tip_m : (3,) float
        Where the tip really was at the bottom of the press, m (the arm's measurement).
    depth_m : float
        How far it pressed past the surface along the press direction, m (nan if unknown).
    force_n : float
        The force it pressed with, N (nan if unknown).
    """

    tip_m: np.ndarray
    depth_m: float
    force_n: float = math.nan


class Probe(Protocol):
    """A robot arm's probe, in the robot's base frame (m); implement it for your arm.

    Each call returns when the arm has done it (or raises: ``ProbeLinkError`` for a lost link,
    ``ProbeError`` for anything else). ``stop`` must be safe to call at any time, any number of
    times, from the session's error handling: it halts the arm and leaves the skin.
    """

    def move_above(self, approach_m: np.ndarray, press_direction: np.ndarray) -> None:
        """Move the tip to ``approach_m (3,)`` m without touching the skin.

        The tip points along ``press_direction (3,)`` (unit), the way it will press.
        """

    def press(
        self,
        target_m: np.ndarray,
        press_direction: np.ndarray,
        depth_m: float | None = None,
        force_n: float | None = None,
    ) -> PressReport:
        """Press from above ``target_m (3,)`` m along ``press_direction``.

        Until ``depth_m`` m past the surface or ``force_n`` N (one of them is given), then hold
        until ``lift``.
        """
        ...

    def lift(self) -> None:
        """Leave the skin, back to the point above the target."""

    def stop(self) -> None:
        """Halt now and leave the skin (the safety stop)."""

    def close(self) -> None:
        """End the link to the arm."""


@dataclass(frozen=True)
class ProbeSettings:
    """How a probe presses, and the limits it never passes.

    Attributes
    ----------
    depth_m : float or None
        Press depth past the surface, m (give this or ``force_n``).
    force_n : float or None
        Press force, N.
    max_depth_m : float
        Deepest press allowed, m: a deeper one is refused before anything moves.
    max_force_n : float
        Strongest press allowed, N.
    clearance_m : float
        Height above a target the probe moves to before pressing, m.
    """

    depth_m: float | None = 0.002
    force_n: float | None = None
    max_depth_m: float = 0.005
    max_force_n: float = 10.0
    clearance_m: float = 0.01

    def as_meta(self) -> dict[str, Any]:
        """The settings as a recording's meta stores them."""
        return asdict(self)


def check_depth(depth_m: float, max_depth_m: float) -> None:
    """Refuse a press ``depth_m`` m that is not finite, not positive or past ``max_depth_m``."""
    if not (math.isfinite(depth_m) and 0 < depth_m <= max_depth_m):
        raise ProbeSafetyError(
            f"press depth {1e3 * depth_m:g} mm is beyond the probe's limit of "
            f"{1e3 * max_depth_m:g} mm"
        )


def check_press(settings: ProbeSettings) -> None:
    """Refuse a press beyond the limits (``ProbeSafetyError``) or ill-formed (``ValueError``)."""
    d, f = settings.depth_m, settings.force_n
    if (d is None) == (f is None):
        raise ValueError("give the press as depth_m or force_n, one of them")
    for name in ("max_depth_m", "max_force_n", "clearance_m"):
        v = getattr(settings, name)
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be > 0, got {v!r}")
    if d is not None:
        if not (math.isfinite(d) and d > 0):
            raise ValueError(f"depth_m must be > 0, got {d!r}")
        if d > settings.max_depth_m:
            raise ProbeSafetyError(
                f"press depth {1e3 * d:g} mm is beyond the limit of "
                f"{1e3 * settings.max_depth_m:g} mm: plan refused"
            )
    if f is not None:
        if not (math.isfinite(f) and f > 0):
            raise ValueError(f"force_n must be > 0, got {f!r}")
        if f > settings.max_force_n:
            raise ProbeSafetyError(
                f"press force {f:g} N is beyond the limit of {settings.max_force_n:g} N: "
                "plan refused"
            )


class SimulatedProbe:
    """A probe over the simulated skin: its presses put the skin's finger down.

    The tip really goes ``position_error_m`` (Gaussian, per axis, base frame) off where it was
    sent, and lands on the surface nearest to that; the arm does not know its own error, so it
    reports the tip where it was sent (plus the press depth along the press direction). The
    press strength in the simulator is ``depth / nominal_depth_m`` or ``force /
    nominal_force_n`` (1 is a typical touch); its contact radius is ``tip_radius_m`` at
    pressure 1 and grows with the pressure as the simulator's finger's does
    (``pressure ** params.radius_pressure_exponent``, docs/simulator.md).

    Parameters
    ----------
    skin : SimulatedSkin
        The skin it presses (its mesh in the mesh frame, m).
    pose : SkinPose, optional
        The skin's pose in the base frame; identity by default.
    position_error_m : float
        Standard deviation of the tip's position error per axis, m.
    max_depth_m, max_force_n : float
        The probe's own limits: a deeper or stronger press raises ``ProbeSafetyError``.
    dwell_s : float
        Time the probe holds still after reaching the depth before the capture starts, s.
    speed_m_s : float
        Travel speed between points, m/s (the skin drifts meanwhile).
    nominal_depth_m, nominal_force_n : float
        The depth and force of a typical touch (pressure 1 in the simulator).
    tip_radius_m : float, optional
        Contact radius of the tip at pressure 1, m; the simulator's finger radius by default.
    random_state : int or None
        Seed of the position errors.
    """

    def __init__(
        self,
        skin,
        *,
        pose: SkinPose | None = None,
        position_error_m: float = 0.0005,
        max_depth_m: float = 0.005,
        max_force_n: float = 10.0,
        dwell_s: float = 0.2,
        speed_m_s: float = 0.1,
        nominal_depth_m: float = 0.002,
        nominal_force_n: float = 2.0,
        tip_radius_m: float | None = None,
        random_state: int | None = None,
    ) -> None:
        for name, v in (
            ("position_error_m", position_error_m),
            ("dwell_s", dwell_s),
        ):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be >= 0, got {v!r}")
        for name, v in (
            ("speed_m_s", speed_m_s),
            ("nominal_depth_m", nominal_depth_m),
            ("nominal_force_n", nominal_force_n),
            ("max_depth_m", max_depth_m),
            ("max_force_n", max_force_n),
        ):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be > 0, got {v!r}")
        self.skin = skin
        self.pose = pose or SkinPose()
        self.position_error_m = float(position_error_m)
        self.max_depth_m, self.max_force_n = float(max_depth_m), float(max_force_n)
        self.dwell_s, self.speed_m_s = float(dwell_s), float(speed_m_s)
        self.nominal_depth_m, self.nominal_force_n = float(nominal_depth_m), float(nominal_force_n)
        self.tip_radius_m = (
            skin.params.finger_radius_m if tip_radius_m is None else float(tip_radius_m)
        )
        self.rng = np.random.default_rng(random_state)
        #: Where the tip is now, base frame, m (None: not yet moved).
        self.position: np.ndarray | None = None
        #: The true contact of each press, mesh frame, m (for diagnosis; models never see it).
        self.contacts: list[np.ndarray] = []
        self.pressing = False
        self.stopped = False
        self._above: np.ndarray | None = None

    def _travel(self, to: np.ndarray) -> None:
        if self.position is not None:
            self.skin.advance(float(np.linalg.norm(to - self.position)) / self.speed_m_s)
        self.position = to

    def _check_running(self) -> None:
        if self.stopped:
            raise ProbeError("the probe was stopped")

    def move_above(self, approach_m: np.ndarray, press_direction: np.ndarray) -> None:
        """Move to ``approach_m (3,)`` m in the base frame (the skin drifts while it travels)."""
        self._check_running()
        if self.pressing:
            raise ProbeError("lift before moving")
        approach = np.asarray(approach_m, dtype=np.float64).reshape(3)
        self._travel(approach)
        self._above = approach

    def press(
        self,
        target_m: np.ndarray,
        press_direction: np.ndarray,
        depth_m: float | None = None,
        force_n: float | None = None,
    ) -> PressReport:
        """Press at ``target_m (3,)`` m (base frame) along ``press_direction``; see the class."""
        self._check_running()
        if (depth_m is None) == (force_n is None):
            raise ValueError("give the press as depth_m or force_n, one of them")
        if depth_m is not None:
            check_depth(depth_m, self.max_depth_m)
        if force_n is not None and not 0 < force_n <= self.max_force_n:
            raise ProbeSafetyError(
                f"press force {force_n:g} N is beyond the probe's limit of {self.max_force_n:g} N"
            )
        target = np.asarray(target_m, dtype=np.float64).reshape(3)
        direction = np.asarray(press_direction, dtype=np.float64).reshape(3)
        direction = direction / np.linalg.norm(direction)
        self._travel(target)
        sent = target + self.position_error_m * self.rng.standard_normal(3)
        landed = self.pose.points_to_skin(sent[None])
        contact = nearest_on_surface(self.skin.mesh, landed)[0][0]
        if depth_m is not None:
            pressure = depth_m / self.nominal_depth_m
            depth, force = float(depth_m), math.nan
        else:
            assert force_n is not None
            pressure = force_n / self.nominal_force_n
            depth, force = math.nan, float(force_n)
        # A deeper press widens the contact as the simulator's finger does (a ~ P^exponent).
        radius = self.tip_radius_m * pressure**self.skin.params.radius_pressure_exponent
        self.skin.press(contact, pressure=pressure, finger_radius_m=radius)
        self.contacts.append(contact)
        self.pressing = True
        self.skin.advance(self.dwell_s)
        # The arm believes the tip went where it was sent, ``depth`` past the surface.
        reported = target + (0.0 if math.isnan(depth) else depth) * direction
        return PressReport(tip_m=reported, depth_m=depth, force_n=force)

    def lift(self) -> None:
        """Leave the skin, back above the target."""
        self._check_running()
        self.skin.release()
        self.pressing = False
        if self._above is not None:
            self._travel(self._above)

    def stop(self) -> None:
        """Halt: the finger leaves the skin, and every later move is refused."""
        self.skin.release()
        self.pressing = False
        self.stopped = True

    def close(self) -> None:
        """Nothing to close for a simulated arm."""


def _press_frame(session: CalibrationSession, plan_pose: SkinPose, target: Points, clearance_m):
    """Approach point, target and press direction of a mesh-frame target, in the base frame."""
    on, _, face = nearest_on_surface(session.mesh, np.reshape(target, (1, 3)))
    normal = np.asarray(session.mesh.face_normals[face[0]], dtype=np.float64)
    approach = plan_pose.points_to_base(on + clearance_m * normal)[0]
    return approach, plan_pose.points_to_base(on)[0], plan_pose.directions_to_base(-normal[None])[0]


def _no_touch_here(session: CalibrationSession, where: str) -> None:
    """Read ``CHECK_FRAMES`` frames; raise ``ProbeSafetyError`` if any shows a touch."""
    assert session.detector is not None
    for _ in range(CHECK_FRAMES):
        frame = session.source.read(timeout_s=1.0)
        if session.detector.is_touched(frame.values):
            raise ProbeSafetyError(f"the skin feels a touch {where}, where none is planned")


def record_probe_point(
    session: CalibrationSession,
    index: int,
    probe: Probe,
    settings: ProbeSettings,
    pose: SkinPose | None = None,
) -> PressReport:
    """Record point log ``index`` of ``session`` with ``probe``; returns the probe's report.

    The target stored is the tip's reported position (``pose`` to the mesh frame) put on the
    surface; the reported tip ``(3,)`` m (mesh frame), the depth and the force go to the
    recording's meta in the same write. Any error (a lost link, a touch felt above the
    target, no touch felt at the target within the session's ``touch_timeout_s``) or Ctrl-C
    stops the probe before it is raised.
    """
    if session.recording is None or session.detector is None:
        raise ProbeError("capture the baseline before probing")
    check_press(settings)
    pose = pose or SkinPose()
    cfg = session.config
    try:
        approach, target, direction = _press_frame(
            session, pose, session.target_for(index), settings.clearance_m
        )
        probe.move_above(approach, direction)
        _no_touch_here(session, f"with the probe above target {index + 1}")
        report = probe.press(target, direction, depth_m=settings.depth_m, force_n=settings.force_n)
        capture = TouchCapture(
            session.detector,
            cfg.samples_per_touch,
            settle_frames=cfg.settle_frames,
            release_frames=RELEASE_FRAMES,
        )
        touch = session.pull(capture)
        assert touch is not None
        tip = pose.points_to_skin(np.reshape(report.tip_m, (1, 3)))
        label = nearest_on_surface(session.mesh, tip)[0][0]
        meta = session.recording.meta

        def added(key: str, value: Any) -> list:
            return [*meta.get(key, [])[:index], value]

        extra = {
            "probe_tips_m": added("probe_tips_m", np.round(tip[0], 7).tolist()),
            "probe_depths_m": added("probe_depths_m", _finite(report.depth_m)),
            "probe_forces_n": added("probe_forces_n", _finite(report.force_n)),
        }
        contacts = getattr(probe, "contacts", None)
        if contacts is not None and len(contacts):  # a simulated probe knows the truth
            extra["true_contacts"] = added("true_contacts", np.round(contacts[-1], 7).tolist())
        session.store_point_log(label, touch.frames, touch.times, meta=extra)
        probe.lift()
        session.pull(capture)
    except BaseException:
        probe.stop()
        raise
    return report


def _finite(value: float) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


def probe_dry_run(
    session: CalibrationSession,
    probe: Probe,
    settings: ProbeSettings,
    pose: SkinPose | None = None,
) -> int:
    """Move above every target of ``session`` in order, pressing nothing; returns the count.

    With a baseline captured (``session.detector``), the skin must feel no touch at any stop
    (``ProbeSafetyError`` otherwise). Any error or Ctrl-C stops the probe first.
    """
    pose = pose or SkinPose()
    try:
        for i, t in enumerate(session.targets):
            approach, _, direction = _press_frame(session, pose, t, settings.clearance_m)
            probe.move_above(approach, direction)
            if session.detector is not None:
                _no_touch_here(session, f"with the probe above target {i + 1} (dry run)")
    except BaseException:
        probe.stop()
        raise
    return len(session.targets)
