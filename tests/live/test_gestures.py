"""Gesture recognition from synthetic tracked-contact streams: exact events, nothing extra."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skinloc.geometry.mesh import cone_skin
from skinloc.geometry.skin_frame import skin_frame, skin_up_axis
from skinloc.live.contact import Contact
from skinloc.live.gestures import GestureConfig, GestureRecognizer, SkinFrame

DT = 0.01  # 100 Hz
CFG = GestureConfig()


def still(p):
    return lambda k: p


def line(a, b, k0, k1):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return lambda k: tuple((a + (b - a) * (k - k0) / max(k1 - k0, 1)).tolist())


def stream(fingers, n_frames):
    """Frames ``(t, contacts)``; fingers are ``(track_id, slot, first frame, last frame, pos)``."""
    out = []
    for k in range(n_frames):
        t = k * DT
        cs = []
        for tid, slot, k0, k1, pos in fingers:
            if k0 <= k <= k1:
                state = "start" if k == k0 else "end" if k == k1 else "move"
                p = tuple(float(v) for v in pos(k))
                cs.append(Contact("s", t, k, state, p, p, 0.9, 20.0, math.nan, 1.0, 1, tid, slot))
        out.append((t, cs))
    return out


def run(frames, frame=None, cfg=CFG):
    rec = GestureRecognizer("s", frame or SkinFrame(None, None, up=(0.0, 1.0, 0.0)), cfg)
    events = []
    for t, cs in frames:
        events += rec.update(t, cs) if cs else rec.tick(t)
    events += rec.flush(frames[-1][0])
    return events


P = (0.0, 0.0, 0.0)
FAR = (0.06, 0.0, 0.0)


def test_a_tap_is_reported_once_when_its_double_tap_window_closes():
    ev = run(stream([(1, 0, 100, 110, still(P))], 200))
    assert [e["kind"] for e in ev] == ["tap"]
    e = ev[0]
    assert e["start_s"] == pytest.approx(1.00) and e["end_s"] == pytest.approx(1.10)
    assert e["track_ids"] == [1] and e["direction"] is None and e["event"] == "gesture"
    due = 1.10 + CFG.double_tap_gap_s
    assert due - 1e-9 <= e["timestamp_s"] <= due + DT + 1e-9  # on the first frame after


def test_two_close_taps_are_one_double_tap_not_taps():
    ev = run(stream([(1, 0, 100, 110, still(P)), (2, 0, 125, 135, still((0.005, 0, 0)))], 300))
    assert [e["kind"] for e in ev] == ["double_tap"]
    assert ev[0]["track_ids"] == [1, 2]
    assert ev[0]["start_s"] == pytest.approx(1.00) and ev[0]["end_s"] == pytest.approx(1.35)
    assert ev[0]["timestamp_s"] == pytest.approx(1.35)  # certain when the second tap lifts


@pytest.mark.parametrize(
    ("second", "why"),
    [((2, 0, 125, 135, still(FAR)), "far apart"), ((2, 0, 160, 170, still(P)), "too late")],
)
def test_taps_too_far_apart_in_place_or_time_are_two_taps(second, why):
    ev = run(stream([(1, 0, 100, 110, still(P)), second], 400))
    assert [e["kind"] for e in ev] == ["tap", "tap"], why
    assert [e["track_ids"] for e in ev] == [[1], [2]]


def test_a_long_press_is_reported_while_held_and_never_as_a_tap():
    ev = run(stream([(1, 0, 100, 250, still(P))], 400))
    assert [e["kind"] for e in ev] == ["long_press"]
    assert ev[0]["timestamp_s"] == pytest.approx(1.00 + CFG.long_press_s, abs=DT + 1e-9)
    assert ev[0]["start_s"] == pytest.approx(1.00)


def test_a_hold_between_a_tap_and_a_long_press_is_nothing():
    assert run(stream([(1, 0, 100, 145, still(P))], 300)) == []


def test_a_tap_then_a_long_press_is_a_tap_and_a_long_press():
    ev = run(stream([(1, 0, 100, 110, still(P)), (2, 0, 120, 250, still(P))], 400))
    assert [e["kind"] for e in ev] == ["tap", "long_press"]
    # the tap is certain once the second touch outlasts a tap
    assert ev[0]["timestamp_s"] <= 1.20 + CFG.tap_max_s + DT + 1e-9


@pytest.mark.parametrize(
    ("end", "direction"),
    [
        ((0, 0.05, 0), "up"),
        ((0, -0.05, 0), "down"),
        ((0.05, 0, 0), "right"),
        ((-0.05, 0, 0), "left"),
    ],
)
def test_swipes_have_their_direction_path_and_speed(end, direction):
    ev = run(stream([(1, 0, 100, 125, line(P, end, 100, 125))], 300))
    assert [(e["kind"], e["direction"]) for e in ev] == [("swipe", direction)]
    e = ev[0]
    assert e["timestamp_s"] == pytest.approx(1.25)  # reported when the finger lifts
    assert e["speed_m_s"] == pytest.approx(0.05 / 0.25, rel=1e-6)
    assert len(e["path_m"]) == 26 and e["path_m"][0] == [0.0, 0.0, 0.0]
    assert np.allclose(e["path_m"][-1], end)


def test_direction_follows_a_rotated_skin_frame():
    # "up" along +x: right is up x normal(+z) = -y
    frame = SkinFrame(None, None, up=(1.0, 0.0, 0.0))
    moves = {(0.05, 0, 0): "up", (0, -0.05, 0): "right", (0, 0.05, 0): "left"}
    for end, direction in moves.items():
        ev = run(stream([(1, 0, 100, 125, line(P, end, 100, 125))], 300), frame)
        assert [e["direction"] for e in ev] == [direction]


def test_default_up_is_the_skin_frame_of_the_simulator():
    mesh = cone_skin()
    v = np.asarray(mesh.vertices)
    up = skin_up_axis(v)
    s = (v - v.mean(axis=0)) @ up
    frame = SkinFrame(v, np.asarray(mesh.faces))
    # the recogniser's frame is the simulator's gesture frame (geometry.skin_frame)
    want = skin_frame(v, np.asarray(mesh.faces))
    assert np.allclose(frame.up, want[0]) and np.allclose(frame.right, want[1])
    # a swipe on the surface along the long axis is "up"; the opposite is "down"
    i, j = np.argmin(s), np.argmax(s)
    a, b = v[i], v[i] + 0.5 * (v[j] - v[i])
    assert frame.direction(a, b) == "up" and frame.direction(b, a) == "down"


def test_slow_drags_and_short_moves_are_not_swipes_nor_taps():
    slow = stream([(1, 0, 100, 190, line(P, (0, 0.05, 0), 100, 190))], 300)  # 0.055 m/s
    assert run(slow) == []
    short = stream([(1, 0, 100, 125, line(P, (0, 0.025, 0), 100, 125))], 300)  # 25 mm
    assert run(short) == []


def test_two_fingers_tapping_together_are_one_two_finger_tap():
    ev = run(stream([(1, 0, 100, 112, still(P)), (2, 1, 103, 114, still(FAR))], 300))
    assert [e["kind"] for e in ev] == ["two_finger_tap"]
    assert ev[0]["track_ids"] == [1, 2] and ev[0]["timestamp_s"] == pytest.approx(1.14)


def test_two_fingers_landing_apart_in_time_are_nothing():
    assert run(stream([(1, 0, 100, 125, still(P)), (2, 1, 120, 130, still(FAR))], 300)) == []


def test_a_tap_waiting_at_the_end_of_the_stream_is_flushed():
    ev = run(stream([(1, 0, 100, 110, still(P))], 115))
    assert [e["kind"] for e in ev] == ["tap"]


def test_config_is_checked():
    with pytest.raises(ValueError, match="long_press_s"):
        GestureConfig(long_press_s=0.1)
    with pytest.raises(ValueError, match="tap_max_s"):
        GestureConfig(tap_max_s=-1.0)
    with pytest.raises(ValueError, match="up"):
        SkinFrame(None, None, up=(0.0, 0.0, 0.0))


# ------------------------------------------------------------- rules against the localiser's slips


def landing(off, p, k0):
    """At ``p``, except its first two frames at ``off`` (a weak landing image)."""
    return lambda k: off if k < k0 + 2 else p


def test_stillness_is_measured_after_the_landing():
    # the first two frames 25 mm off (more than still_mm): still a tap and a long press
    off = (0.025, 0.0, 0.0)
    assert [e["kind"] for e in run(stream([(1, 0, 100, 112, landing(off, P, 100))], 200))] == [
        "tap"
    ]
    ev = run(stream([(1, 0, 100, 190, landing(off, P, 100))], 250))
    assert [e["kind"] for e in ev] == ["long_press"]
    # after the landing the same 25 mm does count: not a tap
    late = lambda k: off if 105 <= k < 107 else P  # noqa: E731
    assert run(stream([(1, 0, 100, 112, late)], 200)) == []


def test_a_path_that_leaps_is_no_swipe():
    # 40 mm in 0.2 s, but 36 mm of it in one frame: a track jumping to another finger
    leap = lambda k: P if k < 110 else (0.0, 0.036 + 0.0004 * (k - 110), 0.0)  # noqa: E731
    assert run(stream([(1, 0, 100, 120, leap)], 200)) == []
    steady = stream([(1, 0, 100, 120, line(P, (0.0, 0.04, 0.0), 100, 120))], 200)
    assert [e["kind"] for e in run(steady)] == ["swipe"]


def test_a_third_track_within_the_sync_window_is_still_a_two_finger_tap():
    ev = run(
        stream(
            [
                (1, 0, 100, 115, still(P)),
                (2, 1, 104, 110, still(FAR)),
                (3, 1, 112, 116, still(FAR)),
            ],
            300,
        )
    )
    assert [e["kind"] for e in ev] == ["two_finger_tap"]
    assert ev[0]["track_ids"] == [1, 2, 3]


def test_a_brief_touch_within_a_long_press_does_not_undo_it():
    ev = run(stream([(1, 0, 100, 200, still(P)), (2, 1, 110, 125, still(FAR))], 300))
    assert [e["kind"] for e in ev] == ["long_press"]
    # not brief (longer than a tap): two fingers held, nothing
    assert run(stream([(1, 0, 100, 200, still(P)), (2, 1, 110, 150, still(FAR))], 300)) == []


def test_a_swipe_is_one_finger():
    two = stream(
        [(1, 0, 100, 120, line(P, (0.0, 0.04, 0.0), 100, 120)), (2, 1, 105, 112, still(FAR))],
        200,
    )
    assert run(two) == []


def test_a_piece_of_a_swiping_finger_split_off_for_a_few_frames_leaves_the_swipe():
    # a track of 4 frames (40 ms) within the swipe: no finger touches that briefly
    ghost = stream(
        [(1, 0, 100, 120, line(P, (0.0, 0.04, 0.0), 100, 120)), (2, 1, 108, 111, still(FAR))],
        200,
    )
    assert [e["kind"] for e in run(ghost)] == ["swipe"]


def _run_leapt(frames, leapt_at):
    """``run`` with the tracker's ``leapt`` track ids fed at the frames of ``leapt_at``."""
    rec = GestureRecognizer("s", SkinFrame(None, None, up=(0.0, 1.0, 0.0)), CFG)
    events = []
    for k, (t, cs) in enumerate(frames):
        events += rec.update(t, cs, leapt=leapt_at.get(k, ())) if cs else rec.tick(t)
    events += rec.flush(frames[-1][0])
    return events


