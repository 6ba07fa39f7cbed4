"""Touch tracking: a frame's contacts become tracks with stable ids (multi-touch protocol B).

The convention is the Linux kernel's multi-touch protocol B: a fixed set of ``K`` slots
(``0..K-1``); a finger that lands takes the lowest free slot and a new tracking id (ids increase
by one per finger landing, never reused); the track lives in its slot until the finger lifts,
then the slot is free again. Each track has its own start, move and end events, so fingers land
and lift independently.

Per frame, ``Tracker.update`` receives the contacts the localiser found (positions on the
surface, strongest first) and:

0. while a touch has one track and the localiser reports one contact, the pair prior
   (``skinloc.live.pair_prior``, optional) may replace that contact by two: a second finger
   the per-frame count missed, seen in the anchored two-contact fit over several frames;
1. matches them to the live tracks by distance (the smallest total distance, each pair within
   ``gate_mm``; straight-line distance, which on a skin is the distance along the surface to
   within 2 % for the few centimetres a finger moves between frames); when one track and one
   contact are left over and the track is still landing (fewer than ``settle_frames`` frames:
   its image weak, the localiser jumping), they are matched whatever their distance. A
   settled track never follows a contact beyond the gate (a finger does not move 30 mm in one
   frame: that is a second finger arriving, the first one lifting beside it, or a slip of a
   weakening image): the track is held, and the contact is a candidate (step 3); if that
   candidate becomes a track, the held one ends, unless the touch never had a second track:
   then no second finger was ever seen (a contact beside the track for fewer than
   ``confirm_frames`` frames is a ghost), the contact is the same finger whose answer leapt (a
   coarse map's answer stays near where a quick stroke landed, then jumps to where the finger
   is), and the held track moves there (``leapt`` names it for the gesture recogniser). When
   the track's recent answers jumped (two
   consecutive ones over half the gate apart), the gate holds from any of its last ``RECENT``
   answers, not only the last: one wrong answer within the gate (the localiser's contact
   slipping back 20-30 mm for a frame or two on a moving finger) moved the last one, and the
   next right answer, beyond the gate from the slip, cut the finger in two tracks;
2. a live track with no match keeps its slot and last position for ``miss_frames`` frames (a
   contact the localiser misses for one frame does not end the finger), then ends;
3. a contact with no match is a candidate finger; it becomes a track (``start``) when seen in
   ``confirm_frames`` consecutive frames (one-frame ghosts never reach the sinks), except the
   strongest contact of the frame a touch starts, which the touch detector has debounced;
4. every track's position goes through its own One-Euro filter, then back onto the surface.

``frame_contacts`` is the one place that asks the model for a frame's contacts.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from skinloc.live.one_euro import one_euro, one_euro_onto

if TYPE_CHECKING:
    from skinloc.geometry.snap import Surface
    from skinloc.live.pair_prior import PairPrior
    from skinloc.models.multi_contact.search import SearchMemory

__all__ = ["RECENT", "Track", "Tracker", "assign", "frame_contacts"]

#: A track's last answers (positions) the gate is measured from: a wrong answer of up to
#: ``RECENT - 1`` frames does not cut a moving finger's track.
RECENT = 3

#: ``(positions (k, 3) m on the surface, raw (k, 3) m, strength (k,) counts, uncertainty (k,) mm)``
FrameContacts = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def frame_contacts(
    engine: object,
    delta: np.ndarray,
    max_contacts: int,
    out: np.ndarray,
    memory: SearchMemory | None = None,
) -> FrameContacts:
    """The contacts of one baseline-subtracted frame, strongest first (0..``max_contacts``).

    The pipeline has already decided that something touches, so there is at least one
    contact. ``max_contacts`` 1 is the single-contact path of before multi-touch
    (``localise_into``; strength unknown: nan); more asks the model's multi-contact search
    (``Engine.contacts``) how many there are, and where. Its own detection rule, calibrated
    on the training touches, may find none in a light touch the pipeline sees: then the
    single-contact answer stands, so that a light touch's track is not lost.

    Parameters
    ----------
    engine : Engine
        The model's engine.
    delta : (n_sensors,) float32
        Baseline-subtracted counts.
    max_contacts : int
        K.
    out : (7,) float64
        Scratch for ``localise_into``.
    memory : SearchMemory, optional
        The stream's memory of its last full multi-contact search (``Engine.contacts``): a
        held touch's frames skip the search while nothing suggests a second finger.
    """
    if max_contacts > 1:
        if memory is None:
            cs = engine.contacts(delta, max_contacts=max_contacts)
        else:
            cs = engine.contacts(delta, max_contacts=max_contacts, memory=memory)
        rows = getattr(cs, "rows", None)  # a ContactSet's one (k, 5) block: its columns as views
        if rows is not None:
            if len(rows):
                pos = rows[:, 0:3]
                return pos, pos, rows[:, 3], rows[:, 4]
        elif len(pos := np.asarray(cs.positions_m, dtype=np.float64).reshape(-1, 3)):
            return pos, pos, np.asarray(cs.strength, float), np.asarray(cs.uncertainty_mm, float)
    engine.localise_into(delta, out)
    return out[None, 3:6], out[None, 0:3], np.full(1, math.nan), out[6:7]


def _within(a: np.ndarray, b: np.ndarray, r: float) -> bool:
    """Whether points ``a`` and ``b`` (3,) are at most ``r`` apart (m)."""
    a0, a1, a2 = a.tolist()  # Python floats: the same sums as NumPy's, without its scalars
    b0, b1, b2 = b.tolist()
    d0, d1, d2 = a0 - b0, a1 - b1, a2 - b2
    return d0 * d0 + d1 * d1 + d2 * d2 <= r * r


def assign(tracks: np.ndarray, detections: np.ndarray, gate_m: float) -> list[tuple[int, int]]:
    """Pairs ``(track i, detection j)`` of least total distance, each pair within ``gate_m``.

    Exact. Among the matchings of the largest size, the one with the smallest summed distance:
    a far pair never displaces a near one. By enumeration up to 4 x 4 (the live case, K <= 3:
    at most 24 orders), ``scipy.optimize.linear_sum_assignment`` beyond.

    Parameters
    ----------
    tracks : (m, 3) float
        Last positions of the live tracks, m.
    detections : (n, 3) float
        This frame's contacts, m.
    gate_m : float
        Largest distance a finger moves between two frames, m.
    """
    m, n = len(tracks), len(detections)
    if m == 0 or n == 0:
        return []
    d = np.linalg.norm(tracks[:, None, :] - detections[None, :, :], axis=2)
    ok = d <= gate_m
    if m * n > 16:
        from scipy.optimize import linear_sum_assignment

        big = gate_m * (m + n + 1) * 10.0  # any gated pair costs more than all pairs within
        rows, cols = linear_sum_assignment(np.where(ok, d, big))
        return [(int(i), int(j)) for i, j in zip(rows, cols, strict=True) if ok[i, j]]
    best: list[tuple[int, int]] = []
    best_key = (0, 0.0)
    if m <= n:
        for cols in itertools.permutations(range(n), m):
            pairs = [(i, j) for i, j in enumerate(cols) if ok[i, j]]
            key = (len(pairs), -sum(d[i, j] for i, j in pairs))
            if key > best_key or not best:
                best, best_key = pairs, key
    else:
        for rows in itertools.permutations(range(m), n):
            pairs = [(i, j) for j, i in enumerate(rows) if ok[i, j]]
            key = (len(pairs), -sum(d[i, j] for i, j in pairs))
            if key > best_key or not best:
                best, best_key = pairs, key
    return sorted(best)


@dataclass(eq=False)
class Track:
    """One finger: its slot, tracking id and latest state.

    Attributes
    ----------
    slot : int
        Slot 0..K-1 (-1 while a candidate).
    track_id : int
        Tracking id (-1 while a candidate).
    position_m : (3,) float
        Filtered position on the surface, m.
    raw_m : (3,) float
        This frame's localiser output for it, m.
    strength : float
        Fitted strength, counts (nan: unknown).
    uncertainty_mm : float
        The localiser's spread, mm.
    seen : int
        Consecutive frames matched (candidates: towards ``confirm_frames``).
    missed : int
        Consecutive frames unmatched.
    start_s : float
        When the track started (its first frame as a candidate), s.
    recent_m : (RECENT, 3) float
        Its last ``RECENT`` measured positions, m (a ring; ``last_m`` is the newest).
    """

    slot: int = -1
    track_id: int = -1
    position_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    raw_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    last_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    strength: float = math.nan
    uncertainty_mm: float = math.nan
    seen: int = 0
    missed: int = 0
    start_s: float = math.nan
    filt: np.ndarray = field(default_factory=lambda: np.zeros(8))
    recent_m: np.ndarray = field(default_factory=lambda: np.zeros((RECENT, 3)))

    def near(self, p: np.ndarray, r: float) -> bool:
        """Whether ``p (3,)`` m is within the gate ``r`` m of the track.

        Of its last answer; or, when its recent answers jumped (two consecutive ones more
        than ``r / 2`` apart: the localiser slipping, not a finger moving 1.5 m/s), of any of
        its last ``RECENT``. A track whose answers moved steadily is gated from the last only,
        so that a second finger landing just beyond the gate stays a second finger.
        """
        if _within(self.last_m, p, r):  # the common frame: near the last answer
            return True
        n = min(self.seen, RECENT)
        rec = self.recent_m
        newest = [(self.seen - 1 - k) % RECENT for k in range(n)]
        jumped = any(not _within(rec[a], rec[b], 0.5 * r) for a, b in itertools.pairwise(newest))
        return jumped and any(_within(rec[i], p, r) for i in newest[1:])


class Tracker:
    """Protocol-B tracks of one skin from per-frame contacts.

    Parameters
    ----------
    max_contacts : int
        K: slots.
    gate_mm : float
        Largest distance between a track's last contact and its next one, mm.
    miss_frames : int
        Frames a track may go unmatched and live on (its position held).
    confirm_frames : int
        Consecutive frames a new contact needs to become a track (not on a touch's first frame).
    constrain : callable(x, y, z, out (3,))
        Puts a point back onto the surface (``Engine.constrain_into``).
    filter_params : (3,) float or None
        One-Euro ``[min_cutoff_hz, beta s/m, d_cutoff_hz]``; None: no filter.
    settle_frames : int, optional
        Frames a landing track may jump beyond the gate (default ``confirm_frames``).
    pair : PairPrior, optional
        The second-finger prior (``skinloc.live.pair_prior``); None: the localiser's count.
    surface : Surface, optional
        The surface ``constrain`` puts points on (``Engine.surface``): given, each track's
        filter and constraint run in one compiled call (``one_euro_onto``), as ``constrain``
        would.
    """

    def __init__(
        self,
        max_contacts: int,
        gate_mm: float,
        miss_frames: int,
        confirm_frames: int,
        constrain: Callable[[float, float, float, np.ndarray], None],
        filter_params: np.ndarray | None,
        settle_frames: int | None = None,
        pair: PairPrior | None = None,
        surface: Surface | None = None,
    ) -> None:
        self.max_contacts = int(max_contacts)
        self.settle_frames = int(confirm_frames if settle_frames is None else settle_frames)
        self.gate_m = float(gate_mm) * 1e-3
        self.miss_frames = int(miss_frames)
        self.confirm_frames = int(confirm_frames)
        self._constrain = constrain
        self._prm = filter_params
        self._surface = None if surface is None else (surface.mode, surface.args)
        self.slots: list[Track | None] = [None] * self.max_contacts
        self.candidates: list[Track] = []
        self.pair = pair
        self.next_id = 1
        self._tmp = np.zeros(3)
        #: Whether the touch so far never showed a second finger: never two tracks at once, never
        #: more than one contact in two frames running (one such frame is a ghost)
        self.single = True
        self._multi = False  # the last frame had more than one contact
        #: Track ids the last ``update`` moved over a leap (no second finger in the touch)
        self.leapt: list[int] = []

    @property
    def tracks(self) -> list[Track]:
        """The live tracks, by slot."""
        return [t for t in self.slots if t is not None]

    def _measure(
        self, t: Track, ts: float, pos: np.ndarray, raw: np.ndarray, s: float, u: float
    ) -> None:
        t.raw_m[:] = raw
        t.last_m[:] = pos
        t.recent_m[t.seen % RECENT] = pos
        t.strength, t.uncertainty_mm = float(s), float(u)
        if t.seen == 0:
            t.start_s = ts
        t.seen += 1
        t.missed = 0
        if self._prm is None:
            t.position_m[:] = pos
        else:
            x, y, z = pos.tolist()  # Python floats: numba's fastest dispatch
            if self._surface is not None:
                mode, args = self._surface
                one_euro_onto(t.filt, x, y, z, ts, self._prm, self._tmp, mode, args, t.position_m)
            else:
                one_euro(t.filt, x, y, z, ts, self._prm, self._tmp)
                self._constrain(self._tmp[0], self._tmp[1], self._tmp[2], t.position_m)

    def update(
        self,
        ts: float,
        positions: np.ndarray,
        raw: np.ndarray,
        strength: np.ndarray,
        uncertainty_mm: np.ndarray,
        touch_start: bool = False,
        new_fingers: bool = True,
    ) -> list[tuple[Track, str]]:
        """One frame's contacts ``(k, 3)`` m into ``(track, state)`` events, by slot.

        ``state`` is ``start``, ``move`` or ``end``; a track missed this frame but within
        ``miss_frames`` reports ``move`` at its last position. ``touch_start``: the touch
        detector's first frame of a touch (its contacts start tracks at once); ``new_fingers``
        False (the touch is being released, its signal below the release threshold): contacts
        that match no track are ignored, as the localiser's answers on a fading image are.
        """
        live = [t for t in self.slots if t is not None]
        k = len(positions)
        if touch_start and not live:
            self.single = True
            self._multi = False
        if self.leapt:
            self.leapt = []
        pair_second = -1
        if self.pair is not None:
            if k == 1 and live and new_fingers:
                got = self.pair.step(ts, live, positions[0])
                if got is not None:
                    positions = raw = got
                    strength = np.array([strength[0], math.nan])
                    uncertainty_mm = np.array([uncertainty_mm[0], math.nan])
                    k = 2
                    pair_second = 1 if len(live) == 1 else -1
            elif k > 1 and new_fingers:
                self.pair.saw(ts, live, positions)
            else:
                self.pair.reset()
        if k > 1 and self._multi:
            self.single = False
        self._multi = k > 1
        if len(live) == 1 and k == 1 and not self.candidates:
            t = live[0]
            if t.seen < self.settle_frames or t.near(positions[0], self.gate_m):
                # one finger, one contact near it (the common frame), or a landing finger:
                # the same finger, as in step 1; no assignment to compute
                self._measure(t, ts, positions[0], raw[0], strength[0], uncertainty_mm[0])
                return [(t, "move")]
        used = [False] * k
        events: list[tuple[Track, str]] = []
        matched: set[int] = set()
        held: Track | None = None
        if live and k:
            prev = np.array([t.last_m for t in live])
            for i, j in assign(prev, positions, self.gate_m):
                self._measure(live[i], ts, positions[j], raw[j], strength[j], uncertainty_mm[j])
                used[j] = True
                matched.add(i)
            lone_t = [i for i in range(len(live)) if i not in matched]
            lone_d = [j for j in range(k) if not used[j]]
            if len(lone_t) == 1 and len(lone_d) == 1:
                i, j = lone_t[0], lone_d[0]
                if live[i].seen < self.settle_frames or live[i].near(positions[j], self.gate_m):
                    # a landing finger (its first frames, a weak and changing image) and one
                    # contact left: the same finger, whose position jumped; or a contact
                    # within the gate of the track's recent path (its last answer was wrong)
                    self._measure(live[i], ts, positions[j], raw[j], strength[j], uncertainty_mm[j])
                    used[j] = True
                    matched.add(i)
                else:
                    # a settled finger does not move that far in one frame: the contact is a
                    # second finger arriving, or a slip of a weakening image. The track is
                    # held, not missed, until the contact's candidate is confirmed (then it
                    # ends: the other finger took over) or the contact comes back
                    held = live[i]
        for i, t in enumerate(live):
            if i in matched or t is held:
                events.append((t, "move"))
                continue
            t.missed += 1
            if t.missed > self.miss_frames:
                self.slots[t.slot] = None
                events.append((t, "end"))
            else:
                events.append((t, "move"))
        # candidates: matched ones grow, unmatched ones vanish
        rest = [j for j in range(k) if not used[j]] if new_fingers else []
        cands = self.candidates
        keep: list[Track] = []
        if cands and rest:
            prev = np.array([c.last_m for c in cands])
            for i, jj in assign(prev, positions[rest], self.gate_m):
                j = rest[jj]
                self._measure(cands[i], ts, positions[j], raw[j], strength[j], uncertainty_mm[j])
                used[j] = True
                keep.append(cands[i])
        for j in rest:
            if not used[j]:
                c = Track()
                self._measure(c, ts, positions[j], raw[j], strength[j], uncertainty_mm[j])
                keep.append(c)
        if pair_second >= 0:
            # the anchored pair has held for its frames: that finger is confirmed
            for c in keep:
                if np.array_equal(c.last_m, positions[pair_second]):
                    c.seen = max(c.seen, self.confirm_frames)
        self.candidates = []
        # On a touch's first frame its strongest contact starts at once (the detector has
        # debounced the touch); any other contact, like every later finger, must last.
        at_once = touch_start and not live
        for n, c in enumerate(keep):
            if held is not None and self.single and c.seen >= self.confirm_frames:
                # the touch never had a second track: no second finger was ever seen, the held
                # finger's answer leapt and stayed there. The same track goes on
                self._measure(held, ts, c.last_m, c.raw_m, c.strength, c.uncertainty_mm)
                self.leapt.append(held.track_id)
                held = None
                continue
            if ((at_once and n == 0) or c.seen >= self.confirm_frames) and None in self.slots:
                c.slot = self.slots.index(None)
                c.track_id = self.next_id
                self.next_id += 1
                self.slots[c.slot] = c
                events.append((c, "start"))
                if held is not None:
                    self.slots[held.slot] = None
                    events.remove((held, "move"))
                    events.append((held, "end"))
                    held = None
            else:
                self.candidates.append(c)
        if self.single and sum(t is not None for t in self.slots) > 1:
            self.single = False
        events.sort(key=lambda e: e[0].slot)
        return events

    def end_all(self) -> list[Track]:
        """End every track (the touch ended); returns them by slot and frees every slot."""
        if self.pair is not None:
            self.pair.end_touch()
        out = [t for t in self.slots if t is not None]
        self.slots = [None] * self.max_contacts
        self.candidates = []
        self.single = True
        self._multi = False
        self.leapt = []
        return out
