"""A scripted hand that performs gestures on a simulated skin, with their ground truth.

``GestureScript`` draws a random sequence of gestures (``tap``, ``double_tap``, ``long_press``,
``swipe`` up/down/left/right, ``two_finger_tap``) and of single touches that are not gestures
(``rest``: a stationary touch longer than a tap and shorter than a long press; ``drag``: a
movement too slow to be a swipe). Each item is a set of ``Stroke`` (one finger's contact: when
it lands and lifts, its path and pressure). ``Timing`` holds every duration, speed and length,
documented in docs/multitouch.md ("Simulated gestures"). Directions are in the skin frame of
``geometry.skin_frame``: "up" is the mesh's long axis, "right" is up x the mean outward normal.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from skinloc.geometry.mesh import sample_surface
from skinloc.geometry.skin_frame import skin_frame
from skinloc.sim.fingers import Finger

__all__ = [
    "DIRECTIONS",
    "GESTURE_KINDS",
    "TOUCH_KINDS",
    "GestureScript",
    "ScriptItem",
    "Stroke",
    "Timing",
]

GESTURE_KINDS = ("tap", "double_tap", "long_press", "swipe", "two_finger_tap")
TOUCH_KINDS = ("rest", "drag")  # single touches that are not gestures
DIRECTIONS = ("up", "down", "left", "right")
MAX_FINGERS = 2
_MAX_TRIES = 500  # random places tried for a swipe or a two-finger tap


@dataclass(frozen=True)
class Timing:
    """Durations (s), speeds (m/s) and lengths (m) of the scripted hand: ``(low, high)`` ranges.

    Every value is drawn uniformly from its range. Chosen from the usual touch-screen
    conventions (the real recordings hold no timestamps, so no real timing could be measured),
    with a margin to each threshold of the live recogniser (``live.gestures.GestureConfig``): a
    tap is <= 200 ms, a rest 400-500 ms, a long press >= 800 ms; a double tap's gap < 250 ms; a
    swipe moves 40-70 mm at 150-300 mm/s (mean speed), a drag 40-50 mm at 50-70 mm/s (it leaves
    the 20 mm of a still finger within 0.6 s, so it is no long press, and is too slow for a
    swipe).
    """

    tap_s: tuple[float, float] = (0.05, 0.20)
    double_tap_press_s: tuple[float, float] = (0.05, 0.15)
    double_tap_gap_s: tuple[float, float] = (0.08, 0.25)
    double_tap_offset_m: float = 0.003  # std per axis of the second tap's landing point
    long_press_s: tuple[float, float] = (0.80, 1.50)
    swipe_speed_m_s: tuple[float, float] = (0.15, 0.30)
    swipe_length_m: tuple[float, float] = (0.04, 0.07)
    two_finger_press_s: tuple[float, float] = (0.06, 0.20)
    two_finger_separation_m: tuple[float, float] = (0.02, 0.06)  # what one hand makes
    two_finger_skew_s: tuple[float, float] = (0.0, 0.04)  # landing (and lifting) time apart
    rest_s: tuple[float, float] = (0.40, 0.50)
    drag_speed_m_s: tuple[float, float] = (0.050, 0.070)
    drag_length_m: tuple[float, float] = (0.040, 0.050)
    idle_s: tuple[float, float] = (0.70, 1.50)  # nothing touches between two items
    lead_in_s: float = 2.0  # untouched at the start, for the baseline
    ramp_s: float = 0.02  # pressure rises (falls) over this at landing (lifting)
    tremor_m: float = 0.0003  # std per axis of a held finger's tremor, m

    def as_dict(self) -> dict[str, Any]:
        """The values, for the recording's meta."""
        return {k: v for k, v in self.__dict__.items()}


