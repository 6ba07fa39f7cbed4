"""Accuracy study on the real recordings: writes docs/accuracy.md and docs/figures/accuracy_*.png.

Run from the repository root (about 10 minutes on 2 cores)::

    python bench/accuracy_study.py --data ../shared/data/hiro-cone-skin

Protocols (issue 3): cross-recording and leave-one-recording-out over the four 2023-12-10
recordings, data efficiency (10-80 touches), cross-session to the 2024-05-23 recordings with
0, 5 and 10 recalibration touches, per touch and per frame. The 2024-05 pair
(train 40PL_1 -> test 20PL_2 and back) is the development split the default was chosen on.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from skinloc.bench.paper import REAL_DEC, REAL_MAY
from skinloc.data.recording import Recording, read_recording
from skinloc.evaluation.metrics import localisation_errors_mm
from skinloc.evaluation.scoring import evaluate, train_localizer, training_arrays
from skinloc.geometry.mesh import SurfaceConstraint

ROOT = Path(__file__).resolve().parents[1]
PAPER_VALIDATION = {20: 22.4, 30: 16.5, 50: 6.8, 80: 5.7, 100: 7.4}  # data README, mm


def short(name: str) -> str:
    """``ConeSkinData80Points_RND_80PL_1.mat`` -> ``80PL_1``."""
    return name.rsplit("_RND_", 1)[-1].removesuffix(".mat")


# ------------------------------------------------------------------------ candidate models
Fit = Callable[[list[Recording]], Callable[[np.ndarray], np.ndarray]]


def skinloc_model(**kw) -> Fit:
    """A ``ContactLocalizer`` configuration as a fit function returning a predictor."""

    def fit(recs: list[Recording]) -> Callable[[np.ndarray], np.ndarray]:
        return train_localizer(recs, **kw).predict

    return fit


def sklearn_model(make, clip_l2: bool = True) -> Fit:
    """A scikit-learn regressor on standardised (clipped, L2-normalised) touch means, snapped."""
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    from skinloc.models.response_map import shape_features

    def fit(recs: list[Recording]) -> Callable[[np.ndarray], np.ndarray]:
        X = np.concatenate([r.touch_means for r in recs])
        y = np.concatenate([r.targets for r in recs])
        feat = (lambda A: shape_features(A)) if clip_l2 else (lambda A: np.asarray(A, float))
        est = make_pipeline(StandardScaler(), make()).fit(feat(X), y)
        snap = SurfaceConstraint(recs[0].mesh, "snap", recs[0].surface_points)
        return lambda A: snap(est.predict(feat(A)))

    return fit


def models() -> dict[str, Fit]:
    """Every model of the comparison table, by name."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from sklearn.gaussian_process.kernels import RBF, WhiteKernel
    from sklearn.linear_model import Ridge
    from sklearn.neighbors import KNeighborsRegressor

    return {
        "response map (default)": skinloc_model(),
        "mlp: 5 x 128-128 relu, frames": skinloc_model(arch="mlp"),
        "paper 64-32-3": skinloc_model(arch="paper"),
        "k-NN (k=3)": sklearn_model(lambda: KNeighborsRegressor(3, weights="distance")),
        "GP regression image -> xyz": sklearn_model(
            lambda: GaussianProcessRegressor(RBF(5.0) + WhiteKernel(0.1), normalize_y=True)
        ),
        "ridge": sklearn_model(lambda: Ridge(1.0)),
    }


def variants() -> dict[str, Fit]:
    """Preprocessing, training and output variants, each one change from a reference."""
    return {
        "map: clip + L2 (default)": skinloc_model(),
        "map: L2 without clipping": skinloc_model(clip_negative=False),
        "mlp: frames (reference)": skinloc_model(arch="mlp"),
        "mlp: touch means": skinloc_model(arch="mlp", train_on="means", epochs=300),
        "mlp: means + input noise 0.1": skinloc_model(
            arch="mlp", train_on="means", epochs=300, noise_std=0.1
        ),
        "mlp: 1 member": skinloc_model(arch="mlp", n_members=1),
        "mlp: no normalisation": skinloc_model(arch="mlp", normalise="none", clip_negative=False),
        "mlp: exact projection": skinloc_model(arch="mlp", constraint="project"),
        "mlp: no constraint": skinloc_model(arch="mlp", constraint="none"),
        "paper: clip + L2 inputs": skinloc_model(arch="paper", normalise="l2", clip_negative=True),
    }


