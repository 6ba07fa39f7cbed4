"""Flattening skins for printable target sheets: exact cone unrolling, general unwrapping."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from skinloc.errors import MeshError
from skinloc.geometry.flatten import fit_y_cone, flatten
from skinloc.geometry.mesh import cone_skin, sample_targets


def grid_sheet(height, n: int = 24) -> trimesh.Trimesh:
    """A sheet z = height(x, y) over a 10 x 6 cm rectangle."""
    x, y = np.meshgrid(np.linspace(-0.05, 0.05, n), np.linspace(-0.03, 0.03, n))
    v = np.stack([x.ravel(), y.ravel(), height(x, y).ravel()], axis=1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            faces += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return trimesh.Trimesh(v, faces)


def geodesic_on_cone(p, q, a, b):
    """Distance along the cone r = a y + b between two points on it (no seam between)."""
    apex = -b / a
    sin_half = abs(a) / np.hypot(1.0, a)
    lp = np.hypot(np.hypot(p[0], p[2]), p[1] - apex)
    lq = np.hypot(np.hypot(q[0], q[2]), q[1] - apex)
    dtheta = abs(np.arctan2(p[2], p[0]) - np.arctan2(q[2], q[0]))
    return np.sqrt(lp**2 + lq**2 - 2 * lp * lq * np.cos(dtheta * sin_half))


def test_the_paper_cone_unrolls_exactly():
    mesh = cone_skin()
    flat = flatten(mesh)
    assert flat.kind == "cone" and flat.stretch == 0.0
    a, b = fit_y_cone(mesh)
    rng = np.random.default_rng(0)
    theta = rng.uniform(0, np.pi, (20, 2))
    y = rng.uniform(-0.1, 0.03, (20, 2))
    for (t1, t2), (y1, y2) in zip(theta, y, strict=True):
        p = np.array([(a * y1 + b) * np.cos(t1), y1, (a * y1 + b) * np.sin(t1)])
        q = np.array([(a * y2 + b) * np.cos(t2), y2, (a * y2 + b) * np.sin(t2)])
        flat_d = np.linalg.norm(np.subtract(*flat.map_points(np.stack([p, q]))))
        assert flat_d == pytest.approx(geodesic_on_cone(p, q, a, b), rel=1e-9)
    # The sheet of the paper's skin is about 254 x 164 mm.
    ext = np.ptp(np.concatenate(flat.boundary), axis=0) * 1e3
    assert ext[0] == pytest.approx(254.3, abs=1) and ext[1] == pytest.approx(164.0, abs=1)


def test_the_cone_sheet_is_not_mirrored():
    mesh = cone_skin()
    uv = flatten(mesh).vertices_2d
    t = uv[mesh.faces]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    assert np.all(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0] > 0)


@settings(max_examples=15, deadline=None)
@given(amplitude=st.floats(0.0, 0.012), freq=st.floats(10.0, 60.0))
def test_developable_sheets_unwrap_without_stretch(amplitude, freq):
    flat = flatten(grid_sheet(lambda x, y: amplitude * np.sin(freq * x)))
    assert flat.kind == "unwrap" and flat.stretch < 1e-6


def test_a_curved_sheet_unwraps_with_small_stretch():
    # A spherical cap cannot flatten exactly; ARAP keeps edge lengths within a few percent.
    flat = flatten(grid_sheet(lambda x, y: 6.0 * (x**2 + y**2)))
    assert 1e-3 < flat.stretch < 0.1
    targets = sample_targets(grid_sheet(lambda x, y: 6.0 * (x**2 + y**2)), 5, "random", 0)
    assert flat.map_points(targets).shape == (5, 2)


def test_meshes_that_cannot_be_flattened():
    with pytest.raises(MeshError, match="closed"):
        flatten(trimesh.creation.icosphere())
    two = trimesh.util.concatenate(
        [grid_sheet(lambda x, y: 0 * x), grid_sheet(lambda x, y: 0 * x + 0.1)]
    )
    with pytest.raises(MeshError, match="pieces"):
        flatten(two)