@dataclass
class Stroke:
    """One finger's contact: lands at ``t0_s``, lifts at ``t1_s``, moves along ``path_m``.

    ``path_m (k, 3)`` m is traversed with a minimum-jerk profile over the contact (a single
    point for a stationary finger); ``slot`` is the finger (0 or 1).
    """

    t0_s: float
    t1_s: float
    path_m: np.ndarray
    pressure: float
    radius_m: float
    slot: int = 0

    def finger_at(self, t_s: float, ramp_s: float) -> Finger | None:
        """The finger at time ``t_s`` (None when not touching)."""
        if not self.t0_s <= t_s < self.t1_s:
            return None
        tau = (t_s - self.t0_s) / max(self.t1_s - self.t0_s, 1e-9)
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)  # minimum jerk: 0 -> 1
        pos = _along(self.path_m, s)
        ramp = min(1.0, (t_s - self.t0_s + 1e-9) / ramp_s, (self.t1_s - t_s) / ramp_s)
        return Finger(pos, self.pressure * max(ramp, 0.05), self.radius_m)


@dataclass
class ScriptItem:
    """One gesture or non-gesture touch: its strokes and its truth record."""

    kind: str
    direction: str | None
    strokes: list[Stroke]
    truth: dict[str, Any] = field(default_factory=dict)

    @property
    def start_s(self) -> float:
        """First landing, s."""
        return min(s.t0_s for s in self.strokes)

    @property
    def end_s(self) -> float:
        """Last lift, s."""
        return max(s.t1_s for s in self.strokes)


def _along(path: np.ndarray, s: float) -> np.ndarray:
    """The point at arc-length fraction ``s`` in [0, 1] of polyline ``path (k, 3)``."""
    if len(path) == 1:
        return path[0].copy()
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] <= 0:
        return path[0].copy()
    target = np.clip(s, 0.0, 1.0) * cum[-1]
    i = int(np.clip(np.searchsorted(cum, target, side="right") - 1, 0, len(seg) - 1))
    f = (target - cum[i]) / max(seg[i], 1e-15)
    return path[i] + f * (path[i + 1] - path[i])


