"""Whether the live pipeline delivered a scripted hand's fingers and gestures, once each.

Scores the JSON lines ``skinloc run`` wrote (contacts and gesture events) against the truth of
a ``sim.hand.ScriptedHand`` that performed a ``GestureScript`` on a virtual skin with faults
(``bench/live_soak.py --gestures``, docs/reliability.md). Every time is one clock: the contacts'
``timestamp_s`` is the monotonic time their bytes arrived, the hand's truth and the device's
``downtimes`` are monotonic too.

Tracks (``score_tracks``): each track (tracking id) of the output is given to the script item
whose span it overlaps most, then, within the item, tracks and fingers (strokes) are paired one
to one by time overlap and distance. A stroke with one track is delivered; with none, lost (or,
for one finger of a two-finger tap whose other finger has a track, *not found*: the
multi-contact search did not see it, a detection limit, docs/multitouch.md); a track beyond the
first for a stroke doubles it: *restarted* if its tracks follow one another (the finger's track
ended and a new one began while it was down: a tracking failure), *split* if two are alive at
once (the search saw a second finger beside this one: a detection limit); a track in no item
is a ghost. A track must have one ``start``,
one ``end``, one slot and no event after its end.

**Unplugs.** A touch held across an unplug (the finger down before and still down after it, the
gap shorter than ``stale_s``) must stay one track, as in the single-finger soak. A finger that
lands or lifts while the link is down (or within ``blind_after_s`` of the replug, while the
runner reopens the port) is *blind*: nobody can see its landing or lift, so it is not scored as
lost or doubled, and a gesture made of such fingers is left out of precision and recall. It is
counted.

Gestures (``score_gestures``): no event may be written twice (same kind, tracks and span), the
runner's count of recognised events must equal the events written, and each true gesture is
matched (``match_gestures``) to at most one event of its kind, for precision and recall.
"""

from __future__ import annotations

import itertools
from collections import Counter, defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = [
    "GESTURE_KINDS",
    "blind",
    "match_gestures",
    "score_gestures",
    "score_tracks",
    "unambiguous_s",
]

GESTURE_KINDS = ("tap", "double_tap", "long_press", "swipe", "two_finger_tap")


def match_gestures(
    events: Sequence[dict], truths: Sequence[dict], slack_s: float
) -> list[tuple[dict, dict]]:
    """Greedy one-to-one pairs ``(event, truth)``: same kind, spans overlapping, earliest first.

    A span is ``start_s``..``end_s`` (s); the event's is widened by ``slack_s`` on each side.
    Each truth is matched at most once.
    """
    pairs, used = [], set()
    for ev in sorted(events, key=lambda e: e["start_s"]):
        for i, t in enumerate(truths):
            if i in used or t["kind"] != ev["kind"]:
                continue
            if ev["start_s"] - slack_s <= t["end_s"] and t["start_s"] <= ev["end_s"] + slack_s:
                pairs.append((ev, t))
                used.add(i)
                break
    return pairs


def unambiguous_s(truth: dict, double_tap_gap_s: float, long_press_s: float) -> float:
    """When a true gesture became certain, s.

    A tap after the double-tap window, a long press once held ``long_press_s``, the others at
    the last lift (the thresholds of ``GestureConfig``).
    """
    if truth["kind"] == "tap":
        return truth["end_s"] + double_tap_gap_s
    if truth["kind"] == "long_press":
        return truth["start_s"] + long_press_s
    return truth["end_s"]


def blind(
    t0: float,
    t1: float,
    downtimes: Sequence[tuple[float, float]],
    before_s: float = 0.05,
    after_s: float = 0.5,
) -> bool:
    """Whether a contact ``t0``..``t1`` (s) lands or lifts while the link is down.

    A downtime ``(a, b)`` covers ``a - before_s``..``b + after_s`` (the frames in the port when
    it was pulled are lost; the runner reopens it up to 0.1 s after, and needs a few frames to
    see a touch). A contact that spans the whole of it is not blind: it is held across.
    """
    for a, b in downtimes:
        lo, hi = a - before_s, b + after_s
        if lo <= t1 and t0 <= hi and not (t0 < lo and t1 > hi):
            return True
    return False


