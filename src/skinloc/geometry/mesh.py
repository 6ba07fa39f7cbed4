"""Skin surfaces: loading meshes, the built-in cone, calibration targets and output constraints.

All coordinates are metres in the mesh frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import trimesh

from skinloc._typing import Points
from skinloc.errors import MeshError
from skinloc.geometry.skin_frame import skin_up_axis  # re-exported: the skin's "up"

log = logging.getLogger(__name__)

__all__ = [
    "ConstraintMode",
    "SamplingMode",
    "SurfaceConstraint",
    "cone_skin",
    "load_mesh",
    "mesh_from_arrays",
    "nearest_on_surface",
    "sample_targets",
    "skin_up_axis",
    "surface_points",
    "tol",
]


@dataclass
class Tolerances:
    """Geometric tolerances, in metres.

    Attributes
    ----------
    on_surface : float
        A point this close to the mesh counts as lying on it.
    auto_mm_extent : float
        ``units="auto"`` reads a mesh whose largest extent exceeds this as millimetres.
    """

    on_surface: float = 1e-7
    auto_mm_extent: float = 5.0


tol = Tolerances()


class SamplingMode(StrEnum):
    """How calibration targets are drawn on the surface."""

    RANDOM = "random"  # area-uniform on the surface
    EDGE = "edge"  # the paper's: a random point on a randomly chosen mesh edge
    EVEN = "even"  # spread evenly: farthest-point sampling of a dense sample

    @classmethod
    def _missing_(cls, value: object) -> SamplingMode:
        valid = ", ".join(m.value for m in cls)
        raise ValueError(f"unknown sampling mode {value!r}; choose one of: {valid}")


class ConstraintMode(StrEnum):
    """How a predicted point is put back on the skin."""

    SNAP = "snap"  # nearest of a discretised set of surface points (the paper's)
    PROJECT = "project"  # exact closest point on the mesh triangles
    NONE = "none"  # raw network output

    @classmethod
    def _missing_(cls, value: object) -> ConstraintMode:
        valid = ", ".join(m.value for m in cls)
        raise ValueError(f"unknown output constraint {value!r}; choose one of: {valid}")


# The paper's skin, read off the mesh stored in its recordings: half of a truncated cone
# lying on its side, axis along +y, the open side at z = 0.
PAPER_CONE = {
    "r_small": 0.034731,
    "r_large": 0.084671,
    "y_small": 0.031931,
    "y_large": -0.109512,
}


def cone_skin(
    r_small: float = PAPER_CONE["r_small"],
    r_large: float = PAPER_CONE["r_large"],
    y_small: float = PAPER_CONE["y_small"],
    y_large: float = PAPER_CONE["y_large"],
    n_segments: int = 72,
    n_rings: int = 1,
) -> trimesh.Trimesh:
    """Build a semi-conical shell: half a truncated cone lying on its side.

    The default is the paper's skin (14.1 cm long, 16.9 x 8.5 cm at the wide end), with the
    same vertex layout as the CAD mesh in its recordings (73 vertices per rim).

    Parameters
    ----------
    r_small, r_large : float
        Radii of the narrow and wide ends, m.
    y_small, y_large : float
        Axial positions of the narrow and wide ends, m.
    n_segments : int
        Facets around the half circumference.
    n_rings : int
        Facets along the axis.

    Returns
    -------
    trimesh.Trimesh
        Open surface with outward normals, ``z >= 0``.

    Examples
    --------
    >>> mesh = cone_skin()
    >>> mesh.vertices.shape
    (146, 3)
    """
    if min(r_small, r_large) <= 0 or y_small == y_large:
        raise ValueError("cone_skin needs positive radii and two distinct end positions")
    if n_segments < 2 or n_rings < 1:
        raise ValueError(
            f"cone_skin needs n_segments >= 2 and n_rings >= 1, got {n_segments}, {n_rings}"
        )
    theta = np.linspace(0.0, np.pi, n_segments + 1)
    s = np.linspace(0.0, 1.0, n_rings + 1)
    radius = r_small + (r_large - r_small) * s
    y = y_small + (y_large - y_small) * s
    ring = np.stack([np.cos(theta), np.zeros_like(theta), np.sin(theta)], axis=1)
    vertices = np.concatenate(
        [ring * [r, 0.0, r] + [0.0, yy, 0.0] for r, yy in zip(radius, y, strict=True)]
    )
    n_col = n_segments + 1
    faces = []
    for i in range(n_rings):
        for j in range(n_segments):
            a, b = i * n_col + j, i * n_col + j + 1
            c, d = a + n_col, b + n_col
            faces += [[a, c, d], [a, d, b]]
    faces = np.asarray(faces, dtype=np.int64)
    # Orient the normals away from the cone's axis (checked on the first facet).
    tri = vertices[faces[0]]
    normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    if normal @ (tri.mean(axis=0) * [1.0, 0.0, 1.0]) < 0:
        faces = faces[:, ::-1].copy()
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    return mesh


def mesh_from_arrays(vertices: Points, faces: np.ndarray) -> trimesh.Trimesh:
    """Make a mesh from ``vertices (V, 3)`` in metres and 0-based ``faces (F, 3)``."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) < 3:
        raise MeshError(f"mesh vertices must have shape (V, 3) with V >= 3, got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise MeshError(f"mesh faces must have shape (F, 3) with F >= 1, got {faces.shape}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError("mesh faces index vertices that do not exist")
    return trimesh.Trimesh(vertices, faces, process=False)


def same_surface(a: trimesh.Trimesh, b: trimesh.Trimesh, tol_m: float = 2e-3) -> bool:
    """Whether two meshes describe one surface to ``tol_m``: a re-export does, another skin not.

    Their bounding boxes must agree to ``tol_m`` and every vertex of each (at most 2000,
    evenly picked) must lie within ``tol_m`` of the other's surface, so the same skin saved
    with another tessellation or vertex order is still the same.
    """
    if np.abs(np.asarray(a.bounds) - np.asarray(b.bounds)).max() > tol_m:
        return False
    for one, other in ((a, b), (b, a)):
        pts = np.asarray(one.vertices)
        pts = pts[np.linspace(0, len(pts) - 1, min(len(pts), 2000)).astype(int)]
        dist = trimesh.proximity.closest_point(other, pts)[1]
        if dist.max() > tol_m:
            return False
    return True


def load_mesh(path: str | Path, units: str = "auto") -> trimesh.Trimesh:
    """Load a skin surface from an OBJ, STL or PLY file.

    Parameters
    ----------
    path : str or Path
        Mesh file.
    units : {"auto", "m", "mm"}
        Units of the file. ``"auto"`` takes millimetres when the mesh is larger than
        ``tol.auto_mm_extent`` metres in any direction, metres otherwise.

    Returns
    -------
    trimesh.Trimesh
        The surface in metres.

    Raises
    ------
    MeshError
        If the file is missing, unreadable or holds no triangles.
    """
    path = Path(path)
    if units not in ("auto", "m", "mm"):
        raise MeshError(f"unknown mesh units {units!r}; choose one of: auto, m, mm")
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path}")
    if path.suffix.lower() not in (".obj", ".stl", ".ply", ".off", ".glb", ".gltf"):
        raise MeshError(f"cannot read mesh {path}: use an OBJ, STL or PLY file")
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except ImportError as exc:
        # trimesh reaches for an optional package only on files it cannot parse as they are
        # (a broken binary STL is retried as text and its encoding guessed).
        raise MeshError(
            f"cannot read mesh {path}: not a valid {path.suffix[1:].upper()} file"
        ) from exc
    except Exception as exc:  # trimesh raises many kinds; all mean "unreadable"
        raise MeshError(f"cannot read mesh {path}: {exc}") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(f"mesh {path} holds no triangles")
    mesh = trimesh.Trimesh(loaded.vertices, loaded.faces, process=False)
    if not np.all(np.isfinite(mesh.vertices)):
        raise MeshError(f"mesh {path} has non-finite vertex coordinates")
    if not mesh.area > 0:  # every triangle degenerate: nothing to touch, nothing to sample
        raise MeshError(f"mesh {path} has zero area: all its triangles are degenerate")
    if units == "mm" or (units == "auto" and mesh.extents.max() > tol.auto_mm_extent):
        mesh.apply_scale(1e-3)
    log.debug("loaded %s: %d vertices, %d faces", path, len(mesh.vertices), len(mesh.faces))
    return mesh


