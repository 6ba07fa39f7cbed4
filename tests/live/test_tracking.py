"""Tracking (multi-touch protocol B): slots, ids, fingers landing and lifting, missed frames."""

from __future__ import annotations

import itertools
import json
import math
import os

import numpy as np
import pytest

from skinloc.live.config import PipelineConfig
from skinloc.live.core import SkinCore
from skinloc.live.sinks import ListSink
from skinloc.live.tracking import Tracker, assign
from skinloc.models.engine import load_engine
from tests._live import model_path

A, B, C = np.array([0.0, 0.0, 0.0]), np.array([0.05, 0.0, 0.0]), np.array([0.0, 0.05, 0.0])


def _tracker(k: int = 3, miss: int = 1, confirm: int = 2) -> Tracker:
    def constrain(x, y, z, out):
        out[:] = (x, y, z)

    return Tracker(k, 30.0, miss, confirm, constrain, None)


def _step(tr: Tracker, t: float, *points: np.ndarray, start: bool = False):
    p = np.array(points, dtype=float).reshape(-1, 3)
    n = len(p)
    ev = tr.update(t, p, p, np.full(n, math.nan), np.full(n, 1.0), touch_start=start)
    return [(e.track_id, e.slot, s) for e, s in ev]


def test_fingers_land_and_lift_independently_with_stable_ids_and_slot_reuse():
    tr = _tracker()
    assert _step(tr, 0.00, A, start=True) == [(1, 0, "start")]
    assert _step(tr, 0.01, A) == [(1, 0, "move")]
    # a second finger lands: a candidate for one frame, a track on the second
    assert _step(tr, 0.02, A, B) == [(1, 0, "move")]
    assert _step(tr, 0.03, B + 0.001, A + 0.001) == [(1, 0, "move"), (2, 1, "start")]
    for k in range(4, 8):
        assert _step(tr, k * 0.01, A, B) == [(1, 0, "move"), (2, 1, "move")]
    # the first finger lifts: one frame held (hysteresis), then its end; the second goes on
    assert _step(tr, 0.08, B) == [(1, 0, "move"), (2, 1, "move")]
    assert _step(tr, 0.09, B) == [(1, 0, "end"), (2, 1, "move")]
    assert _step(tr, 0.10, B) == [(2, 1, "move")]
    # a third finger takes the free slot 0 and a new id
    _step(tr, 0.11, B, C)
    assert _step(tr, 0.12, B, C) == [(3, 0, "start"), (2, 1, "move")]
    assert [t.track_id for t in tr.end_all()] == [3, 2]
    assert tr.tracks == []


def test_one_missed_frame_does_not_end_a_track_and_its_position_is_held():
    tr = _tracker()
    _step(tr, 0.0, A, start=True)
    _step(tr, 0.01, A + 0.002)
    assert _step(tr, 0.02) == [(1, 0, "move")]  # missed: held
    assert np.allclose(tr.tracks[0].position_m, A + 0.002)
    assert _step(tr, 0.03, A + 0.003) == [(1, 0, "move")]  # back: the same track
    assert _step(tr, 0.04) == [(1, 0, "move")]
    assert _step(tr, 0.05) == [(1, 0, "end")]  # two in a row: it ends
    tr0 = _tracker(miss=0)
    _step(tr0, 0.0, A, start=True)
    assert _step(tr0, 0.01) == [(1, 0, "end")]


def test_a_one_frame_ghost_never_becomes_a_track_and_slots_are_capped():
    tr = _tracker(k=2)
    _step(tr, 0.0, A, start=True)
    assert _step(tr, 0.01, A, B) == [(1, 0, "move")]
    assert _step(tr, 0.02, A) == [(1, 0, "move")]
    assert tr.next_id == 2
    # K = 2: a third finger waits for a free slot
    _step(tr, 0.03, A, B)
    _step(tr, 0.04, A, B)
    assert _step(tr, 0.05, A, B, C) == [(1, 0, "move"), (2, 1, "move")]
    assert _step(tr, 0.06, A, B, C) == [(1, 0, "move"), (2, 1, "move")]


def test_close_fingers_moving_together_keep_their_ids():
    # 10 mm apart, both 6 mm along +x per frame: the second track's nearest new contact is the
    # first finger's (4 mm), but the least total distance keeps each finger on its own track
    tr = _tracker()
    step = np.array([0.006, 0.0, 0.0])
    a, b = A.copy(), A + [0.010, 0.0, 0.0]
    _step(tr, 0.0, a, b, start=True)
    for k in range(1, 6):
        a, b = a + step, b + step
        tr.update(k * 0.01, np.array([b, a]), np.array([b, a]), np.ones(2), np.ones(2))
    got = {t.track_id: t.last_m for t in tr.tracks}
    assert np.allclose(got[1], a) and np.allclose(got[2], b)


