"""Glue between recordings and the localiser: training arrays and scored evaluations."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from skinloc.data.recording import Recording
from skinloc.errors import RecordingError
from skinloc.evaluation.metrics import ErrorStats, error_stats, localisation_errors_mm

__all__ = [
    "Evaluation",
    "check_compatible",
    "evaluate",
    "prior_curve",
    "train_localizer",
    "training_arrays",
]


def check_compatible(
    recordings: Sequence[Recording], n_sensors: int | None = None, *, touches: bool = True
) -> int:
    """Check that all recordings share one sensor count (and ``n_sensors`` if given).

    With ``touches`` (the default) each must hold point logs too.
    """
    if not recordings:
        raise RecordingError("no recordings given")
    counts = {r.n_sensors for r in recordings}
    if len(counts) > 1:
        raise RecordingError(f"recordings have different sensor counts: {sorted(counts)}")
    (count,) = counts
    if n_sensors is not None and count != n_sensors:
        raise RecordingError(f"the recording has {count} sensors but the model expects {n_sensors}")
    for r in recordings:
        if touches and r.n_point_logs == 0:
            raise RecordingError("a recording holds no point logs")
    return count


def check_same_skin(model, recordings: Sequence[Recording]) -> None:
    """Refuse recordings made on another mesh than the one ``model`` was trained on.

    A model's targets live in its own mesh's frame: scored against another skin's targets it
    gives a large error that means nothing (121.8 mm for the cone against a sphere).
    """
    from skinloc.geometry.mesh import mesh_from_arrays, same_surface

    vertices = getattr(model, "mesh_vertices_", None)
    faces = getattr(model, "mesh_faces_", None)
    if vertices is None or faces is None:
        return  # a model saved without its mesh: nothing to compare
    mine = mesh_from_arrays(vertices, faces)
    for k, rec in enumerate(recordings):
        theirs = rec.mesh
        if not same_surface(mine, theirs):
            size = np.ptp(np.asarray(theirs.bounds), axis=0) * 1e3
            own = np.ptp(np.asarray(mine.bounds), axis=0) * 1e3
            raise RecordingError(
                f"recording {k + 1} was made on another mesh than the model's (extent "
                f"{size[0]:.0f} x {size[1]:.0f} x {size[2]:.0f} mm against {own[0]:.0f} x "
                f"{own[1]:.0f} x {own[2]:.0f} mm): use recordings of the model's own skin"
            )


def training_arrays(recordings: Sequence[Recording]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every frame of every point log, baseline-subtracted with its own recording's baseline.

    Returns
    -------
    X : (N, n_sensors) float32
        Frames, counts.
    y : (N, 3) float
        Targets, m.
    groups : (N,) int
        Touch index, unique across recordings.
    """
    check_compatible(recordings)
    X, y, groups, offset = [], [], [], 0
    for rec in recordings:
        d = rec.deltas
        n, s = d.shape[:2]
        X.append(d.reshape(n * s, -1))
        y.append(np.repeat(rec.targets, s, axis=0))
        groups.append(np.repeat(np.arange(n) + offset, s))
        offset += n
    return np.concatenate(X), np.concatenate(y), np.concatenate(groups)


@dataclass(frozen=True)
class Evaluation:
    """Scored predictions.

    Attributes
    ----------
    stats : ErrorStats
        Error summary, mm.
    errors_mm : (n,) float
        Error of each scored sample.
    predicted, true : (n, 3) float
        Points, m.
    uncertainty_mm : (n,) float
        Predicted uncertainty of each sample, mm.
    uncertainty_spearman : float
        Rank correlation of uncertainty with error (nan for a single network).
    """

    stats: ErrorStats
    errors_mm: np.ndarray
    predicted: np.ndarray
    true: np.ndarray
    uncertainty_mm: np.ndarray
    uncertainty_spearman: float

    def as_dict(self) -> dict[str, float | int]:
        """Summary for JSON output."""
        return {**self.stats.as_dict(), "uncertainty_spearman": self.uncertainty_spearman}


