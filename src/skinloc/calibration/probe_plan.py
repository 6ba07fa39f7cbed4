"""A probing plan from the skin's mesh: where a robot's probe presses, from where, in what order.

The targets are the session's (``geometry.mesh.sample_targets``: ``even`` or ``random``); each
gets the surface normal of the triangle it lies on (the side the probe comes from), a point
``clearance_m`` above it along that normal (the approach: the probe moves there, then presses
along ``-normal``), and an order that keeps the path between approach points short (greedy
nearest neighbour, then 2-opt). A target the probe cannot reach is left out and listed with its
reason: its normal is more than ``max_tilt_deg`` from the arm's side (the probe would press
against the direction it points in, or slide off a steep face), or it lies closer than
``rim_clearance_m`` to the mesh's rim (its boundary edges: a probe there presses off the edge).

Everything is in the skin's (the mesh's) frame, metres; ``SkinPose`` carries the skin's pose in
the robot's base frame (the skins file's ``parent_frame``, ``translation`` and ``rotation`` or
``rpy``, the pose the ROS 2 ``/tf_static`` publishes) and ``ProbePlan.in_base`` gives the
plan's points and directions there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

from skinloc._typing import Points
from skinloc.geometry.mesh import (
    SamplingMode,
    farthest_point_sampling,
    nearest_on_surface,
    sample_surface,
    sample_targets,
)

__all__ = [
    "MAX_FILL_FACTOR",
    "PLAN_MODES",
    "REASON_RIM",
    "REASON_TILT",
    "ProbePlan",
    "SkinPose",
    "boundary_distance",
    "even_cover",
    "plan_probing",
    "short_path_order",
]

#: Target samplings a probing plan uses (a probe gets its targets up front).
PLAN_MODES = (SamplingMode.EVEN.value, SamplingMode.RANDOM.value)
#: A filled plan draws at most this many times ``n_points`` targets, in at most as many rounds.
MAX_FILL_FACTOR = 8
MAX_FILL_ROUNDS = 8
#: Why a target was left out.
REASON_TILT = "tilt"
REASON_RIM = "rim"


@dataclass(frozen=True)
class SkinPose:
    """The skin's (mesh frame's) pose in the robot's base frame.

    Attributes
    ----------
    translation_m : (3,) float
        Origin of the mesh frame in the base frame, m.
    rotation_xyzw : (4,) float
        Orientation of the mesh frame in the base frame, unit quaternion ``x, y, z, w``.
    parent_frame : str or None
        Name of the base frame (the skins file's ``parent_frame``), for the record.
    """

    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)
    parent_frame: str | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.translation_m, dtype=np.float64)
        q = np.asarray(self.rotation_xyzw, dtype=np.float64)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"translation_m must be 3 finite numbers, got {self.translation_m!r}")
        if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1) > 1e-3:
            raise ValueError(
                f"rotation_xyzw must be a unit quaternion x, y, z, w, got {self.rotation_xyzw!r}"
            )

    @property
    def matrix(self) -> np.ndarray:
        """``(3, 3)`` rotation taking mesh-frame directions to base-frame ones."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(np.asarray(self.rotation_xyzw, dtype=np.float64)).as_matrix()

    def points_to_base(self, points: Points) -> Points:
        """``(n, 3)`` mesh-frame points, m, in the base frame."""
        return np.asarray(points, dtype=np.float64) @ self.matrix.T + np.asarray(self.translation_m)

    def points_to_skin(self, points: Points) -> Points:
        """``(n, 3)`` base-frame points, m, in the mesh frame."""
        p = np.asarray(points, dtype=np.float64) - np.asarray(self.translation_m)
        return p @ self.matrix

    def directions_to_base(self, directions: Points) -> Points:
        """``(n, 3)`` mesh-frame directions in the base frame."""
        return np.asarray(directions, dtype=np.float64) @ self.matrix.T

    def directions_to_skin(self, directions: Points) -> Points:
        """``(n, 3)`` base-frame directions in the mesh frame."""
        return np.asarray(directions, dtype=np.float64) @ self.matrix


@dataclass
class ProbePlan:
    """Where and in what order a probe presses the skin (mesh frame, m).

    Attributes
    ----------
    targets_m : (n, 3) float
        Targets on the surface in the order they are probed, m.
    normals : (n, 3) float
        Unit surface normals at the targets (the probe comes from their side).
    approach_m : (n, 3) float
        Points ``clearance_m`` above the targets along their normals, m.
    skipped_m : (k, 3) float
        Targets left out, m.
    skipped_reasons : list of str
        Why each was left out: ``tilt`` or ``rim``.
    pose : SkinPose
        The skin's pose in the robot's base frame.
    clearance_m : float
        Height of the approach points above the surface, m.
    n_drawn : int
        Targets drawn to make the plan (more than asked for when it was filled).
    """

    targets_m: Points
    normals: Points
    approach_m: Points
    skipped_m: Points
    skipped_reasons: list[str]
    pose: SkinPose = field(default_factory=SkinPose)
    clearance_m: float = 0.01
    n_drawn: int = 0

    def __len__(self) -> int:
        return len(self.targets_m)

    @property
    def path_length_m(self) -> float:
        """Length of the path through the approach points in plan order, m."""
        if len(self.approach_m) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.approach_m, axis=0), axis=1).sum())

    def skipped_counts(self) -> dict[str, int]:
        """How many targets were left out for each reason."""
        reasons, counts = np.unique(np.asarray(self.skipped_reasons, dtype=str), return_counts=True)
        return {str(r): int(c) for r, c in zip(reasons, counts, strict=True)}

    def in_base(self) -> dict[str, Points]:
        """The plan in the robot's base frame.

        Returns ``targets_m`` and ``approach_m`` ``(n, 3)`` m, and ``press_directions``
        ``(n, 3)`` (unit: the way the probe moves when pressing).
        """
        pose = self.pose
        return {
            "targets_m": pose.points_to_base(self.targets_m),
            "approach_m": pose.points_to_base(self.approach_m),
            "press_directions": pose.directions_to_base(-np.asarray(self.normals)),
        }


