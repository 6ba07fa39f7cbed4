import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from skinloc.errors import MeshError
from skinloc.geometry.mesh import (
    SurfaceConstraint,
    cone_skin,
    farthest_point_sampling,
    load_mesh,
    nearest_on_surface,
    sample_targets,
    surface_points,
    tol,
)


def test_cone_matches_paper_size(cone):
    # 16.9 x 14.1 x 8.5 cm, as the mesh stored in the paper's recordings
    np.testing.assert_allclose(cone.extents, [0.169342, 0.141443, 0.084671], atol=1e-5)
    assert cone.vertices[:, 2].min() >= -1e-12
    # normals point away from the cone's axis
    radial = cone.triangles_center * [1, 0, 1]
    assert np.all(np.einsum("ij,ij->i", cone.face_normals, radial) > 0)


def test_cone_matches_real_mesh(real_dir):
    from skinloc.data.recording import read_recording

    rec = read_recording(real_dir / "ConeSkinData80Points_RND_80PL_1.mat")
    _, dist, _ = nearest_on_surface(cone_skin(), rec.vertices)
    assert dist.max() < 1e-5
    _, dist, _ = nearest_on_surface(cone_skin(), rec.targets)
    assert dist.max() < 1e-5


@pytest.mark.parametrize("mode", ["random", "edge", "even"])
def test_targets_lie_on_surface(cone, mode, seed):
    pts = sample_targets(cone, 40, mode, random_state=seed)
    assert pts.shape == (40, 3)
    _, dist, _ = nearest_on_surface(cone, pts)
    assert dist.max() < 1e-9
    np.testing.assert_array_equal(pts, sample_targets(cone, 40, mode, random_state=seed))


def test_edge_targets_lie_on_mesh_edges(cone):
    pts = sample_targets(cone, 30, "edge", random_state=0)
    v = cone.vertices
    a, b = v[cone.edges_unique[:, 0]], v[cone.edges_unique[:, 1]]
    ab = b - a
    for p in pts:
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
        d = np.linalg.norm(a + t[:, None] * ab - p, axis=1)
        assert d.min() < 1e-12


def test_even_targets_are_spread_more_than_random(cone):
    def min_gap(p):
        d = np.linalg.norm(p[:, None] - p[None], axis=2)
        return d[np.triu_indices(len(p), 1)].min()

    even = sample_targets(cone, 60, "even", random_state=0)
    rnd = sample_targets(cone, 60, "random", random_state=0)
    assert min_gap(even) > 2 * min_gap(rnd)


def test_unknown_mode_lists_choices(cone):
    with pytest.raises(ValueError, match="random, edge, even"):
        sample_targets(cone, 5, "grid")


def test_farthest_point_sampling_hand_example():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0.1, 0, 0], [0.5, 0, 0]], float)
    assert list(farthest_point_sampling(pts, 3, start=0)) == [0, 1, 3]


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-0.2, 0.2), min_size=3, max_size=3))
def test_projection_lies_on_surface_and_is_closest(xyz):
    mesh = cone_skin()
    p = np.array([xyz])
    proj = SurfaceConstraint(mesh, "project")(p)
    _, dist, _ = nearest_on_surface(mesh, proj)
    assert dist[0] < 1e-9
    # no discretised surface point is closer than the exact projection
    dense = surface_points(mesh, 2000)
    assert np.linalg.norm(proj - p) <= np.linalg.norm(dense - p, axis=1).min() + 1e-9


def test_snap_returns_grid_points(cone):
    grid = surface_points(cone, 500)
    sc = SurfaceConstraint(cone, "snap", points=grid)
    out = sc(np.array([[0.0, 0.0, 0.2], [0.05, -0.05, 0.05]]))
    assert all((grid == o).all(axis=1).any() for o in out)
    assert np.array_equal(SurfaceConstraint(cone, "none")(out), out)


def test_snap_and_project_agree_within_grid_spacing(cone):
    pts = sample_targets(cone, 50, "random", random_state=3) + 0.004
    snap = SurfaceConstraint(cone, "snap")(pts)
    proj = SurfaceConstraint(cone, "project")(pts)
    # 14,400 points on 281 cm^2: spacing about 1.4 mm
    assert np.linalg.norm(snap - proj, axis=1).max() < 4e-3


def test_constraint_checks_shape(cone):
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        SurfaceConstraint(cone, "project")(np.zeros((4, 2)))
    with pytest.raises(ValueError, match="snap, project, none"):
        SurfaceConstraint(cone, "nearest")


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply"])
def test_load_mesh_formats_and_units(tmp_path, cone, suffix):
    path = tmp_path / f"skin{suffix}"
    cone.export(path)
    m = load_mesh(path, units="m")
    np.testing.assert_allclose(m.extents, cone.extents, rtol=1e-5)
    mm = cone.copy()
    mm.apply_scale(1000)
    mm.export(path)
    np.testing.assert_allclose(load_mesh(path, units="mm").extents, cone.extents, rtol=1e-5)
    np.testing.assert_allclose(load_mesh(path).extents, cone.extents, rtol=1e-5)  # auto
    assert tol.auto_mm_extent < mm.extents.max()


def test_load_real_obj(real_dir):
    m = load_mesh(real_dir / "Color_Cone.obj")
    assert len(m.faces) > 0 and m.extents.max() < 0.2


def test_load_mesh_errors(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        load_mesh(tmp_path / "nope.obj")
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"this is not an stl")
    with pytest.raises(MeshError):
        load_mesh(bad)
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing\n")
    with pytest.raises(MeshError):
        load_mesh(empty)
    txt = tmp_path / "mesh.txt"
    txt.write_text("v 0 0 0\n")
    with pytest.raises(MeshError, match="OBJ, STL or PLY"):
        load_mesh(txt)
    with pytest.raises(MeshError, match="units"):
        load_mesh(bad, units="inch")


def test_other_meshes_work():
    box = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
    pts = sample_targets(box, 20, "even", random_state=0)
    _, dist, _ = nearest_on_surface(box, pts)
    assert dist.max() < 1e-9