class GestureScript:
    """A random sequence of gestures and non-gesture touches on ``mesh``.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The skin surface, m.
    n_gestures : int
        Gestures to perform; the kinds (and swipe directions) are drawn in shuffled rounds, so
        every kind appears once ``n_gestures >= 5`` (every direction once there are 4 swipes).
    n_touches : int, optional
        Non-gesture touches (alternately ``rest`` and ``drag``, in random order) mixed in at
        random places; a quarter of ``n_gestures`` (rounded up) by default.
    random_state : int
        Seed of the script.
    timing : Timing, optional
        Durations, speeds and lengths.
    draw_touch : callable, optional
        ``draw_touch(rng) -> (pressure, radius_m)`` of one finger; ``SimulatedSkin.draw_touch``
        with light touches left out, by default a pressure of 1 and a radius of 10 mm.
    up : (3,) float, optional
        The skin's "up"; ``skin_up_axis`` of the mesh's vertices by default.
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        n_gestures: int,
        *,
        n_touches: int | None = None,
        random_state: int = 0,
        timing: Timing | None = None,
        draw_touch=None,
        up: np.ndarray | None = None,
    ) -> None:
        if not (isinstance(n_gestures, int | np.integer) and n_gestures >= 1):
            raise ValueError(f"the number of gestures must be an int >= 1, got {n_gestures!r}")
        if n_touches is None:
            n_touches = -(-int(n_gestures) // 4)
        if not (isinstance(n_touches, int | np.integer) and n_touches >= 0):
            raise ValueError(f"the number of other touches must be >= 0, got {n_touches!r}")
        self.mesh = mesh
        self.n_gestures, self.n_touches = int(n_gestures), int(n_touches)
        self.timing = Timing() if timing is None else timing
        self.rng = np.random.default_rng(random_state)
        self.up, self.right, self.normal = skin_frame(mesh.vertices, mesh.faces, up)
        self._draw_touch = draw_touch or (lambda rng: (1.0, 0.010))
        self._axes = {
            "up": self.up,
            "down": -self.up,
            "right": self.right,
            "left": -self.right,
        }

    @property
    def n_items(self) -> int:
        """Gestures plus non-gesture touches."""
        return self.n_gestures + self.n_touches

    def max_duration_s(self) -> float:
        """An upper bound of the stream's length, s (to size the output before starting)."""
        t = self.timing
        longest = max(
            t.long_press_s[1],
            2 * t.double_tap_press_s[1] + t.double_tap_gap_s[1],
            t.swipe_length_m[1] / t.swipe_speed_m_s[0],
            t.drag_length_m[1] / t.drag_speed_m_s[0],
            t.two_finger_press_s[1] + 2 * t.two_finger_skew_s[1],
        )
        return t.lead_in_s + self.n_items * (longest + t.idle_s[1]) + 1.0

    def _kinds(self) -> list[tuple[str, str | None]]:
        rng = self.rng
        kinds: list[str] = []
        while len(kinds) < self.n_gestures:
            kinds += list(rng.permutation(GESTURE_KINDS))
        kinds = kinds[: self.n_gestures]
        dirs: list[str] = []
        n_swipes = kinds.count("swipe")
        while len(dirs) < n_swipes:
            dirs += list(rng.permutation(DIRECTIONS))
        items: list[tuple[str, str | None]] = []
        for k in kinds:
            items.append((k, dirs.pop(0) if k == "swipe" else None))
        first = int(rng.integers(2))  # alternate the kinds, so both appear from 2 touches
        others = [TOUCH_KINDS[(first + i) % 2] for i in range(self.n_touches)]
        rng.shuffle(others)
        for k in others:
            items.insert(int(rng.integers(0, len(items) + 1)), (str(k), None))
        return [(str(k), d) for k, d in items]

    def items(self) -> Iterator[ScriptItem]:
        """The items in order, each timed after the previous one (generated lazily)."""
        t = self.timing
        now = t.lead_in_s
        for kind, direction in self._kinds():
            item = self._make(kind, direction, now)
            yield item
            now = item.end_s + float(self.rng.uniform(*t.idle_s))

    # ------------------------------------------------------------------ geometry
    def _point(self) -> tuple[np.ndarray, np.ndarray]:
        """A random point on the surface and its face normal."""
        p, face = sample_surface(self.mesh, 1, self.rng)
        return p[0], self.mesh.face_normals[face[0]]

    def _project(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q, _, face = trimesh.proximity.closest_point(self.mesh, p[None])
        return q[0], self.mesh.face_normals[face[0]]

    def _path(self, axis: np.ndarray, length_m: float) -> np.ndarray | None:
        """A path on the surface that keeps heading along ``axis`` for ``length_m``, or None."""
        p, n = self._point()
        step = 0.001
        path = [p]
        for _ in range(int(np.ceil(length_m / step))):
            d = axis - (axis @ n) * n
            if np.linalg.norm(d) < 0.5:  # the surface turns away from that direction here
                return None
            q, n = self._project(path[-1] + step * d / np.linalg.norm(d))
            if np.linalg.norm(q - path[-1]) < 0.5 * step:  # stuck at the skin's edge
                return None
            path.append(q)
        path_arr = np.asarray(path)
        chord = path_arr[-1] - path_arr[0]
        along = chord @ axis
        others = [chord @ v for v in (self.up, self.right) if abs(v @ axis) < 0.5]
        # The displacement must say the direction clearly in the skin frame.
        if along < 0.6 * length_m or any(abs(o) > 0.5 * along for o in others):
            return None
        return path_arr

    def _stationary(self, p: np.ndarray, t0: float, t1: float, slot: int = 0) -> Stroke:
        pressure, radius = self._draw_touch(self.rng)
        k = max(2, int(np.ceil((t1 - t0) / 0.05)))  # tremor: a point every 50 ms
        shake = self.timing.tremor_m * self.rng.standard_normal((k, 3))
        path = np.asarray([self._project(p + s)[0] for s in shake])
        path[0] = p
        return Stroke(t0, t1, path, pressure, radius, slot)

    # ------------------------------------------------------------------ the items
    def _make(self, kind: str, direction: str | None, now: float) -> ScriptItem:
        t, rng = self.timing, self.rng
        u = lambda r: float(rng.uniform(*r))  # noqa: E731
        strokes: list[Stroke]
        extra: dict[str, Any] = {}
        if kind in ("tap", "long_press", "rest"):
            p, _ = self._point()
            dur = u({"tap": t.tap_s, "long_press": t.long_press_s, "rest": t.rest_s}[kind])
            strokes = [self._stationary(p, now, now + dur)]
        elif kind == "double_tap":
            p, _ = self._point()
            first = u(t.double_tap_press_s)
            gap = u(t.double_tap_gap_s)
            p2, _ = self._project(p + t.double_tap_offset_m * rng.standard_normal(3))
            t2 = now + first + gap
            strokes = [
                self._stationary(p, now, now + first),
                self._stationary(p2, t2, t2 + u(t.double_tap_press_s)),
            ]
            extra["gap_s"] = gap
        elif kind in ("swipe", "drag"):
            speeds, lengths = (
                (t.swipe_speed_m_s, t.swipe_length_m)
                if kind == "swipe"
                else (t.drag_speed_m_s, t.drag_length_m)
            )
            axis_name = direction or str(rng.choice(DIRECTIONS))
            path = None
            for _ in range(_MAX_TRIES):
                path = self._path(self._axes[axis_name], u(lengths))
                if path is not None:
                    break
            else:
                raise ValueError(
                    f"found no place on the skin for a {kind} {axis_name} of "
                    f"{1e3 * lengths[0]:.0f}-{1e3 * lengths[1]:.0f} mm: is the mesh in metres?"
                )
            speed = u(speeds)
            dur = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum()) / speed
            pressure, radius = self._draw_touch(rng)
            strokes = [Stroke(now, now + dur, path, pressure, radius)]
            extra["speed_m_s"] = speed
            extra["path_m"] = [path[0].tolist(), path[-1].tolist()]
            extra["length_m"] = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        elif kind == "two_finger_tap":
            strokes = self._two_fingers(now)
            extra["separation_m"] = float(
                np.linalg.norm(strokes[1].path_m[0] - strokes[0].path_m[0])
            )
        else:
            raise ValueError(f"unknown script item {kind!r}")
        item = ScriptItem(kind, direction, strokes)
        item.truth = {
            "kind": kind,
            "direction": direction,
            "start_s": item.start_s,
            "end_s": item.end_s,
            "n_fingers": len({s.slot for s in strokes}),
            "position_m": strokes[0].path_m[0].tolist(),
            # every finger's landing point, in the order the fingers land
            "fingers_m": [s.path_m[0].tolist() for s in sorted(strokes, key=lambda s: s.t0_s)],
            **extra,
        }
        return item

    def _two_fingers(self, now: float) -> list[Stroke]:
        t, rng = self.timing, self.rng
        sep = float(rng.uniform(*t.two_finger_separation_m))  # drawn once: places are retried
        for _ in range(_MAX_TRIES):
            p, n = self._point()
            a = rng.standard_normal(3)
            a -= (a @ n) * n
            q, _ = self._project(p + sep * a / np.linalg.norm(a))
            # the drawn separation is kept (within 1 mm), so that the separations stay evenly
            # spread: a point pulled back at the skin's edge or by its curvature is drawn again
            if abs(np.linalg.norm(q - p) - sep) <= 0.001:
                break
        else:
            raise ValueError("found no place on the skin for two fingers: is the mesh in metres?")
        press = float(rng.uniform(*t.two_finger_press_s))
        # the second finger lands d0 after the first and lifts d1 after it
        d0, d1 = (float(rng.uniform(*t.two_finger_skew_s)) for _ in range(2))
        lift = max(now + press + d1, now + d0 + t.two_finger_press_s[0])
        return [
            self._stationary(p, now, now + press, slot=0),
            self._stationary(q, now + d0, lift, slot=1),
        ]
