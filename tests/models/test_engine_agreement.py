"""The engine's per-frame path agrees with its batches (the model's prediction); snap and
projection are exact."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from skinloc.geometry.mesh import cone_skin, nearest_on_surface, surface_points
from skinloc.geometry.snap import SnapIndex, closest_on_triangles
from skinloc.models.engine import ModelSpec, load_engine
from skinloc.models.localizer import ContactLocalizer
from tests._live import calibration, model_path

#: Two computations of the same contact agree when within this, m: a micrometre, a thousandth
#: of the localiser's millimetre accuracy; float32 networks summed in a different order (BLAS
#: blocking, thread count, batch size) differ by ~1e-8 m, never by this much.
SAME_M = 1e-6


def same_on_surface(a: np.ndarray, b: np.ndarray, raw: np.ndarray, tol_m: float = SAME_M):
    """Rows where surface points ``a`` and ``b`` (n, 3) m agree for ``raw`` (n, 3) m.

    They agree when within ``tol_m`` of each other, or when the raw prediction is equally near
    both (within ``tol_m``): a snap near a tie may pick either neighbour and both are right.
    """
    close = np.linalg.norm(a - b, axis=1) <= tol_m
    tie = np.abs(np.linalg.norm(a - raw, axis=1) - np.linalg.norm(b - raw, axis=1)) <= 2 * tol_m
    return close | tie


@pytest.mark.parametrize("kind", ["map", "mlp", "paper", "gelu"])
def test_fast_path_matches_predict_full(kind):
    model = ContactLocalizer.load(model_path(kind))
    fast = load_engine(model)
    X = calibration().deltas.reshape(-1, 64)
    ref = model.predict_full(X)
    points, raw, spread = fast.predict_batch(X.astype(np.float32))
    np.testing.assert_allclose(raw, ref.raw, atol=SAME_M)
    if kind == "map":  # candidates a float rounding apart in match distance may swap
        assert np.mean(np.linalg.norm(points - ref.points, axis=1) <= SAME_M) > 0.99
    else:
        assert same_on_surface(points, ref.points, ref.raw).all()
    out = np.empty(7)
    for x, r, p in zip(X[:40], ref.raw[:40], ref.points[:40], strict=True):
        fast.localise_into(x.astype(np.float32), out)
        np.testing.assert_allclose(out[:3], r, atol=SAME_M)
        assert kind == "map" or same_on_surface(out[None, 3:6], p[None], r[None]).all()
    if fast.n_members > 1 or kind == "map":
        np.testing.assert_allclose(spread, ref.uncertainty_mm, atol=1e-3)


def test_batches_larger_than_a_block_give_the_same_rows():
    # predict_batch runs networks in blocks of 65,536 rows: the block edge must not show
    fast = load_engine(ContactLocalizer.load(model_path("mlp")))
    X = calibration().deltas.reshape(-1, 64).astype(np.float32)
    big = np.tile(X, (70_000 // len(X) + 1, 1))[:70_000]
    points, raw, spread = fast.predict_batch(big)
    edge = slice(65_530, 65_540)
    p2, r2, s2 = fast.predict_batch(big[edge])
    # The same rows in another batch size sum in another order (BLAS blocking and threads):
    # the same contact to within a micrometre, the same surface point, not the same bits.
    np.testing.assert_allclose(raw[edge], r2, rtol=0, atol=SAME_M)
    assert same_on_surface(points[edge], p2, r2).all()
    np.testing.assert_allclose(spread[edge], s2, rtol=0, atol=1e-3)  # mm: a micrometre


def test_spec_from_file_equals_spec_from_model():
    path = model_path("mlp")
    a = ModelSpec.load(path)
    b = ModelSpec.from_localizer(ContactLocalizer.load(path))
    for W, V in zip(a.weights, b.weights, strict=True):
        np.testing.assert_array_equal(W, V)
    assert a.layer_sizes == [64, 24, 16, 3] and a.n_members == 3


def test_spec_rejects_layers_that_do_not_chain():
    spec = ModelSpec.load(model_path("paper"))
    with pytest.raises(ValueError, match="do not chain"):
        type(spec)(**{**spec.__dict__, "weights": [spec.weights[1], spec.weights[0]]})


def test_snap_index_is_exact(seed):
    rng = np.random.default_rng(seed)
    pts = surface_points(cone_skin(), 3000, random_state=seed)
    index = SnapIndex(pts)
    q = pts[rng.integers(len(pts), size=300)] + rng.normal(0, 0.01, (300, 3))
    q[:10] += 0.3  # far outside the grid
    want = cKDTree(pts).query(q)[1]
    got = index.query(q)
    d_want = np.linalg.norm(pts[want] - q, axis=1)
    d_got = np.linalg.norm(pts[got] - q, axis=1)
    np.testing.assert_allclose(d_got, d_want, rtol=0, atol=1e-15)


def test_closest_on_triangles_matches_trimesh(seed):
    rng = np.random.default_rng(seed)
    mesh = trimesh.creation.icosphere(subdivisions=1, radius=0.05)
    q = rng.normal(0, 0.06, (200, 3))
    got = closest_on_triangles(q, mesh.triangles)
    want = nearest_on_surface(mesh, q)[0]
    np.testing.assert_allclose(
        np.linalg.norm(got - q, axis=1), np.linalg.norm(want - q, axis=1), atol=1e-12
    )


def test_project_and_none_constraints():
    model = ContactLocalizer.load(model_path("mlp"))
    spec = ModelSpec.from_localizer(model)
    X = calibration().touch_means.astype(np.float32)
    raw = spec.engine("none").predict_batch(X)[0]
    proj = spec.engine("project").predict_batch(X)[0]
    np.testing.assert_allclose(raw, model.predict_full(X).raw, atol=1e-6)
    want = nearest_on_surface(model.mesh, raw)[0]
    np.testing.assert_allclose(
        np.linalg.norm(proj - raw, axis=1), np.linalg.norm(want - raw, axis=1), atol=1e-6
    )
    assert nearest_on_surface(model.mesh, proj)[1].max() < 1e-7  # on the skin
    with pytest.raises(ValueError, match="output constraint"):
        spec.engine("wobble")
