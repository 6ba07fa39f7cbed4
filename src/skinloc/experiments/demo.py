"""``skinloc demo``: simulate the paper's skin, calibrate, train, validate and report.

The report is meant to be pasted into a paper or a lab notebook: it states the seed, skinloc's
version and what "default" is, shows the error against the number of calibration touches
over several simulated skins with the paper's network beside it and the real skin's figures
(``docs/benchmarks.md``), and writes every figure as PNG and SVG.
"""

from __future__ import annotations

import importlib.util
import logging
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skinloc.calibration.session import SessionConfig, simulate_session
from skinloc.evaluation.metrics import ErrorStats, mean_snr_db
from skinloc.evaluation.scoring import evaluate, train_localizer
from skinloc.geometry.mesh import cone_skin, farthest_point_sampling

log = logging.getLogger(__name__)

__all__ = [
    "NO_PRIOR",
    "PROBING_FLOOR_MM",
    "REAL_SKIN_ERROR_MM",
    "REAL_SKIN_SPLIT",
    "DemoConfig",
    "DemoResult",
    "SkinCurve",
    "real_skin_errors",
    "reference_curves",
    "run_demo",
]

#: Mean error (mm) on the real skin of models trained on evenly spread subsets of the
#: 80-point-log recording of 2023-12-10 and tested on the 50 and 30 point logs recorded the
#: same day (80 touches), per touch: ``real_skin_errors`` below; a test recomputes them from
#: the recordings when they are present (``tests/experiments/test_real_skin_figures.py``).
#: "default" uses the map prior where it helps (up to 15 touches), "default, no prior" never.
REAL_SKIN_ERROR_MM: dict[str, dict[int, float]] = {
    "default": {5: 29.3, 10: 17.1, 20: 13.8, 40: 11.2, 80: 9.9},
    "default, no prior": {5: 29.9, 10: 16.9, 20: 13.8, 40: 11.2, 80: 9.9},
    "paper": {5: 46.5, 10: 36.4, 20: 21.5, 40: 17.7, 80: 14.5},
}
#: The default model fitted without the map prior (``--no-prior``): a curve of its own.
NO_PRIOR = "default, no prior"
#: How far a person's touch lands from the prompted point on the real skin, per touch, mm
#: (``docs/accuracy.md``, ``bench/label_noise.py``): no model scores below it against prompts.
PROBING_FLOOR_MM = 6.2
#: The recordings of ``REAL_SKIN_ERROR_MM``: trained on the first, tested on the others.
REAL_SKIN_SPLIT = (
    "ConeSkinData80Points_RND_80PL_1.mat",
    "ConeSkinData50Points_RND_50PL_1.mat",
    "ConeSkinData30Points_RND_30PL_1.mat",
)


def reference_curves() -> dict:
    """The real skin's error curves and the probing floor, as plain JSON-ready data.

    ``{"curves": {label: {"sizes": [...], "mean_mm": [...]}}, "probing_floor_mm": float,
    "trained_on": str, "tested_on": [str, ...]}``; labels are "default" (with the map prior),
    "default, no prior" and "paper" (the paper's 64-32-3 network).
    """
    return {
        "curves": {
            arch: {"sizes": list(errs), "mean_mm": list(errs.values())}
            for arch, errs in REAL_SKIN_ERROR_MM.items()
        },
        "probing_floor_mm": PROBING_FLOOR_MM,
        "trained_on": REAL_SKIN_SPLIT[0],
        "tested_on": list(REAL_SKIN_SPLIT[1:]),
    }