def _as_points(points: Points, name: str = "points") -> Points:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 1 and pts.shape == (3,):
        pts = pts[None, :]
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {pts.shape}")
    return pts


def _rng(random_state: int | np.random.Generator | None) -> np.random.Generator:
    if isinstance(random_state, np.random.Generator):
        return random_state
    return np.random.default_rng(random_state)


def sample_surface(
    mesh: trimesh.Trimesh, n: int, random_state: int | np.random.Generator | None = None
) -> tuple[Points, np.ndarray]:
    """Draw ``n`` area-uniform points on the mesh.

    Returns
    -------
    points : (n, 3) float
        Points on the surface, m.
    face_id : (n,) int
        Triangle each point lies on.
    """
    rng = _rng(random_state)
    area = mesh.area_faces
    face_id = rng.choice(len(area), size=n, p=area / area.sum())
    # Uniform barycentric coordinates by reflecting the unit square onto the triangle.
    u, v = rng.random((2, n))
    flip = u + v > 1.0
    u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
    tri = mesh.triangles[face_id]
    points = tri[:, 0] + u[:, None] * (tri[:, 1] - tri[:, 0]) + v[:, None] * (tri[:, 2] - tri[:, 0])
    return points, face_id


def farthest_point_sampling(points: Points, n: int, start: int = 0) -> np.ndarray:
    """Indices of ``n`` points chosen greedily to be as far from each other as possible."""
    points = _as_points(points)
    if n > len(points):
        raise ValueError(f"cannot pick {n} points from {len(points)}")
    chosen = np.empty(n, dtype=np.int64)
    chosen[0] = start
    dist = np.linalg.norm(points - points[start], axis=1)
    for i in range(1, n):
        chosen[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i]], axis=1))
    return chosen


