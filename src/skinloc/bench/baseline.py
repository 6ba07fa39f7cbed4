"""The plain NumPy baselines the live path is compared with (``skinloc bench --online``).

Used by ``skinloc.bench.online`` (one stream, batches) and ``skinloc.bench.many_skins`` (the
100-skin loop's CPU per frame beside the baseline's, in the loops' own processes). One entry
per model kind in ``PLAIN_BASELINES``; a benchmark's baseline, not a second engine.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["PLAIN_BASELINES", "baseline_fn", "plain_baseline"]


def _plain_network(spec: Any) -> Callable[[np.ndarray], np.ndarray]:
    """A NumPy forward pass over the ensemble and a scipy ``cKDTree`` snap."""
    from scipy.spatial import cKDTree

    from skinloc.models.network_engine import activate_inplace

    pts = spec.surface_points
    tree = cKDTree(pts)

    def plain(X: np.ndarray) -> np.ndarray:
        Z = np.maximum(X, 0.0) if spec.clip_negative else X
        if spec.normalise != "none":
            order = 1 if spec.normalise == "l1" else 2
            Z = Z / np.maximum(np.linalg.norm(Z, ord=order, axis=1, keepdims=True), 1.0)
        h = (Z - spec.feature_mean) / spec.feature_scale
        for i, (W, b) in enumerate(zip(spec.weights, spec.biases, strict=True)):
            h = np.matmul(h, W) + b
            if i < len(spec.weights) - 1:
                h = activate_inplace(h, spec.activation)
        raw = (h * spec.target_scale + spec.target_mean).mean(axis=0)
        return pts[tree.query(raw)[1]]

    return plain


def _plain_map_match(spec: Any) -> Callable[[np.ndarray], np.ndarray]:
    """Coarse-to-fine matching in NumPy, 512 rows at a time: the best of the 8 best cells."""
    T = np.asarray(spec.table, dtype=np.float32)
    sq = (T**2).sum(axis=1)
    coarse, members = spec.coarse, spec.cells

    def plain(X: np.ndarray) -> np.ndarray:
        Z = np.maximum(X, 0.0) if spec.clip_negative else X
        F = (Z / np.maximum(np.linalg.norm(Z, axis=1, keepdims=True), 1.0)).astype(np.float32)
        out = []
        for i in range(0, len(F), 512):
            Fs = F[i : i + 512]
            dc = sq[coarse][None, :] - 2.0 * Fs @ T[coarse].T
            best_cells = np.argpartition(dc, spec.n_cells - 1, axis=1)[:, : spec.n_cells]
            idx = members[best_cells].reshape(len(Fs), -1)
            d = sq[idx] - 2.0 * np.einsum("nk,nck->nc", Fs, T[idx])
            out.append(spec.surface_points[idx[np.arange(len(Fs)), d.argmin(axis=1)]])
        return np.concatenate(out)

    return plain


#: Each model kind's plain NumPy implementation, the engine's baseline in this benchmark, by
#: the kind's name: ``(build(spec) -> rows (n, n_sensors) to points (n, 3) m, its label)``.
#: A response map's is its coarse-to-fine match (the library's own prediction before the
#: engine). A benchmark's baseline, not a second engine: nothing else calls it.
PLAIN_BASELINES: dict[str, tuple[Callable[[Any], Callable[[np.ndarray], np.ndarray]], str]] = {
    "map": (_plain_map_match, "numpy coarse-to-fine match"),
    "network": (_plain_network, "numpy forward + scipy cKDTree snap"),
}


def plain_baseline(kind: str) -> tuple[Callable[[Any], Callable[[np.ndarray], np.ndarray]], str]:
    """The entry of ``PLAIN_BASELINES`` for the model kind ``kind``; ValueError when none."""
    entry = PLAIN_BASELINES.get(kind)
    if entry is None:
        raise ValueError(
            f"no plain baseline for a {kind!r} model; the online benchmark has them for "
            f"{', '.join(PLAIN_BASELINES)} (skinloc.bench.online.PLAIN_BASELINES)"
        )
    return entry


def baseline_fn(model: Any) -> Callable[[np.ndarray], np.ndarray]:
    """The plain NumPy implementation the engine is compared with: rows ``(n, 64)`` to points.

    Its kind's entry of ``PLAIN_BASELINES``.
    """
    spec = model.spec()
    build, _ = plain_baseline(spec.kind)
    return build(spec)
