"""Benchmarks: the paper's experiment on the simulated skin, real-recording splits, timing."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.calibration.session import SessionConfig, simulate_session
from skinloc.data.recording import Recording, read_recording
from skinloc.evaluation.metrics import mean_snr_db
from skinloc.evaluation.scoring import evaluate, train_localizer
from skinloc.geometry.mesh import cone_skin

log = logging.getLogger(__name__)

__all__ = [
    "REAL_DEC",
    "REAL_MAY",
    "SplitResult",
    "paper_experiment",
    "real_splits",
    "timing",
]

Step = Callable[[str, int, int], None]

#: The four recordings of 2023-12-10 (one session) and the two of 2024-05-23.
REAL_DEC = (
    "ConeSkinData_RND_20PL_1.mat",
    "ConeSkinData50Points_RND_50PL_1.mat",
    "ConeSkinData80Points_RND_80PL_1.mat",
    "ConeSkinData30Points_RND_30PL_1.mat",
)
REAL_MAY = ("ConeSkinData_RND_20PL_2.mat", "ConeSkinData_RND_40PL_1.mat")
#: The multi-touch figures' split of that session: the default model trained on 80PL_1, tested
#: on the other three (which choose or tune nothing).
TRAIN_DEC = "ConeSkinData80Points_RND_80PL_1.mat"
TEST_DEC = tuple(r for r in REAL_DEC if r != TRAIN_DEC)


def _noop(*_: object) -> None:
    return None


@dataclass(frozen=True)
class SplitResult:
    """Error of one train/test split, mm."""

    protocol: str
    arch: str
    train: str
    test: str
    per: str
    n: int
    mean_mm: float
    std_mm: float
    median_mm: float
    p95_mm: float


def paper_experiment(
    sizes: Sequence[int] = (20, 50, 80, 100),
    n_validation: int = 20,
    seeds: Sequence[int] = (0, 1, 2),
    archs: Sequence[str] = ("paper", "default"),
    samples_per_touch: int = 50,
    tmp_dir: Path | None = None,
    step: Step = _noop,
) -> list[dict]:
    """The paper's Fig. 3 on simulated skins.

    For each seed a new simulated skin (a new random wiring) is calibrated once per size with
    the paper's edge sampling, and every model is validated on the same ``n_validation`` fresh
    random touches of that skin.

    Returns
    -------
    list of dict
        One row per (seed, size, arch): ``seed, n_points, arch, snr_db, mean_mm, std_mm``.
    """
    import tempfile

    from skinloc.sim.skin import SimulatedSkin

    rows: list[dict] = []
    mesh = cone_skin()
    total, done = len(seeds) * (len(sizes) + 1), 0
    with tempfile.TemporaryDirectory(dir=tmp_dir) as tmp:
        for seed in seeds:
            skin = SimulatedSkin(mesh, random_state=seed)
            with skin:
                val = simulate_session(
                    skin,
                    mesh,
                    Path(tmp) / f"val{seed}.h5",
                    SessionConfig(
                        n_points=n_validation,
                        mode="random",
                        samples_per_touch=samples_per_touch,
                        random_state=10_000 + seed,
                    ),
                )
                done += 1
                step("paper experiment", done, total)
                for n in sizes:
                    cal = simulate_session(
                        skin,
                        mesh,
                        Path(tmp) / f"cal{seed}_{n}.h5",
                        SessionConfig(
                            n_points=n,
                            mode="edge",
                            samples_per_touch=samples_per_touch,
                            random_state=seed * 1000 + n,
                        ),
                    )
                    snr = mean_snr_db(cal.touch_means, cal.baseline_frames)
                    for arch in archs:
                        model = train_localizer([cal], arch=arch, random_state=seed)
                        st = evaluate(model, [val]).stats
                        rows.append(
                            dict(
                                seed=seed,
                                n_points=n,
                                arch=arch,
                                snr_db=snr,
                                mean_mm=st.mean_mm,
                                std_mm=st.std_mm,
                                fit_time_s=model.fit_time_s_,
                            )
                        )
                    done += 1
                    step("paper experiment", done, total)
    return rows


def _load_all(data_dir: Path, names: Sequence[str]) -> dict[str, Recording]:
    return {n: read_recording(Path(data_dir) / n) for n in names}


def real_splits(
    data_dir: str | Path,
    archs: Sequence[str] = ("default", "mlp", "paper"),
    random_state: int = 0,
    step: Step = _noop,
) -> list[SplitResult]:
    """The issue's protocols on the real recordings of 2023-12-10.

    * ``cross``: train on the 80-point-log recording, test on each of the other three;
    * ``loro``: leave one recording out over the four, train on the other three.

    Each split is scored per touch (mean of its frames) and per frame.
    """
    data_dir = Path(data_dir)
    recs = _load_all(data_dir, REAL_DEC)
    splits: list[tuple[str, list[str], str]] = []
    train80 = "ConeSkinData80Points_RND_80PL_1.mat"
    for test in REAL_DEC:
        if test != train80:
            splits.append(("cross", [train80], test))
    for test in REAL_DEC:
        splits.append(("loro", [n for n in REAL_DEC if n != test], test))
    out: list[SplitResult] = []
    total = len(splits) * len(archs)
    for i, (protocol, train, test) in enumerate(splits):
        for j, arch in enumerate(archs):
            step("real-recording splits", i * len(archs) + j, total)
            model = train_localizer([recs[n] for n in train], arch=arch, random_state=random_state)
            for per, per_frame in (("touch", False), ("frame", True)):
                st = evaluate(model, [recs[test]], per_frame=per_frame).stats
                out.append(
                    SplitResult(
                        protocol,
                        arch,
                        "+".join(_short(n) for n in train),
                        _short(test),
                        per,
                        st.n,
                        st.mean_mm,
                        st.std_mm,
                        st.median_mm,
                        st.p95_mm,
                    )
                )
    step("real-recording splits", total, total)
    return out


def _naive_map_predictor(model) -> Callable[[np.ndarray], np.ndarray]:
    """Arg-min of ``np.linalg.norm(table - f)`` per frame: the obvious matcher, 64 frames a step."""
    from skinloc.models.response_map import shape_features

    table, cand = model.map_.table, model.map_.candidates

    def predict(x: np.ndarray) -> np.ndarray:
        F = shape_features(x, model.config_["clip_negative"]).astype(np.float32)
        idx = [
            np.linalg.norm(table[None] - F[i : i + 64, None], axis=2).argmin(axis=1)
            for i in range(0, len(F), 64)
        ]
        return cand[np.concatenate(idx)]

    return predict


def _torch_predictor(model) -> Callable[[np.ndarray], np.ndarray]:
    """The network's weights as one ``torch.nn.Sequential`` per member, then the KD-tree snap."""
    import torch
    from scipy.spatial import cKDTree

    act = {"relu": torch.nn.ReLU, "tanh": torch.nn.Tanh, "gelu": torch.nn.GELU}[
        model.config_["activation"]
    ]
    members = []
    for m in range(len(model.coefs_[0])):
        layers: list[torch.nn.Module] = []
        for i, (W, b) in enumerate(zip(model.coefs_, model.intercepts_, strict=True)):
            lin = torch.nn.Linear(W.shape[1], W.shape[2]).double()
            lin.weight.data = torch.as_tensor(W[m].T.copy())
            lin.bias.data = torch.as_tensor(b[m, 0].copy())
            layers.append(lin)
            if i < len(model.coefs_) - 1:
                layers.append(act())
        members.append(torch.nn.Sequential(*layers))
    pts = model.surface_points_
    tree = cKDTree(pts)
    torch.set_num_threads(1)

    def predict(x: np.ndarray) -> np.ndarray:
        f = (model._features(x, model.config_) - model.feature_mean_) / model.feature_scale_
        with torch.inference_mode():
            t = torch.as_tensor(f)
            out = torch.stack([net(t) for net in members]).mean(0).numpy()
        return pts[tree.query(out * model.target_scale_ + model.target_mean_)[1]]

    return predict