def test_lone_track_and_lone_contact_are_the_same_finger_whatever_the_jump():
    tr = _tracker()
    _step(tr, 0.0, A, start=True)
    assert _step(tr, 0.01, A + 0.1) == [(1, 0, "move")]
    assert tr.next_id == 2


def test_while_releasing_no_new_finger_starts():
    tr = _tracker()
    _step(tr, 0.0, A, start=True)
    p = np.array([A, B])
    for k in range(1, 4):
        ev = tr.update(k * 0.01, p, p, np.ones(2), np.ones(2), new_fingers=False)
        assert [(e.track_id, s) for e, s in ev] == [(1, "move")]


def test_assignment_is_the_least_total_distance_within_the_gate():
    rng = np.random.default_rng(0)
    for _ in range(200):
        m, n = rng.integers(1, 5, size=2)
        t, d = rng.uniform(0, 0.05, (m, 3)), rng.uniform(0, 0.05, (n, 3))
        pairs = assign(t, d, 0.03)
        dist = np.linalg.norm(t[:, None] - d[None], axis=2)
        assert all(dist[i, j] <= 0.03 for i, j in pairs)
        best = (0, 0.0)
        for perm in itertools.permutations(range(max(m, n))):
            ps = [(i, perm[i]) for i in range(m) if perm[i] < n and dist[i, perm[i]] <= 0.03]
            best = max(best, (len(ps), -sum(dist[i, j] for i, j in ps)))
        assert (len(pairs), -sum(dist[i, j] for i, j in pairs)) == pytest.approx(best)
    assert assign(np.zeros((0, 3)), np.zeros((2, 3)), 0.03) == []
    big = assign(rng.uniform(0, 0.01, (5, 3)), rng.uniform(0, 0.01, (5, 3)), 0.03)
    assert len(big) == 5  # scipy beyond 4 x 4


# ---------------------------------------------------------------------------- in the pipeline


class _Scripted:
    """An engine whose ``contacts`` returns scripted points (the multi-contact API)."""

    def __init__(self, script):
        self.script = list(script)
        self.calls = 0

    def __call__(self, x, max_contacts=3, memory=None):
        pts = self.script[min(self.calls, len(self.script) - 1)][:max_contacts]
        self.calls += 1
        n = len(pts)

        class CS:
            positions_m = np.array(pts, dtype=float).reshape(-1, 3)
            strength = np.full(n, 100.0)
            uncertainty_mm = np.full(n, 2.0)

        return CS


def _frames(n_touch: int, rng) -> np.ndarray:
    base = 1000.0 + rng.normal(0, 2.0, (60 + n_touch + 10, 64))
    base[60 : 60 + n_touch, 10] += 400.0
    return base


def test_pipeline_emits_one_contact_per_track_and_a_two_finger_tap():
    rng = np.random.default_rng(0)
    engine = load_engine(model_path("map"))
    script = [[A]] * 2 + [[A, B]] * 8 + [[A]] * 3
    engine.contacts = _Scripted(script)
    try:
        core = SkinCore(engine, PipelineConfig(baseline_frames=50), name="s")
        # tracking is tested here: this model counts two at no separation, so two tracks whose
        # image never changed would be held back (test_gestures.py covers that rule)
        core._recognizer.two_point_mm = None
        sink = ListSink()
        frames = _frames(12, rng)
        for k, f in enumerate(frames):
            cs = core.process_frame(f, k * 0.01, k)
            if cs:
                sink.emit_contacts("s", k * 0.01, cs)
        core.flush_gestures()
        per_frame = [[(c.track_id, c.slot, c.state) for c in f] for f in sink.frames]
        assert per_frame[0] == [(1, 0, "start")]
        confirm = PipelineConfig().track_confirm_frames
        for k in range(2, 2 + confirm - 1):  # a candidate until seen in `confirm` frames
            assert [x for x in per_frame[k] if x[0] == 2] == []
        assert [(2, 1, "start")] == [x for x in per_frame[2 + confirm - 1] if x[0] == 2]
        assert max(len(f) for f in per_frame) == 2
        assert all(c.strength == 100.0 for c in sink.contacts if c.state != "end")
        ends = [(c.track_id, c.state) for c in sink.contacts if c.state == "end"]
        assert sorted(ends) == [(1, "end"), (2, "end")]
        kinds = [g["kind"] for g in core.take_gestures()]
        assert kinds == ["two_finger_tap"]
    finally:
        del engine.contacts


