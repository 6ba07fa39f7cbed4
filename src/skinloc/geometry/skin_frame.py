"""The skin's own directions: "up" (the mesh's long axis), "right" and the outward normal.

Gestures name swipe directions in this frame (docs/multitouch.md, "Skin frame"); the gesture
script of the simulator and the live gesture recogniser use the same definitions.
"""

from __future__ import annotations

import math

import numpy as np

from skinloc._typing import Points

__all__ = ["quaternion_from_rpy", "skin_frame", "skin_up_axis"]


def skin_up_axis(vertices: Points) -> np.ndarray:
    """The mesh's long axis: the principal axis of its vertices, as a unit vector.

    Sign convention: the component of largest magnitude is positive (ties: the first such
    axis of x, y, z), so the result does not depend on the vertex order or on the SVD's sign.
    On the paper's semi-cone this is (0, 0.97, -0.23): up the cone's slope towards its narrow
    top (its vertices spread most along the height, although the chord across is wider); there
    ``skin_frame`` gives right = +x and the normal (0, 0.23, 0.97).

    Parameters
    ----------
    vertices : (n, 3) float
        Mesh vertices, m (any units: only the direction is returned).

    Returns
    -------
    (3,) float
        Unit vector.

    Raises
    ------
    ValueError
        If there are fewer than 2 distinct finite vertices.
    """
    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise ValueError(f"vertices must be a finite (n, 3) array, got shape {v.shape}")
    if len(v) < 2 or not np.any(v - v[0]):
        raise ValueError("vertices must hold at least 2 distinct points")
    centred = v - v.mean(axis=0)
    # eigh sorts eigenvalues ascending: the last eigenvector is the axis of largest spread
    _, vecs = np.linalg.eigh(centred.T @ centred)
    up = vecs[:, -1]
    # round before choosing the largest component, so that a near-tie between axes is settled
    # the same way on every machine
    if up[int(np.argmax(np.round(np.abs(up), 9)))] < 0:
        up = -up
    return up / np.linalg.norm(up)


def skin_frame(
    vertices: Points, faces: np.ndarray, up: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The skin's ``(up, right, normal)``: three orthonormal vectors.

    ``normal`` is the area-weighted mean of the face normals (outward as the faces' winding
    says), made orthogonal to ``up``; ``right = up x normal``: "right" as seen by someone
    looking at the skin from outside with "up" pointing up.

    Parameters
    ----------
    vertices : (n, 3) float
        Mesh vertices, m.
    faces : (f, 3) int
        Triangles.
    up : (3,) float, optional
        The skin's up; ``skin_up_axis(vertices)`` by default.

    Returns
    -------
    up, right, normal : (3,) float
        Unit vectors.
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    up = skin_up_axis(v) if up is None else np.asarray(up, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(up)) or np.linalg.norm(up) == 0:
        raise ValueError(f"up must be a finite non-zero (3,) vector, got {up!r}")
    up = up / np.linalg.norm(up)
    tri = v[f]
    area_normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])  # |n| = 2 x area
    normal = area_normals.sum(axis=0)
    normal = normal - (normal @ up) * up
    if np.linalg.norm(normal) < 1e-12 * max(np.abs(area_normals).sum(), 1e-300):
        # a closed surface has no mean normal: any direction orthogonal to up
        normal = np.cross(up, np.eye(3)[int(np.argmin(np.abs(up)))])
    normal /= np.linalg.norm(normal)
    right = np.cross(up, normal)
    return up, right / np.linalg.norm(right), normal


def quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Quaternion ``(x, y, z, w)`` of fixed-axis roll, pitch, yaw (rad), as ROS's ``tf2``."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    )
