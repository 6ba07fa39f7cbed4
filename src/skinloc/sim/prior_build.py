"""Build the response map's prior from simulated skins (``skinloc prior build``).

Each skin is drawn afresh: its own wiring (seeded layout), its physics jittered around the
simulator's defaults (footprint fall-off, silicone thickness, line coupling, peak signal,
gains) and its faults moved (a random weak RX line, a random noisy crossing), so the prior
holds what skins share and no particular skin's layout. Each skin is calibrated like the
real ones (``n_touches`` targets on random mesh edges, a person's probing error, 50 frames a
touch, means minus a no-touch baseline).

Two stages, each over its own skins, each run through joblib (``Parallel``/``delayed``; under
``joblib.parallel_config(backend="dask")`` the same calls run on a Dask cluster):

1. *hyperparameters*: the GP's maximum-likelihood hyperparameters of every skin's full
   calibration; their log mean and spread are the prior's log-normal hyperpriors, and the
   mean shape feature the common level;
2. *strength*: on other skins, the map's error from 5, 10 and 20 touches for each candidate
   widening of the hyperpriors and ``mean_pseudo_touches``; the least mean error is kept.
   The same skins give the error with and without the prior (``BuildReport.curve``), on
   skins the first stage never saw, and ``max_touches``: up to where the prior helped.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skinloc.models.map_prior import PRIOR_FORMAT_VERSION, MapPrior

__all__ = [
    "BuildReport",
    "build_prior",
    "draw_params",
    "errors_mm",
    "simulate_calibration",
    "skin_hyperparameters",
]

#: Candidate weights of the common level in the map's mean, in touches.
PSEUDO_TOUCH_GRID = (0.0, 2.0, 5.0, 10.0)
#: Candidate widenings of the hyperpriors' log spread (1: the spread between skins).
SPREAD_GRID = (0.5, 1.0, 3.0)
#: Calibration sizes the shrinkage is chosen on (and the curve reported at).
CURVE_SIZES = (5, 10, 15, 20, 40)
#: Surface points the simulated maps choose among (fewer than a real model's 14400: speed).
_N_CANDIDATES = 4000
#: Floor of a hyperprior's log spread: the prior narrows the search, it never pins a value.
_MIN_LOG_STD = 0.1


def draw_params(rng: np.random.Generator, n_rx: int, n_tx: int) -> Any:
    """The simulator's defaults with the physics jittered and the faults moved."""
    from skinloc.sim.params import SkinParams

    p = SkinParams.default()

    def jitter(v: float, rel: float) -> float:
        return float(v * np.exp(rel * rng.standard_normal()))

    return dataclasses.replace(
        p,
        falloff_exponent=jitter(p.falloff_exponent, 0.15),
        silicone_thickness_m=jitter(p.silicone_thickness_m, 0.15),
        silicone_thickness_base_m=jitter(p.silicone_thickness_base_m, 0.15),
        line_coupling=jitter(p.line_coupling, 0.3),
        peak_signal_counts=jitter(p.peak_signal_counts, 0.2),
        gain_std=jitter(p.gain_std, 0.3),
        weak_rx_lines=(int(rng.integers(n_rx)),),
        noisy_sensors=((int(rng.integers(n_tx)), int(rng.integers(n_rx))),),
    )