def real_skin_errors(
    data_dir: str | Path, arch: str = "default", sizes: tuple[int, ...] = (5, 10, 20, 40, 80)
) -> dict[int, float]:
    """``REAL_SKIN_ERROR_MM[arch]`` recomputed from the real recordings in ``data_dir``.

    ``arch`` is a ``ContactLocalizer`` configuration, or ``"default, no prior"``. Returns the
    mean error per touch, mm, rounded to 0.1 mm, by calibration size.
    """
    from skinloc.data.recording import read_recording

    train, *tests = (read_recording(Path(data_dir) / n) for n in REAL_SKIN_SPLIT)
    kw = {"arch": arch} if arch != NO_PRIOR else {"prior": "none"}
    out = {}
    for n in sizes:
        sub = train.subset(_even_subset(train.targets, n))
        model = train_localizer([sub], random_state=0, count_rule=False, **kw)
        out[n] = round(float(evaluate(model, tests).stats.mean_mm), 1)
    return out


@dataclass
class DemoConfig:
    """Settings of the demo.

    Attributes
    ----------
    out_dir : Path
        Report folder (recordings, model, PNG and SVG figures, index.html).
    n_points : int
        Calibration point logs (the paper's best model: 80).
    n_validation : int
        Fresh random validation touches on the first skin (the paper: 20).
    samples_per_touch : int
        Frames per touch.
    curve_sizes : tuple of int
        Point-log counts for the error-against-point-logs figure.
    random_state : int
        Seed of the first simulated skin and its sessions; the other skins use the next seeds.
    arch : str
        Localiser configuration.
    n_skins : int
        Simulated skins (wirings) the error curve is measured on, the first included.
    n_validation_extra : int
        Fresh random validation touches on each of the other skins.
    compare_paper : bool
        Also train the paper's 64-32-3 network at every size, for the curve.
    """

    out_dir: Path = Path("skinloc-demo")
    n_points: int = 80
    n_validation: int = 20
    samples_per_touch: int = 50
    curve_sizes: tuple[int, ...] = (5, 10, 20, 40, 80)
    random_state: int = 0
    arch: str = "default"
    n_skins: int = 3
    n_validation_extra: int = 20
    compare_paper: bool = True


@dataclass
class SkinCurve:
    """Mean error (mm) per calibration size on each simulated skin, for one configuration."""

    arch: str
    sizes: list[int]
    per_skin: list[list[float]]  # per_skin[s][i]: skin s, size sizes[i]

    def mean(self) -> np.ndarray:
        """Mean over skins per size, mm."""
        return np.mean(np.asarray(self.per_skin), axis=0)

    def spread(self) -> np.ndarray:
        """Standard deviation over skins per size, mm (0 with one skin)."""
        return np.std(np.asarray(self.per_skin), axis=0)


@dataclass
class DemoResult:
    """What the demo measured."""

    stats: ErrorStats
    mean_snr_db: float
    curve: dict[int, ErrorStats] = field(default_factory=dict)
    report: Path | None = None
    fit_time_s: float = float("nan")
    skins: dict[str, SkinCurve] = field(default_factory=dict)
    uncertainty_spearman: float = float("nan")
    prior_sizes: list[int] = field(default_factory=list)

    def prior_lines(self) -> list[str]:
        """One line per calibration size the map prior was applied at: with it and without.

        The simulated skins' mean +- std, and the real skin's figures where known, mm.
        """
        main, off = self.skins.get("main"), self.skins.get("no prior")
        if main is None or off is None:
            return []
        lines = []
        for n in self.prior_sizes:
            i = main.sizes.index(n)
            line = (
                f"{n} touches: {main.mean()[i]:.1f} +- {main.spread()[i]:.1f} mm with the map "
                f"prior, {off.mean()[i]:.1f} +- {off.spread()[i]:.1f} mm without "
                f"({len(main.per_skin)} simulated skins)"
            )
            real = [REAL_SKIN_ERROR_MM[a].get(n) for a in (main.arch, NO_PRIOR)]
            if None not in real:
                line += f"; real skin {real[0]:.1f} / {real[1]:.1f} mm"
            lines.append(line)
        return lines

    def headline(self) -> tuple[float, float, int]:
        """Mean and spread (std over skins) of the error at the largest size, mm; skins."""
        c = self.skins.get("main")
        if c is None or not c.per_skin:
            return self.stats.mean_mm, 0.0, 1
        return float(c.mean()[-1]), float(c.spread()[-1]), len(c.per_skin)