def _tracks(contacts: Sequence[dict]) -> dict[int, dict[str, Any]]:
    """Per tracking id: first/last time, starts, ends, slots, events after the end, positions."""
    out: dict[int, dict[str, Any]] = {}
    for c in contacts:
        tid = int(c.get("track_id", c.get("touch_id", -1)))
        tr = out.setdefault(
            tid,
            {
                "first": c["timestamp_s"],
                "last": c["timestamp_s"],
                "starts": 0,
                "ends": 0,
                "slots": set(),
                "after_end": 0,
                "pos": [],
            },
        )
        tr["last"] = c["timestamp_s"]
        tr["slots"].add(c.get("slot", 0))
        if tr["ends"]:
            tr["after_end"] += 1
        if c["state"] == "start":
            tr["starts"] += 1
        elif c["state"] == "end":
            tr["ends"] += 1
        p = c.get("position_m")
        if p is not None and p[0] is not None:
            tr["pos"].append(p)
    return out


def _overlap(a0: float, a1: float, b0: float, b1: float) -> float:
    return max(0.0, min(a1, b1) - max(a0, b0))


def score_tracks(
    contacts: Sequence[dict],
    strokes: Sequence[dict],
    downtimes: Sequence[tuple[float, float]] = (),
    *,
    lag_s: float = 0.15,
    blind_after_s: float = 0.5,
) -> dict[str, Any]:
    """Fingers against tracks (see the module's docstring).

    Parameters
    ----------
    contacts : sequence of dict
        The runner's contact lines (``state``, ``timestamp_s`` s, ``track_id``, ``slot``,
        ``position_m`` m).
    strokes : sequence of dict
        ``ScriptedHand.truth()["strokes"]``: ``item``, ``kind``, ``slot``, ``t0_s``, ``t1_s``,
        ``start_m``, ``end_m``.
    downtimes : sequence of (float, float)
        The device's unplugs and replugs, s.
    lag_s : float
        How late a track may end after its finger lifted (release debounce, the pty), s.
    blind_after_s : float
        See ``blind``.

    Returns
    -------
    dict
        Counts (``strokes``, ``delivered``, ``lost``, ``not_found``, ``doubled`` (=
        ``restarted`` + ``split``), ``blind``,
        ``held_across_unplug``, ``held_across_unplug_one_track``, ``ghost_tracks``,
        ``bad_tracks``...) and ``examples`` of each failure (times in s).
    """
    from scipy.optimize import linear_sum_assignment

    tracks = _tracks(contacts)
    items: dict[int, list[int]] = defaultdict(list)
    for k, s in enumerate(strokes):
        items[s["item"]].append(k)
    span = {
        i: (min(strokes[k]["t0_s"] for k in ks), max(strokes[k]["t1_s"] for k in ks) + lag_s)
        for i, ks in items.items()
    }
    order = sorted(span, key=lambda i: span[i][0])
    starts = np.array([span[i][0] for i in order])
    by_item: dict[int, list[int]] = defaultdict(list)
    ghosts: list[int] = []
    for tid, tr in tracks.items():
        # the items around the track's span (the script's items never overlap)
        j = int(np.searchsorted(starts, tr["first"], side="right"))
        near = order[max(0, j - 2) : j + 2]
        best = max(near, key=lambda i: _overlap(tr["first"], tr["last"], *span[i]), default=None)
        if best is None or _overlap(tr["first"], tr["last"], *span[best]) <= 0:
            # a track of one frame has no length: the item whose span holds it
            best = next((i for i in near if span[i][0] <= tr["first"] <= span[i][1]), None)
        if best is None:
            ghosts.append(tid)
        else:
            by_item[best].append(tid)
    of: dict[int, list[int]] = defaultdict(list)  # stroke -> its tracks
    for i, ks in items.items():
        tids = by_item.get(i, [])
        if not tids:
            continue
        cost = np.zeros((len(ks), len(tids)))
        for a, k in enumerate(ks):
            s = strokes[k]
            mid = 0.5 * (np.asarray(s["start_m"]) + np.asarray(s["end_m"]))
            for b, tid in enumerate(tids):
                tr = tracks[tid]
                ov = _overlap(tr["first"], tr["last"], s["t0_s"], s["t1_s"] + lag_s)
                frac = ov / max(s["t1_s"] + lag_s - s["t0_s"], 1e-3)
                dist = np.linalg.norm(np.mean(tr["pos"], axis=0) - mid) if tr["pos"] else 0.1
                cost[a, b] = (1.0 - frac) + dist / 0.03
        rows, cols = linear_sum_assignment(cost)
        paired = set()
        for a, b in zip(rows, cols, strict=True):
            of[ks[a]].append(tids[b])
            paired.add(b)
        for b in range(len(tids)):
            if b not in paired:  # an extra track: it doubles the finger it fits best
                of[ks[int(np.argmin(cost[:, b]))]].append(tids[b])
    res: Counter = Counter()
    examples: dict[str, list] = defaultdict(list)
    for k, s in enumerate(strokes):
        n = len(of[k])
        res["strokes"] += 1
        if blind(s["t0_s"], s["t1_s"], downtimes, after_s=blind_after_s):
            res["blind"] += 1
            continue
        across = any(s["t0_s"] < a and s["t1_s"] > b for a, b in downtimes)
        res["held_across_unplug"] += across
        res["held_across_unplug_one_track"] += across and n == 1
        if n == 1:
            res["delivered"] += 1
            continue
        if n == 0:
            partners = [q for q in items[s["item"]] if q != k and strokes[q]["slot"] != s["slot"]]
            seen = any(of[q] for q in partners)
            label = "not_found" if s["kind"] == "two_finger_tap" and seen else "lost"
        else:
            # two tracks at once: the contact search saw a second finger by this one (split);
            # one after the other: the finger's track ended and restarted while it was down
            spans = sorted((tracks[t]["first"], tracks[t]["last"]) for t in of[k])
            pairs = itertools.pairwise(spans)
            label = "split" if any(b0 < a1 for (_, a1), (b0, _) in pairs) else "restarted"
            res["doubled"] += 1
        res[label] += 1
        if len(examples[label]) < 10:
            examples[label].append(
                {
                    "kind": s["kind"],
                    "slot": s["slot"],
                    "t0_s": s["t0_s"],
                    "t1_s": s["t1_s"],
                    "track_ids": of[k],
                }
            )
    bad = [
        tid
        for tid, tr in tracks.items()
        if tr["starts"] != 1 or tr["ends"] != 1 or len(tr["slots"]) != 1 or tr["after_end"]
    ]
    for tid in bad[:10]:
        tr = tracks[tid]
        examples["bad_tracks"].append(
            {
                "track_id": tid,
                "starts": tr["starts"],
                "ends": tr["ends"],
                "slots": sorted(tr["slots"]),
                "first_s": tr["first"],
            }
        )
    for tid in ghosts[:10]:
        examples["ghost_tracks"].append(
            {"track_id": tid, "first_s": tracks[tid]["first"], "last_s": tracks[tid]["last"]}
        )
    out = {
        k: int(res[k])
        for k in (
            "strokes",
            "delivered",
            "lost",
            "not_found",
            "doubled",
            "restarted",
            "split",
            "blind",
            "held_across_unplug",
            "held_across_unplug_one_track",
        )
    }
    out.update(tracks=len(tracks), ghost_tracks=len(ghosts), bad_tracks=len(bad))
    out["examples"] = dict(examples)
    return out