def simulate_calibration(
    seed: int, n_touches: int, n_tx: int = 8, n_rx: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """One simulated skin's calibration: ``(targets (n, 3) m, touch means (n, k) counts)``.

    The skin (wiring, physics, faults, touches, noise) follows ``seed`` alone.
    """
    from skinloc.geometry.mesh import cone_skin, sample_targets
    from skinloc.sim.skin import SimulatedSkin

    rng = np.random.default_rng([seed, 25])
    mesh = cone_skin()
    skin = SimulatedSkin(
        mesh, n_tx=n_tx, n_rx=n_rx, params=draw_params(rng, n_rx, n_tx), random_state=seed
    )
    targets = sample_targets(mesh, n_touches, "edge", rng)
    return targets, touch_means(skin, targets, rng)


def touch_means(skin: Any, targets: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Mean images of simulated touches, baseline subtracted.

    One touch (50 frames) near each of ``targets (n, 3)`` m on the simulated ``skin``, 2 s
    apart; returns ``(n, n_sensors)`` counts.
    """
    means = np.empty((len(targets), skin.n_sensors))
    with skin:
        baseline = skin.read_many(50)[0].mean(axis=0)
        for i, target in enumerate(targets):
            skin.touch_near(target, rng)
            means[i] = skin.read_many(50)[0].mean(axis=0) - baseline
            skin.release()
            skin.advance(2.0)
    return means


def skin_hyperparameters(seed: int, n_touches: int) -> tuple[np.ndarray, float]:
    """Stage 1 for one skin: ``(log hyperparameters (3,), mean shape feature)``.

    The hyperparameters (log amplitude, log length scale in mm, log noise) maximise the
    marginal likelihood of the skin's whole calibration, as a map without prior chooses them.
    """
    from skinloc.models.response_map import fit_gp, shape_features

    targets, means = simulate_calibration(seed, n_touches)
    F = shape_features(means)
    gp = fit_gp(1e3 * targets, F - F.mean(axis=0), 20.0, (2.0, 300.0), None)
    return np.asarray(gp.kernel_.theta, dtype=np.float64), float(F.mean())


def errors_mm(rmap: Any, F_test: np.ndarray, y_test: np.ndarray) -> np.ndarray:
    """Touch errors, mm, of matching ``F_test (m, k)`` against ``rmap``'s table."""
    return 1e3 * np.linalg.norm(rmap.nearest(F_test) - y_test, axis=1)


def _candidates(base: MapPrior) -> dict[tuple[float, float], MapPrior]:
    """The priors stage 2 chooses among, by (spread widening, pseudo-touches)."""
    return {
        (k, w): dataclasses.replace(
            base, log_std=tuple(k * v for v in base.log_std), mean_pseudo_touches=w
        )
        for k in SPREAD_GRID
        for w in PSEUDO_TOUCH_GRID
    }


def skin_curve(seed: int, n_touches: int, base: MapPrior) -> dict[str, Any]:
    """Stage 2 for one skin: mean error (mm) against calibration size, without and with priors.

    Returns ``{"none": {n: mm}, "prior": {(spread, pseudo-touches): {n: mm}}}`` over
    ``CURVE_SIZES`` and the candidates of ``_candidates(base)``; the first ``n`` touches are
    spread evenly (farthest-point) over all but the last 20, which are the test.
    """
    from skinloc.geometry.mesh import cone_skin, farthest_point_sampling, surface_points
    from skinloc.models.response_map import ResponseMap, shape_features

    targets, means = simulate_calibration(seed, n_touches)
    F = shape_features(means)
    cands = surface_points(cone_skin(), _N_CANDIDATES)
    pool, test = np.arange(n_touches - 20), np.arange(n_touches - 20, n_touches)
    priors = _candidates(base)
    out: dict[str, Any] = {"none": {}, "prior": {key: {} for key in priors}}
    for n in CURVE_SIZES:
        if n > len(pool):
            continue
        idx = pool[farthest_point_sampling(targets[pool], n, 0)]
        fit = ResponseMap.fit(targets[idx], F[idx], cands)
        out["none"][n] = float(errors_mm(fit, F[test], targets[test]).mean())
        for key, p in priors.items():
            fit = ResponseMap.fit(targets[idx], F[idx], cands, prior=p)
            out["prior"][key][n] = float(errors_mm(fit, F[test], targets[test]).mean())
    return out


@dataclass
class BuildReport:
    """What a build measured.

    Attributes
    ----------
    prior : MapPrior
        The prior built.
    curve : dict
        ``{"none": {n: mm}, "prior": {n: mm}}``: mean error on the stage-2 skins, the prior
        applied at every size (``max_touches`` is where it stops helping).
    by_candidate : dict
        ``{(spread widening, pseudo-touches): mean mm over 5, 10 and 20 touches}``.
    seconds : float
        Wall time of the build, s.
    skins_per_minute : float
        Simulated skins (both stages) per minute of wall time.
    """

    prior: MapPrior
    curve: dict[str, dict[int, float]]
    by_candidate: dict[tuple[float, float], float]
    seconds: float
    skins_per_minute: float
    per_skin: list[Any] = field(default_factory=list, repr=False)


def build_prior(
    n_skins: int = 24,
    n_eval_skins: int = 40,
    n_touches: int = 80,
    n_jobs: int = -1,
    seed: int = 1000,
    progress: Any = None,
) -> BuildReport:
    """Simulate skins and learn the prior (the module's docstring describes the stages).

    Skins ``seed .. seed + n_skins - 1`` give the hyperpriors, the next ``n_eval_skins`` the
    shrinkage and the curve. ``n_jobs`` is joblib's (``-1``: every core); the joblib backend
    in force (``joblib.parallel_config``) runs the skins.
    """
    from joblib import Parallel, delayed

    if n_skins < 2 or n_eval_skins < 1 or n_touches < 40:
        raise ValueError("a prior needs at least 2 + 1 skins of at least 40 touches each")
    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    seeds1 = range(seed, seed + n_skins)
    stage1 = Parallel(n_jobs=n_jobs)(delayed(skin_hyperparameters)(s, n_touches) for s in seeds1)
    thetas = np.array([t for t, _ in stage1])
    say(f"stage 1: {n_skins} skins in {time.perf_counter() - t0:.0f} s")
    base = MapPrior(
        log_mean=tuple(float(v) for v in thetas.mean(axis=0)),
        log_std=tuple(float(max(v, _MIN_LOG_STD)) for v in thetas.std(axis=0)),
        common_feature=float(np.mean([c for _, c in stage1])),
        mean_pseudo_touches=0.0,
        max_touches=max(CURVE_SIZES),
    )
    seeds2 = range(seed + n_skins, seed + n_skins + n_eval_skins)
    stage2 = Parallel(n_jobs=n_jobs)(delayed(skin_curve)(s, n_touches, base) for s in seeds2)
    seconds = time.perf_counter() - t0
    choose = (5, 10, 20)
    by_candidate = {
        key: float(np.mean([r["prior"][key][n] for r in stage2 for n in choose]))
        for key in stage2[0]["prior"]
    }
    best = min(by_candidate, key=by_candidate.__getitem__)
    sizes = [n for n in CURVE_SIZES if n in stage2[0]["none"]]
    curve = {
        "none": {n: float(np.mean([r["none"][n] for r in stage2])) for n in sizes},
        "prior": {n: float(np.mean([r["prior"][best][n] for r in stage2])) for n in sizes},
    }
    helps = 0  # the most touches up to which the prior lowered the error at every size
    for n in sizes:
        if curve["prior"][n] >= curve["none"][n]:
            break
        helps = n
    prior = dataclasses.replace(
        _candidates(base)[best],
        max_touches=helps,
        provenance={
            "command": (
                f"skinloc prior build --skins {n_skins} --eval-skins {n_eval_skins} "
                f"--touches {n_touches} --seed {seed}"
            ),
            "skins": n_skins + n_eval_skins,
            "seeds": [seed, seed + n_skins + n_eval_skins - 1],
            "touches_per_skin": n_touches,
            "simulated_error_mm": curve,
            "build_seconds": round(seconds, 1),
            "format": PRIOR_FORMAT_VERSION,
        },
    )
    say(f"stage 2: {n_eval_skins} skins; spread x{best[0]:g}, pseudo-touches {best[1]:g}")
    return BuildReport(
        prior,
        curve,
        by_candidate,
        seconds,
        60.0 * (n_skins + n_eval_skins) / seconds,
        stage2,
    )