def boundary_distance(mesh: trimesh.Trimesh, points: Points) -> np.ndarray:
    """Distance from each of ``points (n, 3)`` m to the mesh's rim (its boundary edges), m.

    ``inf`` for a closed mesh (no rim).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    edges = mesh.edges_sorted
    rim = edges[trimesh.grouping.group_rows(edges, require_count=1)]
    if len(rim) == 0:
        return np.full(len(points), np.inf)
    a = mesh.vertices[rim[:, 0]]
    ab = mesh.vertices[rim[:, 1]] - a
    out = np.empty(len(points))
    for i, p in enumerate(points):  # (n x edges) pairs, a row at a time to bound memory
        t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
        out[i] = np.linalg.norm(a + t[:, None] * ab - p, axis=1).min()
    return out


def short_path_order(points: Points, start: int = 0, max_passes: int = 50) -> np.ndarray:
    """An order of ``points (n, 3)`` whose open path is short: nearest neighbour, then 2-opt.

    Starts at index ``start``; returns a permutation ``(n,)`` of ``range(n)``. The 2-opt
    passes reverse any stretch of the path that makes it shorter until none does (or
    ``max_passes``); the first point stays first.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    if n <= 2:
        return np.arange(n)
    if not 0 <= start < n:
        raise ValueError(f"start must be in [0, {n}), got {start}")
    dist = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=2)
    order = [start]
    left = np.ones(n, dtype=bool)
    left[start] = False
    for _ in range(n - 1):
        d = np.where(left, dist[order[-1]], np.inf)
        nxt = int(np.argmin(d))
        order.append(nxt)
        left[nxt] = False
    path = np.asarray(order)
    for _ in range(max_passes):
        improved = False
        for i in range(1, n - 1):
            # Reverse path[i..j]: edges (i-1, i) and (j, j+1) become (i-1, j) and (i, j+1);
            # j = n-1 has no edge after it (an open path).
            j = np.arange(i + 1, n)
            a, b = path[i - 1], path[i]
            c = path[j]
            d_next = np.append(dist[path[j[:-1]], path[j[:-1] + 1]], 0.0)
            d_new_next = np.append(dist[b, path[j[:-1] + 1]], 0.0)
            gain = dist[a, b] + d_next - dist[a, c] - d_new_next
            k = int(np.argmax(gain))
            if gain[k] > 1e-12:
                path[i : j[k] + 1] = path[i : j[k] + 1][::-1]
                improved = True
        if not improved:
            break
    return path


