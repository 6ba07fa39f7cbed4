"""Compare the simulated skin with the paper's real recordings, side by side, and fit it.

Computes, on the real recordings and on simulated sessions of the same size (80 point logs of
50 frames, targets drawn like the paper's, "a random point on a random mesh edge"):

- no-touch noise std per sensor (median, counts), sensors above 5 sigma per touch, peak signal
  per touch, the array-wide offset during a touch (median of the touch image), the paper's
  Eq. 1 SNR;
- over a day of four sessions (sizes 20, 50, 80 and 30 with the real recordings' shared
  targets: 70 pairs of touches at the same target in two sessions): the same-target
  repeatability (median distance between the two touches' shape features, the L2-normalised
  clipped images the default model matches), the same distance for touches 3-6, 6-10, 10-15,
  15-25 and 25-40 mm apart (the response's shape), the share of weak touches (peak under 0.45
  times the session's median), the lower cone's response (median peak of touches below
  y = -75 mm over the median peak of all) and the rank-one share of the images;
- the error of the paper's 64-32-3 network (tanh, MSE, standardised inputs, outputs snapped to
  the nearest of 14,400 surface points): real = trained on the 80 PL recording, tested on the
  50 PL and 30 PL ones of the same day; sim = trained on a simulated 80-touch session, tested
  on 20 fresh touches, over several seeds;
- with ``--model-error``: skinloc's default model (and ``--arch paper``) trained on 10, 20, 40
  and 80 even touches: real = farthest-point subsets of the 80 PL recording, tested on 50 PL
  and 30 PL; sim = a fresh even session of each size on each of 3 skins, tested on 40 fresh
  random touches. The model's error is a consequence to check, never a fitting target.

``--grid name=v1,v2,...`` fits one parameter: it prints the simulated statistics for each
value and the value whose statistic (``FIT_TARGETS``) lies nearest the real one.

Usage::

    python bench/fit_simulator.py                       # the table (about 1 min)
    python bench/fit_simulator.py --model-error         # plus the model errors (about 3 min)
    python bench/fit_simulator.py --grid probe_error_std_m=0.004,0.0045,0.005 --no-real-net
    python bench/fit_simulator.py --figures             # also docs/figures/sim_*.png/svg
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from skinloc.data.recording import read_recording
from skinloc.evaluation.metrics import snr_db
from skinloc.evaluation.scoring import evaluate, train_localizer
from skinloc.geometry.mesh import cone_skin, farthest_point_sampling, sample_targets, surface_points
from skinloc.models.response_map import shape_features
from skinloc.sim.skin import SimulatedSkin, SkinParams

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "hiro-cone-skin"
if not DATA.is_dir():
    DATA = Path("/work/shared/data/hiro-cone-skin")
TRAIN_REAL = "ConeSkinData80Points_RND_80PL_1.mat"
TEST_REAL = ("ConeSkinData50Points_RND_50PL_1.mat", "ConeSkinData30Points_RND_30PL_1.mat")
DAY_REAL = (
    "ConeSkinData_RND_20PL_1.mat",
    "ConeSkinData50Points_RND_50PL_1.mat",
    TRAIN_REAL,
    "ConeSkinData30Points_RND_30PL_1.mat",
)
SECONDS_BETWEEN_TOUCHES = 4.5  # the paper: 1-2 minutes per 20 point logs
#: Bins of target distance for the shape-distance curve, mm.
DIST_BINS_MM = ((3, 6), (6, 10), (10, 15), (15, 25), (25, 40))
WEAK_FRACTION = 0.45  # a weak touch peaks under this fraction of its session's median peak
LOW_CONE_Y_M = -0.075  # "lower cone": targets below this height (the wide end)
MODEL_SIZES = (10, 20, 40, 80)
#: The statistic each fitted parameter is matched on (see ``--grid``).
FIT_TARGETS = {
    "probe_error_std_m": "same_target",
    "weak_touch_prob": "weak_share",
    "weak_touch_pressure": "weak_peak",
    "silicone_thickness_base_m": "low_cone",
    "falloff_exponent": "curve",
    "peak_signal_counts": "peak",
    "line_coupling": "above5",
    "crossing_width_std": "rank_one",
}


# --------------------------------------------------------------------------------------------
# statistics


def session_stats(touch_means: np.ndarray, baseline_frames: np.ndarray) -> dict[str, np.ndarray]:
    """Per-touch and per-sensor statistics of one session (the README's definitions)."""
    sigma = baseline_frames.astype(np.float64).std(axis=0)
    return {
        "noise": sigma,
        "above5": (touch_means > 5 * sigma).sum(axis=1),
        "peak": touch_means.max(axis=1),
        "offset": np.median(touch_means, axis=1),
        "snr": snr_db(touch_means, baseline_frames),
    }


def simulate_session(
    params: SkinParams, seed: int, n_train: int = 80, n_test: int = 20, n_frames: int = 50
) -> dict[str, np.ndarray]:
    """One simulated calibration session plus fresh test touches, on the paper's cone."""
    mesh = cone_skin()
    skin = SimulatedSkin(mesh, params=params, random_state=seed)
    rng = np.random.default_rng(10_000 + seed)
    targets = sample_targets(mesh, n_train + n_test, "edge", random_state=rng)
    with skin:
        baseline_frames, _ = skin.read_many(n_frames)
        baseline = baseline_frames.astype(np.float64).mean(axis=0)
        frames = np.empty((len(targets), n_frames, skin.n_sensors))
        contacts = np.empty_like(targets)
        for i, target in enumerate(targets):
            skin.advance(SECONDS_BETWEEN_TOUCHES)
            contacts[i] = skin.touch_near(target, rng)
            frames[i] = skin.read_many(n_frames)[0]
            skin.release()
    means = (frames - baseline).mean(axis=1)
    return {
        "baseline_frames": baseline_frames,
        "means": means,
        "targets": targets,
        "contacts": contacts,
        "n_train": n_train,
        "skin": skin,
    }


def day_stats(means: list[np.ndarray], targets: list[np.ndarray]) -> dict[str, float]:
    """Statistics of a day of sessions: repeatability, shape curve, weak touches, rank one.

    ``means[i]`` ``(n_i, n_sensors)`` are session i's baseline-subtracted touch images,
    ``targets[i]`` ``(n_i, 3)`` m their prompted targets. Distances between the shape features
    (clipped, L2-normalised images) are taken between touches of different sessions, as the
    same-target pairs only exist across sessions.
    """
    T, M = np.vstack(targets), np.vstack(means).astype(np.float64)
    F = shape_features(M)
    session = np.concatenate([np.full(len(t), i) for i, t in enumerate(targets)])
    iu = np.triu_indices(len(T), 1)
    cross = session[iu[0]] != session[iu[1]]
    dist_mm = 1e3 * np.linalg.norm(T[iu[0]] - T[iu[1]], axis=1)
    fdist = np.linalg.norm(F[iu[0]] - F[iu[1]], axis=1)
    out = {"same_target": float(np.median(fdist[cross & (dist_mm < 1.0)]))}
    out["same_pairs"] = float(np.count_nonzero(cross & (dist_mm < 1.0)))
    for lo, hi in DIST_BINS_MM:
        m = cross & (dist_mm >= lo) & (dist_mm < hi)
        out[f"d{lo}-{hi}"] = float(np.median(fdist[m])) if m.any() else float("nan")
    peaks = [m.max(axis=1) for m in means]
    weak = np.concatenate([p < WEAK_FRACTION * np.median(p) for p in peaks])
    rel = np.concatenate([p / np.median(p) for p in peaks])
    out["weak_share"] = float(weak.mean())
    out["weak_peak"] = float(np.median(rel[weak])) if weak.any() else float("nan")
    low = T[:, 1] < LOW_CONE_Y_M
    out["low_cone"] = float(np.median(rel[low])) if low.any() else float("nan")
    n_tx = int(round(np.sqrt(M.shape[1])))
    sv = np.linalg.svd(F.reshape(len(F), n_tx, -1), compute_uv=False)
    out["rank_one"] = float(np.median(sv[:, 0] ** 2 / (sv**2).sum(axis=1)))
    return out


def line_heights() -> str:
    """Mean TX and RX line profiles (max over the other family) of the day's touches by height."""
    recs = [read_recording(DATA / n) for n in DAY_REAL]
    M = np.vstack([r.touch_means for r in recs])
    y = 1e3 * np.vstack([r.targets for r in recs])[:, 1]
    lines = ["y band (mm) | touches | TX profile (counts) | RX profile (counts)"]
    for lo, hi in ((-110, -85), (-85, -65), (-65, -45), (-45, -25), (-25, 0), (0, 40)):
        img = M[(y >= lo) & (y < hi)].reshape(-1, recs[0].n_tx, recs[0].n_rx)
        tx = " ".join(f"{v:3.0f}" for v in img.max(axis=2).mean(axis=0))
        rx = " ".join(f"{v:3.0f}" for v in img.max(axis=1).mean(axis=0))
        lines.append(f"{lo:5d} to {hi:4d} | {len(img):3d} | {tx} | {rx}")
    return "\n".join(lines)


def real_day() -> dict[str, float]:
    """``day_stats`` of the four real recordings of 2023-12-10."""
    recs = [read_recording(DATA / n) for n in DAY_REAL]
    return day_stats([r.touch_means for r in recs], [r.targets for r in recs])


def simulate_day(params: SkinParams, seed: int, n_frames: int = 50) -> dict[str, float]:
    """``day_stats`` of four simulated sessions on one skin, with the real day's target overlap.

    The real recordings share targets: the first 10 of each are the same, and the 20 PL
    session's 20 are the 80 PL session's first 20 (70 same-target pairs). With C, D, E, F, G
    blocks of 10, 10, 60, 40 and 20 edge targets the sessions are C+D, C+F, C+D+E and C+G.
    """
    mesh = cone_skin()
    skin = SimulatedSkin(mesh, params=params, random_state=seed)
    rng = np.random.default_rng(20_000 + seed)
    pool = sample_targets(mesh, 140, "edge", random_state=rng)
    c, d, e, f, g = np.split(pool, [10, 20, 80, 120])
    plans = [np.vstack(b) for b in ((c, d), (c, f), (c, d, e), (c, g))]
    means = []
    with skin:
        for i, plan in enumerate(plans):
            skin.reseed(100 + i)  # a new session: fresh noise, drift and touches
            base = skin.read_many(n_frames)[0].astype(np.float64).mean(axis=0)
            imgs = np.empty((len(plan), skin.n_sensors))
            for k, target in enumerate(plan):
                skin.advance(SECONDS_BETWEEN_TOUCHES)
                skin.touch_near(target, rng)
                imgs[k] = skin.read_many(n_frames)[0].mean(axis=0) - base
                skin.release()
            means.append(imgs)
    return day_stats(means, plans)


# --------------------------------------------------------------------------------------------
# skinloc's models against the number of touches


def _even_subset(targets: np.ndarray, n: int) -> np.ndarray:
    """Indices of ``n`` of ``targets`` spread evenly (farthest-point sampling from the first)."""
    return farthest_point_sampling(targets, n, start=0)


def real_model_errors(archs: tuple[str, ...] = ("default",)) -> dict[str, dict[int, float]]:
    """Mean error, mm, of models trained on even subsets of 80 PL, tested on 50 PL + 30 PL."""
    from skinloc.experiments.demo import real_skin_errors

    return {arch: real_skin_errors(DATA, arch, tuple(MODEL_SIZES)) for arch in archs}


def sim_model_errors(
    params: SkinParams,
    seeds: list[int],
    archs: tuple[str, ...] = ("default",),
    n_validation: int = 40,
    n_frames: int = 50,
) -> dict[str, dict[int, list[float]]]:
    """Mean error, mm, per skin: a fresh even session of each size, 40 random touches to test."""
    import tempfile

    from skinloc.calibration.session import SessionConfig
    from skinloc.calibration.session import simulate_session as record_session

    mesh = cone_skin()
    out: dict[str, dict[int, list[float]]] = {a: {n: [] for n in MODEL_SIZES} for a in archs}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            skin = SimulatedSkin(mesh, params=params, random_state=seed)
            with skin:
                skin.reseed(1)
                val = record_session(
                    skin,
                    mesh,
                    Path(tmp) / "val.h5",
                    SessionConfig(n_validation, "random", n_frames, random_state=seed + 1000),
                )
                for n in MODEL_SIZES:
                    skin.reseed(10 + n)
                    cal = record_session(
                        skin,
                        mesh,
                        Path(tmp) / f"cal{n}.h5",
                        SessionConfig(n, "even", n_frames, random_state=seed * 100 + n),
                    )
                    for arch in archs:
                        model = train_localizer([cal], arch=arch, random_state=seed)
                        out[arch][n].append(evaluate(model, [val]).stats.mean_mm)
    return out


# --------------------------------------------------------------------------------------------
# the paper's network


def paper_net_errors_mm(
    X_train: np.ndarray,
    y_train: np.ndarray,
    X_test: np.ndarray,
    y_test: np.ndarray,
    snap_points: np.ndarray,
    seed: int,
    epochs: int = 2000,
    lr: float = 1e-2,
) -> np.ndarray:
    """Train the paper's 64-32-3 tanh MLP (MSE, Adam, full batch) and return test errors, mm."""
    torch.manual_seed(seed)
    x_mean, x_std = X_train.mean(axis=0), X_train.std(axis=0) + 1e-6
    y_mean, y_std = y_train.mean(axis=0), y_train.std(axis=0).max()
    X = torch.tensor((X_train - x_mean) / x_std, dtype=torch.float32)
    Y = torch.tensor((y_train - y_mean) / y_std, dtype=torch.float32)
    net = torch.nn.Sequential(
        torch.nn.Linear(X.shape[1], 32), torch.nn.Tanh(), torch.nn.Linear(32, 3)
    )
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    for _ in range(epochs):
        opt.zero_grad()
        loss = torch.nn.functional.mse_loss(net(X), Y)
        loss.backward()
        opt.step()
    with torch.no_grad():
        Xt = torch.tensor((X_test - x_mean) / x_std, dtype=torch.float32)
        pred = net(Xt).numpy() * y_std + y_mean
    snapped = snap_points[cKDTree(snap_points).query(pred)[1]]
    return 1e3 * np.linalg.norm(snapped - y_test, axis=1)


# --------------------------------------------------------------------------------------------
# the comparison


def real_side(n_net_seeds: int, model_error: bool = False) -> dict[str, object]:
    """Statistics of the real recordings; the paper net's (and the models') error across them."""
    train = read_recording(DATA / TRAIN_REAL)
    stats = session_stats(train.touch_means, train.baseline_frames)
    snap = train.surface_points
    errors = {}
    for name in TEST_REAL if n_net_seeds > 0 else ():
        test = read_recording(DATA / name)
        errors[name] = np.array(
            [
                paper_net_errors_mm(
                    train.touch_means, train.targets, test.touch_means, test.targets, snap, seed
                ).mean()
                for seed in range(n_net_seeds)
            ]
        )
    out: dict[str, object] = {"stats": stats, "net": errors, "day": real_day()}
    if model_error:
        out["models"] = real_model_errors(("default", "paper"))
    return out


def sim_side(
    params: SkinParams, seeds: list[int], n_net_seeds: int, model_error: bool = False
) -> dict[str, object]:
    """Statistics of simulated sessions and days; the paper net's error on fresh touches."""
    snap = surface_points(cone_skin())
    per_seed = []
    net = []
    probe = []
    days = []
    for seed in seeds:
        s = simulate_session(params, seed)
        n = s["n_train"]
        per_seed.append(session_stats(s["means"][:n], s["baseline_frames"]))
        probe.append(1e3 * np.linalg.norm(s["contacts"] - s["targets"], axis=1).mean())
        days.append(simulate_day(params, seed))
        errs = [
            paper_net_errors_mm(
                s["means"][:n], s["targets"][:n], s["means"][n:], s["targets"][n:], snap, net_seed
            ).mean()
            for net_seed in range(n_net_seeds)
        ]
        net.append(float(np.mean(errs)) if errs else float("nan"))
    out: dict[str, object] = {
        "stats": per_seed,
        "net": np.array(net),
        "probe_mm": float(np.mean(probe)),
        "days": days,
    }
    if model_error:
        out["models"] = sim_model_errors(params, seeds[:3], ("default", "paper"))
    return out


def _fmt_range(values: np.ndarray, fmt: str = "{:.0f}") -> str:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    med, lo, hi = (fmt.format(v) for v in (np.median(values), values.min(), values.max()))
    return f"{med} ({lo}-{hi})"


DAY_ROWS = (
    ("same_target", "same-target repeatability: shape distance of two touches at one target"),
    ("d3-6", "shape distance, touches 3-6 mm apart"),
    ("d6-10", "shape distance, touches 6-10 mm apart"),
    ("d10-15", "shape distance, touches 10-15 mm apart"),
    ("d15-25", "shape distance, touches 15-25 mm apart"),
    ("d25-40", "shape distance, touches 25-40 mm apart"),
    ("weak_share", "weak touches (peak < 0.45 x session median), share"),
    ("weak_peak", "weak touches' peak / session median peak"),
    ("low_cone", "lower cone (y < -75 mm): median peak / session median"),
    ("rank_one", "rank-one share of the shape image (median)"),
)


def day_table_rows(real_day_stats: dict[str, float], days: list[dict[str, float]]) -> list:
    """Rows ``(label, real, sim)`` of the day statistics; sim is the mean [min-max] over skins."""
    rows = []
    for key, label in DAY_ROWS:
        v = np.array([d[key] for d in days])
        fmt = "{:.1%}" if key == "weak_share" else "{:.2f}" if key != "rank_one" else "{:.3f}"
        rows.append(
            (
                label,
                fmt.format(real_day_stats[key]),
                f"{fmt.format(np.nanmean(v))} [skins {fmt.format(np.nanmin(v))}-"
                f"{fmt.format(np.nanmax(v))}]",
            )
        )
    return rows


def table(real: dict[str, object], sim: dict[str, object]) -> str:
    """The side-by-side markdown table."""
    rs = real["stats"]
    sims = sim["stats"]
    noise_sim = np.concatenate([s["noise"] for s in sims])

    def sim_med(key: str, fn=np.nanmedian) -> str:
        # Median over sessions of each session's statistic, min and max: an 80-touch session
        # is compared with an 80-touch session, not with the pool of all simulated touches.
        per = np.array([fn(s[key]) for s in sims])
        lo = np.median([np.nanmin(s[key]) for s in sims])
        hi = np.median([np.nanmax(s[key]) for s in sims])
        return f"{np.median(per):.1f} ({lo:.0f}-{hi:.0f}) [seeds {per.min():.1f}-{per.max():.1f}]"

    def real_med(key: str, fn=np.median) -> str:
        v = rs[key][np.isfinite(rs[key])]
        return f"{fn(v):.1f} ({v.min():.0f}-{v.max():.0f})"

    rows = [
        (
            "no-touch noise std, median (min-max) counts",
            f"{np.median(rs['noise']):.2f} ({rs['noise'].min():.1f}-{rs['noise'].max():.1f})",
            f"{np.median(noise_sim):.2f} ({noise_sim.min():.1f}-{noise_sim.max():.1f})",
        ),
        ("sensors > 5 sigma per touch, median (range)", real_med("above5"), sim_med("above5")),
        ("peak signal per touch, median (range) counts", real_med("peak"), sim_med("peak")),
        ("array offset per touch (median of image), counts", real_med("offset"), sim_med("offset")),
        ("Eq. 1 SNR, mean (range) dB", real_med("snr", np.nanmean), sim_med("snr", np.nanmean)),
    ]
    rows += day_table_rows(real["day"], sim["days"])
    if real["net"]:
        net_real = np.concatenate(list(real["net"].values()))
        per_file = ", ".join(
            f"{k.split('_')[0].replace('ConeSkinData', '')}: {v.mean():.1f}"
            for k, v in real["net"].items()
        )
        rows.append(
            (
                "paper 64-32-3 net (this script's), 80 edge touches, mean error mm",
                f"{net_real.mean():.1f} ({per_file})",
                f"{np.mean(sim['net']):.1f} [seeds {np.min(sim['net']):.1f}-"
                f"{np.max(sim['net']):.1f}]",
            )
        )
    if "models" in real and "models" in sim:
        for arch in ("default", "paper"):
            for n in MODEL_SIZES:
                v = np.array(sim["models"][arch][n])
                rows.append(
                    (
                        f"skinloc `{arch}`, {n} even touches, mean error mm",
                        f"{real['models'][arch][n]:.1f}",
                        f"{v.mean():.1f} +- {v.std():.1f} [skins "
                        + ", ".join(f"{x:.1f}" for x in v)
                        + "]",
                    )
                )
    lines = [
        "| statistic | real | simulated |",
        "|---|---|---|",
    ]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    return "\n".join(lines)


def _parse_set(items: list[str]) -> dict[str, object]:
    out: dict[str, object] = {}
    for item in items:
        key, _, value = item.partition("=")
        out[key] = type(getattr(SkinParams.default(), key))(float(value)) if value else value
    return out


def _stat_of(key: str, sim: dict[str, object]) -> float:
    """The simulated statistic ``key`` (a day statistic, "curve", or a session median)."""
    days = sim["days"]
    if key == "curve":
        return float(np.mean([[d[f"d{lo}-{hi}"] for lo, hi in DIST_BINS_MM] for d in days]))
    if key in days[0]:
        return float(np.nanmean([d[key] for d in days]))
    return float(np.median([np.nanmedian(s[key]) for s in sim["stats"]]))


def _real_stat_of(key: str, real: dict[str, object]) -> float:
    day = real["day"]
    if key == "curve":
        return float(np.mean([day[f"d{lo}-{hi}"] for lo, hi in DIST_BINS_MM]))
    if key in day:
        return float(day[key])
    return float(np.nanmedian(real["stats"][key]))


def grid(params: SkinParams, spec: str, seeds: list[int], real: dict[str, object]) -> None:
    """Fit one parameter on a grid: print each value's statistics and the nearest to real."""
    name, _, values = spec.partition("=")
    key = FIT_TARGETS.get(name)
    if key is None:
        raise SystemExit(f"--grid: {name} is not a fitted parameter ({', '.join(FIT_TARGETS)})")
    target = _real_stat_of(key, real)
    best, best_gap = None, np.inf
    for value in values.split(","):
        p = dataclasses.replace(params, **_parse_set([f"{name}={value}"]))
        sim = sim_side(p, seeds, 0)
        got = _stat_of(key, sim)
        others = {k: round(_stat_of(k, sim), 3) for k in sorted(set(FIT_TARGETS.values()))}
        print(f"{name}={value}: {key} {got:.3f} (real {target:.3f}); all {others}")
        if abs(got - target) < best_gap:
            best, best_gap = value, abs(got - target)
    print(f"fitted {name} = {best} (its {key} nearest the real {target:.3f})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6, help="simulated skins/sessions")
    ap.add_argument("--net-seeds", type=int, default=3, help="network initialisations")
    ap.add_argument("--set", nargs="*", default=[], help="override SkinParams, e.g. x=1.0")
    ap.add_argument("--no-real", action="store_true", help="skip the real side (tuning)")
    ap.add_argument("--model-error", action="store_true", help="also the models' errors")
    ap.add_argument("--grid", help="fit one parameter on a grid: name=v1,v2,...")
    ap.add_argument("--figures", action="store_true", help="write docs/figures/sim_*.png/svg")
    ap.add_argument("--line-heights", action="store_true", help="real line profiles by height")
    args = ap.parse_args()
    if args.line_heights:
        print(line_heights())
        return
    torch.set_num_threads(1)
    t0 = time.time()
    params = dataclasses.replace(SkinParams.default(), **_parse_set(args.set))
    seeds = list(range(args.seeds))
    if args.grid:
        grid(params, args.grid, seeds, real_side(0))
        print(f"({time.time() - t0:.0f} s)")
        return
    sim = sim_side(params, seeds, args.net_seeds, args.model_error)
    print(f"simulated probing error: mean {sim['probe_mm']:.1f} mm from the target")
    if args.no_real:
        for k in ("above5", "peak", "offset"):
            print(k, _fmt_range(np.concatenate([s[k] for s in sim["stats"]])))
        print("snr", np.mean([np.nanmean(s["snr"]) for s in sim["stats"]]))
        print("net", sim["net"].round(1), sim["net"].mean().round(1))
        for key, _ in DAY_ROWS:
            print(key, np.round([d[key] for d in sim["days"]], 3))
        if args.model_error:
            print(sim["models"])
    else:
        real = real_side(args.net_seeds, args.model_error)
        print(table(real, sim))
    if args.figures:
        make_figures(params)
    print(f"({time.time() - t0:.0f} s)")


# --------------------------------------------------------------------------------------------
# figures


def make_figures(params: SkinParams) -> None:
    """Real vs simulated touch images, and the simulated wiring on the cone."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = ROOT / "docs" / "figures"
    out.mkdir(parents=True, exist_ok=True)
    real = read_recording(DATA / TRAIN_REAL)
    sim = simulate_session(params, seed=0)
    pick = [0, 16, 32, 48, 64]
    fig, axes = plt.subplots(2, len(pick), figsize=(2.4 * len(pick), 5.0), squeeze=False)
    for row, (name, means, targets) in enumerate(
        [("real", real.touch_means, real.targets), ("sim", sim["means"], sim["targets"])]
    ):
        for col, i in enumerate(pick):
            ax = axes[row, col]
            im = ax.imshow(means[i].reshape(8, 8), cmap="viridis", vmin=-10, vmax=250)
            t = targets[i]
            ang = np.degrees(np.arctan2(t[2], t[0]))
            ax.set_title(f"{name} #{i}\ny={t[1] * 1e3:.0f} mm, {ang:.0f} deg", fontsize=8)
            ax.set_xticks(range(0, 8, 2))
            ax.set_yticks(range(0, 8, 2))
            if col == 0:
                ax.set_ylabel("TX")
            if row == 1:
                ax.set_xlabel("RX")
    fig.colorbar(im, ax=axes, shrink=0.8, label="counts above baseline (mean of 50 frames)")
    fig.savefig(out / "sim_touch_images.png", dpi=110)
    fig.savefig(out / "sim_touch_images.svg")
    plt.close(fig)

    skin = sim["skin"]
    lay = skin.layout
    mesh = skin.mesh
    fig = plt.figure(figsize=(7, 5))
    ax = fig.add_subplot(projection="3d")
    ax.plot_trisurf(*mesh.vertices.T, triangles=mesh.faces, color="0.85", alpha=0.3, linewidth=0)
    for i, w in enumerate(lay.tx_wires):
        ax.plot(*w.T, color="tab:red", lw=1.2, label="TX (along the cone)" if i == 0 else None)
    for j, w in enumerate(lay.rx_wires):
        ax.plot(*w.T, color="tab:blue", lw=1.2, label="RX (around the cone)" if j == 0 else None)
    ax.scatter(*lay.sensor_positions.T, color="k", s=10, label="sensors (crossings)")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_box_aspect(np.ptp(mesh.vertices, axis=0))
    ax.view_init(elev=55, azim=-60)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("simulated wiring, seed 0 (8 TX x 8 RX)")
    fig.savefig(out / "sim_layout.png", dpi=110)
    fig.savefig(out / "sim_layout.svg")
    plt.close(fig)
    print(f"wrote {out / 'sim_touch_images.png'} and {out / 'sim_layout.png'}")


if __name__ == "__main__":
    main()
