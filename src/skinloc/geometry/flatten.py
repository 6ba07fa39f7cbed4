"""Flattening a skin surface onto the plane, for printable target sheets.

A cone or cylinder about the y axis (the paper's skin) unrolls exactly: distances along the
surface are kept. Any other open, disc-like mesh is unwrapped by a least-squares conformal map
refined with as-rigid-as-possible iterations, which keeps triangle shapes and sizes as far as
the surface allows; ``Flattening.stretch`` says how far that is.

All lengths are metres, in the mesh frame (3D) and in the sheet (2D).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Literal

import numpy as np
import trimesh

from skinloc._typing import Points
from skinloc.errors import MeshError

log = logging.getLogger(__name__)

__all__ = ["Flattening", "fit_y_cone", "flatten"]

#: Relative radius residual below which a mesh counts as a cone or cylinder about y.
CONE_TOLERANCE = 0.01


@dataclass(frozen=True)
class Flattening:
    """A map from a skin surface to the plane.

    Attributes
    ----------
    kind : {"cone", "cylinder", "unwrap"}
        ``cone`` and ``cylinder`` unroll exactly; ``unwrap`` is the conformal + ARAP unwrapping.
    vertices_2d : (V, 2) float
        Flat position of every mesh vertex, m.
    boundary : list of (k, 2) float
        The outline of the flat skin as closed polylines, m.
    stretch : float
        Largest relative change of a mesh edge's length (0 for an exact unrolling).
    """

    kind: Literal["cone", "cylinder", "unwrap"]
    vertices_2d: np.ndarray
    boundary: list[np.ndarray]
    stretch: float
    _mesh: trimesh.Trimesh
    _cone: tuple[float, float, float, float, bool] | None = None  # a, b, seam, centre, mirror

    def map_points(self, points: Points) -> np.ndarray:
        """Flat positions ``(n, 2)`` m of points ``(n, 3)`` m on (or near) the surface."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if self._cone is not None:
            a, b, seam, centre, mirror = self._cone
            return _unroll(pts, a, b, seam, centre) * [-1.0 if mirror else 1.0, 1.0]
        closest, _, face = trimesh.proximity.closest_point(self._mesh, pts)
        bary = trimesh.triangles.points_to_barycentric(self._mesh.triangles[face], closest)
        return np.einsum("nk,nkd->nd", bary, self.vertices_2d[self._mesh.faces[face]])


def fit_y_cone(mesh: trimesh.Trimesh) -> tuple[float, float] | None:
    """Fit ``r = a y + b`` (r the distance from the y axis) when the mesh is a cone about y.

    Returns ``(a, b)`` when every vertex and face centre lies within ``CONE_TOLERANCE`` of the
    fit (relative to the mean radius), else ``None``. ``a == 0`` is a cylinder.
    """
    v = np.concatenate([mesh.vertices, mesh.triangles_center])
    r = np.hypot(v[:, 0], v[:, 2])
    if len(mesh.vertices) < 6 or np.ptp(v[:, 1]) <= 1e-9 or r.mean() <= 1e-9:
        return None
    a, b = np.polyfit(v[:, 1], r, 1)
    if np.abs(a * v[:, 1] + b - r).max() > CONE_TOLERANCE * r.mean():
        return None
    return float(a), float(b)


def _seam_angle(theta: np.ndarray) -> float:
    """The angle in the middle of the widest gap between vertex angles (where to cut)."""
    t = np.sort(np.mod(theta, 2 * np.pi))
    gaps = np.diff(np.concatenate([t, [t[0] + 2 * np.pi]]))
    i = int(np.argmax(gaps))
    return float(t[i] + gaps[i] / 2)


def _unroll(points: np.ndarray, a: float, b: float, seam: float, centre: float = 0.0) -> np.ndarray:
    """Exact unrolling of points on the cone ``r = a y + b`` cut at angle ``seam``.

    ``centre`` is the angle from the seam that ends up in the middle of the sheet.
    """
    theta = np.arctan2(points[:, 2], points[:, 0])
    # Angle from the seam, in (0, 2 pi): the cut lies at both ends.
    phi = np.mod(theta - seam, 2 * np.pi) - centre
    r = np.hypot(points[:, 0], points[:, 2])
    y = points[:, 1]
    if abs(a) < 1e-9:  # cylinder: arc length around, height along
        return np.stack([r * phi, y], axis=1)
    apex = -b / a
    slant = np.hypot(r, y - apex)  # distance from the apex, along the surface
    sin_half = abs(a) / np.hypot(1.0, a)  # sine of the cone's half-angle
    psi = phi * sin_half  # angle in the flat sector
    # The wide end at the bottom of the sheet: the apex lies above, on the y axis of the sheet.
    sign = 1.0 if a > 0 else -1.0
    return np.stack([slant * np.sin(psi), -slant * np.cos(psi)], axis=1) * sign