# ------------------------------------------------------------------------ protocols
def splits() -> list[tuple[str, list[str], str]]:
    """(protocol, train names, test name): dev, cross-recording and leave-one-out."""
    out = [("dev", [REAL_MAY[1]], REAL_MAY[0]), ("dev", [REAL_MAY[0]], REAL_MAY[1])]
    train80 = REAL_DEC[2]
    out += [("cross", [train80], t) for t in REAL_DEC if t != train80]
    out += [("loro", [n for n in REAL_DEC if n != t], t) for t in REAL_DEC]
    return out


def score(predict, rec: Recording, per_frame: bool) -> float:
    """Mean error, mm, of ``predict`` on a recording's touch means or every frame."""
    if per_frame:
        X, y, _ = training_arrays([rec])
    else:
        X, y = rec.touch_means, rec.targets
    return float(localisation_errors_mm(predict(X), y).mean())


def table(recs: dict[str, Recording], fits: dict[str, Fit], per_frame: bool = True) -> list[dict]:
    """Every fit on every split; rows of name, split, per-touch and per-frame error, fit time."""
    rows = []
    for name, fit in fits.items():
        for protocol, train, test in splits():
            t0 = time.perf_counter()
            predict = fit([recs[n] for n in train])
            dt = time.perf_counter() - t0
            row = dict(
                model=name,
                protocol=protocol,
                split=f"{'+'.join(short(n) for n in train)} -> {short(test)}",
                touch=score(predict, recs[test], False),
                frame=score(predict, recs[test], True) if per_frame else float("nan"),
                fit_s=dt,
            )
            rows.append(row)
            print(f"{name:34s} {row['split']:32s} {row['touch']:6.1f} {row['frame']:6.1f}")
    return rows


def efficiency(recs: dict[str, Recording], reps: int = 5) -> dict[str, dict[int, list[float]]]:
    """Train on n random touches of 80PL_1, test on 50PL_1 and 30PL_1 (touch means)."""
    train = recs[REAL_DEC[2]]
    tests = [recs[REAL_DEC[1]], recs[REAL_DEC[3]]]
    out: dict[str, dict[int, list[float]]] = {}
    for arch, n_reps in (("default", reps), ("mlp", 3), ("paper", reps)):
        out[arch] = {}
        for n in (10, 20, 40, 80):
            errs = []
            for rep in range(n_reps if n < train.n_point_logs else 1):
                idx = np.sort(np.random.default_rng(rep).choice(train.n_point_logs, n, False))
                m = train_localizer([train.subset(idx)], arch=arch, random_state=rep)
                errs += [evaluate(m, [t]).stats.mean_mm for t in tests]
            out[arch][n] = errs
            print(f"efficiency {arch:8s} {n:3d}: {np.mean(errs):.1f} mm")
    return out