def test_a_leap_the_tracker_kept_as_the_same_finger_leaves_a_swipe():
    # a quick stroke on a coarse map: the answer stays at the landing point for 10 frames, leaps
    # 36 mm, moves on. Unsteady (a track jumping to another finger) unless the tracker moved
    # the track over the leap sure it was the same finger (no second finger in the touch)
    leap = lambda k: P if k < 110 else (0.0, 0.036 + 0.0004 * (k - 110), 0.0)  # noqa: E731
    frames = stream([(1, 0, 100, 120, leap)], 200)
    assert _run_leapt(frames, {}) == []
    ev = _run_leapt(frames, {110: [1]})
    assert [(e["kind"], e["direction"]) for e in ev] == [("swipe", "up")]
    assert _run_leapt(frames, {110: [2]}) == []  # another track's leap


def test_a_brief_trail_behind_a_quick_swipe_leaves_the_swipe():
    # 60 mm in 0.2 s; a track of 70 ms (longer than GHOST_S) stays at the landing point while
    # the finger moves away: its image's trail, not a second finger
    swipe = line(P, (0.0, 0.06, 0.0), 100, 120)
    at_landing = (0.0, 0.002, 0.0)
    ev = run(stream([(1, 0, 100, 120, swipe), (2, 1, 106, 113, still(at_landing))], 200))
    assert [(e["kind"], e["track_ids"]) for e in ev] == [("swipe", [1])]
    # ahead of the finger (where it goes: the other finger of a two-finger tap it drifts to),
    # beside its path, or longer than TRAIL_S: a second finger, no swipe
    for pos, k1 in (((0.0, 0.05, 0.0), 113), (FAR, 113), (at_landing, 118)):
        assert run(stream([(1, 0, 100, 120, swipe), (2, 1, 106, k1, still(pos))], 200)) == []


