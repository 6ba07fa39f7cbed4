"""Gestures from tracks: tap, double tap, long press, swipe (with a direction), two-finger tap.

``GestureRecognizer`` reads a skin's tracked contacts frame by frame (``update``: one ``Contact``
per track, ``start``/``move``/``end``) and returns gesture events, JSON-ready dicts::

    {"event": "gesture", "skin": "arm", "kind": "swipe", "direction": "up",
     "start_s": 12.31, "end_s": 12.62, "timestamp_s": 12.62, "track_ids": [7],
     "confidence": 1.0, "path_m": [[x, y, z], ...], "speed_m_s": 0.21}

It works on *episodes*: from the first finger down to the last finger up. An episode of one
finger is a tap (short, still), a long press (still for ``long_press_s``: reported then, while
the finger may still be down), a swipe (far and fast enough: reported when the finger lifts) or
nothing (a slow drag, a hold between a tap and a long press). An episode of two fingers that
land together and both tap is a two-finger tap. Two taps close in time and place are one
double tap, so a tap is reported only when the double-tap window after it has closed (or the
next touch shows it is no second tap); a double tap is never also two taps, a long press or a
swipe never also a tap. Every event is reported on the first frame at which it is certain.

A tap of one track is not always one finger: two fingers too close for the contact search
land as one track. The touch's image change as it landed and lifted (``live.landing``, against
the skin's calibrated ``landing_change`` and ``landing_hold``) makes such a tap a two-finger
tap (``confidence`` below 1) or, when it is uncertain, holds it back: no tap is reported of a
touch that may have been two fingers. So, when the pipeline asks for it
(``PipelineConfig.footprint_gestures``, off by default), does the image's footprint
(``live.footprint``: wider and fuller than one finger's at its place, against the skin's
calibrated ``footprint_two`` and ``footprint_hold``; such a two-finger tap has ``confidence``
0.7). ``confidence`` is 1.0 when every finger was tracked.

Two tracks are not always two fingers either: below the skin's two-point threshold
(``two_point_mm``, measured at calibration: ``models.multi_contact.two_point``) the search
cannot reliably tell two fingers from one, and a finger's image split for a few frames makes a
second track beside the first. So a tap of several tracks all closer than the threshold is a
two-finger tap only if the image changed more than one finger's does as they landed and lifted
(``landing_hold``) or its footprint is two fingers' (``footprint_two``); otherwise it is
one finger's tap whose count is uncertain: held back like the taps above, or one tap of a
double tap. A two-finger tap closer than the threshold carries a ``confidence`` below 1. The
threshold is a distance between two fingers: it replaces none of the distances of one finger
(``still_mm``, ``double_tap_mm``, ``swipe_min_mm``: how far one finger moves), and a swipe is
one moving finger whatever its length.

Directions are in the skin's own frame, the one the simulator's gesture script uses too
(``geometry.skin_frame``): ``up`` is a direction of the mesh frame (per skin; default: the mesh's
long axis, ``skin_up_axis``) and "right" is up x the skin's mean outward normal (the right hand
of someone facing the skin, head towards "up"). The swipe's displacement, landing to lift, is
split between the two and the larger part names the direction.

Units: metres and seconds inside; thresholds in mm and s (``GestureConfig``).
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from skinloc.geometry.skin_frame import skin_frame, skin_up_axis
from skinloc.live.contact import Contact

__all__ = ["GestureConfig", "GestureRecognizer", "SkinFrame"]

#: Points of a swipe's ``path_m`` at most (a longer path is subsampled evenly).
MAX_PATH_POINTS = 64
#: How long after the first finger a brief touch within it may lift and still be a piece of
#: its image (``GestureRecognizer._main``), s.
BRIEF_SLACK_S = 0.05
#: Longest track, s, that is a piece of a moving finger's image (the search splitting it for
#: a few frames) rather than a second finger: a second finger touches for 60 ms or more.
GHOST_S = 0.045
#: Longest track, s, that is a trail of a moving finger's image when it stays behind that
#: finger (``TRAIL_BEHIND`` times nearer to its path so far than to its path on): a quick
#: stroke leaves a contact at its landing point for a few frames while the finger moves on.
TRAIL_S = 0.10
#: How many times nearer to where the finger had been than to where it went a trail stays (a
#: second finger beside a swipe is about as near to both).
TRAIL_BEHIND = 2.0
#: Confidence of a two-finger tap of one track told by its footprint alone (the time cue's is
#: 0.5-0.9 with how far its change passed the skin's threshold).
FOOTPRINT_CONFIDENCE = 0.7


@dataclass
class GestureConfig:
    """Thresholds of the recogniser (docs/live.md, "Multi-touch and gestures").

    Attributes
    ----------
    tap_max_s : float
        Longest touch that is a tap, s (finger down to up as tracked).
    still_mm : float
        Largest distance from where a finger landed for a tap or a long press, mm.
    double_tap_gap_s : float
        Longest time from a tap's end to the next tap's start for a double tap, s; also how
        long a tap waits before it is reported.
    double_tap_mm : float
        Largest distance between the two taps of a double tap, mm.
    long_press_s : float
        Time a still finger must be held for a long press, s.
    swipe_min_mm : float
        Shortest straight distance, landing to lift, of a swipe, mm.
    swipe_min_speed_m_s : float
        Slowest mean speed (that distance over the touch's duration) of a swipe, m/s.
    two_finger_sync_s : float
        Largest time between the two fingers' landings (and lifts) of a two-finger tap, s.
    landing_s : float
        A finger's first moments, s, whose positions (a weak, rising image) are not where it
        settled: stillness is measured from its position at the end of them.
    swipe_max_jump_frac : float
        Largest share of a swipe's path length its two largest frame-to-frame steps may
        take (a path that leaps is a track jumping to another finger, not a swipe).
    """

    tap_max_s: float = 0.30
    still_mm: float = 20.0
    double_tap_gap_s: float = 0.30
    double_tap_mm: float = 30.0
    long_press_s: float = 0.60
    swipe_min_mm: float = 30.0
    swipe_min_speed_m_s: float = 0.10
    two_finger_sync_s: float = 0.15
    swipe_max_jump_frac: float = 0.5
    landing_s: float = 0.03

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, int | float) or isinstance(v, bool) or not v > 0:
                raise ValueError(f"GestureConfig.{f.name} must be a number > 0, got {v!r}")
            if not math.isfinite(v):
                raise ValueError(f"GestureConfig.{f.name} must be finite, got {v!r}")
        if self.long_press_s <= self.tap_max_s:
            raise ValueError("GestureConfig.long_press_s must be longer than tap_max_s")
        if self.swipe_max_jump_frac > 1.0:
            raise ValueError("GestureConfig.swipe_max_jump_frac must be at most 1")
        if self.landing_s >= self.tap_max_s:
            raise ValueError("GestureConfig.landing_s must be shorter than tap_max_s")
        if self.swipe_min_mm <= self.still_mm:
            raise ValueError("GestureConfig.swipe_min_mm must be larger than still_mm")


class SkinFrame:
    """Up and right on a skin, for swipe directions (``geometry.skin_frame``).

    Parameters
    ----------
    vertices : (V, 3) float or None
        Mesh vertices, m (None: no mesh; then ``up`` must be given and the skin is taken as
        facing the mesh frame's +z).
    faces : (F, 3) int or None
        Triangles (their winding says which side is outward).
    up : (3,) float, optional
        "Up" in the mesh frame; default ``skin_up_axis(vertices)``, the mesh's long axis.
    """

    def __init__(
        self,
        vertices: np.ndarray | None,
        faces: np.ndarray | None,
        up: Sequence[float] | None = None,
    ) -> None:
        if up is None and vertices is None:
            raise ValueError("a skin frame needs the mesh or an 'up' direction")
        u = None
        if up is not None:
            u = np.asarray(up, dtype=np.float64).reshape(-1)
            if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) < 1e-9:
                raise ValueError(f"'up' must be 3 finite numbers, not all 0, got {up!r}")
        if vertices is not None and faces is not None:
            self.up, self.right, self.normal = skin_frame(vertices, faces, u)
            return
        if u is None:
            u = skin_up_axis(vertices)
        u = u / np.linalg.norm(u)
        n = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        n = n - (n @ u) * u
        self.up, self.normal = u, n / np.linalg.norm(n)
        self.right = np.cross(self.up, self.normal)

    def direction(self, start: np.ndarray, end: np.ndarray) -> str:
        """``up``, ``down``, ``left`` or ``right`` of the move ``start -> end`` (m)."""
        d = np.asarray(end, dtype=np.float64) - np.asarray(start, dtype=np.float64)
        a, b = float(d @ self.up), float(d @ self.right)
        if abs(a) >= abs(b):
            return "up" if a >= 0 else "down"
        return "right" if b >= 0 else "left"


@dataclass(eq=False)
class _Finger:
    track_id: int
    start_s: float
    first: tuple[float, float, float]  # where the finger settled, m
    path: list[tuple[float, float, float]]
    end_s: float = math.nan
    last_s: float = math.nan
    max_from_first: float = 0.0  # m
    uncertain: bool = False  # a tap whose image changed too much to be sure it was one finger
    main_n: int = 0  # points of the episode's first finger's path when this one started
    leaps: list[int] = field(default_factory=list)  # path indices the tracker leapt to

    @property
    def ended(self) -> bool:
        return self.end_s == self.end_s


@dataclass(eq=False)
class _Episode:
    start_s: float
    fingers: list[_Finger] = field(default_factory=list)
    active: int = 0
    done: bool = False  # reported (a long press) or ruled out: nothing more from it
    change: float = 0.0  # the touch's image change as fingers landed and lifted (noise levels)
    footprint: float | None = None  # the touch's mean footprint score (None: not measured)


class GestureRecognizer:
    """Gesture events of one skin from its tracked contacts.

    Parameters
    ----------
    skin : str
        Name carried by the events.
    frame : SkinFrame
        Up / right on the surface.
    config : GestureConfig, optional
        Thresholds.
    landing_change : float
        The skin's threshold of a touch's image change as it lands and lifts, noise levels
        (``CountRule.landing_change``, calibrated on the skin's own touches), above which a
        tap of one track is two fingers the tracker did not separate; 0: off.
    landing_hold : float
        The change above which a tap of one track is no longer surely one finger
        (``CountRule.landing_hold``): such a tap is not reported (``n_held`` counts them),
        unless it is one of a double tap; 0: off.
    two_point_mm : float or None
        The skin's two-point threshold, mm (``two_point.recogniser_mm`` of the model's rule):
        tracks closer than it need the change to reach ``landing_hold`` to be two fingers;
        ``math.inf``: no separation is reliably two; None: unknown (two tracks are two
        fingers, the rule is off; so it is with ``landing_hold`` 0).
    footprint_levels : (float, float) or None
        The skin's footprint score levels (``CountRule.footprint_two`` and ``footprint_hold``,
        calibrated on its own touches): from the first a touch seen as one track holds two
        fingers (a two-finger tap, and tracks closer than the two-point threshold are two);
        from the second a tap of one track is no longer surely one finger (held back, as with
        ``landing_hold``). None: the cue is off.
    """

    def __init__(
        self,
        skin: str,
        frame: SkinFrame,
        config: GestureConfig | None = None,
        landing_change: float = 0.0,
        landing_hold: float = 0.0,
        two_point_mm: float | None = None,
        footprint_levels: tuple[float, float] | None = None,
    ) -> None:
        for name, v in (("landing_change", landing_change), ("landing_hold", landing_hold)):
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a number >= 0, got {v!r}")
        if two_point_mm is not None and not (two_point_mm > 0):  # inf: none at any separation
            raise ValueError(f"two_point_mm must be a number > 0 or None, got {two_point_mm!r}")
        self.two_point_mm = None if two_point_mm is None else float(two_point_mm)
        if footprint_levels is not None:
            two, hold = (float(v) for v in footprint_levels)
            if not (math.isfinite(two) and math.isfinite(hold) and hold <= two):
                raise ValueError(
                    f"footprint_levels must be two numbers, hold <= two, got {footprint_levels!r}"
                )
            footprint_levels = (two, hold)
        self.footprint_levels = footprint_levels
        self.landing_change = float(landing_change)
        self.landing_hold = float(landing_hold)
        self.n_held = 0  # taps not reported: the count was uncertain
        self.skin = skin
        self.frame = frame
        self.cfg = GestureConfig() if config is None else config
        self._fingers: dict[int, _Finger] = {}
        self._episode: _Episode | None = None
        self._pending: _Finger | None = None  # a tap waiting for its double-tap window
        self.n_events = 0

    @property
    def busy(self) -> bool:
        """Whether a finger is down or a tap waits: ``tick`` must be called every frame."""
        return self._episode is not None or self._pending is not None

    # ------------------------------------------------------------------ input
    def update(
        self,
        ts: float,
        contacts: Sequence[Contact],
        releasing: bool = False,
        change: float = 0.0,
        footprint: float | None = None,
        leapt: Collection[int] = (),
    ) -> list[dict[str, Any]]:
        """One frame's contacts (one per track) at stream time ``ts``; returns due events.

        ``releasing``: the touch detector is ending the touch (the signal is below its release
        threshold): the positions of such a fading image are not the finger's and are left
        out of the paths (the states still count). ``change``: the touch's largest image change
        so far (``live.landing.LandingWatch``), noise levels. ``footprint``: the touch's mean
        footprint score so far (``live.footprint.FootprintWatch``; None: not measured).
        ``leapt``: track ids the tracker moved over a leap this frame, sure it was the same
        finger (``Tracker.leapt``: no second finger in the touch); such a step does not make
        a swipe unsteady.
        """
        for c in contacts:
            tid = c.track_id
            p = c.position_m
            if c.state == "start" or tid not in self._fingers:
                if c.state not in ("start", "move"):
                    continue
                f = _Finger(tid, c.timestamp_s, p, [p], last_s=c.timestamp_s)
                self._fingers[tid] = f
                ep = self._episode
                if ep is None:
                    ep = self._episode = _Episode(c.timestamp_s)
                for g in ep.fingers:
                    if not g.ended and c.timestamp_s - g.start_s <= self.cfg.two_finger_sync_s:
                        # until this finger was found, the other's positions were one
                        # contact's fit to both fingers' image: its stillness starts now
                        g.first = g.path[-1]
                        g.max_from_first = 0.0
                if ep.fingers:
                    f.main_n = len(ep.fingers[0].path)
                ep.fingers.append(f)
                ep.active += 1
                continue
            f = self._fingers[tid]
            if p[0] == p[0] and not releasing:
                f.path.append(p)
                if tid in leapt:
                    f.leaps.append(len(f.path) - 1)
                if c.timestamp_s - f.start_s < self.cfg.landing_s:
                    # still landing (the pressure rising, the image weak): the position
                    # settles; stillness is measured from where it settled
                    f.first = p  # a tuple: math.dist takes it without converting
                else:
                    f.max_from_first = max(f.max_from_first, math.dist(p, f.first))
            f.last_s = c.timestamp_s
            if c.state == "end":
                f.end_s = c.timestamp_s
                del self._fingers[tid]
                if self._episode is not None:
                    self._episode.active -= 1
        if self._episode is not None and change > self._episode.change:
            self._episode.change = change
        if self._episode is not None and footprint is not None:
            self._episode.footprint = footprint
        return self.tick(ts)

    def tick(self, ts: float) -> list[dict[str, Any]]:
        """Advance the clock to ``ts`` (a frame without contacts); returns due events."""
        out: list[dict[str, Any]] = []
        cfg = self.cfg
        ep = self._episode
        pend = self._pending
        if pend is not None and ts >= pend.end_s + cfg.double_tap_gap_s:
            if ep is None or ep.start_s > pend.end_s + cfg.double_tap_gap_s:
                out += self._resolve_pending(ts)  # the window closed: a single tap
                pend = None
        if ep is None:
            return out
        f = self._main(ep) if not ep.done else None
        if f is not None:
            still = f.max_from_first <= cfg.still_mm * 1e-3
            held = (f.end_s if f.ended else ts) - f.start_s
            if still and held >= cfg.long_press_s:
                out += self._resolve_pending(ts)
                # reported now, the finger may still be down: ``end_s`` is this moment
                out.append(self._event("long_press", [f], ts, end_s=f.end_s if f.ended else ts))
                ep.done = True
        if pend is not None and not self._could_pair(ep, pend):
            out += self._resolve_pending(ts)
        if ep.active <= 0:
            self._episode = None
            if not ep.done:
                out += self._classify(ep, ts)
        return out

    def flush(self, ts: float) -> list[dict[str, Any]]:
        """The stream ended at ``ts``: report what waits (a tap whose window is still open)."""
        return self._resolve_pending(ts)

    # ------------------------------------------------------------------ decisions
    def _is_tap(self, f: _Finger) -> bool:
        cfg = self.cfg
        return (
            f.ended
            and f.end_s - f.start_s <= cfg.tap_max_s
            and f.max_from_first <= cfg.still_mm * 1e-3
        )

    def _steady(self, f: _Finger) -> bool:
        """Whether a path moves steadily (its 2 largest steps <= ``swipe_max_jump_frac``).

        The two largest frame-to-frame steps against the path's length. A swiping finger's
        speed rises and falls smoothly (its largest steps are a few millimetres of several
        centimetres); a track whose position leaps across in one or two frames followed another
        finger (landing or lifting beside it) or a fading image. A step the tracker leapt over
        sure it was the same finger (``update``'s ``leapt``) counts in the length but is not
        one of the steps weighed.
        """
        path = f.path
        if len(path) < 3:
            return False
        steps = [math.dist(path[i - 1], path[i]) for i in range(1, len(path))]
        length = sum(steps)
        weighed = sorted(d for i, d in enumerate(steps, 1) if i not in f.leaps)
        if len(weighed) < 2:
            return False
        return length > 0.0 and weighed[-1] + weighed[-2] <= self.cfg.swipe_max_jump_frac * length

    def _main(self, ep: _Episode) -> _Finger | None:
        """The episode's one finger: its first, if every other is a brief touch within it.

        A brief touch (lifted, at most ``tap_max_s``) that lands after the first finger and
        lifts before it (within ``BRIEF_SLACK_S``) is taken as a piece of the first finger's
        image that the localiser split off, so that it does not undo a long press or a swipe;
        two fingers that both tap are a two-finger tap first (``_classify``).
        """
        fs = ep.fingers
        f = fs[0]
        for g in fs[1:]:
            if not (
                g.ended
                and g.end_s - g.start_s <= self.cfg.tap_max_s
                and g.start_s >= f.start_s
                and (not f.ended or g.end_s <= f.end_s + BRIEF_SLACK_S)
            ):
                return None
        return f

    def _piece_of(self, f: _Finger, g: _Finger) -> bool:
        """Whether track ``g``, within the moving finger ``f``'s touch, is a piece of its image.

        A track of at most ``GHOST_S`` anywhere (the search split the image for a few frames),
        or of at most ``TRAIL_S`` whose every point is ``TRAIL_BEHIND`` times nearer to where
        ``f`` had been before ``g`` started than to where ``f`` went from then on (its landing
        point's image lingering behind the moving finger). The other finger of a two-finger tap
        that ``f`` drifted towards lies ahead of ``f``, not behind it; a finger beside the
        swipe is about as near to both.
        """
        held = g.end_s - g.start_s
        if held <= GHOST_S:
            return True
        if held > TRAIL_S or not 0 < g.main_n < len(f.path):
            return False
        trail = np.asarray(g.path)[:, None, :]
        before = np.linalg.norm(trail - np.asarray(f.path[: g.main_n])[None], axis=2).min(axis=1)
        after = np.linalg.norm(trail - np.asarray(f.path[g.main_n :])[None], axis=2).min(axis=1)
        return bool(np.all(TRAIL_BEHIND * before <= after))

    def _two_in_time(self, ep: _Episode) -> bool:
        """Whether the episode's image changed as a second finger's landing or lifting does."""
        return self.landing_change > 0.0 and ep.change >= self.landing_change

    def _footprint_at(self, ep: _Episode, level: int) -> bool:
        """Whether the touch's footprint reached level 0 (two fingers) or 1 (not surely one)."""
        lv = self.footprint_levels
        return lv is not None and ep.footprint is not None and ep.footprint >= lv[level]

    def _two_by_footprint(self, ep: _Episode) -> bool:
        """Whether the touch's image is as much wider than one finger's as two fingers' are."""
        return self._footprint_at(ep, 0)

    def _two_from_change(self, ep: _Episode, fs: list[_Finger], ts: float) -> dict[str, Any]:
        """A two-finger tap of one track, its confidence from how far the change passed."""
        conf = min(0.9, 0.5 * ep.change / self.landing_change)
        return self._event("two_finger_tap", fs, ts, confidence=conf)

    def _uncertain(self, ep: _Episode) -> bool:
        """Whether the image changed more than the skin's single fingers (but not enough)."""
        return self.landing_hold > 0.0 and ep.change >= self.landing_hold

    def _count_uncertain(self, ep: _Episode) -> bool:
        """Whether a one-track tap may be two fingers: the change or the footprint says so."""
        return self._uncertain(ep) or self._footprint_at(ep, 1)

    @staticmethod
    def _spread_m(fs: list[_Finger]) -> float:
        """Largest distance between the tracks' last places, m (where each was last seen)."""
        return max(
            (math.dist(a.path[-1], b.path[-1]) for i, a in enumerate(fs) for b in fs[i + 1 :]),
            default=0.0,
        )

    def _one_finger(self, ep: _Episode) -> _Finger | None:
        """The episode's finger if it may be one (its first track), else None.

        A single track, or tracks all closer than the skin's two-point threshold whose image
        changed as one finger's does: below the threshold a second contact is as likely a piece
        of one finger's image the search split off (a few frames beside a tapping finger) as a
        second finger; without the time cue (a change past ``landing_hold``) nothing says it
        is two.
        """
        fs = ep.fingers
        if len(fs) == 1:
            return fs[0]
        tp = self.two_point_mm
        if tp is None or self.landing_hold <= 0.0 or self._uncertain(ep):
            return None
        if self._two_by_footprint(ep):
            return None
        return fs[0] if self._spread_m(fs) < tp * 1e-3 else None

    def _pair_confidence(self, ep: _Episode, fs: list[_Finger]) -> float:
        """How sure a two-finger tap of several tracks is of its count.

        1.0 at or beyond the skin's two-point threshold (or with it unknown); closer, 0.9 when
        the image's change reached the skin's two-finger level, else 0.5 to 0.9 with the
        separation's share of the threshold.
        """
        tp = self.two_point_mm
        sep_mm = self._spread_m(fs) * 1e3
        if tp is None or sep_mm >= tp:
            return 1.0
        if self._two_in_time(ep) or self._two_by_footprint(ep):
            return 0.9
        return 0.5 + 0.4 * (sep_mm / tp if math.isfinite(tp) else 0.0)

    def _one_tap(self, ep: _Episode, f: _Finger, ts: float) -> list[dict[str, Any]]:
        """One finger's tap ``f``: the second of a double tap with the pending one, or pending."""
        pend = self._pending
        if pend is not None and self._could_pair(ep, pend):
            self._pending = None
            return [self._event("double_tap", [pend, f], ts)]
        out = self._resolve_pending(ts)
        self._pending = f
        return out

    def _could_pair(self, ep: _Episode, pend: _Finger) -> bool:
        """Whether episode ``ep`` may still be the second tap of the pending tap."""
        cfg = self.cfg
        if ep.done or ep.start_s > pend.end_s + cfg.double_tap_gap_s:
            return False
        f = self._one_finger(ep)
        if f is None or self._two_in_time(ep) or self._two_by_footprint(ep):
            return False
        if math.dist(f.path[0], pend.path[-1]) > cfg.double_tap_mm * 1e-3:
            return False
        if f.max_from_first > cfg.still_mm * 1e-3:
            return False
        return (f.end_s if f.ended else f.last_s) - f.start_s <= cfg.tap_max_s

    def _resolve_pending(self, ts: float) -> list[dict[str, Any]]:
        pend, self._pending = self._pending, None
        if pend is None:
            return []
        if pend.uncertain:  # one finger or two: neither is reported
            self.n_held += 1
            return []
        return [self._event("tap", [pend], ts)]

    def _classify(self, ep: _Episode, ts: float) -> list[dict[str, Any]]:
        """An episode that just ended (every finger up), not yet reported."""
        cfg = self.cfg
        out: list[dict[str, Any]] = []
        fs = ep.fingers
        main = self._main(ep)
        if main is not None and (len(fs) == 1 or not all(self._is_tap(g) for g in fs)):
            f = main
            if len(fs) == 1 and self._is_tap(f) and self._two_in_time(ep):
                # one track, but the image changed as a second finger's landing or lifting
                # does: a two-finger tap whose fingers the tracker did not separate (never a
                # tap); the confidence says how far past the skin's threshold
                out += self._resolve_pending(ts)
                out.append(self._two_from_change(ep, fs, ts))
                return out
            if len(fs) == 1 and self._is_tap(f) and self._two_by_footprint(ep):
                # one track, but its image as much wider than one finger's as two fingers'
                # are: a two-finger tap, less sure than the time cue's
                out += self._resolve_pending(ts)
                out.append(self._event("two_finger_tap", fs, ts, confidence=FOOTPRINT_CONFIDENCE))
                return out
            if len(fs) == 1 and self._is_tap(f):
                f.uncertain = self._count_uncertain(ep)
                return out + self._one_tap(ep, f, ts)
            out += self._resolve_pending(ts)
            if len(fs) > 1 and not all(self._piece_of(f, g) for g in fs[1:]):
                # a swipe is one finger: a brief second touch within a moving one is as likely
                # the other finger of a two-finger tap the first track drifted towards (but a
                # track of a few frames, or a brief trail where the finger has been, is a piece
                # of the moving finger's image split off)
                return out
            dist = math.dist(f.path[0], f.path[-1])
            dur = max(f.end_s - f.start_s, 1e-6)
            if (
                dist >= cfg.swipe_min_mm * 1e-3
                and dist / dur >= cfg.swipe_min_speed_m_s
                and self._steady(f)
            ):
                out.append(self._event("swipe", [f], ts))
            return out
        if all(self._is_tap(f) for f in fs):
            # two fingers tapping together; a third track within the same window is a piece of
            # one of them (the localiser lost a finger for a few frames), not a third finger
            sync = cfg.two_finger_sync_s
            starts, ends = [f.start_s for f in fs], [f.end_s for f in fs]
            if max(starts) - min(starts) <= sync and max(ends) - min(ends) <= sync:
                f = self._one_finger(ep)
                if f is not None:
                    # tracks closer than the two-point threshold, the image changed as one
                    # finger's: one finger's tap of uncertain count (a second tap or held)
                    f.uncertain = True
                    return out + self._one_tap(ep, f, ts)
                out += self._resolve_pending(ts)
                conf = self._pair_confidence(ep, fs)
                out.append(self._event("two_finger_tap", fs, ts, confidence=conf))
                return out
        return out + self._resolve_pending(ts)

    def _event(
        self,
        kind: str,
        fs: list[_Finger],
        ts: float,
        end_s: float | None = None,
        confidence: float = 1.0,
    ) -> dict[str, Any]:
        start = min(f.start_s for f in fs)
        end = max(f.end_s for f in fs) if end_s is None else end_s
        ev: dict[str, Any] = {
            "event": "gesture",
            "skin": self.skin,
            "kind": kind,
            "direction": None,
            "start_s": start,
            "end_s": end,
            "timestamp_s": ts,
            "track_ids": [f.track_id for f in fs],
            "confidence": confidence,
        }
        if kind == "swipe":
            f = fs[0]
            path = f.path
            if len(path) > MAX_PATH_POINTS:
                idx = np.linspace(0, len(path) - 1, MAX_PATH_POINTS).round().astype(int)
                path = [path[i] for i in idx]
            a, b = np.array(f.path[0]), np.array(f.path[-1])
            ev["direction"] = self.frame.direction(a, b)
            ev["path_m"] = [list(p) for p in path]
            length = sum(math.dist(p, q) for p, q in zip(f.path, f.path[1:], strict=False))
            ev["speed_m_s"] = length / max(f.end_s - f.start_s, 1e-6)
        self.n_events += 1
        return ev