def _mirrored(mesh: trimesh.Trimesh, uv: np.ndarray) -> bool:
    """Whether the flat faces turn the other way than the mesh's (front) faces."""
    t = uv[mesh.faces]
    e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
    return bool((e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum() < 0)


def _boundary_loops(mesh: trimesh.Trimesh) -> list[np.ndarray]:
    """Vertex indices of each boundary loop (edges used by exactly one face)."""
    edges = mesh.edges_sorted
    groups = trimesh.grouping.group_rows(edges, require_count=1)
    if len(groups) == 0:
        return []
    boundary = edges[groups]
    nxt: dict[int, list[int]] = {}
    for u, v in boundary:
        nxt.setdefault(int(u), []).append(int(v))
        nxt.setdefault(int(v), []).append(int(u))
    loops, seen = [], set()
    for start in nxt:
        if start in seen:
            continue
        loop, prev, cur = [start], -1, start
        seen.add(start)
        while True:
            options = [w for w in nxt[cur] if w != prev and (w not in seen or w == start)]
            if not options:
                break
            prev, cur = cur, options[0]
            if cur == start:
                break
            loop.append(cur)
            seen.add(cur)
        loops.append(np.asarray(loop))
    return loops


def _edge_stretch(mesh: trimesh.Trimesh, uv: np.ndarray) -> float:
    e = mesh.edges_unique
    l3 = np.linalg.norm(mesh.vertices[e[:, 0]] - mesh.vertices[e[:, 1]], axis=1)
    l2 = np.linalg.norm(uv[e[:, 0]] - uv[e[:, 1]], axis=1)
    ok = l3 > 1e-12
    return float(np.abs(l2[ok] / l3[ok] - 1.0).max()) if ok.any() else 0.0


def flatten(mesh: trimesh.Trimesh, arap_iterations: int = 40) -> Flattening:
    """Flatten a skin surface: exact for a cone or cylinder about y, else unwrapped.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Open skin surface, m.
    arap_iterations : int
        As-rigid-as-possible refinement steps of the general unwrapping.

    Returns
    -------
    Flattening

    Raises
    ------
    MeshError
        If a mesh that is not a cone must be unwrapped but is closed, in pieces, or not a disc.

    Examples
    --------
    >>> from skinloc.geometry.mesh import cone_skin
    >>> flat = flatten(cone_skin())
    >>> flat.kind, round(flat.stretch, 3) < 0.01
    ('cone', True)
    """
    mesh = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)  # merge duplicate vertices
    cone = fit_y_cone(mesh)
    if cone is not None:
        a, b = cone
        theta = np.arctan2(mesh.vertices[:, 2], mesh.vertices[:, 0])
        seam = _seam_angle(theta)
        phi = np.mod(theta - seam, 2 * np.pi)
        centre = float(phi.min() + phi.max()) / 2
        uv = _unroll(mesh.vertices, a, b, seam, centre)
        # Seen from the front of the skin, the sheet must not come out mirrored.
        mirror = _mirrored(mesh, uv)
        flip = np.array([-1.0 if mirror else 1.0, 1.0])
        uv = uv * flip
        outline = []
        for loop in _boundary_loops(mesh):
            # Unroll points along each rim edge too, so arcs come out as arcs.
            p = mesh.vertices[loop]
            q = np.roll(p, -1, axis=0)
            t = np.linspace(0.0, 1.0, 9)[:-1, None, None]
            dense = (p[None] * (1 - t) + q[None] * t).transpose(1, 0, 2).reshape(-1, 3)
            # Keep the dense points on the true cone (chords cut inside it).
            r_true = a * dense[:, 1] + b
            r_now = np.maximum(np.hypot(dense[:, 0], dense[:, 2]), 1e-12)
            dense[:, [0, 2]] *= (r_true / r_now)[:, None]
            outline.append(_unroll(dense, a, b, seam, centre) * flip)
        kind: Literal["cone", "cylinder"] = "cylinder" if abs(a) < 1e-9 else "cone"
        # Exact by construction; report the chord error of the mesh against the true cone.
        return Flattening(kind, uv, outline, 0.0, mesh, (a, b, seam, centre, mirror))

    if mesh.body_count != 1:
        raise MeshError(
            f"cannot unwrap a skin mesh in {mesh.body_count} pieces: export one connected surface"
        )
    loops = _boundary_loops(mesh)
    if not loops:
        raise MeshError("cannot unwrap a closed mesh: export only the skin's open surface")
    if mesh.euler_number != 1 or len(loops) != 1:
        raise MeshError(
            "cannot unwrap this skin mesh: it must be a single sheet with one outline "
            f"(Euler number {mesh.euler_number}, {len(loops)} outlines)"
        )
    uv = _lscm(mesh, loops[0])
    uv = _arap(mesh, uv, arap_iterations)
    if _mirrored(mesh, uv):
        uv[:, 0] *= -1
    outline = [np.vstack([uv[loop], uv[loop[:1]]]) for loop in loops]
    return Flattening("unwrap", uv, outline, _edge_stretch(mesh, uv), mesh)


# ------------------------------------------------------------------------------------------------
# the general unwrapping