#: The obvious implementation each model kind's prediction is timed against, by kind name.
_NAIVE_PREDICTORS: dict[str, Callable[[Any], Callable[[np.ndarray], np.ndarray]]] = {
    "map": _naive_map_predictor,
    "network": _torch_predictor,
}


def _short(name: str) -> str:
    """``ConeSkinData80Points_RND_80PL_1.mat`` -> ``80PL_1``."""
    return name.rsplit("_RND_", 1)[-1].removesuffix(".mat")


def timing(
    n_points: int = 100,
    samples_per_touch: int = 50,
    n_latency: int = 2000,
    batch: int = 20_000,
    arch: str = "default",
    random_state: int = 0,
    step: Step = _noop,
) -> dict[str, float]:
    """Training time, single-frame latency and batch throughput, with a baseline in the same run.

    The baseline is what a straightforward implementation of the same trained model would do:
    for a response map, the distance from the features to every row of the map table by
    broadcasting, then the arg-min; for a network, a ``torch.nn.Sequential`` per member under
    ``torch.inference_mode`` followed by the same KD-tree snap.
    """
    import tempfile

    from skinloc.sim.skin import SimulatedSkin

    mesh = cone_skin()
    with tempfile.TemporaryDirectory() as tmp:
        skin = SimulatedSkin(mesh, random_state=random_state)
        with skin:
            step("timing: simulating", 0, 3)
            cal = simulate_session(
                skin,
                mesh,
                Path(tmp) / "cal.h5",
                SessionConfig(
                    n_points=n_points,
                    mode="even",
                    samples_per_touch=samples_per_touch,
                    random_state=random_state,
                ),
                progress=lambda d, t: step("timing: simulating", d, t),
            )
    step("timing: training", 1, 3)
    t0 = time.perf_counter()
    model = train_localizer([cal], arch=arch, random_state=random_state)
    fit_s = time.perf_counter() - t0

    step("timing: prediction", 2, 3)
    frames = cal.deltas.reshape(-1, cal.n_sensors)
    rng = np.random.default_rng(random_state)
    single = frames[rng.integers(len(frames), size=n_latency)]
    baseline = _NAIVE_PREDICTORS.get(model.kind.name)
    if baseline is None:
        raise ValueError(
            f"no naive predictor to time a {model.kind.name!r} model against; the paper's "
            f"benchmark has them for {', '.join(_NAIVE_PREDICTORS)}"
        )
    baseline_predict = baseline(model)

    def lat(fn: Callable[[np.ndarray], np.ndarray]) -> np.ndarray:
        fn(single[:1])
        ts = np.empty(n_latency)
        for i in range(n_latency):
            t = time.perf_counter()
            fn(single[i : i + 1])
            ts[i] = time.perf_counter() - t
        return ts * 1e6

    ours, base = lat(model.predict), lat(baseline_predict)
    big = frames[rng.integers(len(frames), size=batch)]
    t = time.perf_counter()
    model.predict(big)
    ours_tp = batch / (time.perf_counter() - t)
    t = time.perf_counter()
    baseline_predict(big)
    base_tp = batch / (time.perf_counter() - t)
    step("timing", 3, 3)
    return {
        "fit_s": fit_s,
        "n_points": n_points,
        "samples_per_touch": samples_per_touch,
        "latency_median_us": float(np.median(ours)),
        "latency_p99_us": float(np.percentile(ours, 99)),
        "baseline_latency_median_us": float(np.median(base)),
        "baseline_latency_p99_us": float(np.percentile(base, 99)),
        "latency_speedup": float(np.median(base) / np.median(ours)),
        "batch_frames_per_s": ours_tp,
        "baseline_batch_frames_per_s": base_tp,
        "batch_speedup": ours_tp / base_tp,
    }