def _even_subset(targets: np.ndarray, n: int) -> np.ndarray:
    """``n`` indices of ``targets`` spread evenly over them (farthest-point sampling)."""
    return farthest_point_sampling(targets, n, start=0)


def _session(skin, mesh, path: Path, n: int, mode: str, cfg: DemoConfig, seed: int, say, label):
    return simulate_session(
        skin,
        mesh,
        path,
        SessionConfig(
            n_points=n,
            mode=mode,
            samples_per_touch=cfg.samples_per_touch,
            random_state=seed,
            description=f"skinloc demo {label}",
        ),
        progress=lambda d, t: say(label, d, t),
    )


def run_demo(cfg: DemoConfig, step: Callable[[str, int, int], None] | None = None) -> DemoResult:
    """Run the whole path on simulated paper skins and write the report folder (see ``_run``)."""
    try:
        import torch
    except ImportError:  # a plain install: no network is trained (see _run)
        return _run(cfg, step)
    # Many small networks: one thread each is several times faster than two fighting over a
    # busy machine's cores (measured: 9 s against 127 s for the paper net under load).
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _run(cfg, step)
    finally:
        torch.set_num_threads(threads)


def _run(cfg: DemoConfig, step: Callable[[str, int, int], None] | None) -> DemoResult:
    """Run the whole path on simulated paper skins and write the report folder.

    The first skin (seed ``random_state``) is calibrated with ``n_points`` even touches and
    validated on ``n_validation`` fresh random ones; its recordings and model are kept. The
    error curve repeats the calibration on ``n_skins`` skins (the next seeds), each validated
    on its own fresh touches. ``step(label, done, total)`` reports progress.
    """
    from skinloc import __version__
    from skinloc.evaluation import report
    from skinloc.sim.skin import SimulatedSkin

    say = step or (lambda *a: None)
    out = Path(cfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    mesh = cone_skin()
    seeds = [cfg.random_state + k for k in range(max(1, cfg.n_skins))]
    compare = cfg.compare_paper and cfg.arch != "paper"
    # The paper's network trains in PyTorch, the [nets] extra; the plain install skips it.
    without_torch = compare and importlib.util.find_spec("torch") is None
    if without_torch:
        log.warning("the paper's network is left out: it trains in PyTorch (skinloc[nets])")
    # the default model is drawn with and without the map prior (a curve each)
    archs = [cfg.arch] + ([NO_PRIOR] if cfg.arch == "default" else [])
    archs += ["paper"] if compare and not without_torch else []
    sizes = sorted({n for n in cfg.curve_sizes if 1 <= n <= cfg.n_points} | {cfg.n_points})
    per_skin: dict[str, list[list[float]]] = {a: [] for a in archs}
    ev = cal = val = model = None
    curve: dict[int, ErrorStats] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k, seed in enumerate(seeds):
            first = k == 0
            where = out if first else Path(tmp)
            skin = SimulatedSkin(mesh, random_state=seed)
            tag = "" if first else f" (skin {k + 1} of {len(seeds)})"
            with skin:
                c = _session(
                    skin,
                    mesh,
                    where / "calibration.h5",
                    cfg.n_points,
                    "even",
                    cfg,
                    seed,
                    say,
                    "calibrating (simulated touches)" + tag,
                )
                v = _session(
                    skin,
                    mesh,
                    where / "validation.h5",
                    cfg.n_validation if first else cfg.n_validation_extra,
                    "random",
                    cfg,
                    seed + 1000,
                    say,
                    "validating (fresh random touches)" + tag,
                )
            prior_used: dict[int, bool] = {}
            for arch in archs:
                row = []
                for i, n in enumerate(sizes):
                    if arch == NO_PRIOR and not prior_used[n]:
                        # the default fitted this size without the prior: the same model
                        row.append(per_skin[cfg.arch][-1][i])
                        continue
                    say("error against point logs" + tag, i, len(sizes))
                    sub = c if n == c.n_point_logs else c.subset(_even_subset(c.targets, n))
                    kw = {"prior": "none"} if arch == NO_PRIOR else {"arch": arch}
                    kept = first and arch == cfg.arch and n == c.n_point_logs
                    # only the kept model goes live: the others need no count rule
                    m = train_localizer([sub], random_state=seed, count_rule=kept, **kw)
                    prior_used.setdefault(n, bool(getattr(m, "prior_used_", False)))
                    e = evaluate(m, [v])
                    row.append(e.stats.mean_mm)
                    if first and arch == cfg.arch:
                        curve[n] = e.stats
                        if n == c.n_point_logs:
                            model, ev = m, e
                per_skin[arch].append(row)
            if first:
                cal, val = c, v
    assert ev is not None and cal is not None and val is not None and model is not None
    model.save(out / "model.h5")
    snr = mean_snr_db(cal.touch_means, cal.baseline_frames)
    skins = {"main": SkinCurve(cfg.arch, sizes, per_skin[cfg.arch])}
    if NO_PRIOR in per_skin:
        skins["no prior"] = SkinCurve(NO_PRIOR, sizes, per_skin[NO_PRIOR])
    if "paper" in per_skin and cfg.arch != "paper":
        skins["paper"] = SkinCurve("paper", sizes, per_skin["paper"])

    applied = sorted(n for n, used in prior_used.items() if used) if NO_PRIOR in archs else []
    res = DemoResult(
        ev.stats, snr, curve, None, model.fit_time_s_, skins, ev.uncertainty_spearman, applied
    )
    figs = _figures(cfg, out, mesh, cal, ev, skins, report)
    mean, spread, n_sk = (
        float(skins["main"].mean()[-1]),
        float(skins["main"].spread()[-1]),
        len(seeds),
    )
    real = REAL_SKIN_ERROR_MM.get(cfg.arch, {}).get(cfg.n_points)
    summary = {
        "skinloc version": __version__,
        "seed": f"{cfg.random_state} (skins {seeds[0]}-{seeds[-1]}; validation sessions "
        f"seed + 1000)",
        "model": f"{cfg.arch}: {_describe(cfg.arch)}; trained in {model.fit_time_s_:.1f} s",
        "skin": "simulated semi-conical skin of the paper (8 TX x 8 RX), physics fitted to the "
        "real recordings (docs/simulator.md)",
        "calibration": f"{cal.n_point_logs} point logs (even), {cal.samples_per_touch} frames "
        "each; smaller sizes are evenly spread subsets of them",
        "validation": f"{val.n_point_logs} fresh random touches on skin 1, "
        f"{cfg.n_validation_extra} on each other skin; the label is the prompted target "
        "(the simulated person misses it, as a real one does)",
        f"expected error, {cal.n_point_logs} touches": f"{mean:.1f} +- {spread:.1f} mm "
        f"(mean +- std over {n_sk} simulated skins)"
        + (f"; real skin: {real:.1f} mm (docs/benchmarks.md)" if real else ""),
        **(
            {
                f"paper 64-32-3 network, {cal.n_point_logs} touches": (
                    f"{skins['paper'].mean()[-1]:.1f} +- {skins['paper'].spread()[-1]:.1f} mm "
                    f"(same skins and touches)"
                    + (
                        f"; real skin: {REAL_SKIN_ERROR_MM['paper'][cal.n_point_logs]:.1f} mm"
                        if cal.n_point_logs in REAL_SKIN_ERROR_MM["paper"]
                        else ""
                    )
                )
            }
            if "paper" in skins
            else {}
        ),
        **(
            {
                "paper 64-32-3 network": "not trained here: it needs PyTorch "
                "(pip install 'skinloc[nets]')"
            }
            if without_torch
            else {}
        ),
        **{
            f"map prior, {line.split(': ', 1)[0]}": line.split(": ", 1)[1]
            for line in res.prior_lines()
        },
        "this skin's error": str(ev.stats),
        "uncertainty vs error": f"Spearman {ev.uncertainty_spearman:.2f}",
        "mean SNR (Eq. 1)": f"{snr:.1f} dB",
        **{f"skin 1, {n} point logs": str(s) for n, s in curve.items()},
    }
    page = report.write_html(
        out / "index.html",
        "skinloc demo: simulated paper skin",
        summary,
        figs,
        notes="Recordings and the model are in this folder: calibration.h5, validation.h5, "
        "model.h5. Every figure is also saved as SVG beside its PNG. Reproduce with "
        f"`skinloc demo --seed {cfg.random_state} --points {cfg.n_points} "
        f"--validation {cfg.n_validation} --skins {len(seeds)}`.",
    )
    res.report = page
    return res


def _describe(arch: str) -> str:
    from skinloc.models.localizer import architecture_kind

    if arch == "paper":
        return "the paper's 64-32-3 tanh network, outputs snapped to the surface"
    return architecture_kind(arch).summary


def _figures(cfg, out, mesh, cal, ev, skins, report) -> list[tuple[str, str]]:
    """Write the figures (PNG + SVG) and return ``(png name, caption)`` pairs."""
    strongest = int(np.argmax(cal.touch_means.max(axis=1)))
    main = skins["main"]
    n_sk = len(main.per_skin)
    curves = {
        f"{main.arch} (simulated, {n_sk} skins)": (main.sizes, main.mean(), main.spread()),
    }
    if "no prior" in skins:
        p = skins["no prior"]
        curves[f"{NO_PRIOR} (simulated, {n_sk} skins)"] = (p.sizes, p.mean(), p.spread())
    if "paper" in skins:
        p = skins["paper"]
        curves[f"paper 64-32-3 (simulated, {n_sk} skins)"] = (p.sizes, p.mean(), p.spread())
    # the real skin's curves in the same order (and so colours) as the simulated ones
    shown = [main.arch] + ([NO_PRIOR] if "no prior" in skins else [])
    shown += ["paper"] if "paper" in skins else []
    real = {
        f"{a} (real skin)": (list(REAL_SKIN_ERROR_MM[a]), list(REAL_SKIN_ERROR_MM[a].values()))
        for a in shown
        if a in REAL_SKIN_ERROR_MM
    }
    paths = [
        (
            report.plot_sensor_image(
                cal.touch_means[strongest],
                cal.n_tx,
                cal.n_rx,
                out / "sensor_image.png",
                f"Touch {strongest}: mean of {cal.samples_per_touch} frames",
            ),
            "A touch's sensor image (TX x RX), counts above baseline.",
        ),
        (
            report.plot_predictions_3d(mesh, ev.true, ev.predicted, out / "predictions_3d.png"),
            f"{len(ev.true)} validation touches on skin 1: each segment joins the prompted "
            "target (o) to the prediction (x); colour is the error.",
        ),
        (
            report.plot_error_curves(
                curves, real, out / "error_vs_points.png", floor_mm=PROBING_FLOOR_MM
            ),
            f"Validation error against calibration point logs. Simulated: mean over {n_sk} "
            "skins, error bars one standard deviation between skins (each skin's error is "
            f"the mean over its validation touches). Real skin: {', '.join(real)} from "
            "docs/benchmarks.md (trained on evenly spread subsets of one real recording, "
            'tested on two others of the same day). "default" uses the map prior learned '
            'from simulated skins where it helps (few touches); "default, no prior" is '
            "`skinloc train --no-prior`. Dotted: the probing floor, how far a person's touch "
            f"lands from the prompt on the real skin (~{PROBING_FLOOR_MM:.1f} mm).",
        ),
        (
            report.plot_uncertainty(ev.uncertainty_mm, ev.errors_mm, out / "uncertainty.png"),
            f"The model's own uncertainty against its error, per validation touch "
            f"(Spearman {ev.uncertainty_spearman:.2f}).",
        ),
    ]
    return [(p.name, cap) for p, cap in paths]
