"""Active calibration: ask for the touch that lowers the expected localisation error most.

Greedy: from a few well-spread touches, fit the response map on the touches so far, and for
every candidate target ``c`` predict how the map's posterior variance would shrink if ``c``
were touched (a rank-one update that needs no image of ``c``), hence the new expected error
over the skin (``sensors.coverage``); ask for the ``c`` with the lowest mean. Only the images
of touches already made are used.

``select_point_logs`` applies a strategy (``active``, ``random``, ``even``) to the point logs
of existing recordings, to train on a subset and measure the gain on real data.

``recalibration_targets`` chooses the touches a later session is asked for, to recalibrate an
old map (``skinloc train NEW --init OLD --select k``), from the old map alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from skinloc._typing import Points
from skinloc.sensors.coverage import GPState, expected_error_mm, gp_state

__all__ = [
    "STRATEGIES",
    "TARGET_STRATEGIES",
    "next_targets",
    "recalibration_targets",
    "scores_after_touch",
    "select_point_logs",
    "subset_recordings",
]

STRATEGIES = ("active", "random", "even")
#: How ``recalibration_targets`` chooses.
TARGET_STRATEGIES = ("active", "random")
#: Well-spread touches an active session starts from.
N_START = 4


def _fit_map(
    targets: Points, images: np.ndarray, candidates: Points, prior: str = "package"
) -> tuple[Any, np.ndarray]:
    """The map of the touches so far, with the map prior where the default model uses it."""
    from skinloc.models.map_prior import load_prior
    from skinloc.models.response_map import ResponseMap, shape_features

    F = shape_features(images)
    p = None if prior == "none" else load_prior(None if prior == "package" else prior)
    if p is not None and not p.applies(len(F)):
        p = None
    return ResponseMap.fit(targets, F, candidates, prior=p), F


def active_scores(
    targets: Points,
    images: np.ndarray,
    pool: Points,
    eval_points: Points,
    candidates: Points,
    prior: str = "package",
) -> np.ndarray:
    """Mean expected error over ``eval_points`` (mm) after touching each pool target.

    Parameters
    ----------
    targets : (n, 3) float
        Touches made so far, m.
    images : (n, k) float
        Their baseline-subtracted mean images, counts.
    pool : (c, 3) float
        Candidate next targets, m.
    eval_points : (E, 3) float
        Where the expected error is averaged, m.
    candidates : (P, 3) float
        The map's surface points, m.
    prior : str
        The map prior, as ``ContactLocalizer``'s ``prior`` (``"package"``, ``"none"``, a path).

    Returns
    -------
    (c,) float
        Mean expected error after each candidate touch, mm (lower is better).
    """
    rmap, F = _fit_map(targets, images, candidates, prior)
    return scores_after_touch(gp_state(rmap, F), rmap, pool, eval_points)


def scores_after_touch(gp: GPState, rmap: Any, pool: Points, eval_points: Points) -> np.ndarray:
    """Mean expected error over ``eval_points (E, 3)`` m after touching each of ``pool (c, 3)``.

    ``gp`` holds the touches so far (its posterior variance needs no image); ``rmap`` (a
    ``ResponseMap``) gives the features the competitors are told apart by. Returns ``(c,)``
    mm, lower is better.
    """
    E_mm, C_mm = 1e3 * np.asarray(eval_points), 1e3 * np.asarray(pool)
    mu = rmap.evaluate_mm(E_mm)
    var_e = gp.posterior_var(E_mm)
    var_c = gp.posterior_var(C_mm)
    cov_ec = gp.posterior_cov(E_mm, C_mm)  # (E, c)
    # Posterior variance at the evaluation points after a touch at c (no image needed).
    shrink = cov_ec**2 / (var_c + gp.noise)[None, :]
    scores = np.empty(len(C_mm))
    for j in range(len(C_mm)):
        s2 = gp.noise + np.maximum(var_e - shrink[:, j], 0.0)
        # Unnormalised, self included: poorly known places count as competitors everywhere,
        # so touching them scores high. Measured on 80PL_1, 20 touches, seed 0: 10.4 mm; the
        # normalised score clusters the touches (28 mm), excluding self gave 13.0 mm.
        scores[j] = expected_error_mm(
            eval_points, mu, s2, normalised=False, exclude_self=False
        ).mean()
    return scores


def next_targets(
    targets: Points,
    images: np.ndarray,
    pool: Points,
    candidates: Points,
    n_eval: int = 200,
) -> int:
    """Index into ``pool (c, 3)`` m of the target to ask for next (see ``active_scores``)."""
    from skinloc.geometry.mesh import farthest_point_sampling

    ev = candidates[farthest_point_sampling(candidates, min(n_eval, len(candidates)))]
    return int(np.argmin(active_scores(targets, images, pool, ev, candidates)))


def recalibration_targets(
    old_map: Any,
    k: int,
    pool: Points | None = None,
    *,
    strategy: str = "active",
    random_state: int = 0,
    n_eval: int = 200,
) -> np.ndarray:
    """Which ``k`` targets to ask a later session for, to recalibrate ``old_map`` on them.

    Nothing of the new session is known before its touches, so the choice rests on the old map
    alone. ``active``: the first target is drawn (seeded), then greedily the one after which a
    map of the new touches (a Gaussian process with the old map's kernel: length scale,
    amplitude, noise) has the lowest mean expected error over ``n_eval`` evenly spread surface
    points, the competitors told apart by the old map's features (``scores_after_touch``, the
    score of active calibration): the touches spread over the surface, denser where the old
    map's responses are alike (where a changed response most likely moves the match).
    ``random``: ``k`` distinct targets in a seeded random order.

    Parameters
    ----------
    old_map : ResponseMap or None
        The old session's map (``ContactLocalizer.map_``); ``None`` will do for ``random``
        from a given ``pool``.
    k : int
        Targets wanted, ``0 <= k <=`` the pool's distinct targets.
    pool : (c, 3) float, optional
        Where touches may be asked, m (e.g. a recording's targets); default: ``n_eval`` evenly
        spread points of the map's surface. A target listed twice is one candidate.
    strategy : {"active", "random"}
    random_state : int, default=0
        Seed of the first (``active``) or every (``random``) target.
    n_eval : int, default=200
        Surface points the expected error is averaged over.

    Returns
    -------
    (k,) int
        Indices into ``pool`` (into the default pool: ``pool`` is then ``old_map.candidates``
        spread as described), in the order chosen; distinct targets.

    Raises
    ------
    ValueError
        For an unknown strategy or ``k`` outside ``0..`` the distinct targets.
    """
    from skinloc.geometry.mesh import farthest_point_sampling

    if strategy not in TARGET_STRATEGIES:
        raise ValueError(
            f"strategy must be one of {', '.join(TARGET_STRATEGIES)}; got {strategy!r}"
        )
    if old_map is None and (strategy == "active" or pool is None):
        raise ValueError("old_map is needed for strategy 'active' or without a pool")
    ev = None
    if old_map is not None:
        cands = np.asarray(old_map.candidates, dtype=np.float64)
        ev = cands[farthest_point_sampling(cands, min(n_eval, len(cands)))]
    pool = ev if pool is None else np.asarray(pool, dtype=np.float64).reshape(-1, 3)
    first = np.sort(_unique_rows(pool)[0])
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= len(first):
        raise ValueError(
            f"k must be an integer between 0 and {len(first)} (distinct targets), got {k!r}"
        )
    rng = np.random.default_rng(random_state)
    if strategy == "random" or k == 0:
        return rng.permutation(first)[:k]
    old = gp_state(old_map)
    chosen = [int(first[rng.integers(len(first))])]
    while len(chosen) < k:
        left = np.setdiff1d(first, chosen)
        gp = GPState(1e3 * pool[chosen], old.length_scale_mm, old.amplitude, old.noise)
        chosen.append(int(left[np.argmin(scores_after_touch(gp, old_map, pool[left], ev))]))
    return np.asarray(chosen, dtype=np.int64)


def _unique_rows(points: Points) -> tuple[np.ndarray, np.ndarray]:
    """First index of each distinct target (mm-rounded) and the owner of every row."""
    key = np.round(1e3 * np.asarray(points), 3)
    _, first, owner = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return first, owner.ravel()


def select_point_logs(
    recordings: Sequence[Any],
    n: int,
    strategy: str = "active",
    random_state: int = 0,
    n_eval: int = 200,
    progress: Any = None,
    eval_at: str = "surface",
    prior: str = "package",
) -> list[tuple[int, int]]:
    """Choose ``n`` point logs from recordings in the order a strategy asks for them.

    ``random`` draws them in a seeded random order; ``even`` spreads them by farthest-point
    sampling from a seeded first touch; ``active`` starts like ``even`` with ``N_START``
    touches, then adds the touch that lowers the mean expected error most (using only the
    images of the touches already chosen). A target recorded twice is one candidate; the
    first recording that holds it supplies the image. ``eval_at="surface"`` averages the
    expected error over ``n_eval`` evenly spread surface points; ``"pool"`` over the pool's
    distinct targets (where touches are asked: denser towards the cone's narrow top). The
    pool variant won on a development split and lost on the reported one
    (docs/accuracy.md), so it is not the default. ``prior`` is the map prior the active
    strategy's maps are fitted with, as ``ContactLocalizer``'s (applied up to its
    ``max_touches``).

    Returns
    -------
    list of (recording index, point-log index)
        In the order chosen.

    Raises
    ------
    ValueError
        For an unknown strategy or ``n`` larger than the pool.
    """
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy must be one of {', '.join(STRATEGIES)}; got {strategy!r}")
    if eval_at not in ("pool", "surface"):
        raise ValueError(f"eval_at must be 'pool' or 'surface', got {eval_at!r}")
    from skinloc.geometry.mesh import farthest_point_sampling

    owners = [(r, i) for r, rec in enumerate(recordings) for i in range(rec.n_point_logs)]
    targets = np.concatenate([rec.targets for rec in recordings])
    images = np.concatenate([rec.touch_means for rec in recordings]).astype(np.float64)
    first, _ = _unique_rows(targets)
    first = np.sort(first)
    if not 1 <= n <= len(first):
        raise ValueError(f"--select must be between 1 and {len(first)} (distinct targets), got {n}")
    rng = np.random.default_rng(random_state)
    if strategy == "random":
        order = rng.permutation(first)[:n]
        return [owners[i] for i in order]
    start = int(rng.integers(len(first)))
    spread = farthest_point_sampling(
        targets[first], n if strategy == "even" else min(n, N_START), start
    )
    chosen = list(first[spread])
    if strategy == "active" and n > len(chosen):
        cands = recordings[0].surface_points
        if cands is None:
            from skinloc.geometry.mesh import surface_points

            cands = surface_points(recordings[0].mesh)
        ev = (
            targets[first]
            if eval_at == "pool"
            else cands[farthest_point_sampling(cands, min(n_eval, len(cands)))]
        )
        while len(chosen) < n:
            left = np.setdiff1d(first, chosen)
            scores = active_scores(targets[chosen], images[chosen], targets[left], ev, cands, prior)
            chosen.append(int(left[np.argmin(scores)]))
            if progress is not None:
                progress(len(chosen), n)
    return [owners[i] for i in chosen]


def subset_recordings(recordings: Sequence[Any], picks: list[tuple[int, int]]) -> list[Any]:
    """The chosen point logs as recordings (each keeps its own baseline), in pick order."""
    out = []
    for r, rec in enumerate(recordings):
        idx = [i for rr, i in picks if rr == r]
        if idx:
            out.append(rec.subset(idx))
    return out