def test_new_thresholds_are_checked():
    with pytest.raises(ValueError, match="swipe_max_jump_frac"):
        GestureConfig(swipe_max_jump_frac=1.5)
    with pytest.raises(ValueError, match="landing_s"):
        GestureConfig(landing_s=0.5)


def test_a_finger_drifting_until_the_second_is_found_is_still_in_a_two_finger_tap():
    # one contact's fit to both fingers' image drifts 40 mm from the first landing until the
    # second finger is found (within the sync window); from then on both rest: a two-finger tap
    drift = lambda k: (0.0, 0.008 * min(k - 100, 5), 0.0)  # noqa: E731
    ev = run(stream([(1, 0, 100, 115, drift), (2, 1, 105, 114, still(FAR))], 300))
    assert [e["kind"] for e in ev] == ["two_finger_tap"]
    # the same drift with no second finger is the finger moving: a swipe, not a tap
    assert [e["kind"] for e in run(stream([(1, 0, 100, 115, drift)], 300))] == ["swipe"]


def _run_with_change(frames, change, thr=2.5, hold=2.0):
    """``run`` with the touch's image change (``LandingWatch.most``) fed every frame."""
    rec = GestureRecognizer(
        "s", SkinFrame(None, None, up=(0.0, 1.0, 0.0)), CFG, landing_change=thr, landing_hold=hold
    )
    events = []
    for t, cs in frames:
        events += rec.update(t, cs, change=change) if cs else rec.tick(t)
    events += rec.flush(frames[-1][0])
    return events, rec


