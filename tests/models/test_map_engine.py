"""The response-map engine's pruned coarse search: exact, and the same alone or in a batch."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from skinloc.models.localizer import ContactLocalizer
from skinloc.models.map_engine import MapEngine, MapSpec
from skinloc.models.map_match import _group_coarse
from tests._live import calibration, model_path


def _frames(n_features: int, seed: int = 0) -> np.ndarray:
    """Real-like and awkward frames: touches, noise of every scale, zeros, negatives."""
    rng = np.random.default_rng(seed)
    real = calibration().deltas.reshape(-1, 64).astype(np.float32)[:, :n_features]
    return np.concatenate(
        [
            real,
            real * rng.uniform(0.05, 3.0, size=(len(real), 1)).astype(np.float32),
            rng.normal(0.0, 50.0, size=(300, n_features)),
            rng.normal(0.0, 0.3, size=(100, n_features)),  # norm under one count: not scaled
            -np.abs(rng.normal(0.0, 40.0, size=(50, n_features))),  # nothing left once clipped
            np.zeros((20, n_features)),
        ]
    ).astype(np.float32)


def _exhaustive(spec: MapSpec, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every coarse point measured, in float64: ``(point (n, 3), d (n, P))``.

    ``d`` is the squared feature distance of each row to every candidate, for judging ties.
    """
    T = np.asarray(spec.table, dtype=np.float64)
    sq = (T**2).sum(axis=1)
    Z = np.maximum(X, 0.0) if spec.clip_negative else X.astype(np.float64)
    F = Z / np.maximum(np.linalg.norm(Z, axis=1, keepdims=True), 1.0)
    d = sq[None, :] - 2.0 * F @ T.T + (F**2).sum(axis=1, keepdims=True)
    nb = min(spec.n_cells, len(spec.coarse))
    best_cells = np.argsort(d[:, spec.coarse], axis=1, kind="stable")[:, :nb]
    idx = spec.cells[best_cells].reshape(len(X), -1)
    best = idx[np.arange(len(X)), np.argmin(np.take_along_axis(d, idx, axis=1), axis=1)]
    return spec.surface_points[best], d


def _assert_exact(engine: MapEngine, spec: MapSpec, X: np.ndarray) -> None:
    """The engine's batch, its single frames and the exhaustive search agree.

    Batch and single frame: the same point, spread to 1e-9 mm. Against the float64 search, a
    different point only at a tie (its distance within float32 rounding of the least).
    """
    points, raw, spread = engine.predict_batch(X)
    np.testing.assert_array_equal(points, raw)
    out = np.empty(7)
    for i, x in enumerate(X):
        engine.localise_into(x, out)
        np.testing.assert_allclose(out[3:6], points[i], rtol=0, atol=1e-6)  # 1 um
        assert abs(out[6] - spread[i]) <= 1e-9
    ref, d = _exhaustive(spec, X)
    differ = np.flatnonzero(np.abs(points - ref).max(axis=1) > 1e-9)
    pos = {tuple(p): j for j, p in enumerate(np.asarray(spec.surface_points))}
    for i in differ:
        got = pos[tuple(points[i])]
        want = pos[tuple(ref[i])]
        assert d[i, got] - d[i, want] <= 1e-5, f"row {i}: not a tie"
    assert len(differ) <= 0.01 * len(X)


@pytest.mark.parametrize("clip", [True, False])
def test_trained_map_batch_frame_and_exhaustive_search_agree(clip):
    spec = dataclasses.replace(ContactLocalizer.load(model_path("map")).spec(), clip_negative=clip)
    engine = MapEngine(spec)
    X = _frames(spec.n_features)
    assert len(X) > 512  # the parallel batch path, not the few-rows one
    _assert_exact(engine, spec, X)
    few = engine.predict_batch(X[:7])  # the few-rows path
    np.testing.assert_array_equal(few[0], engine.predict_batch(X)[0][:7])


def _random_map(P: int, k: int, n_cells: int, seed: int) -> MapSpec:
    """A response map over random points: a smooth table plus noise, cells as the model's."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-0.05, 0.05, size=(P, 3))
    centres = rng.uniform(-0.05, 0.05, size=(k, 3))
    table = np.exp(-(((pts[:, None, :] - centres[None]) ** 2).sum(-1)) / 0.02**2)
    table = table / np.linalg.norm(table, axis=1, keepdims=True) + rng.normal(0, 0.05, (P, k))
    coarse = np.arange(0, P, 16)
    owner = cKDTree(pts[coarse]).query(pts)[1]
    width = np.bincount(owner, minlength=len(coarse)).max()
    cells = np.repeat(coarse[:, None], width, axis=1)
    for c in range(len(coarse)):
        members = np.flatnonzero(owner == c)
        cells[c, : len(members)] = members
    return MapSpec(
        n_features=k,
        clip_negative=True,
        surface_points=pts,
        table=table.astype(np.float32),
        coarse=coarse,
        cells=cells,
        noise=1e-3,
        n_cells=n_cells,
    )


@pytest.mark.parametrize(
    ("P", "k", "n_cells"),
    [(16, 5, 8), (160, 7, 1), (800, 12, 3), (3000, 24, 8), (3000, 24, 400)],
)
def test_pruned_search_is_exact_on_any_map(P, k, n_cells):
    # one coarse point (a single group), cells fewer than n_cells, many groups, all cells
    spec = _random_map(P, k, n_cells, seed=P + k)
    rng = np.random.default_rng(1)
    X = np.concatenate(
        [
            rng.normal(0.0, 30.0, size=(600, k)),
            100.0 * spec.table[rng.integers(0, P, 300)] + rng.normal(0, 2.0, (300, k)),
        ]
    ).astype(np.float32)
    _assert_exact(MapEngine(spec), spec, X)


def test_coarse_groups_cover_every_point_once_and_bound_it():
    ct = ContactLocalizer.load(model_path("map")).spec()
    table = np.asarray(ct.table, dtype=np.float32)[ct.coarse]
    label, centres = _group_coarse(table)
    assert sorted(set(label.tolist())) == list(range(len(centres)))  # no empty group
    assert 1 < len(centres) < len(table)
    engine = MapEngine(ct)
    mu, gmin, gmax_r, gtab, gsq, grad, gcell, goff, eps = engine._groups
    assert sorted(gcell.tolist()) == list(range(len(table)))
    for g in range(len(mu)):
        rows = slice(goff[g], goff[g + 1])
        r = np.linalg.norm(gtab[rows].astype(np.float64) - mu[g], axis=1)
        assert np.all(r <= grad[rows]) and grad[rows].max() <= gmax_r[g]
        assert gmin[g] == gsq[rows].min()
