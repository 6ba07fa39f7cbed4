"""The anchored two-contact fit (``skinloc.models.multi_contact.refit``) on a trained map model."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.models.engine import load_engine
from skinloc.models.multi_contact.refit import PairRefit
from tests._live import model_path


@pytest.fixture(scope="module")
def engine():
    return load_engine(model_path("map"))


def _image(engine, rows, strength=60.0):
    t = engine.search_tables()
    Ft, w = t.arrays[6], t.arrays[0]
    return (strength * sum(Ft[r].astype(float) for r in rows) / w).astype(np.float32)


def test_two_fingers_give_a_large_reduction_and_the_second_place(engine):
    fpos = engine.search_tables().arrays[7]
    refit = PairRefit(engine)
    rng = np.random.default_rng(0)
    for _ in range(5):
        i = int(rng.integers(len(fpos)))
        far = np.flatnonzero(np.linalg.norm(fpos - fpos[i], axis=1) > 0.045)
        j = int(rng.choice(far))
        x = _image(engine, [i, j]) + rng.normal(0, 1.0, 64).astype(np.float32)
        fit = refit.fit(x, fpos[i] + 0.003)
        assert fit is not None
        assert fit.ratio > 1.0 and fit.z2 > 5.0
        assert np.linalg.norm(fit.first_m - fpos[i]) < 0.012
        assert np.linalg.norm(fit.second_m - fpos[j]) < 0.012


def test_one_finger_gives_little_for_a_second_and_the_engine_scratch_is_untouched(engine):
    fpos = engine.search_tables().arrays[7]
    refit = PairRefit(engine)
    rng = np.random.default_rng(1)
    before = [a.copy() for a in engine.search_tables().scratch]
    for _ in range(5):
        i = int(rng.integers(len(fpos)))
        x = _image(engine, [i]) + rng.normal(0, 1.0, 64).astype(np.float32)
        fit = refit.fit(x, fpos[i])
        assert fit is None or fit.ratio < 0.1 or fit.z2 < 3.0
    after = engine.search_tables().scratch
    assert all(np.array_equal(a, b) for a, b in zip(before, after, strict=True))


def test_an_engine_without_the_search_has_no_pair_prior():
    from skinloc.live.pair_prior import pair_prior

    class NoSearch:  # an engine whose kind has no contact search (a network)
        def search_tables(self):
            return None

    assert pair_prior(NoSearch(), np.zeros(64, np.float32)) is None