def test_a_tap_whose_image_changed_as_two_fingers_is_a_two_finger_tap_never_a_tap():
    ev, _ = _run_with_change(stream([(1, 0, 100, 110, still(P))], 200), change=4.0)
    assert [e["kind"] for e in ev] == ["two_finger_tap"]
    assert ev[0]["track_ids"] == [1]
    # reported when the finger lifts (certain then), with a confidence below a tracked pair's
    assert ev[0]["timestamp_s"] == pytest.approx(1.10)
    assert 0.5 <= ev[0]["confidence"] < 1.0


def test_a_tap_of_uncertain_count_is_held_back_and_a_plain_one_reported():
    ev, rec = _run_with_change(stream([(1, 0, 100, 110, still(P))], 200), change=2.2)
    assert ev == [] and rec.n_held == 1  # one finger or two: neither is said
    ev, rec = _run_with_change(stream([(1, 0, 100, 110, still(P))], 200), change=1.4)
    assert [e["kind"] for e in ev] == ["tap"] and ev[0]["confidence"] == 1.0
    assert rec.n_held == 0


def test_the_change_leaves_double_taps_long_presses_and_swipes_alone():
    double = stream([(1, 0, 100, 110, still(P)), (2, 0, 125, 135, still((0.005, 0, 0)))], 300)
    ev, _ = _run_with_change(double, change=2.2)  # uncertain: still a double tap
    assert [e["kind"] for e in ev] == ["double_tap"]
    ev, _ = _run_with_change(stream([(1, 0, 100, 200, still(P))], 260), change=9.0)
    assert [e["kind"] for e in ev] == ["long_press"]
    swipe = stream([(1, 0, 100, 125, line(P, (0.0, 0.05, 0.0), 100, 125))], 200)
    ev, _ = _run_with_change(swipe, change=9.0)  # a moving finger's image changes too
    assert [e["kind"] for e in ev] == ["swipe"]


def test_every_event_carries_its_confidence():
    frames = stream(
        [(1, 0, 100, 110, still(P)), (2, 1, 101, 111, still(FAR)), (3, 0, 200, 300, still(P))],
        400,
    )
    ev = run(frames)
    assert [e["kind"] for e in ev] == ["two_finger_tap", "long_press"]
    assert all(e["confidence"] == 1.0 for e in ev)  # every finger tracked: a certain count


