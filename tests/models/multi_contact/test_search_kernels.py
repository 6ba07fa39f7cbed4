"""The search's shortcuts give the answers of the plain kernels they stand for."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.models.engine import load_engine
from skinloc.models.multi_contact.search import (
    _dot,
    _dot2,
    _rounds,
    nnls,
    nnls2,
    nnls2_interior,
    nnls3_interior,
    polish,
)
from tests._live import model_path


@pytest.fixture(scope="module")
def engine():
    return load_engine(model_path("map"))


def _grams(rng: np.random.Generator, n: int, m: int):
    for _ in range(n):
        A = rng.normal(size=(8, m)) + rng.uniform(-0.5, 1.5)
        yield A.T @ A, A.T @ rng.normal(size=8)


def test_interior_nnls_keeps_exactly_the_all_positive_answers():
    rng = np.random.default_rng(0)
    kept = 0
    for G, b in _grams(rng, 2000, 3):
        s, si = np.zeros(3), np.zeros(3)
        g = nnls(G, b, 3, s)
        gi = nnls3_interior(G, b, si)
        if (s > 0.0).all():
            kept += 1
            assert gi == pytest.approx(g, rel=1e-12)
            np.testing.assert_allclose(si, s, rtol=1e-12)
        else:
            assert gi == -1.0
    for G, b in _grams(rng, 2000, 2):
        g, s1, s2 = nnls2(G[0, 0], G[0, 1], G[1, 1], b[0], b[1])
        gi, t1, t2 = nnls2_interior(G[0, 0], G[0, 1], G[1, 1], b[0], b[1])
        if s1 > 0.0 and s2 > 0.0:
            assert (gi, t1, t2) == pytest.approx((g, s1, s2), rel=1e-12)
        else:
            assert gi == -1.0
    assert kept > 100  # both branches were exercised


def test_a_settled_polish_then_one_round_with_spreads_is_the_polish_with_spreads(engine):
    t = engine.search_tables()
    w, Ft = t.arrays[0], t.arrays[6]
    S = t.scratch.fresh()
    rng = np.random.default_rng(1)
    min2 = float(t.prm[1])
    settled_seen = 0
    for _ in range(40):
        a, b = rng.choice(len(Ft), 2, replace=False)
        x = (rng.uniform(20, 80) * Ft[a] + rng.uniform(20, 80) * Ft[b]) / w
        x = (x + rng.normal(0.0, 2.0, x.shape)).astype(np.float32)
        xw = (x * w).astype(np.float32)
        xx = float(np.dot(xw.astype(np.float64), xw.astype(np.float64)))
        start = rng.choice(len(Ft), 2, replace=False)
        ref = start.astype(np.int64).copy()
        g_ref = polish(2, ref, xw, xx, t.arrays, min2, S)
        s_ref, sp_ref = S[8][:2].copy(), S[9][:2].copy()
        fi = start.astype(np.int64).copy()
        g, settled = _rounds(2, fi, xw, xx, t.arrays, min2, S, 2, False)
        assert g == g_ref
        np.testing.assert_array_equal(fi[:2], ref[:2])
        if settled:
            settled_seen += 1
            polish(2, fi, xw, xx, t.arrays, min2, S, 1, True)
            np.testing.assert_array_equal(fi[:2], ref[:2])
            np.testing.assert_allclose(S[8][:2], s_ref, rtol=1e-12)
            np.testing.assert_allclose(S[9][:2], sp_ref, rtol=1e-12, equal_nan=True)
    assert settled_seen > 0


def test_two_dot_products_in_one_pass_are_the_single_ones_bit_for_bit(engine):
    # the refinement's candidates and the third contact's scan take both products of a row at
    # once: the answers stay bitwise those of the search with one product at a time
    Ft = engine.search_tables().arrays[6]
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 20.0, Ft.shape[1]).astype(np.float32)
    for q in rng.choice(len(Ft), 300, replace=False):
        other = Ft[(q + 7) % len(Ft)]
        assert _dot2(Ft[q], x, other) == (_dot(Ft[q], x), _dot(Ft[q], other))