#: Surface points per target ``even_cover`` spreads the targets over, and its Lloyd steps.
COVER_SAMPLES_PER_TARGET = 50
COVER_STEPS = 30


def even_cover(surface: Points, reachable: np.ndarray, start: Points) -> Points:
    """Targets among the reachable surface points that cover the whole surface evenly.

    Lloyd's iterations on a dense sample of the surface: each target takes the surface points
    nearest to it (reachable or not), moves to their centroid, and is put on the reachable
    point nearest that. A target then sits in the middle of the area it stands for, so a rim
    band the probe cannot press is covered from just inside it, where farthest-point sampling
    crowds the targets at the reachable region's border (the area-uniform touches a map is
    used on fall mostly inside).

    Parameters
    ----------
    surface : (m, 3) float
        Area-uniform points of the whole surface, m.
    reachable : (m,) bool
        Which of them the probe can press.
    start : (n, 3) float
        Initial targets, reachable, m.

    Returns
    -------
    (n, 3) float
        The targets, each one of ``surface[reachable]``, m.
    """
    from scipy.spatial import cKDTree

    surface = np.asarray(surface, dtype=np.float64)
    ok = surface[np.asarray(reachable, dtype=bool)]
    if not len(ok):
        raise ValueError("no surface point is reachable")
    on_ok = cKDTree(ok)
    targets = ok[on_ok.query(np.asarray(start, dtype=np.float64))[1]]
    for _ in range(COVER_STEPS):
        cell = cKDTree(targets).query(surface)[1]
        counts = np.bincount(cell, minlength=len(targets))
        sums = np.zeros_like(targets)
        np.add.at(sums, cell, surface)
        centroids = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], targets)
        moved = ok[on_ok.query(centroids)[1]]
        # two targets put on the same point: the later ones stay where they were
        _, first = np.unique(moved, axis=0, return_index=True)
        twin = np.ones(len(moved), dtype=bool)
        twin[first] = False
        moved[twin] = targets[twin]
        if np.array_equal(moved, targets):
            break
        targets = moved
    return targets