def test_max_contacts_1_is_one_track_per_touch():
    rng = np.random.default_rng(1)
    core = SkinCore(model_path("map"), PipelineConfig(baseline_frames=50, max_contacts=1))
    out = []
    for k, f in enumerate(_frames(20, rng)):
        out += core.process_frame(f, k * 0.01, k)
    assert {(c.track_id, c.slot, c.touch_id) for c in out} == {(1, 0, 1)}
    assert [c.state for c in out][0] == "start" and out[-1].state == "end"


def test_pipeline_config_checks_the_tracking_fields():
    with pytest.raises(ValueError, match="max_contacts"):
        PipelineConfig(max_contacts=0)
    with pytest.raises(ValueError, match="track_miss_frames"):
        PipelineConfig(track_miss_frames=-1)
    with pytest.raises(ValueError, match="gestures"):
        PipelineConfig(gestures="yes")


# ------------------------------------------------------------------- jumps and the pair prior


def test_a_settled_track_does_not_jump_to_a_far_contact_it_is_a_second_finger():
    # settled (seen >= settle_frames = confirm = 2): a contact 50 mm away in the next frame is
    # not the finger moving (that would be 5 m/s) but another one, in a touch that has had two
    # fingers; the first is held, then ends
    tr = _tracker()
    _step(tr, 0.00, A, start=True)
    _step(tr, 0.01, A, C)
    assert _step(tr, 0.02, A, C) == [(1, 0, "move"), (2, 1, "start")]  # a second finger
    _step(tr, 0.03, A)
    assert _step(tr, 0.04, A) == [(1, 0, "move"), (2, 1, "end")]  # it lifts
    assert _step(tr, 0.05, B) == [(1, 0, "move")]
    assert np.allclose(tr.tracks[0].last_m, A)  # held, not moved to B
    assert _step(tr, 0.06, B) == [(1, 0, "end"), (3, 1, "start")]  # B took over
    assert np.allclose(tr.tracks[0].last_m, B)
    # within the gate it is motion, even on the one-finger fast path
    tr = _tracker()
    _step(tr, 0.00, A, start=True)
    _step(tr, 0.01, A)
    near = A + np.array([0.02, 0.0, 0.0])
    assert _step(tr, 0.02, near) == [(1, 0, "move")]
    assert np.allclose(tr.tracks[0].last_m, near)


def test_a_landing_track_may_jump_until_it_settles():
    tr = _tracker(confirm=4)  # settle_frames defaults to confirm_frames
    _step(tr, 0.00, A, start=True)
    assert _step(tr, 0.01, B) == [(1, 0, "move")]
    assert np.allclose(tr.tracks[0].last_m, B)
    tr = Tracker(3, 30.0, 1, 4, lambda x, y, z, out: out.__setitem__(slice(None), (x, y, z)),
                 None, settle_frames=1)  # fmt: skip
    _step(tr, 0.00, A, start=True)
    _step(tr, 0.01, B)
    assert np.allclose(tr.tracks[0].last_m, A)


class _Fit:
    def __init__(self, ratio, z2, first, second):
        self.ratio, self.z2 = ratio, z2
        self.first_m, self.second_m = np.asarray(first, float), np.asarray(second, float)


class _Refit:
    """A scripted anchored fit: one ``_Fit`` (or None) per call."""

    def __init__(self, fits):
        self.fits = list(fits)
        self.calls = 0

    def fit(self, x, anchor):
        f = self.fits[min(self.calls, len(self.fits) - 1)]
        self.calls += 1
        return f


def _pair_tracker(fits, rule=None):
    from skinloc.live.pair_prior import PairPrior

    def constrain(x, y, z, out):
        out[:] = (x, y, z)

    prior = PairPrior(_Refit(fits), np.zeros(64, np.float32), rule)
    return Tracker(3, 30.0, 1, 4, constrain, None, pair=prior), prior


def test_pair_prior_starts_a_second_finger_after_consistent_frames_without_the_confirm_wait():
    good = _Fit(0.5, 12.0, A, B)
    tr, prior = _pair_tracker([good])
    assert _step(tr, 0.00, A, start=True) == [(1, 0, "start")]
    # frames 1, 2 of the evidence (start_frames = 3): nothing yet
    assert _step(tr, 0.01, A) == [(1, 0, "move")]
    assert _step(tr, 0.02, A) == [(1, 0, "move")]
    # third consistent frame: the second finger starts at once (not after 4 more frames)
    assert _step(tr, 0.03, A) == [(1, 0, "move"), (2, 1, "start")]
    assert np.allclose(tr.slots[1].last_m, B)
    # then kept while the anchored fit stays better than one (keep thresholds, lower)
    prior.refit.fits = [_Fit(0.1, 4.0, A, B)]
    assert _step(tr, 0.04, A) == [(1, 0, "move"), (2, 1, "move")]
    # below the keep thresholds: the search's one contact only; the second finger ends
    prior.refit.fits = [_Fit(0.01, 1.0, A, B)]
    _step(tr, 0.05, A)
    assert _step(tr, 0.06, A) == [(1, 0, "move"), (2, 1, "end")]


