"""The pruned seed and pair stages give the plain loops' answer (multi_contact.pairs)."""

from __future__ import annotations

import itertools

import numba
import numpy as np
import pytest

from skinloc.data.recording import read_recording
from skinloc.evaluation.scoring import train_localizer
from skinloc.models.engine import load_engine
from skinloc.models.multi_contact.pairs import PairTables, seeds_and_pair
from skinloc.models.multi_contact.search import _dot, _row_norms
from tests._live import calibration, model_path


@numba.njit(fastmath=True)
def _plain_far(p, q, m2):
    d = 0.0
    for t in range(3):
        d += (p[t] - q[t]) ** 2
    return d >= m2


@numba.njit(fastmath=True)
def plain_seeds_and_pair(bC, g1, Cg, Cd, Cpos, min2, top):
    """The search's seed and pair loops as they were before pruning, written plainly.

    Compiled like the search's kernels (``fastmath``), so that two pairs whose gains tie to
    the last bit (a pair and its mirror, both seeds) resolve as in the search.
    """
    C = g1.shape[0]
    n_seeds = 0
    for t in range(top.shape[0]):
        best = -1.0
        bi = -1
        for c in range(C):
            if g1[c] > best:
                best = g1[c]
                bi = c
        if bi < 0:
            break
        top[t] = bi
        n_seeds += 1
        for c in range(C):
            if not _plain_far(Cpos[c], Cpos[bi], 0.25 * min2):
                g1[c] = -1.0
    bestg = -1.0
    pa = -1
    pb = -1
    for t in range(n_seeds):
        a = top[t]
        gaa = float(Cg[a, a])
        ba = bC[a]
        for c in range(C):
            bb = bC[c]
            if bb <= 0.0 or c == a:
                continue
            gab = float(Cg[a, c])
            gbb = Cd[c]
            det = gaa * gbb - gab * gab
            if det <= 1e-12 * gaa * gbb:
                continue
            na = gbb * ba - gab * bb
            nb = gaa * bb - gab * ba
            if na <= 0.0 or nb <= 0.0:
                continue
            if na * ba + nb * bb > bestg * det and _plain_far(Cpos[a], Cpos[c], min2):
                bestg = (na * ba + nb * bb) / det
                pa = a
                pb = c
    return n_seeds, pa, pb


def _stages(tables, X):
    """Per image: the coarse correlations and gains as the search computes them."""
    w, Ct, _, Cd = tables.arrays[:4]
    for x in X:
        xw = (x * w).astype(np.float32)
        bC = np.array([_dot(Ct[c], xw) for c in range(len(Ct))])
        g1 = np.where(bC > 0.0, bC * bC / np.where(bC > 0.0, Cd, 1.0), 0.0)
        yield bC, g1


def _check_same(tables, X):
    _, _, Cg, Cd, Cpos = tables.arrays[:5]
    min2, n_top = float(tables.prm[1]), len(tables.scratch[3])
    pairs_found = 0
    for bC, g1 in _stages(tables, X):
        top_ref = np.zeros(n_top, dtype=np.int64)
        g1_ref = g1.copy()
        n_ref, pa_ref, pb_ref = plain_seeds_and_pair(bC, g1_ref, Cg, Cd, Cpos, min2, top_ref)
        top = np.zeros(n_top, dtype=np.int64)
        g1_new = g1.copy()
        n, pa, pb = seeds_and_pair(bC, g1_new, Cg, Cd, Cpos, min2, top, *tables.pair.kernel_args)
        assert top[:n].tolist() == top_ref[:n_ref].tolist()
        assert (pa, pb) == (pa_ref, pb_ref)
        np.testing.assert_array_equal(g1_new, g1_ref)  # the suppression the search sees after
        pairs_found += pa >= 0
    return pairs_found


@pytest.fixture(scope="module")
def tables():
    return load_engine(model_path("map")).search_tables()


def test_simulated_single_and_multi_touch_frames_give_the_plain_loops_answer(tables):
    cal = calibration()
    means = cal.touch_means.astype(np.float32)
    rng = np.random.default_rng(3)
    n = len(means)
    two = [means[a] + means[b] for a, b in itertools.combinations(range(n), 2)][:60]
    three = [means[rng.choice(n, 3, replace=False)].sum(axis=0) for _ in range(30)]
    frames = cal.deltas.astype(np.float32).reshape(-1, means.shape[1])[::7][:80]
    X = np.concatenate([means, np.array(two), np.array(three), frames])
    assert _check_same(tables, X) > 0


def test_noise_and_odd_images_give_the_plain_loops_answer(tables):
    rng = np.random.default_rng(4)
    k = tables.arrays[1].shape[1]
    X = np.concatenate(
        [
            rng.normal(0.0, 5.0, (20, k)),  # no touch: many weak, scattered candidates
            -np.abs(rng.normal(0.0, 50.0, (5, k))),  # all negative: no positive correlation
            np.zeros((2, k)),  # every gain 0: ties everywhere
            rng.exponential(200.0, (10, k)),  # everything touched
        ]
    ).astype(np.float32)
    _check_same(tables, X)


def test_real_touches_single_and_summed_give_the_plain_loops_answer(real_dir):
    train = read_recording(real_dir / "ConeSkinData80Points_RND_80PL_1.mat")
    tables = train_localizer([train]).engine().search_tables()
    rec = read_recording(real_dir / "ConeSkinData50Points_RND_50PL_1.mat")
    d = rec.deltas.astype(np.float32)
    rng = np.random.default_rng(5)
    singles = d[:, ::10].reshape(-1, d.shape[-1])
    n = rec.n_point_logs
    pairs = [
        d[a, rng.integers(d.shape[1])] + d[b, 0] for a, b in itertools.combinations(range(n), 2)
    ]
    X = np.concatenate([singles, np.array(pairs[::6])])
    assert _check_same(tables, X) > 0


def test_the_precomputed_row_norms_are_the_searchs_own_products(tables):
    Ft = tables.arrays[6]
    Fn = tables.arrays[-1]
    assert Fn.shape == (len(Ft),)
    assert all(Fn[q] == _dot(Ft[q], Ft[q]) for q in range(0, len(Ft), 37))
    np.testing.assert_array_equal(_row_norms(Ft[:50]), Fn[:50])


def test_pair_tables_near_lists_and_bound_factors():
    rng = np.random.default_rng(6)
    pos = rng.uniform(0.0, 0.1, (40, 3))
    U = rng.uniform(0.0, 1.0, (40, 8)).astype(np.float32)
    U[3] = -U[5]  # one exactly opposite pair: the bound of its rows cannot prune
    t = PairTables(U @ U.T, pos, 0.03**2)
    off, idx, kappa = t.arrays
    for a in range(40):
        near = np.flatnonzero(((pos - pos[a]) ** 2).sum(axis=1) < 0.25 * 0.03**2)
        assert idx[off[a] : off[a + 1]].tolist() == near.tolist()
    assert np.all(kappa >= 1.0)
    assert kappa[3] > 1e5 and kappa[5] > 1e5  # no pruning to speak of
