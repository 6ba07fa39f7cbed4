"""The gesture script and the gesture stream (skinloc.sim.gestures, sim.gesture_stream)."""

from __future__ import annotations

import os
from pathlib import Path

import h5py
import numpy as np
import pytest
import trimesh

from skinloc.errors import Interrupted
from skinloc.geometry.mesh import cone_skin
from skinloc.sim.gesture_stream import read_gesture_truth, record_gestures
from skinloc.sim.gestures import DIRECTIONS, GESTURE_KINDS, GestureScript, Timing
from skinloc.sim.skin import SimulatedSkin
from skinloc.sources.replay import read_stream

SEED = int(os.environ.get("SKINLOC_TEST_SEED", "0"))
T = Timing()
EPS = 1e-9


@pytest.fixture(scope="module")
def cone() -> trimesh.Trimesh:
    return cone_skin()


@pytest.fixture(scope="module")
def items(cone: trimesh.Trimesh) -> list:
    script = GestureScript(cone, 24, n_touches=6, random_state=SEED)
    return list(script.items())


def _inside(x: float, lo_hi: tuple[float, float]) -> bool:
    return lo_hi[0] - EPS <= x <= lo_hi[1] + EPS


def test_every_kind_and_direction_appears(items: list) -> None:
    kinds = [it.kind for it in items]
    assert set(kinds) == {*GESTURE_KINDS, "rest", "drag"}
    assert sum(k in GESTURE_KINDS for k in kinds) == 24 and len(kinds) == 30
    assert {it.direction for it in items if it.kind == "swipe"} == set(DIRECTIONS)
    assert all(it.direction is None for it in items if it.kind != "swipe")


def test_timings_within_the_documented_ranges(items: list) -> None:
    for it in items:
        s = it.strokes
        dur = [x.t1_s - x.t0_s for x in s]
        if it.kind == "tap":
            assert len(s) == 1 and _inside(dur[0], T.tap_s)
        elif it.kind == "long_press":
            assert len(s) == 1 and dur[0] >= 0.6 and _inside(dur[0], T.long_press_s)
        elif it.kind == "rest":
            assert len(s) == 1 and T.tap_s[1] < dur[0] < 0.6
        elif it.kind == "double_tap":
            assert len(s) == 2 and all(_inside(d, T.double_tap_press_s) for d in dur)
            gap = s[1].t0_s - s[0].t1_s
            assert 0 < gap < 0.3 and np.isclose(gap, it.truth["gap_s"])
            assert np.linalg.norm(s[1].path_m[0] - s[0].path_m[0]) < 0.015
        elif it.kind in ("swipe", "drag"):
            length = np.linalg.norm(np.diff(s[0].path_m, axis=0), axis=1).sum()
            speed = length / dur[0]
            if it.kind == "swipe":
                lo, hi = T.swipe_length_m
                assert _inside(speed, T.swipe_speed_m_s) and lo <= length <= 1.04 * hi
            else:
                lo, hi = T.drag_length_m
                assert _inside(speed, T.drag_speed_m_s) and lo <= length <= 1.04 * hi
            assert np.isclose(speed, it.truth["speed_m_s"])
        elif it.kind == "two_finger_tap":
            assert {x.slot for x in s} == {0, 1} and it.truth["n_fingers"] == 2
            sep = np.linalg.norm(s[1].path_m[0] - s[0].path_m[0])
            lo, hi = T.two_finger_separation_m
            assert lo - 0.001 <= sep <= hi + 0.001 and np.isclose(sep, it.truth["separation_m"])
            assert abs(s[1].t0_s - s[0].t0_s) <= T.two_finger_skew_s[1] + EPS
            assert all(d <= T.two_finger_press_s[1] + T.two_finger_skew_s[1] + EPS for d in dur)
        assert it.truth["start_s"] == it.start_s and it.truth["end_s"] == it.end_s
        landings = sorted(s, key=lambda x: x.t0_s)
        assert np.allclose(it.truth["fingers_m"], [x.path_m[0] for x in landings])
    # items never overlap, and the idle time between them is longer than a double-tap window
    for a, b in zip(items, items[1:], strict=False):
        assert b.start_s - a.end_s >= T.idle_s[0] - EPS
    assert items[0].start_s >= T.lead_in_s - EPS


def test_swipes_go_their_way_in_the_skin_frame(cone: trimesh.Trimesh, items: list) -> None:
    script = GestureScript(cone, 1)
    axes = {"up": script.up, "down": -script.up, "right": script.right, "left": -script.right}
    for it in items:
        if it.kind != "swipe":
            continue
        chord = it.strokes[0].path_m[-1] - it.strokes[0].path_m[0]
        along = chord @ axes[it.direction]
        other = chord @ (script.right if it.direction in ("up", "down") else script.up)
        assert along >= 0.6 * T.swipe_length_m[0] and abs(other) <= 0.5 * along
        # and the path lies on the skin
        d = trimesh.proximity.closest_point(cone, it.strokes[0].path_m)[1]
        assert d.max() < 1e-6


def test_two_finger_separations_spread_over_the_whole_range(cone: trimesh.Trimesh) -> None:
    script = GestureScript(cone, 1, random_state=SEED)
    seps = np.array(
        [np.linalg.norm(np.subtract(*[x.path_m[0] for x in script._two_fingers(0.0)]))
         for _ in range(200)]
    )  # fmt: skip
    lo, hi = T.two_finger_separation_m
    assert lo - 0.001 <= seps.min() and seps.max() <= hi + 0.001
    # evenly spread: each quarter of the range holds about a quarter of the taps (50 +- 25)
    counts = np.histogram(seps, bins=4, range=(lo - 0.001, hi + 0.001))[0]
    assert counts.min() >= 25, counts