def test_pair_prior_wants_a_second_contact_that_stays_put_strong_and_early():
    # the second contact wandering (more than 15 mm between frames): never a finger
    wander = [_Fit(0.5, 12.0, A, B + [0.0, 0.02 * (k % 2), 0.0]) for k in range(10)]
    tr, _ = _pair_tracker(wander)
    _step(tr, 0.0, A, start=True)
    for k in range(1, 10):
        assert _step(tr, k * 0.01, A) == [(1, 0, "move")]
    # too weak (z2 under start_z), then too late (after window_s of the first landing)
    tr, prior = _pair_tracker([_Fit(0.5, 3.0, A, B)])
    _step(tr, 0.0, A, start=True)
    for k in range(1, 6):
        assert _step(tr, k * 0.01, A) == [(1, 0, "move")]
    prior.refit.fits = [_Fit(0.5, 12.0, A, B)]
    for k in range(30, 40):
        assert _step(tr, k * 0.01, A) == [(1, 0, "move")]
    # a frame without evidence restarts the count
    tr, prior = _pair_tracker([_Fit(0.5, 12.0, A, B)] * 2 + [None] + [_Fit(0.5, 12.0, A, B)] * 5)
    _step(tr, 0.0, A, start=True)
    got = [len(_step(tr, k * 0.01, A)) for k in range(1, 7)]
    assert got == [1, 1, 1, 1, 1, 2]


def test_pair_prior_takes_two_close_fingers_fit_either_way_round():
    # two close fingers: the anchored contact swaps between them from frame to frame; the
    # pair stays put, so it is consistent evidence (the second contact jumps 50 mm)
    tr, _ = _pair_tracker([_Fit(0.5, 12.0, A, B), _Fit(0.5, 12.0, B, A)] * 3)
    _step(tr, 0.0, A, start=True)
    assert [len(_step(tr, k * 0.01, A)) for k in (1, 2, 3)] == [1, 1, 2]
    # or the second contact on either side of an unmoved first, as far along one line
    # (the mirror): consistent while the fingers land (mirror_s), not later in the touch
    M = 2.0 * A - B
    tr, _ = _pair_tracker([_Fit(0.5, 12.0, A, B), _Fit(0.5, 12.0, A, M)] * 3)
    _step(tr, 0.0, A, start=True)
    assert [len(_step(tr, k * 0.01, A)) for k in (1, 2, 3)] == [1, 1, 2]
    tr, prior = _pair_tracker([_Fit(0.01, 1.0, A, B)])
    _step(tr, 0.0, A, start=True)
    for k in range(1, 12):
        _step(tr, k * 0.01, A)
    prior.refit.fits, prior.refit.calls = [_Fit(0.5, 12.0, A, B), _Fit(0.5, 12.0, A, M)] * 5, 0
    assert [len(_step(tr, k * 0.01, A)) for k in range(12, 20)] == [1] * 8
    # a mirror about a first that moved, or a swap of a pair that moved: not consistent
    A2 = A + np.array([0.0, 0.03, 0.0])
    tr, _ = _pair_tracker([_Fit(0.5, 12.0, A, B), _Fit(0.5, 12.0, A2, 2.0 * A2 - B)] * 3)
    _step(tr, 0.0, A, start=True)
    assert [len(_step(tr, k * 0.01, A)) for k in range(1, 7)] == [1] * 6
    tr, _ = _pair_tracker([_Fit(0.5, 12.0, A, B), _Fit(0.5, 12.0, B, C)] * 3)
    _step(tr, 0.0, A, start=True)
    assert [len(_step(tr, k * 0.01, A)) for k in range(1, 7)] == [1] * 6


def test_pair_prior_stays_out_of_the_way_when_the_search_sees_two_or_the_touch_releases():
    tr, prior = _pair_tracker([_Fit(0.5, 12.0, A, B)])
    _step(tr, 0.0, A, start=True)
    _step(tr, 0.01, A, C)  # the search's own two contacts: no fit asked
    assert prior.refit.calls == 0
    p = np.array([A])
    tr.update(0.02, p, p, np.ones(1), np.ones(1), new_fingers=False)
    assert prior.refit.calls == 0