@pytest.mark.parametrize("bad", [-1.0, math.nan, math.inf])
def test_landing_thresholds_are_checked(bad):
    with pytest.raises(ValueError, match="landing_change"):
        GestureRecognizer("s", SkinFrame(None, None, up=(0.0, 1.0, 0.0)), landing_change=bad)
    with pytest.raises(ValueError, match="landing_hold"):
        GestureRecognizer("s", SkinFrame(None, None, up=(0.0, 1.0, 0.0)), landing_hold=bad)


# the skin's two-point threshold (``two_point_mm``): tracks closer than it may be one finger
NEAR = (0.03, 0.0, 0.0)  # 30 mm from P: under a 50 mm threshold


def _run_two_point(frames, change, two_point_mm, thr=2.5, hold=2.0):
    """``run`` with the image change and the skin's two-point threshold."""
    rec = GestureRecognizer(
        "s",
        SkinFrame(None, None, up=(0.0, 1.0, 0.0)),
        CFG,
        landing_change=thr,
        landing_hold=hold,
        two_point_mm=two_point_mm,
    )
    events = []
    for t, cs in frames:
        events += rec.update(t, cs, change=change) if cs else rec.tick(t)
    events += rec.flush(frames[-1][0])
    return events, rec


def _pair(b, first=100):
    return stream(
        [(1, 0, first, first + 10, still(P)), (2, 1, first + 3, first + 9, still(b))], 300
    )


def test_two_tracks_closer_than_the_threshold_that_changed_as_one_finger_are_held_back():
    ev, rec = _run_two_point(_pair(NEAR), change=1.4, two_point_mm=50.0)
    assert ev == [] and rec.n_held == 1  # neither a tap nor a two-finger tap is said
    # a skin measured to count two at no separation: the same at any distance
    ev, rec = _run_two_point(_pair(FAR), change=1.4, two_point_mm=math.inf)
    assert ev == [] and rec.n_held == 1


def test_two_tracks_at_or_beyond_the_threshold_are_a_sure_two_finger_tap():
    ev, _ = _run_two_point(_pair(FAR), change=1.4, two_point_mm=50.0)  # 60 mm apart
    assert [e["kind"] for e in ev] == ["two_finger_tap"] and ev[0]["confidence"] == 1.0


def test_closer_than_the_threshold_the_change_makes_a_two_finger_tap_of_lower_confidence():
    ev, _ = _run_two_point(_pair(NEAR), change=4.0, two_point_mm=50.0)  # past landing_change
    assert [e["kind"] for e in ev] == ["two_finger_tap"]
    assert ev[0]["confidence"] == pytest.approx(0.9)
    ev, _ = _run_two_point(_pair(NEAR), change=2.2, two_point_mm=50.0)  # past the hold only
    assert [e["kind"] for e in ev] == ["two_finger_tap"]
    assert ev[0]["confidence"] == pytest.approx(0.5 + 0.4 * 30.0 / 50.0)
    assert ev[0]["track_ids"] == [1, 2]


def test_without_a_threshold_or_a_hold_level_two_tracks_are_two_fingers_as_before():
    for tp, hold in ((None, 2.0), (50.0, 0.0)):
        ev, rec = _run_two_point(_pair(NEAR), change=1.4, two_point_mm=tp, hold=hold)
        assert [e["kind"] for e in ev] == ["two_finger_tap"] and rec.n_held == 0
        assert ev[0]["confidence"] == (1.0 if tp is None else pytest.approx(0.5 + 0.4 * 0.6))


def test_a_split_second_track_in_a_double_taps_tap_leaves_one_double_tap():
    # the first tap's image split for a few frames into a second track 20 mm away
    ghost = (0.02, 0.0, 0.0)
    frames = stream(
        [(1, 0, 100, 110, still(P)), (2, 1, 104, 107, still(ghost)), (3, 0, 125, 135, still(P))],
        300,
    )
    ev, rec = _run_two_point(frames, change=1.3, two_point_mm=50.0)
    assert [e["kind"] for e in ev] == ["double_tap"] and ev[0]["track_ids"] == [1, 3]
    # the split in the second tap: the first tap is not reported while the ghost is down
    frames = stream(
        [(1, 0, 100, 110, still(P)), (2, 0, 125, 135, still(P)), (3, 1, 130, 133, still(ghost))],
        300,
    )
    ev, _ = _run_two_point(frames, change=1.3, two_point_mm=50.0)
    assert [e["kind"] for e in ev] == ["double_tap"] and ev[0]["track_ids"] == [1, 2]
    # without the threshold the split is a second finger (the old reading)
    ev, _ = _run_two_point(frames, change=1.3, two_point_mm=None)
    assert [e["kind"] for e in ev] == ["tap", "two_finger_tap"]