def sample_targets(
    mesh: trimesh.Trimesh,
    n: int,
    mode: SamplingMode | str = SamplingMode.EVEN,
    random_state: int | np.random.Generator | None = None,
) -> Points:
    """Calibration targets on the skin.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Skin surface, m.
    n : int
        Number of targets.
    mode : {"random", "edge", "even"}
        ``random`` is area-uniform; ``edge`` picks a random point on a random mesh edge (the
        paper's method); ``even`` spreads the targets evenly by farthest-point sampling.
    random_state : int, Generator or None
        Seed.

    Returns
    -------
    (n, 3) float
        Targets on the surface, m.

    Examples
    --------
    >>> sample_targets(cone_skin(), 5, "even", random_state=0).shape
    (5, 3)
    """
    mode = SamplingMode(mode)
    if n < 1:
        raise ValueError(f"number of targets must be at least 1, got {n}")
    rng = _rng(random_state)
    if mode is SamplingMode.RANDOM:
        return sample_surface(mesh, n, rng)[0]
    if mode is SamplingMode.EDGE:
        edges = mesh.edges_unique
        pick = edges[rng.integers(len(edges), size=n)]
        t = rng.random(n)[:, None]
        v = mesh.vertices
        return v[pick[:, 0]] + t * (v[pick[:, 1]] - v[pick[:, 0]])
    dense = sample_surface(mesh, max(40 * n, 4000), rng)[0]
    return dense[farthest_point_sampling(dense, n, start=int(rng.integers(len(dense))))]


def surface_points(mesh: trimesh.Trimesh, n: int = 14400, random_state: int = 0) -> Points:
    """A dense, fixed discretisation of the surface (the paper snaps to 14,400 such points).

    Returns
    -------
    (n, 3) float
        Area-uniform points, m, the same for the same mesh and seed.
    """
    return sample_surface(mesh, n, random_state)[0]


def nearest_on_surface(
    mesh: trimesh.Trimesh, points: Points
) -> tuple[Points, np.ndarray, np.ndarray]:
    """Exact closest points on the mesh.

    Returns
    -------
    closest : (n, 3) float
        Closest points on the surface, m.
    distance : (n,) float
        Distance from each input point, m.
    face_id : (n,) int
        Triangle holding each closest point.
    """
    pts = _as_points(points)
    closest, distance, face_id = trimesh.proximity.closest_point(mesh, pts)
    return closest, distance, face_id


class SurfaceConstraint:
    """Put predicted points back on the skin.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Skin surface, m.
    mode : {"snap", "project", "none"}
        ``snap``: nearest of ``points`` (the paper's method); ``project``: exact closest point on
        the triangles; ``none``: leave the points as they are.
    points : (P, 3) float, optional
        The discretised surface for ``snap``; by default ``surface_points(mesh)``.
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        mode: ConstraintMode | str = ConstraintMode.SNAP,
        points: Points | None = None,
    ) -> None:
        from skinloc.geometry.snap import Surface

        self.mesh = mesh
        self.mode = ConstraintMode(mode)
        self.points = (
            surface_points(mesh) if points is None else _as_points(points, "surface points")
        )
        # the engines' own constraint (skinloc.geometry.snap), so that there is one of it
        self._surface = Surface(
            self.mode.value,
            self.points,
            np.asarray(mesh.vertices, dtype=np.float64),
            np.asarray(mesh.faces, dtype=np.int64),
        )

    def __call__(self, points: Points) -> Points:
        """Constrain ``points (n, 3)`` m; returns ``(n, 3)`` m."""
        pts = _as_points(points)
        if self.mode is ConstraintMode.NONE:
            return pts
        return self._surface.constrain(pts)