def plan_probing(
    mesh: trimesh.Trimesh,
    n_points: int,
    mode: str = "even",
    *,
    random_state: int = 0,
    pose: SkinPose | None = None,
    arm_direction: Points = (0.0, 0.0, -1.0),
    max_tilt_deg: float = 60.0,
    rim_clearance_m: float = 0.005,
    clearance_m: float = 0.01,
    targets: Points | None = None,
    fill: bool = False,
) -> ProbePlan:
    """Plan a probing session on ``mesh``.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Skin surface in its own frame, m; its face normals point to the side probed.
    n_points : int
        Targets drawn (those the probe cannot reach are then left out).
    mode : {"even", "random"}
        Target sampling, as a session's (``sample_targets``).
    random_state : int
        Seed of the targets.
    pose : SkinPose, optional
        The skin's pose in the robot's base frame; identity by default.
    arm_direction : (3,) float
        The direction the probe points (moves when pressing) in the base frame; a target is
        reachable when its inward normal (``-normal``) is within ``max_tilt_deg`` of it.
    max_tilt_deg : float
        Largest angle between the press and ``arm_direction``, degrees, in (0, 180].
    rim_clearance_m : float
        Smallest distance from a target to the mesh's rim, m (0: no limit).
    clearance_m : float
        Height of the approach point above the target along the normal, m (> 0).
    targets : (n, 3) float, optional
        Targets to plan instead of sampling them (put on the surface first).
    fill : bool
        Plan ``n_points`` reachable targets: draw more (up to ``MAX_FILL_FACTOR`` times as
        many) until enough are reachable, then keep ``n_points`` of them (an even plan by
        farthest-point sampling, a random one the first drawn). Those left out of the last
        draw are listed. By default the ``n_points`` drawn are planned, less those left out.

    Returns
    -------
    ProbePlan
        The reachable targets in a short-path order, and those left out with their reasons.
    """
    if mode not in PLAN_MODES:
        raise ValueError(f"mode must be one of {', '.join(PLAN_MODES)} for a probe, got {mode!r}")
    if not 0 < max_tilt_deg <= 180:
        raise ValueError(f"max_tilt_deg must be in (0, 180], got {max_tilt_deg!r}")
    if not (rim_clearance_m >= 0 and np.isfinite(rim_clearance_m)):
        raise ValueError(f"rim_clearance_m must be >= 0, got {rim_clearance_m!r}")
    if not (clearance_m > 0 and np.isfinite(clearance_m)):
        raise ValueError(f"clearance_m must be > 0, got {clearance_m!r}")
    arm = np.asarray(arm_direction, dtype=np.float64).reshape(-1)
    if arm.shape != (3,) or not np.linalg.norm(arm) > 0:
        raise ValueError(f"arm_direction must be a direction (3 numbers), got {arm_direction!r}")
    arm = arm / np.linalg.norm(arm)
    pose = pose or SkinPose()

    def drawn(points: Points) -> tuple[Points, Points, np.ndarray]:
        on_surface, _, face = nearest_on_surface(mesh, points)
        normals = np.asarray(mesh.face_normals[face], dtype=np.float64)
        press_base = pose.directions_to_base(-normals)
        tilt = np.degrees(np.arccos(np.clip(press_base @ arm, -1.0, 1.0)))
        reasons = np.full(len(on_surface), "", dtype=object)
        reasons[tilt > max_tilt_deg] = REASON_TILT
        if rim_clearance_m > 0:
            near_rim = boundary_distance(mesh, on_surface) < rim_clearance_m
            reasons[near_rim & (reasons == "")] = REASON_RIM
        return on_surface, normals, reasons

    if targets is not None:
        on_surface, normals, reasons = drawn(targets)
    else:
        n_drawn = n_points
        for _ in range(MAX_FILL_ROUNDS):
            targets = sample_targets(mesh, n_drawn, mode, random_state=random_state)
            on_surface, normals, reasons = drawn(targets)
            n_ok = int(np.count_nonzero(reasons == ""))
            if not fill or n_ok >= n_points or n_ok == 0 or n_drawn >= MAX_FILL_FACTOR * n_points:
                break
            n_drawn = min(
                int(np.ceil(1.25 * n_drawn * n_points / n_ok)), MAX_FILL_FACTOR * n_points
            )
    keep = reasons == ""
    pts, nrm = on_surface[keep], normals[keep]
    if len(pts) >= n_points and targets is not None and fill:
        # A filled even plan spreads its targets over the whole skin, the parts it cannot
        # reach included (covered from their reachable side); a random one keeps the first.
        if mode == SamplingMode.EVEN.value:
            pick = np.sort(farthest_point_sampling(pts, n_points))
            dense = sample_surface(mesh, COVER_SAMPLES_PER_TARGET * n_points, random_state)[0]
            dense_on, _, dense_why = drawn(dense)
            pts = even_cover(dense_on, dense_why == "", pts[pick])
            nrm = drawn(pts)[1]
        else:
            pts, nrm = pts[:n_points], nrm[:n_points]
    approach = pts + clearance_m * nrm
    order = short_path_order(approach) if len(pts) else np.zeros(0, dtype=int)
    return ProbePlan(
        targets_m=pts[order],
        normals=nrm[order],
        approach_m=approach[order],
        skipped_m=on_surface[~keep],
        skipped_reasons=[str(r) for r in reasons[~keep]],
        pose=pose,
        clearance_m=float(clearance_m),
        n_drawn=len(on_surface),
    )