def test_pipeline_with_a_real_model_finds_the_second_finger_the_search_missed():
    # the scripted search says one contact; the image holds two fingers: the anchored fit on
    # the model's own tables finds the second, and a two-finger tap is reported
    engine = load_engine(model_path("map"))
    t = engine.search_tables()
    Fpos, Ft, w = t.arrays[7], t.arrays[6], t.arrays[0]
    i = int(np.argmax(Fpos[:, 2]))
    j = int(np.argmax(np.linalg.norm(Fpos - Fpos[i], axis=1) > 0.045))
    img = 60.0 * (Ft[i].astype(float) + Ft[j].astype(float)) / w  # counts
    rng = np.random.default_rng(3)
    frames = 1000.0 + rng.normal(0, 2.0, (80, 64))
    frames[55:70] += img
    engine.contacts = _Scripted([[Fpos[i]]])
    try:
        core = SkinCore(engine, PipelineConfig(baseline_frames=50), name="s")
        out = []
        for k, f in enumerate(frames):
            out += core.process_frame(f, k * 0.01, k)
        core.flush_gestures()
        ids = {c.track_id for c in out}
        assert ids == {1, 2}
        # both fingers landed in one frame (no change of shape) on a skin that counts two at
        # no separation: not sure of two, the tap is held back, never said as a tap
        assert core.take_gestures() == [] and core._recognizer.n_held == 1
        core = SkinCore(engine, PipelineConfig(baseline_frames=50), name="s")
        core._recognizer.two_point_mm = None  # the threshold unknown: two tracks, two fingers
        out = []
        for k, f in enumerate(frames):
            out += core.process_frame(f, k * 0.01, k)
        core.flush_gestures()
        second = [c for c in out if c.track_id == 2 and c.state == "start"][0]
        assert np.linalg.norm(np.subtract(second.raw_m, Fpos[j])) < 0.015
        assert [g["kind"] for g in core.take_gestures()] == ["two_finger_tap"]
    finally:
        del engine.contacts


def test_a_held_track_outlives_a_weak_image_whose_contact_wanders_far():
    # the contact slips far for several frames, never twice in the same place: no candidate
    # is confirmed, so the finger's track is held (not ended by misses) and goes on after
    tr = _tracker(miss=1, confirm=2)
    _step(tr, 0.00, A, start=True)
    _step(tr, 0.01, A)
    for k, p in enumerate([B, C, B, C, B]):
        assert _step(tr, 0.02 + 0.01 * k, p) == [(1, 0, "move")]
        assert np.allclose(tr.tracks[0].last_m, A)
    assert _step(tr, 0.08, A + 0.001) == [(1, 0, "move")]
    assert tr.next_id == 2


def test_pair_prior_weighs_the_mean_of_its_window_not_each_frame():
    # one weak frame between strong ones: the window's means still reach the thresholds
    fits = [_Fit(0.5, 12.0, A, B), _Fit(0.05, 2.0, A, B), _Fit(0.5, 12.0, A, B)]
    tr, _ = _pair_tracker(fits)
    _step(tr, 0.0, A, start=True)
    assert [len(_step(tr, k * 0.01, A)) for k in (1, 2, 3)] == [1, 1, 2]
    # three frames just under on average: nothing
    tr, _ = _pair_tracker([_Fit(0.14, 12.0, A, B)])
    _step(tr, 0.0, A, start=True)
    assert [len(_step(tr, k * 0.01, A)) for k in range(1, 8)] == [1] * 7


def test_frames_where_the_search_saw_two_count_towards_the_pair():
    # the search reports the second finger in one frame, the anchored fit in the next two:
    # together three frames of evidence, and the candidate the search started is confirmed
    tr, prior = _pair_tracker([_Fit(0.5, 12.0, A, B)])
    _step(tr, 0.00, A, start=True)
    _step(tr, 0.01, A, B)
    assert prior.run == 1 and prior.refit.calls == 0
    assert _step(tr, 0.02, A) == [(1, 0, "move")]
    assert _step(tr, 0.03, A) == [(1, 0, "move"), (2, 1, "start")]


def test_pair_prior_fits_at_most_max_fits_per_touch_whatever_the_timestamps():
    # frames stamped 1 us apart (a replay as fast as it goes): the time window never closes,
    # the cap on fits per touch does; a new touch may fit again
    from skinloc.live.pair_prior import PairRule

    tr, prior = _pair_tracker([_Fit(0.0, 0.0, A, B)], PairRule(max_fits=5))
    _step(tr, 0.0, A, start=True)
    for k in range(1, 20):
        _step(tr, k * 1e-6, A)
    assert prior.refit.calls == 5
    tr.end_all()
    _step(tr, 1.0, A, start=True)
    _step(tr, 1.0 + 1e-6, A)
    assert prior.refit.calls == 6