def evaluate(model, recordings: Sequence[Recording], per_frame: bool = False) -> Evaluation:
    """Score ``model`` on recordings: each touch's mean image, or every frame."""
    check_compatible(recordings, getattr(model, "n_features_in_", None))
    check_same_skin(model, recordings)
    if per_frame:
        X, y, _ = training_arrays(recordings)
    else:
        X = np.concatenate([r.touch_means for r in recordings])
        y = np.concatenate([r.targets for r in recordings])
    pred = model.predict_full(X)
    errors = localisation_errors_mm(pred.points, y)
    rho = float("nan")
    if np.all(np.isfinite(pred.uncertainty_mm)) and len(errors) > 2:
        from scipy.stats import spearmanr

        rho = float(spearmanr(pred.uncertainty_mm, errors).statistic)
    return Evaluation(error_stats(errors), errors, pred.points, y, pred.uncertainty_mm, rho)


def train_localizer(
    recordings: Sequence[Recording],
    *,
    arch: str = "default",
    constraint: str = "snap",
    random_state: int = 0,
    mesh=None,
    progress=None,
    **overrides,
):
    """Fit a ``ContactLocalizer`` on recordings of one skin.

    The surface constraint uses ``mesh`` if given, else the first recording's mesh and its
    discretised surface points. Extra keyword arguments override the architecture's settings.
    """
    from skinloc.models.localizer import ContactLocalizer

    X, y, groups = training_arrays(recordings)
    first = recordings[0]
    model = ContactLocalizer(
        arch=arch, constraint=constraint, random_state=random_state, **overrides
    )
    model.fit(
        X,
        y,
        groups=groups,
        mesh=first.mesh if mesh is None else mesh,
        surface_points=first.surface_points if mesh is None else None,
        progress=progress,
    )
    model.training_meta_ = {
        "n_recordings": len(recordings),
        "n_point_logs": int(sum(r.n_point_logs for r in recordings)),
        "sources": [r.meta.get("description") or r.meta.get("source", "") for r in recordings],
        "n_tx": first.n_tx,
        "n_rx": first.n_rx,
    }
    return model


def prior_curve(
    train: Recording,
    tests: Sequence[Recording],
    sizes: Sequence[int] = (5, 10, 20, 40, 80),
    *,
    mesh=None,
    **overrides,
) -> dict[str, list]:
    """Error against calibration touches with and without the map prior, on one skin.

    The default model (a response map) is fitted on evenly spread subsets of ``train``'s
    touches (farthest-point, the first touch first) of each size in ``sizes`` up to all of
    them, with its map prior (``overrides["prior"]``, else the package's) and without it, and
    scored on ``tests``. Where the prior is not applied (more touches than it helps at) the
    two models are the same and fitted once.

    Returns
    -------
    dict
        ``sizes`` (touches), ``prior_mm`` and ``no_prior_mm`` (mean error per touch, mm,
        rounded to 0.1), ``prior_applied`` (bool per size).
    """
    from skinloc.geometry.mesh import farthest_point_sampling

    n = train.n_point_logs
    ns = sorted({int(k) for k in sizes if 1 <= k < n} | {n})
    out: dict[str, list] = {"sizes": ns, "prior_mm": [], "no_prior_mm": [], "prior_applied": []}
    for k in ns:
        sub = train if k == n else train.subset(farthest_point_sampling(train.targets, k, 0))
        # scored on single touches only: no count rule (models.localizer, count_rule)
        with_prior = train_localizer([sub], mesh=mesh, count_rule=False, **overrides)
        used = bool(getattr(with_prior, "prior_used_", False))
        mm = round(float(evaluate(with_prior, tests).stats.mean_mm), 1)
        if used:
            plain = train_localizer(
                [sub], mesh=mesh, count_rule=False, **{**overrides, "prior": "none"}
            )
            plain_mm = round(float(evaluate(plain, tests).stats.mean_mm), 1)
        else:
            plain_mm = mm
        out["prior_mm"].append(mm)
        out["no_prior_mm"].append(plain_mm)
        out["prior_applied"].append(used)
    return out