def _local_gradients(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Per-face gradient operators ``G (F, 2, 3)`` in a local frame, and face areas ``(F,)``."""
    tri = mesh.triangles
    e1 = tri[:, 1] - tri[:, 0]
    e2 = tri[:, 2] - tri[:, 0]
    n = np.cross(e1, e2)
    area2 = np.linalg.norm(n, axis=1)
    if np.any(area2 <= 1e-18):
        raise MeshError("cannot unwrap a mesh with degenerate (zero-area) triangles")
    x = e1 / np.linalg.norm(e1, axis=1, keepdims=True)
    y = np.cross(n / area2[:, None], x)
    # Local 2D edge vectors: D @ grad = [f1 - f0, f2 - f0].
    D = np.stack(
        [
            np.stack([(e1 * x).sum(1), (e1 * y).sum(1)], axis=1),
            np.stack([(e2 * x).sum(1), (e2 * y).sum(1)], axis=1),
        ],
        axis=1,
    )
    G = np.linalg.inv(D) @ np.array([[-1.0, 1.0, 0.0], [-1.0, 0.0, 1.0]])
    return G, area2 / 2


def _gradient_matrix(mesh: trimesh.Trimesh, G: np.ndarray, area: np.ndarray):
    """Sparse ``(2F, V)`` matrix of area-weighted per-face gradients (x rows, then y rows)."""
    from scipy import sparse

    F, V = len(mesh.faces), len(mesh.vertices)
    w = np.sqrt(area)[:, None]
    rows = np.concatenate([np.repeat(np.arange(F), 3), F + np.repeat(np.arange(F), 3)])
    cols = np.tile(mesh.faces.ravel(), 2)
    vals = np.concatenate([(G[:, 0] * w).ravel(), (G[:, 1] * w).ravel()])
    return sparse.csr_matrix((vals, (rows, cols)), shape=(2 * F, V))


def _lscm(mesh: trimesh.Trimesh, loop: np.ndarray) -> np.ndarray:
    """Least-squares conformal map with two far-apart boundary vertices pinned."""
    from scipy import sparse
    from scipy.sparse.linalg import lsqr

    G, area = _local_gradients(mesh)
    A = _gradient_matrix(mesh, G, area)  # rows: d/dx (F), then d/dy (F)
    F, V = len(mesh.faces), len(mesh.vertices)
    Ax, Ay = A[:F], A[F:]
    # Cauchy-Riemann: du/dx = dv/dy and du/dy = -dv/dx.
    M = sparse.vstack([sparse.hstack([Ax, -Ay]), sparse.hstack([Ay, Ax])]).tocsc()
    p = mesh.vertices[loop]
    d = np.linalg.norm(p[:, None] - p[None], axis=2)
    i, j = np.unravel_index(int(np.argmax(d)), d.shape)
    pins = {int(loop[i]): (0.0, 0.0), int(loop[j]): (float(d[i, j]), 0.0)}
    fixed = np.zeros(2 * V, dtype=bool)
    x_fixed = np.zeros(2 * V)
    for vid, (u, v) in pins.items():
        fixed[[vid, V + vid]] = True
        x_fixed[vid], x_fixed[V + vid] = u, v
    rhs = -(M[:, fixed] @ x_fixed[fixed])
    sol = lsqr(M[:, ~fixed], rhs, atol=1e-12, btol=1e-12, iter_lim=20 * V)[0]
    x = x_fixed.copy()
    x[~fixed] = sol
    return np.stack([x[:V], x[V:]], axis=1)


def _arap(mesh: trimesh.Trimesh, uv: np.ndarray, iterations: int) -> np.ndarray:
    """As-rigid-as-possible refinement (local rotations, global Poisson solve)."""
    from scipy.sparse.linalg import factorized

    G, area = _local_gradients(mesh)
    A = _gradient_matrix(mesh, G, area)
    V = len(mesh.vertices)
    L = (A.T @ A).tocsc()
    keep = np.arange(1, V)  # vertex 0 pinned where it is (translation)
    solve = factorized(L[keep][:, keep].tocsc())
    w = np.sqrt(area)
    faces = mesh.faces
    for _ in range(iterations):
        J = np.einsum("fij,fjk->fik", G, uv[faces])  # (F, 2 local, 2 uv): J[f, :, c] = grad uv_c
        U, _, Vt = np.linalg.svd(J)
        R = U @ Vt
        flip = np.linalg.det(R) < 0
        if flip.any():
            U[flip, :, -1] *= -1
            R[flip] = U[flip] @ Vt[flip]
        new = uv.copy()
        for c in range(2):
            target = np.concatenate([R[:, 0, c] * w, R[:, 1, c] * w])
            rhs = A.T @ target - L[:, [0]] @ uv[[0], [c]]
            new[keep, c] = solve(rhs[keep])
        uv = new
    # Centre and turn so that the longest extent runs along x.
    uv = uv - uv.mean(axis=0)
    _, _, axes = np.linalg.svd(uv, full_matrices=False)
    return uv @ axes.T
