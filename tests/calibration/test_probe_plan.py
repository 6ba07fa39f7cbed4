import itertools

import numpy as np
import pytest
import trimesh

from skinloc.calibration.probe_plan import (
    REASON_RIM,
    REASON_TILT,
    SkinPose,
    boundary_distance,
    even_cover,
    plan_probing,
    short_path_order,
)
from skinloc.geometry.mesh import (
    farthest_point_sampling,
    nearest_on_surface,
    sample_surface,
    sample_targets,
)
from skinloc.geometry.skin_frame import quaternion_from_rpy


@pytest.fixture
def plate():
    # a 100 mm square plate at z = 0, normals +z, made of a grid of triangles
    xs = np.linspace(0, 0.1, 11)
    v = np.array([(x, y, 0.0) for y in xs for x in xs])
    f = []
    for i, j in itertools.product(range(10), range(10)):
        a = i * 11 + j
        f += [(a, a + 1, a + 12), (a, a + 12, a + 11)]
    return trimesh.Trimesh(v, np.array(f), process=False)


def _path(points):
    return np.linalg.norm(np.diff(points, axis=0), axis=1).sum()


def test_plan_targets_normals_and_approach(cone):
    plan = plan_probing(cone, 40, "even", random_state=3, max_tilt_deg=180, rim_clearance_m=0)
    assert len(plan) == 40 and not plan.skipped_reasons
    # the same targets a session samples, reordered
    expected = sample_targets(cone, 40, "even", random_state=3)
    d = np.linalg.norm(plan.targets_m[:, None] - expected[None], axis=2)
    assert d.min(axis=1).max() < 1e-9 and d.min(axis=0).max() < 1e-9
    _, dist, face = nearest_on_surface(cone, plan.targets_m)
    assert dist.max() < 1e-9
    np.testing.assert_allclose(np.linalg.norm(plan.normals, axis=1), 1.0)
    assert np.all(np.einsum("ij,ij->i", plan.normals, cone.face_normals[face]) > 0.999)
    np.testing.assert_allclose(plan.approach_m - plan.targets_m, 0.01 * plan.normals, atol=1e-12)


def test_plan_order_is_shorter_than_sampling_order(cone):
    plan = plan_probing(cone, 60, "random", random_state=1, max_tilt_deg=180, rim_clearance_m=0)
    drawn = sample_targets(cone, 60, "random", random_state=1)
    assert plan.path_length_m < 0.5 * _path(drawn)


def test_short_path_order_two_opt_untangles():
    rng = np.random.default_rng(0)
    pts = rng.random((80, 3))
    order = short_path_order(pts)
    assert sorted(order.tolist()) == list(range(80)) and order[0] == 0
    # 2-opt leaves no improving reversal
    p = pts[order]

    def d(a, b):
        return 0.0 if b == 80 else np.linalg.norm(p[a] - p[b])

    for i in range(1, 79):
        for j in range(i + 1, 80):
            assert d(i - 1, j) + d(i, j + 1) >= d(i - 1, i) + d(j, j + 1) - 1e-9
    # points on a line come out in line order
    line = np.c_[np.array([0.3, 0.0, 0.1, 0.2, 0.5, 0.4]), np.zeros((6, 2))]
    assert line[short_path_order(line, start=1)][:, 0].tolist() == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5]
    assert short_path_order(np.zeros((1, 3))).tolist() == [0]
    with pytest.raises(ValueError, match="start"):
        short_path_order(pts, start=80)


def test_rim_targets_are_left_out(plate):
    d = boundary_distance(plate, [[0.05, 0.05, 0.0], [0.002, 0.05, 0.0], [0.1, 0.1, 0.0]])
    np.testing.assert_allclose(d, [0.05, 0.002, 0.0], atol=1e-12)
    targets = [[0.05, 0.05, 0.0], [0.003, 0.05, 0.0], [0.05, 0.099, 0.0], [0.02, 0.03, 0.0]]
    plan = plan_probing(plate, 4, targets=targets, rim_clearance_m=0.005)
    assert len(plan) == 2 and plan.skipped_reasons == [REASON_RIM, REASON_RIM]
    np.testing.assert_allclose(plan.skipped_m, [targets[1], targets[2]])
    assert plan.skipped_counts() == {REASON_RIM: 2}
    closed = trimesh.creation.icosphere(2, 0.05)
    assert np.isinf(boundary_distance(closed, [[0, 0, 0.05]])).all()