@pytest.mark.parametrize("bad", [0.0, -10.0, math.nan])
def test_the_two_point_threshold_is_checked(bad):
    with pytest.raises(ValueError, match="two_point_mm"):
        GestureRecognizer("s", SkinFrame(None, None, up=(0.0, 1.0, 0.0)), two_point_mm=bad)


# the footprint cue (``footprint_levels``): the touch's image wider than one finger's
def _run_footprint(frames, footprint, levels=(3.0, 2.0), two_point_mm=None, change=1.4):
    """``run`` with the touch's mean footprint score (``FootprintWatch.mean``) every frame."""
    rec = GestureRecognizer(
        "s",
        SkinFrame(None, None, up=(0.0, 1.0, 0.0)),
        CFG,
        landing_change=2.5,
        landing_hold=2.0,
        two_point_mm=two_point_mm,
        footprint_levels=levels,
    )
    events = []
    for t, cs in frames:
        events += rec.update(t, cs, change=change, footprint=footprint) if cs else rec.tick(t)
    events += rec.flush(frames[-1][0])
    return events, rec


def test_a_tap_whose_footprint_is_two_fingers_is_a_two_finger_tap_of_lower_confidence():
    ev, _ = _run_footprint(stream([(1, 0, 100, 110, still(P))], 200), footprint=3.5)
    assert [e["kind"] for e in ev] == ["two_finger_tap"] and ev[0]["track_ids"] == [1]
    assert ev[0]["confidence"] == pytest.approx(0.7)
    assert ev[0]["timestamp_s"] == pytest.approx(1.10)  # when the finger lifts


def test_a_tap_of_uncertain_footprint_is_held_back_and_a_plain_one_reported():
    ev, rec = _run_footprint(stream([(1, 0, 100, 110, still(P))], 200), footprint=2.5)
    assert ev == [] and rec.n_held == 1
    for foot, levels in ((1.0, (3.0, 2.0)), (None, (3.0, 2.0)), (9.0, None)):
        ev, rec = _run_footprint(stream([(1, 0, 100, 110, still(P))], 200), foot, levels)
        assert [e["kind"] for e in ev] == ["tap"] and rec.n_held == 0


def test_the_footprint_leaves_long_presses_and_swipes_alone_and_ends_a_double_tap():
    ev, _ = _run_footprint(stream([(1, 0, 100, 200, still(P))], 260), footprint=9.0)
    assert [e["kind"] for e in ev] == ["long_press"]
    swipe = stream([(1, 0, 100, 125, line(P, (0.0, 0.05, 0.0), 100, 125))], 200)
    assert [e["kind"] for e in _run_footprint(swipe, footprint=9.0)[0]] == ["swipe"]
    # two taps in a row whose footprint is two fingers': two two-finger taps, no double tap
    double = stream([(1, 0, 100, 110, still(P)), (2, 0, 125, 135, still((0.005, 0, 0)))], 300)
    ev, _ = _run_footprint(double, footprint=3.5)
    assert [e["kind"] for e in ev] == ["two_finger_tap", "two_finger_tap"]


def test_close_tracks_whose_footprint_is_two_fingers_are_a_two_finger_tap():
    ev, rec = _run_footprint(_pair(NEAR), footprint=1.0, two_point_mm=50.0)
    assert ev == [] and rec.n_held == 1  # as before: one finger's tap of uncertain count
    ev, _ = _run_footprint(_pair(NEAR), footprint=3.5, two_point_mm=50.0)
    assert [e["kind"] for e in ev] == ["two_finger_tap"] and ev[0]["track_ids"] == [1, 2]
    assert ev[0]["confidence"] == pytest.approx(0.9)


@pytest.mark.parametrize("bad", [(1.0, 2.0), (math.nan, 1.0), (1.0, math.inf)])
def test_footprint_levels_are_checked(bad):
    with pytest.raises(ValueError, match="footprint_levels"):
        GestureRecognizer("s", SkinFrame(None, None, up=(0.0, 1.0, 0.0)), footprint_levels=bad)
