"""The skin's frame (skinloc.geometry.skin_frame): up = the long axis, right = up x normal."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from skinloc.geometry.mesh import cone_skin
from skinloc.geometry.mesh import skin_up_axis as reexported
from skinloc.geometry.skin_frame import skin_frame, skin_up_axis


def test_long_axis_and_its_sign() -> None:
    box = trimesh.creation.box(extents=(0.02, 0.05, 0.2))
    np.testing.assert_allclose(skin_up_axis(box.vertices), [0, 0, 1], atol=1e-9)
    # the sign does not follow the vertex order or a flip of the mesh
    rng = np.random.default_rng(0)
    v = box.vertices[rng.permutation(len(box.vertices))]
    np.testing.assert_allclose(skin_up_axis(v), [0, 0, 1], atol=1e-9)
    np.testing.assert_allclose(skin_up_axis(-v), [0, 0, 1], atol=1e-9)
    tilted = np.array([[0, 0, 0], [-3.0, 1.0, 0], [3.0, -1.0, 0]])  # largest component x
    up = skin_up_axis(tilted)
    assert up[0] > 0 and np.isclose(np.linalg.norm(up), 1.0)
    assert reexported is skin_up_axis


def test_the_paper_cone() -> None:
    m = cone_skin()
    up, right, normal = skin_frame(m.vertices, m.faces)
    np.testing.assert_allclose(up, [0, 0.972, -0.234], atol=2e-3)  # up the slope, to the top
    np.testing.assert_allclose(right, [1, 0, 0], atol=1e-9)
    np.testing.assert_allclose(normal, [0, 0.234, 0.972], atol=2e-3)  # outward (z >= 0 side)
    frame = np.stack([up, right, normal])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.cross(up, normal), right, atol=1e-12)


def test_given_up_and_closed_surface() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=2)
    up, right, normal = skin_frame(sphere.vertices, sphere.faces, up=[0, 0, 2.0])
    np.testing.assert_allclose(up, [0, 0, 1])
    frame = np.stack([up, right, normal])
    np.testing.assert_allclose(frame @ frame.T, np.eye(3), atol=1e-9)


@pytest.mark.parametrize(
    "bad", [np.zeros((0, 3)), np.ones((4, 3)), np.ones((3, 2)), [[np.nan] * 3] * 3]
)
def test_bad_vertices(bad) -> None:
    with pytest.raises(ValueError, match="vertices"):
        skin_up_axis(np.asarray(bad, dtype=float))
