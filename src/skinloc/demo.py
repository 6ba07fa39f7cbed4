"""``skinloc demo``: simulate the paper's skin, calibrate, train, validate and report."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skinloc.calibrate import SessionConfig, simulate_session
from skinloc.evaluation import evaluate, train_localizer
from skinloc.geometry import cone_skin
from skinloc.metrics import ErrorStats, mean_snr_db

log = logging.getLogger(__name__)

__all__ = ["DemoConfig", "DemoResult", "run_demo"]


@dataclass
class DemoConfig:
    """Settings of the demo.

    Attributes
    ----------
    out_dir : Path
        Report folder (recordings, model, PNG figures, index.html).
    n_points : int
        Calibration point logs (the paper's best model: 80).
    n_validation : int
        Fresh random validation touches (the paper: 20).
    samples_per_touch : int
        Frames per touch.
    curve_sizes : tuple of int
        Point-log counts for the error-against-point-logs figure.
    random_state : int
        Seed of the simulated skin and the session.
    arch : str
        Localiser configuration.
    """

    out_dir: Path = Path("skinloc-demo")
    n_points: int = 80
    n_validation: int = 20
    samples_per_touch: int = 50
    curve_sizes: tuple[int, ...] = (10, 20, 40, 80)
    random_state: int = 0
    arch: str = "default"


@dataclass
class DemoResult:
    """What the demo measured."""

    stats: ErrorStats
    mean_snr_db: float
    curve: dict[int, ErrorStats] = field(default_factory=dict)
    report: Path | None = None
    fit_time_s: float = float("nan")


def run_demo(cfg: DemoConfig, step: Callable[[str, int, int], None] | None = None) -> DemoResult:
    """Run the whole path on the simulated paper skin and write the report folder.

    ``step(label, done, total)`` reports progress.
    """
    from skinloc import report
    from skinloc.sources.sim import SimulatedSkin

    say = step or (lambda *a: None)
    out = Path(cfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mesh = cone_skin()
    skin = SimulatedSkin(mesh, random_state=cfg.random_state)
    with skin:
        cal = simulate_session(
            skin,
            mesh,
            out / "calibration.h5",
            SessionConfig(
                n_points=cfg.n_points,
                mode="even",
                samples_per_touch=cfg.samples_per_touch,
                random_state=cfg.random_state,
                description="skinloc demo calibration",
            ),
            progress=lambda d, t: say("calibrating (simulated touches)", d, t),
        )
        val = simulate_session(
            skin,
            mesh,
            out / "validation.h5",
            SessionConfig(
                n_points=cfg.n_validation,
                mode="random",
                samples_per_touch=cfg.samples_per_touch,
                random_state=cfg.random_state + 1000,
                description="skinloc demo validation",
            ),
            progress=lambda d, t: say("validating (fresh random touches)", d, t),
        )
    model = train_localizer(
        [cal],
        arch=cfg.arch,
        random_state=cfg.random_state,
        progress=lambda d, t: say("training", d, t),
    )
    model.save(out / "model.h5")
    ev = evaluate(model, [val])
    snr = mean_snr_db(cal.touch_means, cal.baseline_frames)

    curve: dict[int, ErrorStats] = {}
    sizes = [n for n in cfg.curve_sizes if n <= cal.n_point_logs]
    for i, n in enumerate(sizes):
        say("error against point logs", i, len(sizes))
        # An evenly spread subset stands for a smaller session of the same skin.
        idx = np.linspace(0, cal.n_point_logs - 1, n).round().astype(int)
        sub = train_localizer([cal.subset(idx)], arch=cfg.arch, random_state=cfg.random_state)
        curve[n] = evaluate(sub, [val]).stats
    say("error against point logs", len(sizes), len(sizes))

    strongest = int(np.argmax(cal.touch_means.max(axis=1)))
    figs = [
        (
            report.plot_sensor_image(
                cal.touch_means[strongest],
                cal.n_tx,
                cal.n_rx,
                out / "sensor_image.png",
                f"Touch {strongest}: mean of {cal.samples_per_touch} frames",
            ),
            "A touch's sensor image (TX x RX), counts above baseline",
        ),
        (
            report.plot_predictions_3d(mesh, ev.true, ev.predicted, out / "predictions_3d.png"),
            f"{cfg.n_validation} validation touches: predicted against true",
        ),
        (
            report.plot_error_curve(
                list(curve),
                [s.mean_mm for s in curve.values()],
                [s.std_mm for s in curve.values()],
                out / "error_vs_points.png",
            ),
            "Validation error against calibration point logs",
        ),
    ]
    page = report.write_html(
        out / "index.html",
        "skinloc demo: simulated paper skin",
        {
            "skin": "built-in semi-conical skin (paper size), 8 TX x 8 RX simulated sensors",
            "calibration": f"{cal.n_point_logs} point logs (even), "
            f"{cal.samples_per_touch} frames each",
            "validation": f"{val.n_point_logs} fresh random touches",
            "model": f"{cfg.arch}, trained in {model.fit_time_s_:.1f} s",
            "error": str(ev.stats),
            "mean SNR (Eq. 1)": f"{snr:.1f} dB",
            **{f"error with {n} point logs": str(s) for n, s in curve.items()},
        },
        [(p.name, cap) for p, cap in figs],
        notes="Recordings and the model are in this folder: calibration.h5, validation.h5, "
        "model.h5.",
    )
    return DemoResult(ev.stats, snr, curve, page, model.fit_time_s_)
