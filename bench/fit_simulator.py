"""Compare the simulated skin with the paper's real recordings, side by side.

Computes, on the real recordings and on simulated sessions of the same size (80 point logs of
50 frames, targets drawn like the paper's, "a random point on a random mesh edge"):

- no-touch noise std per sensor (median, counts), sensors above 5 sigma per touch, peak signal
  per touch, the array-wide offset during a touch (median of the touch image), the paper's
  Eq. 1 SNR;
- the error of the paper's 64-32-3 network (tanh, MSE, standardised inputs, outputs snapped to
  the nearest of 14,400 surface points): real = trained on the 80 PL recording, tested on the
  50 PL and 30 PL ones of the same day; sim = trained on a simulated 80-touch session, tested
  on 20 fresh touches, over several seeds.

Usage::

    /tmp/venv/bin/python bench/fit_simulator.py                 # the table (about 1 min)
    /tmp/venv/bin/python bench/fit_simulator.py --set probe_error_std_m=0.005 --seeds 6
    /tmp/venv/bin/python bench/fit_simulator.py --figures       # also docs/figures/sim_*.png
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from skinloc.dataset import read_recording
from skinloc.geometry import cone_skin, sample_targets, surface_points
from skinloc.metrics import snr_db
from skinloc.sources.sim import SimulatedSkin, SkinParams

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "hiro-cone-skin"
if not DATA.is_dir():
    DATA = Path("/work/shared/data/hiro-cone-skin")
TRAIN_REAL = "ConeSkinData80Points_RND_80PL_1.mat"
TEST_REAL = ("ConeSkinData50Points_RND_50PL_1.mat", "ConeSkinData30Points_RND_30PL_1.mat")
SECONDS_BETWEEN_TOUCHES = 4.5  # the paper: 1-2 minutes per 20 point logs


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


def real_side(n_net_seeds: int) -> dict[str, object]:
    """Statistics of the 80 PL recording and the paper net's error across recordings."""
    train = read_recording(DATA / TRAIN_REAL)
    stats = session_stats(train.touch_means, train.baseline_frames)
    snap = train.surface_points
    errors = {}
    for name in TEST_REAL:
        test = read_recording(DATA / name)
        errors[name] = np.array(
            [
                paper_net_errors_mm(
                    train.touch_means, train.targets, test.touch_means, test.targets, snap, seed
                ).mean()
                for seed in range(n_net_seeds)
            ]
        )
    return {"stats": stats, "net": errors}


def sim_side(params: SkinParams, seeds: list[int], n_net_seeds: int) -> dict[str, object]:
    """Statistics of simulated 80-touch sessions and the paper net's error on fresh touches."""
    snap = surface_points(cone_skin())
    per_seed = []
    net = []
    probe = []
    for seed in seeds:
        s = simulate_session(params, seed)
        n = s["n_train"]
        per_seed.append(session_stats(s["means"][:n], s["baseline_frames"]))
        probe.append(1e3 * np.linalg.norm(s["contacts"] - s["targets"], axis=1).mean())
        errs = [
            paper_net_errors_mm(
                s["means"][:n], s["targets"][:n], s["means"][n:], s["targets"][n:], snap, net_seed
            ).mean()
            for net_seed in range(n_net_seeds)
        ]
        net.append(float(np.mean(errs)))
    return {"stats": per_seed, "net": np.array(net), "probe_mm": float(np.mean(probe))}


def _fmt_range(values: np.ndarray, fmt: str = "{:.0f}") -> str:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    med, lo, hi = (fmt.format(v) for v in (np.median(values), values.min(), values.max()))
    return f"{med} ({lo}-{hi})"


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
    net_real = np.concatenate(list(real["net"].values()))
    per_file = ", ".join(
        f"{k.split('_')[0].replace('ConeSkinData', '')}: {v.mean():.1f}"
        for k, v in real["net"].items()
    )
    rows.append(
        (
            "paper 64-32-3 net, mean error mm",
            f"{net_real.mean():.1f} ({per_file})",
            f"{sim['net'].mean():.1f} [seeds {sim['net'].min():.1f}-{sim['net'].max():.1f}]",
        )
    )
    lines = [
        "| statistic | real (80 PL) | simulated (80 touches; median over seeds) |",
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6, help="simulated skins/sessions")
    ap.add_argument("--net-seeds", type=int, default=3, help="network initialisations")
    ap.add_argument("--set", nargs="*", default=[], help="override SkinParams, e.g. x=1.0")
    ap.add_argument("--no-real", action="store_true", help="skip the real side (tuning)")
    ap.add_argument("--figures", action="store_true", help="write docs/figures/sim_*.png")
    args = ap.parse_args()
    torch.set_num_threads(1)
    t0 = time.time()
    params = dataclasses.replace(SkinParams.default(), **_parse_set(args.set))
    sim = sim_side(params, list(range(args.seeds)), args.net_seeds)
    print(f"simulated probing error: mean {sim['probe_mm']:.1f} mm from the target")
    if args.no_real:
        for k in ("above5", "peak", "offset"):
            print(k, _fmt_range(np.concatenate([s[k] for s in sim["stats"]])))
        print("snr", np.mean([np.nanmean(s["snr"]) for s in sim["stats"]]))
        print("net", sim["net"].round(1), sim["net"].mean().round(1))
    else:
        real = real_side(args.net_seeds)
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
    plt.close(fig)
    print(f"wrote {out / 'sim_touch_images.png'} and {out / 'sim_layout.png'}")


if __name__ == "__main__":
    main()