def cross_session(recs: dict[str, Recording], reps: int = 5) -> list[dict]:
    """Train on the four 2023-12 recordings; test on each 2024-05 recording after recalibration.

    For k = 0, 5, 10 new touches (random draws, the rest tested): the 2023 model as is or
    recalibrated on the k touches, a model pooled from 2023 plus the k touches, and a model
    trained on the k touches alone.
    """
    base = train_localizer([recs[n] for n in REAL_DEC])
    rows = []
    for name in REAL_MAY:
        rec = recs[name]
        for k in (0, 5, 10):
            res: dict[str, list[float]] = {"recalibrated": [], "pooled": [], "new touches only": []}
            for rep in range(reps if k else 1):
                idx = np.random.default_rng(rep).permutation(rec.n_point_logs)
                cal, test = rec.subset(np.sort(idx[:k])), rec.subset(np.sort(idx[k:]))
                if k == 0:
                    res["recalibrated"].append(evaluate(base, [test]).stats.mean_mm)
                    continue
                X, y, g = training_arrays([cal])
                res["recalibrated"].append(
                    evaluate(base.recalibrate(X, y, groups=g), [test]).stats.mean_mm
                )
                pooled = train_localizer([*(recs[n] for n in REAL_DEC), cal])
                res["pooled"].append(evaluate(pooled, [test]).stats.mean_mm)
                if k >= 2:
                    own = train_localizer([cal])
                    res["new touches only"].append(evaluate(own, [test]).stats.mean_mm)
            for how, errs in res.items():
                if errs:
                    rows.append(dict(test=short(name), k=k, how=how, mean=float(np.mean(errs))))
                    print(f"cross-session {short(name)} k={k:2d} {how:18s} {np.mean(errs):.1f}")
    return rows


def uncertainty(recs: dict[str, Recording]) -> list[dict]:
    """Spearman rank correlation of the default model's uncertainty with its error."""
    rows = []
    for protocol, train, test in splits():
        m = train_localizer([recs[n] for n in train])
        for per_frame in (False, True):
            ev = evaluate(m, [recs[test]], per_frame=per_frame)
            rows.append(
                dict(
                    protocol=protocol,
                    split=f"{'+'.join(short(n) for n in train)} -> {short(test)}",
                    per="frame" if per_frame else "touch",
                    rho=ev.uncertainty_spearman,
                )
            )
    return rows


# ------------------------------------------------------------------------ report
def md_table(rows: list[dict], key: str) -> str:
    """Markdown table: one row per model, one column per split, ``key`` in the cells."""
    names = list(dict.fromkeys(r["model"] for r in rows))
    cols = list(dict.fromkeys((r["protocol"], r["split"]) for r in rows))
    head = "| model | " + " | ".join(f"{p}: {s}" for p, s in cols) + " | worst test split |"
    lines = [head, "|---" * (len(cols) + 2) + "|"]
    for n in names:
        cell = {(r["protocol"], r["split"]): r[key] for r in rows if r["model"] == n}
        worst = max(v for (p, _), v in cell.items() if p != "dev")
        lines.append(f"| {n} | " + " | ".join(f"{cell[c]:.1f}" for c in cols) + f" | {worst:.1f} |")
    return "\n".join(lines)


def plot_efficiency(eff: dict[str, dict[int, list[float]]], path: Path) -> None:
    """Error against calibration touches, with the paper's own validation figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.6), dpi=150)
    labels = {"default": "skinloc default (response map)", "mlp": "mlp", "paper": "paper 64-32-3"}
    for arch, by_n in eff.items():
        ns = sorted(by_n)
        mean = [np.mean(by_n[n]) for n in ns]
        std = [np.std(by_n[n]) for n in ns]
        ax.errorbar(ns, mean, yerr=std, marker="o", capsize=3, label=labels[arch])
    pn = sorted(PAPER_VALIDATION)
    ax.plot(pn, [PAPER_VALIDATION[n] for n in pn], "k--s", label="paper, own online validation")
    ax.set_xlabel("calibration touches")
    ax.set_ylabel("mean error (mm)")
    ax.set_title("Real skin: train on n touches of 80PL_1, test on 50PL_1 and 30PL_1", fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    """Run every protocol and write docs/accuracy.md."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared/data/hiro-cone-skin")
    ap.add_argument("--out", type=Path, default=ROOT / "docs")
    args = ap.parse_args()
    recs = {n: read_recording(args.data / n) for n in (*REAL_DEC, *REAL_MAY)}
    t0 = time.perf_counter()
    main_rows = table(recs, models())
    var_rows = table(recs, variants(), per_frame=False)
    eff = efficiency(recs)
    xs = cross_session(recs)
    unc = uncertainty(recs)
    (args.out / "figures").mkdir(parents=True, exist_ok=True)
    plot_efficiency(eff, args.out / "figures" / "accuracy_efficiency.png")
    write_report(
        args.out / "accuracy.md", main_rows, var_rows, eff, xs, unc, time.perf_counter() - t0
    )


