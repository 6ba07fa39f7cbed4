"""A stream's search memory (``SearchMemory``): the full search's answers on fixed frames."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from skinloc.models.engine import load_engine
from skinloc.models.multi_contact.search import REFRESH_FRAMES, SearchMemory
from tests._live import calibration, model_path, stream


@pytest.fixture(scope="module")
def engine():
    return load_engine(model_path("map"))


def _held(frames: np.ndarray, n: int) -> np.ndarray:
    """``n`` frames of one held touch: its frames back and forth (a touch's own variation)."""
    order = np.r_[np.arange(len(frames)), np.arange(len(frames) - 2, 0, -1)]
    return frames[np.resize(order, n)]


@pytest.fixture(scope="module")
def streams():
    """Held single touches, held pairs and second fingers landing on a held one."""
    cal = calibration()
    d = cal.deltas.astype(np.float32)
    far = [
        (a, b)
        for a, b in itertools.combinations(range(len(d)), 2)
        if np.linalg.norm(cal.targets[a] - cal.targets[b]) > 0.045
    ][::9]
    n = 3 * REFRESH_FRAMES // 2  # past one refresh of the memory
    single = [_held(d[a], n) for a in range(len(d))]
    pairs = [_held(d[a], n) + _held(d[b], n) for a, b in far]
    landing = []
    for a, b in far:
        s = _held(d[a], n)
        s[n // 2 :] += _held(d[b], n - n // 2)
        landing.append(s)
    return {"single": single, "pairs": pairs, "landing": landing}


def _answers(engine, X: np.ndarray, memory: SearchMemory | None) -> list[np.ndarray]:
    return [engine.contacts(x, 3, memory).rows.copy() for x in X]


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return len(a) == len(b) and np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True)


def test_held_single_touches_and_pairs_give_the_full_searchs_answers(engine, streams):
    n_fast = 0
    for kind in ("single", "pairs"):
        for X in streams[kind]:
            mem = SearchMemory()
            full = _answers(engine, X, None)
            for x, ref in zip(X, full, strict=True):
                got = engine.contacts(x, 3, mem).rows
                assert _same(got, ref), kind
                n_fast += mem.state[3] > 0
    assert n_fast > 0  # the memory answered some frames itself


def test_a_landing_second_finger_is_counted_as_the_full_search_counts_it(engine, streams):
    n = changed = 0
    for X in streams["landing"]:
        mem = SearchMemory()
        for x in X:
            ref = engine.contacts(x, 3).rows.copy()
            got = engine.contacts(x, 3, mem).rows
            n += 1
            if not _same(got, ref):
                changed += 1
                # the memory only ever answers one contact; more is always the full search's
                assert len(got) == 1 and len(ref) > 1
    assert changed <= 0.01 * n


def test_a_frame_with_nothing_touched_is_none_and_a_reset_forgets(engine):
    cal = calibration()
    x = cal.deltas[0, 0].astype(np.float32)
    mem = SearchMemory()
    engine.contacts(x, 3, mem)
    engine.contacts(x, 3, mem)
    assert mem.state[0] == 1.0 and mem.state[3] == 1.0  # the second frame from the memory
    assert len(engine.contacts(np.zeros_like(x), 3, mem)) == 0
    assert mem.state[0] == 0.0
    engine.contacts(x, 3, mem)
    mem.reset()
    assert not mem.state.any()


def test_the_live_loop_emits_the_same_contacts_with_and_without_the_memory(engine):
    from skinloc.live.core import PipelineConfig, SkinCore

    frames, _ = stream(1200)
    outs = []
    for use in (False, True):
        core = SkinCore(engine, PipelineConfig(max_contacts=3))
        if not use:
            core.search_memory = None
        # frame-count timestamps: the filters see the same times in both runs
        outs.append([core.process_frame(f, 0.01 * i, i) for i, f in enumerate(frames)])
    touched = 0
    for a, b in zip(*outs, strict=True):
        assert [(c.state, c.track_id) for c in a] == [(c.state, c.track_id) for c in b]
        for p, q in zip(a, b, strict=True):
            np.testing.assert_allclose(p.position_m, q.position_m, rtol=0, atol=1e-9)
        touched += bool(a)
    assert touched > 100


def test_a_rule_that_counts_any_pair_never_divides_by_its_zero_threshold(streams):
    """A small session's rule may have tau2 0 (no held-out single touch reached z2_min): the
    memory's safety score is then unbounded, and the stream keeps the full search's answers
    (it raised ZeroDivisionError in the compiled score and stopped the live loop)."""
    from skinloc.models.localizer import ContactLocalizer

    model = ContactLocalizer.load(model_path("map"))
    model.contact_rule_ = {**model.contact_rule_, "tau2": 0.0}
    engine = load_engine(model)
    assert engine.search_tables().prm[2] == 0.0
    for X in streams["single"][:5] + streams["pairs"][:5]:
        mem = SearchMemory()
        for x in X:
            ref = engine.contacts(x, 3).rows.copy()
            assert _same(engine.contacts(x, 3, mem).rows, ref)