_REPLAY = """
import json
import sys
from numba.core.registry import CPUDispatcher
from skinloc.live.core import SkinCore
from skinloc.sim.gestures import GestureScript
from skinloc.sim.hand import ScriptedHand, script_items
from skinloc.sim.skin import SimulatedSkin

def compiled():
    return {f"{m}.{a}": len(v.signatures) for m, mod in list(sys.modules.items())
            if m.startswith("skinloc") for a, v in vars(mod).items()
            if isinstance(v, CPUDispatcher)}

core = SkinCore(sys.argv[1])
before = compiled()
skin = SimulatedSkin(random_state=0)
script = GestureScript(skin.mesh, 5, n_touches=0, random_state=3,
                       draw_touch=lambda rng: skin.draw_touch(rng, weak=False))
items = script_items(script, 60.0, skin)
hand = ScriptedHand(items, t0=1.0, ramp_s=script.timing.ramp_s)
slots = set()
with skin:
    for k in range(int((hand.end_s + 2.0) * 100)):
        fingers = hand(k * 0.01)
        if fingers is not None:
            skin.touch(fingers)
        slots |= {c.slot for c in core.process_frame(skin.read().values, k * 0.01, k)}
after = compiled()
print(json.dumps({"slots": sorted(slots),
                  "late": sorted(n for n in after if after[n] != before.get(n, 0))}))
"""