def write_report(path, main_rows, var_rows, eff, xs, unc, elapsed) -> None:
    """docs/accuracy.md from the measured rows (numbers only; the discussion lives in the file
    header and is kept by hand below the marker)."""
    keep = ""
    if path.exists() and "<!-- discussion -->" in path.read_text():
        keep = path.read_text().split("<!-- discussion -->", 1)[1]
    ns = sorted(next(iter(eff.values())))
    eff_lines = [
        "| model | " + " | ".join(f"{n} touches" for n in ns) + " |",
        "|---" * (len(ns) + 1) + "|",
    ]
    for arch, by_n in eff.items():
        eff_lines.append(
            f"| {arch} | "
            + " | ".join(f"{np.mean(by_n[n]):.1f} +- {np.std(by_n[n]):.1f}" for n in ns)
            + " |"
        )
    eff_lines.append(
        "| paper, own online validation | "
        + " | ".join(f"{PAPER_VALIDATION.get(n, float('nan')):.1f}" for n in ns)
        + " |"
    )
    xs_lines = [
        "| test recording | recalibration touches | method | mean error (mm) |",
        "|---|---|---|---|",
    ]
    xs_lines += [f"| {r['test']} | {r['k']} | {r['how']} | {r['mean']:.1f} |" for r in xs]
    unc_lines = ["| split | per touch | per frame |", "|---|---|---|"]
    by_split: dict[str, dict[str, float]] = {}
    for r in unc:
        by_split.setdefault(f"{r['protocol']}: {r['split']}", {})[r["per"]] = r["rho"]
    unc_lines += [f"| {s} | {v['touch']:.2f} | {v['frame']:.2f} |" for s, v in by_split.items()]
    fit_default = [r["fit_s"] for r in main_rows if r["model"].endswith("(default)")]
    text = f"""# Accuracy on the real skin

Generated by `python bench/accuracy_study.py --data ../shared/data/hiro-cone-skin`
({elapsed / 60:.0f} min on this machine). Numbers are mean Euclidean errors in mm between the
prediction (snapped to the skin's surface points) and the prompted touch point.

Splits: **dev** = the 2024-05-23 pair (train 40PL_1 -> test 20PL_2, and back), the split the
default was chosen on; **cross** = train on 80PL_1 of 2023-12-10, test on each other recording
of that day; **loro** = leave one of the four 2023-12-10 recordings out, train on the other three.
"worst test split" is over cross and loro.

## Models, per touch (mean of the 50 frames)

{md_table(main_rows, "touch")}

## Models, per frame (the live case)

{md_table(main_rows, "frame")}

Fitting the default took {np.median(fit_default):.2f} s median per split here
({max(fit_default):.2f} s at most).

## Variants (one change each), per touch

{md_table(var_rows, "touch")}

## Data efficiency

Train on n random touches of 80PL_1 (5 draws; 3 for mlp), test on 50PL_1 and 30PL_1; mean +- std
over draws and both tests. The paper's figures are its own online validation files of models
with that many touches (a different test set, for scale).

{chr(10).join(eff_lines)}

![error against touches](figures/accuracy_efficiency.png)

## Cross-session: 2023-12 model on the 2024-05 skin

The default model trained on all four 2023-12-10 recordings, tested on the 2024-05-23
recordings; k of their touches (5 random draws) are used to adapt, the rest are tested.
*recalibrated* = `skinloc train NEW --init MODEL` (a correction layer on the response map);
*pooled* = one map fitted to 2023 and the k new touches; *new touches only* = a map from
the k touches alone.

{chr(10).join(xs_lines)}

## Confidence

Spearman rank correlation between the default model's `uncertainty_mm` and its real error.

{chr(10).join(unc_lines)}

<!-- discussion -->{keep}"""
    path.write_text(text)


if __name__ == "__main__":
    main()