def test_tilt_against_the_arm_and_the_pose(plate):
    targets = [[0.05, 0.05, 0.0]]
    # plate normal +z: a probe pointing down presses along -z, one pointing up cannot
    assert len(plan_probing(plate, 1, targets=targets, arm_direction=(0, 0, -1))) == 1
    up = plan_probing(plate, 1, targets=targets, arm_direction=(0, 0, 1))
    assert len(up) == 0 and up.skipped_reasons == [REASON_TILT]
    # the plate mounted on a wall (rolled 90 degrees): its normal is -y in the base frame
    pose = SkinPose((0.5, 0.0, 0.3), quaternion_from_rpy(np.pi / 2, 0, 0), "base_link")
    down = plan_probing(plate, 1, targets=targets, pose=pose, arm_direction=(0, 0, -1))
    assert down.skipped_reasons == [REASON_TILT]
    side = plan_probing(plate, 1, targets=targets, pose=pose, arm_direction=(0, 1, 0))
    assert len(side) == 1
    base = side.in_base()
    np.testing.assert_allclose(base["targets_m"], [[0.55, 0.0, 0.35]], atol=1e-12)
    np.testing.assert_allclose(base["approach_m"], [[0.55, -0.01, 0.35]], atol=1e-12)
    np.testing.assert_allclose(base["press_directions"], [[0.0, 1.0, 0.0]], atol=1e-12)
    back = pose.points_to_skin(base["targets_m"])
    np.testing.assert_allclose(back, targets, atol=1e-12)
    # a tilt limit of 45 degrees leaves out a face at 60 degrees
    tilted = SkinPose(rotation_xyzw=quaternion_from_rpy(np.radians(60), 0, 0))
    assert len(plan_probing(plate, 1, targets=targets, pose=tilted, max_tilt_deg=45)) == 0
    assert len(plan_probing(plate, 1, targets=targets, pose=tilted, max_tilt_deg=65)) == 1


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"mode": "edge"}, "mode"),
        ({"max_tilt_deg": 0}, "max_tilt_deg"),
        ({"rim_clearance_m": -1}, "rim_clearance_m"),
        ({"clearance_m": 0}, "clearance_m"),
        ({"arm_direction": (0, 0, 0)}, "arm_direction"),
    ],
)
def test_plan_refuses_bad_parameters(cone, kwargs, match):
    with pytest.raises(ValueError, match=match):
        plan_probing(cone, 5, **kwargs)


def test_pose_refuses_a_bad_quaternion():
    with pytest.raises(ValueError, match="rotation_xyzw"):
        SkinPose(rotation_xyzw=(0, 0, 0, 2))
    with pytest.raises(ValueError, match="translation_m"):
        SkinPose(translation_m=(0, 0))


def test_skin_mount_from_a_skins_file(tmp_path):
    from skinloc.live.skins_file import skin_mount

    path = tmp_path / "skins.toml"
    path.write_text(
        '[defaults]\nparent_frame = "base_link"\n'
        '[[skin]]\nname = "a"\ntranslation = [0.1, 0.2, 0.3]\nrpy = [0.0, 0.0, 1.5707963]\n'
        '[[skin]]\nname = "b"\nparent_frame = "link7"\nrotation = [0, 0, 0, 1]\n'
    )
    frame, t, q = skin_mount(path, "a")
    assert frame == "base_link" and t == (0.1, 0.2, 0.3)
    np.testing.assert_allclose(q, quaternion_from_rpy(0, 0, 1.5707963))
    pose = SkinPose(t, q, frame)
    np.testing.assert_allclose(pose.points_to_base([[1.0, 0, 0]]), [[0.1, 1.2, 0.3]], atol=1e-6)
    assert skin_mount(path, "b") == ("link7", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="has 2 skins: name one"):
        skin_mount(path)
    with pytest.raises(ValueError, match="no skin 'c'"):
        skin_mount(path, "c")
    path.write_text("[[skin]]\nrpy = [1, 2]\n")
    with pytest.raises(ValueError, match="skin 'skin0': rpy must be 3 finite numbers"):
        skin_mount(path)
    with pytest.raises(ValueError, match="not found"):
        skin_mount(tmp_path / "none.toml")


@pytest.mark.parametrize("mode", ["even", "random"])
def test_a_filled_plan_has_the_targets_asked_for(cone, mode):
    plain = plan_probing(cone, 40, mode, random_state=2)
    assert 0 < len(plain) < 40 and len(plain) + len(plain.skipped_m) == plain.n_drawn == 40
    full = plan_probing(cone, 40, mode, random_state=2, fill=True)
    assert len(full) == 40 and full.n_drawn > 40
    # all reachable: pointing down within 60 degrees, 5 mm from the rim
    assert np.all(full.normals[:, 2] >= np.cos(np.radians(60)) - 1e-9)
    assert boundary_distance(cone, full.targets_m).min() >= 0.005
    assert len(np.unique(np.round(full.targets_m, 9), axis=0)) == 40
    # nothing reachable: no endless drawing
    none = plan_probing(cone, 10, mode, arm_direction=(0, 0, 1), fill=True)
    assert len(none) == 0 and none.n_drawn == 10


def test_an_even_plan_covers_the_rim_band_from_inside(plate):
    # the probe keeps 10 mm off the rim; the touches a map serves fall anywhere
    plan = plan_probing(plate, 16, "even", rim_clearance_m=0.01, random_state=0, fill=True)
    assert len(plan) == 16 and boundary_distance(plate, plan.targets_m).min() >= 0.01
    assert len(np.unique(plan.targets_m, axis=0)) == 16
    touches = sample_surface(plate, 4000, 1)[0]

    def mean_gap(targets):  # mean distance from a touch to its nearest target, m
        return np.linalg.norm(touches[:, None] - targets[None], axis=2).min(axis=1).mean()

    # farthest-point sampling of the reachable part crowds its border; the cover does not,
    # and covers the plate as well
    reachable = touches[boundary_distance(plate, touches) >= 0.01]
    fps = reachable[farthest_point_sampling(reachable, 16)]
    assert mean_gap(plan.targets_m) < 1.05 * mean_gap(fps)
    on_border = np.count_nonzero(boundary_distance(plate, plan.targets_m) < 0.012)
    assert 2 * on_border <= np.count_nonzero(boundary_distance(plate, fps) < 0.012)


def test_even_cover_needs_a_reachable_point():
    pts = np.random.default_rng(0).random((50, 3))
    with pytest.raises(ValueError, match="no surface point is reachable"):
        even_cover(pts, np.zeros(50, dtype=bool), pts[:3])
    got = even_cover(pts, np.ones(50, dtype=bool), pts[:3])
    assert got.shape == (3, 3) and len(np.unique(got, axis=0)) == 3