def test_no_kernel_compiles_on_a_touch_the_core_warms_them_all_up():
    # A kernel compiled on a touch holds up the live loop (seconds on a cold numba cache): the
    # frames read after it all carry one late arrival time, and a two-finger tap's second
    # finger became a one-frame track half a second after its lift. A fresh process (where
    # nothing was compiled yet) replays a gesture script, a two-finger tap first, through a
    # core: every kernel it calls must have been compiled (or loaded) with the core.
    import subprocess
    import sys

    from tests._helpers import SRC

    path = os.pathsep.join(p for p in (str(SRC), os.environ.get("PYTHONPATH")) if p)
    env = {**os.environ, "PYTHONPATH": path}
    res = subprocess.run(
        [sys.executable, "-c", _REPLAY, str(model_path("map"))],
        capture_output=True, text=True, env=env, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stderr[-2000:]
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert got["slots"] == [0, 1]  # the two-finger tap was seen as two fingers
    assert got["late"] == [], "compiled on a touch, not with the core"


def _landing_frames(img_a, img_b, lag, sigma, rng):
    """Raw frames (noise ``sigma (64,)`` counts): finger A ramping up, B ``lag`` frames later."""
    ramp = np.r_[0.25, 0.5, 0.75, np.ones(8), 0.75, 0.5, 0.25]
    frames = 1000.0 + sigma * rng.standard_normal((60 + len(ramp) + lag + 40, 64))
    frames[60 : 60 + len(ramp)] += ramp[:, None] * img_a
    if img_b is not None:
        frames[60 + lag : 60 + lag + len(ramp)] += ramp[:, None] * img_b
    return frames


@pytest.mark.parametrize(("second", "kind"), [(False, "tap"), (True, "two_finger_tap")])
def test_a_second_finger_landing_later_makes_the_tap_two_finger_whatever_the_search(second, kind):
    # the scripted search sees one contact, the tracker one track (the fingers 25 mm apart):
    # the image's change as the second finger lands is what tells a two-finger tap
    engine = load_engine(model_path("map"))
    rule = engine.rule
    assert rule.landing_change > rule.landing_hold > 1.0  # calibrated in fit
    t = engine.search_tables()
    Fpos, Ft, w = t.arrays[7], t.arrays[6], t.arrays[0]
    i = int(np.argmax(Fpos[:, 2]))
    j = int(np.argmin(np.abs(np.linalg.norm(Fpos - Fpos[i], axis=1) - 0.025)))
    unit = 1.0 / w.astype(float)  # the model's noise per sensor, counts
    img_a = 40.0 * unit * Ft[i] / Ft[i].max()  # 40 noise levels at its peak
    img_b = 40.0 * unit * Ft[j] / Ft[j].max() if second else None
    frames = _landing_frames(img_a, img_b, 3, unit, np.random.default_rng(4))
    engine.contacts = _Scripted([[Fpos[i]]])
    try:
        core = SkinCore(engine, PipelineConfig(baseline_frames=50), name="s")
        core._tracker.pair = None  # nor the anchored fit: one track whatever the image
        for k, f in enumerate(frames):
            core.process_frame(f, k * 0.01, k)
        core.flush_gestures()
        events = core.take_gestures()
        assert [g["kind"] for g in events] == [kind]
        assert (events[0]["confidence"] < 1.0) == second  # a count from the change: less sure
    finally:
        del engine.contacts


def test_the_core_hands_its_recogniser_the_skins_two_point_threshold():
    import dataclasses

    from skinloc.models.multi_contact.two_point import recogniser_mm, two_point_of

    engine = load_engine(model_path("map"))
    core = SkinCore(engine, name="s")
    want, _ = recogniser_mm(two_point_of(engine.spec.contact_rule))
    assert want is not None and core._recognizer.two_point_mm == want
    # a rule that has no threshold (saved before it): unknown, the rule is off
    rule = {k: v for k, v in engine.spec.contact_rule.items() if k != "two_point"}
    engine.spec = dataclasses.replace(engine.spec, contact_rule=rule)
    assert SkinCore(engine, name="s")._recognizer.two_point_mm is None
    # measured, counted two at no separation: no separation is sure
    none = {"counted_two_mm": None, "threshold_mm": None, "bins": {}}
    engine.spec = dataclasses.replace(engine.spec, contact_rule={**rule, "two_point": none})
    assert SkinCore(engine, name="s")._recognizer.two_point_mm == math.inf


def test_the_core_scores_a_touchs_footprint_for_its_recogniser():
    import dataclasses

    from skinloc.models.multi_contact.footprint import features_of

    engine = load_engine(model_path("map"))
    rule = engine.rule
    assert SkinCore(engine, name="s")._footprint is None  # off unless asked for
    core = SkinCore(engine, PipelineConfig(baseline_frames=50, footprint_gestures=True), name="s")
    assert core._recognizer.footprint_levels == (rule.footprint_two, rule.footprint_hold)
    t = engine.search_tables()
    i = int(np.argmax(t.Fpos[:, 2]))
    unit = 1.0 / t.w.astype(float)
    img = 40.0 * unit * t.Ft[i] / t.Ft[i].max()
    frames = _landing_frames(img, None, 0, unit, np.random.default_rng(5))
    scores = []
    fw = core._footprint
    step = fw.step

    def scored_step():
        # the frame's own score, from the search's image and one-contact row
        st = t.scratch[-1]
        if st[5] > 0 and t.scratch[0].max() >= rule.z_on:
            z, u = t.scratch[0].astype(float), t.Ft[int(st[11])].astype(float)
            f = features_of(z[None], u[None])[0]
            scores.append((float(f @ rule.footprint_weights), float(f[7])))
        return step()

    fw.step = scored_step
    for k, f in enumerate(frames):
        core.process_frame(f, k * 0.01, k)
    fw = core._footprint
    assert fw.n == len(scores) >= 5
    # the touch's strong frames (the ramps' weak ones left out)
    s, peak = np.array(scores).T
    strong = peak >= peak.max() + np.log(0.7)
    assert 0 < strong.sum() < len(s)
    assert fw.mean == pytest.approx(s[strong].mean(), rel=1e-4, abs=1e-4)
    assert fw.mean < rule.footprint_hold  # one finger: surely one
    # a rule saved before the cue: no watch, no levels
    old = {k: v for k, v in engine.spec.contact_rule.items() if not k.startswith("footprint")}
    engine.spec = dataclasses.replace(engine.spec, contact_rule=old)
    engine.rule = type(rule).from_dict(old)
    try:
        core = SkinCore(engine, PipelineConfig(footprint_gestures=True), name="s")
        assert core._footprint is None and core._recognizer.footprint_levels is None
    finally:
        engine.rule = rule


def test_one_wrong_contact_within_the_gate_does_not_cut_a_moving_finger():
    # a finger swiping 3 mm a frame; the localiser's answer slips 28 mm back for one frame
    # (within the gate: the track follows it); the next right answer is beyond the gate from
    # the slip but on the finger's path: the same finger moving on, not a second one (the
    # track was held, then ended and restarted: a swipe delivered as two tracks)
    tr = _tracker()
    step = np.array([0.003, 0.0, 0.0])
    p = [A + k * step for k in range(12)]
    _step(tr, 0.0, p[0], start=True)
    for k in range(1, 6):
        _step(tr, 0.01 * k, p[k])
    slip = p[5] - np.array([0.028, 0.0, 0.0])
    assert _step(tr, 0.06, slip) == [(1, 0, "move")]
    for k in range(7, 12):
        assert _step(tr, 0.01 * k, p[k]) == [(1, 0, "move")]
        assert np.allclose(tr.tracks[0].last_m, p[k])
    assert tr.next_id == 2
    # a contact beyond the gate of every recent answer is still a second finger: held
    tr = _tracker()
    _step(tr, 0.00, A, start=True)
    for k in range(1, 4):
        _step(tr, 0.01 * k, A + k * step)
    far = A + 3 * step + np.array([0.0, 0.035, 0.0])
    assert _step(tr, 0.04, far) == [(1, 0, "move")]
    assert np.allclose(tr.tracks[0].last_m, A + 3 * step)
    # answers that moved steadily (no jump): the gate holds from the last one only, and a
    # contact 29 mm from an earlier answer but 31 mm from the last is a second finger
    tr = _tracker()
    _step(tr, 0.00, A, start=True)
    for k in range(1, 4):
        _step(tr, 0.01 * k, A + k * step)
    beside = A + np.array([-0.004, 0.0281, 0.0])
    assert _step(tr, 0.04, beside) == [(1, 0, "move")]
    assert np.allclose(tr.tracks[0].last_m, A + 3 * step)


def test_pair_prior_starts_no_finger_again_on_the_evidence_that_started_the_last():
    # the second finger the prior started ends when its anchored fit falls below the keep
    # thresholds; the frames that started it are spent: one weaker frame after it does not
    # start another (a two-finger tap's finger restarted while down, or a ghost after it lifted)
    good = _Fit(0.5, 12.0, A, B)
    tr, prior = _pair_tracker([good])
    _step(tr, 0.00, A, start=True)
    for k in (1, 2, 3):
        _step(tr, 0.01 * k, A)
    assert tr.slots[1] is not None
    prior.refit.fits = [_Fit(0.01, 1.0, A, B)]
    _step(tr, 0.04, A)
    assert _step(tr, 0.05, A) == [(1, 0, "move"), (2, 1, "end")]
    prior.refit.fits = [_Fit(0.2, 4.0, A, B)]  # alone under the start's means
    assert _step(tr, 0.06, A) == [(1, 0, "move")]
    # fresh evidence over start_frames frames starts a finger again
    prior.refit.fits = [good]
    assert [len(_step(tr, t, A)) for t in (0.07, 0.08)] == [1, 2]


def _identity(x, y, z, out):
    out[:] = (x, y, z)


def test_a_quick_strokes_answer_that_leaps_goes_on_as_the_same_track():
    # a quick stroke on a coarse map (bench/app_strokes.py): the answer creeps near the landing
    # point while the finger moves on, then leaps 52 mm to where it is. No second finger was
    # confirmed in the touch (one contact a frame, bar a one-frame ghost beside it): the same
    # finger, one track, moved there once the far answer has held for the confirm frames
    tr = Tracker(3, 30.0, 1, 4, _identity, None)  # the pipeline's gate, misses and confirm
    creep = np.array([0.0, 0.001, 0.0])
    _step(tr, 0.00, A, start=True)
    for k in range(1, 8):
        assert _step(tr, 0.01 * k, A + k * creep) == [(1, 0, "move")]
    far = A + np.array([0.0, 0.06, 0.0])
    assert _step(tr, 0.08, A + 8 * creep, far) == [(1, 0, "move")]
    for k in range(9, 11):  # held while the far answer's candidate waits
        assert _step(tr, 0.01 * k, far) == [(1, 0, "move")]
        assert np.allclose(tr.tracks[0].last_m, A + 8 * creep) and tr.leapt == []
    assert _step(tr, 0.11, far) == [(1, 0, "move")]  # its 4th frame: the same finger, there
    assert tr.leapt == [1] and np.allclose(tr.tracks[0].last_m, far)
    for k in range(12, 16):
        assert _step(tr, 0.01 * k, far + (k - 11) * 3 * creep) == [(1, 0, "move")]
    assert tr.leapt == [] and tr.next_id == 2
    assert [t.track_id for t in tr.end_all()] == [1] and tr.single


def test_a_second_contact_in_two_frames_running_is_a_finger_the_held_track_ends():
    # the same leap, but the far contact was seen beside the track in two frames running: a
    # second finger may have landed, and the held track ends when the far one is confirmed
    tr = Tracker(3, 30.0, 1, 4, _identity, None)
    _step(tr, 0.00, A, start=True)
    for k in range(1, 8):
        _step(tr, 0.01 * k, A)
    far = A + np.array([0.0, 0.06, 0.0])
    _step(tr, 0.08, A, far)
    assert _step(tr, 0.09, A, far) == [(1, 0, "move")] and not tr.single
    assert _step(tr, 0.10, far) == [(1, 0, "move")]  # held
    assert _step(tr, 0.11, far) == [(1, 0, "end"), (2, 1, "start")] and tr.leapt == []
