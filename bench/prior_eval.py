"""Error against calibration touches on the real development splits, with and without the prior.

Run from the repository root::

    python bench/prior_eval.py --data ../shared/data/hiro-cone-skin [--json OUT]
    python bench/prior_eval.py --remount    # does the prior help --init? (simulated skins)

Splits (all 2023-12-10): 5 and 10 touches spread evenly (farthest-point, seeds 0-2) over
20PL_1's targets, and all 20 of 20PL_1, each tested on 50PL_1, 80PL_1 and 30PL_1; 40 touches
spread evenly over 80PL_1 (seeds 0-2), and all 80 of 80PL_1, each tested on 20PL_1, 50PL_1 and
30PL_1. Per touch: mean error of the touch means; per frame: every frame, with the share of
frames more than 30 mm off. The prior's settings were chosen on simulated skins only.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from skinloc.bench.paper import REAL_DEC
from skinloc.calibration.active import select_point_logs, subset_recordings
from skinloc.data.recording import read_recording
from skinloc.evaluation.metrics import localisation_errors_mm
from skinloc.evaluation.scoring import train_localizer, training_arrays

SMALL, LARGE = REAL_DEC[0], REAL_DEC[2]  # 20PL_1, 80PL_1


def short(name: str) -> str:
    """``ConeSkinData80Points_RND_80PL_1.mat`` -> ``80PL_1``."""
    return name.rsplit("_RND_", 1)[-1].removesuffix(".mat")


def splits(n: int) -> list[tuple[str, int]]:
    """(source recording, seed) pairs for ``n`` touches; seed -1 = the whole recording."""
    src = SMALL if n <= 20 else LARGE
    full = 20 if src == SMALL else 80
    return [(src, -1)] if n == full else [(src, s) for s in range(3)]


def run(
    data: Path, ns: list[int], use_prior: bool, strategy: str = "even", arch: str = "default"
) -> dict:
    recs = {n: read_recording(data / n) for n in REAL_DEC}
    out: dict = {}
    for n in ns:
        touch, frame, fit_s = [], [], []
        for src, seed in splits(n):
            train = [recs[src]]
            if seed >= 0:
                picks = select_point_logs(
                    train, n, strategy, random_state=seed, prior="package" if use_prior else "none"
                )
                train = subset_recordings(train, picks)
            t0 = time.perf_counter()
            if arch == "default":
                model = train_localizer(train, prior="package" if use_prior else "none")
            else:
                model = train_localizer(train, arch=arch)
            fit_s.append(time.perf_counter() - t0)
            for name in REAL_DEC:
                if name == src:
                    continue
                rec = recs[name]
                touch.append(localisation_errors_mm(model.predict(rec.touch_means), rec.targets))
                X, y, _ = training_arrays([rec])
                frame.append(localisation_errors_mm(model.predict(X), y))
        t, f = np.concatenate(touch), np.concatenate(frame)
        out[n] = dict(
            touch_mm=float(t.mean()),
            frame_mm=float(f.mean()),
            frame_p95_mm=float(np.percentile(f, 95)),
            frames_over_30mm=float((f > 30).mean()),
            fit_s=float(np.median(fit_s)),
            train=f"{short(src)}" + (f" ({strategy}, seeds 0-2)" if seed >= 0 else ""),
        )
        r = out[n]
        print(
            f"{n:3d} touches {arch} {'prior' if use_prior else 'none ':5s}"
            f" per touch {r['touch_mm']:5.1f}"
            f" per frame {r['frame_mm']:5.1f} p95 {r['frame_p95_mm']:5.1f}"
            f" >30mm {100 * r['frames_over_30mm']:4.1f}% fit {r['fit_s']:.2f}s",
            flush=True,
        )
    return out


def recalibration(data: Path, reps: int = 5) -> dict:
    """2023-12 -> 2024-05-23 with k new touches: recalibrated, and new touches alone.

    The 2023 model (all four 2023-12-10 recordings, 180 touches: beyond the prior's reach) is
    recalibrated on k random touches of a 2024-05-23 recording (5 draws) and tested on the
    rest; a model of the k touches alone is fitted with and without the prior.
    """
    from skinloc.bench.paper import REAL_MAY
    from skinloc.evaluation.scoring import evaluate

    recs = {n: read_recording(data / n) for n in (*REAL_DEC, *REAL_MAY)}
    base = train_localizer([recs[n] for n in REAL_DEC])
    out: dict = {}
    for name in REAL_MAY:
        rec = recs[name]
        for k in (5, 10):
            res: dict[str, list[float]] = {"recalibrated": [], "alone": [], "alone, prior": []}
            for rep in range(reps):
                idx = np.random.default_rng(rep).permutation(rec.n_point_logs)
                cal, test = rec.subset(np.sort(idx[:k])), rec.subset(np.sort(idx[k:]))
                X, y, g = training_arrays([cal])
                res["recalibrated"].append(
                    evaluate(base.recalibrate(X, y, groups=g), [test]).stats.mean_mm
                )
                for how, prior in (("alone", "none"), ("alone, prior", "package")):
                    own = train_localizer([cal], prior=prior)
                    res[how].append(evaluate(own, [test]).stats.mean_mm)
            row = {how: float(np.mean(v)) for how, v in res.items()}
            out[f"{short(name)} k={k}"] = row
            print(f"recalibration {short(name)} k={k:2d}", {h: round(v, 1) for h, v in row.items()})
    return out


def simulated(n_skins: int = 20, first_seed: int = 5000) -> dict:
    """The same curve on simulated skins no stage of the prior's build saw (seeds 5000-).

    Each skin: 80 touches on random mesh edges, the first n of the first 60 spread evenly,
    the last 20 the test (per touch); the prior applied at every size.
    """
    from skinloc.geometry.mesh import cone_skin, farthest_point_sampling, surface_points
    from skinloc.models.map_prior import load_prior
    from skinloc.models.response_map import ResponseMap, shape_features
    from skinloc.sim.prior_build import errors_mm, simulate_calibration

    prior, cands = load_prior(), surface_points(cone_skin(), 4000)
    errs: dict = {"no prior": {}, "prior": {}}
    for seed in range(first_seed, first_seed + n_skins):
        targets, means = simulate_calibration(seed, 80)
        F = shape_features(means)
        pool, test = np.arange(60), np.arange(60, 80)
        for n in (5, 10, 20, 40):
            idx = pool[farthest_point_sampling(targets[pool], n, 0)]
            for how, p in (("no prior", None), ("prior", prior)):
                rmap = ResponseMap.fit(targets[idx], F[idx], cands, prior=p)
                errs[how].setdefault(n, []).append(errors_mm(rmap, F[test], targets[test]).mean())
    out = {how: {n: float(np.mean(v)) for n, v in d.items()} for how, d in errs.items()}
    for how, d in out.items():
        print(f"simulated, {how:8s}", " / ".join(f"{v:.1f}" for v in d.values()), "mm")
    return out


def remount(n_skins: int = 20, first_seed: int = 7000, jitter: float = 0.4) -> dict:
    """Does the prior help ``--init``? Simulated skins re-mounted, judged before any real split.

    Each skin (seeds 7000-, none used by the prior's build): a map of 80 touches on random
    mesh edges; then a second session of the same wiring with its physics jittered (log-normal,
    ``jitter``: footprint fall-off at half of it, silicone thickness, line coupling, peak
    signal, gain spread at twice it) and 40 touches, the first k (5, 10) the new calibration,
    the last 20 the test (per touch). Compared: the old map as is; ``--init`` as it is (a
    correction layer with the old map's hyperparameters); the correction layer with its
    hyperparameters a posteriori under the prior; a shared offset of the new session's mean
    feature shrunk by the prior's pseudo-touches; the k touches alone, without and with the
    prior.
    """
    import dataclasses

    from skinloc.geometry.mesh import cone_skin, sample_targets, surface_points
    from skinloc.models.map_prior import load_prior
    from skinloc.models.response_map import ResponseMap, fit_layer, shape_features
    from skinloc.sim.prior_build import draw_params, errors_mm, touch_means
    from skinloc.sim.skin import SimulatedSkin

    prior, mesh = load_prior(), cone_skin()
    cands = surface_points(mesh, 4000)

    def session(params, seed, rng, n):
        skin = SimulatedSkin(mesh, params=params, random_state=seed)
        targets = sample_targets(mesh, n, "edge", rng)
        return targets, shape_features(touch_means(skin, targets, rng))

    def jittered(p, rng):
        def j(v: float, rel: float) -> float:
            return float(v * np.exp(rel * rng.standard_normal()))

        return dataclasses.replace(
            p,
            falloff_exponent=j(p.falloff_exponent, jitter / 2),
            silicone_thickness_m=j(p.silicone_thickness_m, jitter),
            line_coupling=j(p.line_coupling, jitter),
            peak_signal_counts=j(p.peak_signal_counts, jitter),
            gain_std=min(j(p.gain_std, 2 * jitter), 1.5),
        )

    def corrected(rmap, q, F, how):
        R = F - rmap.evaluate_mm(1e3 * q)
        base, off = rmap.layers[0], np.zeros(R.shape[1])
        if how == "offset":
            off = R.sum(axis=0) / (len(R) + prior.mean_pseudo_touches)
        fixed = (None, None) if how == "prior" else (base.length_scale_mm, base.noise)
        layer = fit_layer(1e3 * q, R - off, fixed[0], (2.0, 300.0), fixed[1], prior)
        return ResponseMap(rmap.mean + off, [*rmap.layers, layer], rmap.candidates)

    errs: dict = {}
    for seed in range(first_seed, first_seed + n_skins):
        rng = np.random.default_rng([seed, 77])
        p1 = draw_params(rng, 8, 8)
        t1, F1 = session(p1, seed, rng, 80)
        old = ResponseMap.fit(t1, F1, cands)
        t2, F2 = session(jittered(p1, rng), seed, rng, 40)
        for k in (5, 10):
            q, F = t2[:k], F2[:k]
            maps = {
                "old map": old,
                "--init": old.refined(q, F),
                "--init, prior hyperparameters": corrected(old, q, F, "prior"),
                "--init, shrunk offset": corrected(old, q, F, "offset"),
                "alone, --no-prior": ResponseMap.fit(q, F, cands),
                "alone, prior": ResponseMap.fit(q, F, cands, prior=prior),
            }
            for how, m in maps.items():
                e = errors_mm(m, F2[20:], t2[20:]).mean()
                errs.setdefault(f"k={k}", {}).setdefault(how, []).append(float(e))
    out = {k: {h: float(np.mean(v)) for h, v in d.items()} for k, d in errs.items()}
    for k, d in out.items():
        print(f"re-mounted, {k}:", ", ".join(f"{h} {v:.1f}" for h, v in d.items()))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=Path("../shared/data/hiro-cone-skin"))
    ap.add_argument("--touches", type=int, nargs="+", default=[5, 10, 20, 40, 80])
    ap.add_argument("--which", choices=["both", "prior", "none", "paper"], default="both")
    ap.add_argument("--strategy", default="even")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--recalibration", action="store_true", help="2023-12 -> 2024-05 instead")
    ap.add_argument("--simulated", action="store_true", help="20 unseen simulated skins instead")
    ap.add_argument("--remount", action="store_true", help="--init on re-mounted simulated skins")
    a = ap.parse_args()
    if a.recalibration or a.simulated or a.remount:
        res = recalibration(a.data) if a.recalibration else remount() if a.remount else simulated()
        if a.json:
            a.json.write_text(json.dumps(res, indent=1))
        return
    res = {}
    if a.which == "paper":  # the paper's 64-32-3 network (PyTorch), for scale
        res["paper"] = run(a.data, a.touches, False, a.strategy, arch="paper")
    for use in {"both": [False, True], "prior": [True], "none": [False]}.get(a.which, []):
        res["prior" if use else "no prior"] = run(a.data, a.touches, use, a.strategy)
    if a.json:
        a.json.write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