def test_script_is_deterministic_and_checks_its_input(cone: trimesh.Trimesh) -> None:
    a = [it.truth for it in GestureScript(cone, 6, random_state=3).items()]
    b = [it.truth for it in GestureScript(cone, 6, random_state=3).items()]
    assert a == b
    with pytest.raises(ValueError, match="gestures"):
        GestureScript(cone, 0)
    with pytest.raises(ValueError, match="other touches"):
        GestureScript(cone, 3, n_touches=-1)


def _record(cone, path: Path, **kw) -> dict:
    skin = SimulatedSkin(cone, random_state=SEED)
    skin.reseed(1)
    script = GestureScript(
        cone, 5, n_touches=2, random_state=SEED + 1, draw_touch=lambda r: skin.draw_touch(r, False)
    )
    return record_gestures(skin, path, script, **kw)


@pytest.fixture(scope="module")
def stream(cone: trimesh.Trimesh, tmp_path_factory) -> tuple[Path, dict]:
    path = tmp_path_factory.mktemp("g") / "g.h5"
    return path, _record(cone, path)


def test_truth_matches_the_fingers_and_the_frames(stream) -> None:
    path, res = stream
    frames, times, index = read_stream(path)
    with h5py.File(path) as f:
        fingers = f["truth/fingers_m"][()]
        base_frames = f["baseline/frames"][()]
    base = base_frames.mean(axis=0)
    ordinary = base_frames.std(axis=0) < 10  # not the noisy sensor
    assert len(frames) == len(times) == len(fingers) == res["n_frames"]
    assert times[0] == 0 and np.allclose(np.diff(times), 0.01) and np.all(np.diff(index) == 1)
    down = np.isfinite(fingers[:, :, 0])
    covered = np.zeros(len(times), dtype=bool)
    for g in res["truth_gestures"] + res["truth_touches"]:
        span = (times >= g["start_s"] - EPS) & (times < g["end_s"])
        covered |= span
        assert down[span, 0].any() or down[span, 1].any()
        assert down[span].any(axis=0).sum() == g["n_fingers"]
        first = np.flatnonzero(span & down.any(axis=1))[0]
        np.testing.assert_allclose(fingers[first, 0], g["position_m"], atol=1e-3)
        if g["kind"] in ("swipe", "drag"):
            last = np.flatnonzero(span & down[:, 0])[-1]
            step = g["speed_m_s"] * 0.01 * 2 + 1e-3  # a frame's travel at the peak speed
            np.testing.assert_allclose(fingers[last, 0], g["path_m"][1], atol=step)
        # the skin feels it: during the touch the strongest sensor rises well above the noise
        assert (frames[span & down.any(axis=1)] - base).max() > 30
    # no finger outside the truth, and the untouched frames are untouched
    assert not down[~covered].any()
    idle = np.abs(frames[~covered][:, ordinary] - base[ordinary]).max(axis=1)
    assert np.percentile(idle, 99) < 35
    truth = read_gesture_truth(path)
    assert truth == {k: res[k] for k in ("truth_gestures", "truth_touches")}
    assert {g["kind"] for g in truth["truth_gestures"]} == set(GESTURE_KINDS)
    assert {g["kind"] for g in truth["truth_touches"]} == {"rest", "drag"}


def test_chunking_does_not_change_the_stream(cone, stream, tmp_path: Path) -> None:
    path, _ = stream
    other = tmp_path / "g2.h5"
    _record(cone, other, chunk_frames=37)
    a, b = read_stream(path), read_stream(other)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert read_gesture_truth(path) == read_gesture_truth(other)
    assert not list(tmp_path.glob("*partial*"))


def test_interrupt_keeps_the_complete_items(cone, tmp_path: Path) -> None:
    out = tmp_path / "g.h5"

    def stop_after_two(done: int, total: int) -> None:
        if done == 2:
            raise KeyboardInterrupt

    with pytest.raises(Interrupted, match="kept the 2 complete"):
        _record(cone, out, progress=stop_after_two)
    assert not out.exists()
    side = tmp_path / "g.partial.h5"
    truth = read_gesture_truth(side)
    items = truth["truth_gestures"] + truth["truth_touches"]
    assert len(items) == 2
    _, times, _ = read_stream(side)
    assert times[-1] < max(g["end_s"] for g in items) + 0.011


def test_other_errors_leave_no_side_file(cone, tmp_path: Path) -> None:
    def boom(done: int, total: int) -> None:
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        _record(cone, tmp_path / "g.h5", progress=boom)
    assert list(tmp_path.iterdir()) == []


def test_read_gesture_truth_of_other_files(tmp_path: Path) -> None:
    assert read_gesture_truth(tmp_path / "x.mat") is None
    p = tmp_path / "plain.h5"
    with h5py.File(p, "w") as f:
        f["x"] = 1
    assert read_gesture_truth(p) is None


def test_a_skin_too_small_for_a_swipe_says_so() -> None:
    tiny = trimesh.creation.icosphere(subdivisions=2, radius=0.008)
    script = GestureScript(tiny, 5, n_touches=0, random_state=0)
    with pytest.raises(ValueError, match="no place on the skin"):
        list(script.items())