def score_gestures(
    events: Sequence[dict],
    truth_gestures: Sequence[dict],
    truth_touches: Sequence[dict] = (),
    downtimes: Sequence[tuple[float, float]] = (),
    *,
    slack_s: float = 0.1,
    blind_after_s: float = 0.5,
    n_recognised: int | None = None,
    contact_track_ids: set[int] | None = None,
    double_tap_gap_s: float = 0.30,
    long_press_s: float = 0.60,
) -> dict[str, Any]:
    """Gesture events against the truth: delivered once, and per-kind precision and recall.

    Parameters
    ----------
    events : sequence of dict
        The runner's gesture lines.
    truth_gestures, truth_touches : sequence of dict
        ``ScriptedHand.truth()``'s (``kind``, ``start_s``, ``end_s`` s).
    downtimes : sequence of (float, float)
        The device's unplugs and replugs, s: gestures (and events) touching one are left out
        of precision and recall (counted in ``blind_truths``, ``blind_events``).
    slack_s : float
        Widening of an event's span for matching, s.
    blind_after_s : float
        See ``blind``.
    n_recognised : int, optional
        The runner's own count of gesture events (``--stats``), to compare with the lines.
    contact_track_ids : set of int, optional
        Tracking ids of the contact lines: each event's ``track_ids`` must be among them.
    double_tap_gap_s, long_press_s : float
        ``GestureConfig``'s, for the delay (``unambiguous_s``).

    Returns
    -------
    dict
        ``events``, ``duplicates`` (events written again), ``events_sharing_a_track``,
        ``second_event_for_one_gesture`` (a true gesture overlapped by two events of its
        kind), ``unknown_track_ids``, ``recognised_equals_written``, ``per_kind`` (precision,
        recall, delay), ``false_events``.
    """

    def is_blind(d: dict) -> bool:
        return blind(d["start_s"], d["end_s"], downtimes, after_s=blind_after_s)

    keys = Counter(
        (e["kind"], tuple(e.get("track_ids", ())), e["start_s"], e["end_s"]) for e in events
    )
    duplicates = sum(n - 1 for n in keys.values() if n > 1)
    owner: dict[int, int] = {}
    sharing = 0
    for n, e in enumerate(events):
        for tid in e.get("track_ids", ()):
            if tid in owner and owner[tid] != n:
                sharing += 1
            owner[tid] = n
    unknown = 0
    if contact_track_ids is not None:
        unknown = sum(
            any(t not in contact_track_ids for t in e.get("track_ids", ())) for e in events
        )
    seen_truths = [t for t in truth_gestures if not is_blind(t)]
    seen_events = [e for e in events if not is_blind(e)]
    second = 0
    for t in seen_truths:
        over = [
            e
            for e in seen_events
            if e["kind"] == t["kind"]
            and e["start_s"] - slack_s <= t["end_s"]
            and t["start_s"] <= e["end_s"] + slack_s
        ]
        second += len(over) > 1
    pairs = match_gestures(seen_events, seen_truths, slack_s)
    n_ev = Counter(e["kind"] for e in seen_events)
    n_tr = Counter(t["kind"] for t in seen_truths)
    n_ok = Counter(t["kind"] for _, t in pairs)
    delays: dict[str, list[float]] = defaultdict(list)
    for ev, t in pairs:
        delays[t["kind"]].append(
            ev["timestamp_s"] - unambiguous_s(t, double_tap_gap_s, long_press_s)
        )
    per_kind = {}
    for k in GESTURE_KINDS:
        d = np.asarray(delays[k]) * 1e3
        per_kind[k] = {
            "n_true": n_tr[k],
            "n_reported": n_ev[k],
            "precision": n_ok[k] / n_ev[k] if n_ev[k] else None,
            "recall": n_ok[k] / n_tr[k] if n_tr[k] else None,
            "delay_median_ms": float(np.median(d)) if d.size else None,
            "delay_p95_ms": float(np.percentile(d, 95)) if d.size else None,
        }
    matched = {id(e) for e, _ in pairs}
    confusions: Counter = Counter()
    everything = [*seen_truths, *truth_touches]
    for ev in seen_events:
        if id(ev) in matched:
            continue
        over = [
            t["kind"]
            for t in everything
            if ev["start_s"] - slack_s <= t["end_s"] and t["start_s"] <= ev["end_s"] + slack_s
        ]
        confusions[f"{ev['kind']} during {over[0] if over else 'nothing'}"] += 1
    return {
        "events": len(events),
        "truths": len(truth_gestures),
        "blind_truths": len(truth_gestures) - len(seen_truths),
        "blind_events": len(events) - len(seen_events),
        "duplicates": int(duplicates),
        "events_sharing_a_track": int(sharing),
        "second_event_for_one_gesture": int(second),
        "unknown_track_ids": int(unknown),
        "recognised": n_recognised,
        "recognised_equals_written": None if n_recognised is None else n_recognised == len(events),
        "per_kind": per_kind,
        "false_events": dict(confusions.most_common()),
    }
