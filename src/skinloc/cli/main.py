"""The ``skinloc`` command line: simulate, train, evaluate, inspect, convert, benchmark, demo.

The shared objects (``app``, consoles, ``friendly_errors``, ``check_output``, ``progress_steps``,
option types) live in ``skinloc.cli.common``; the command groups in their own modules register
themselves on ``app`` at the end of this one.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from skinloc.cli import app as app_cli
from skinloc.cli import hardware as cli_hardware
from skinloc.cli import live as cli_live
from skinloc.cli import predict as cli_predict
from skinloc.cli import skin as cli_skin
from skinloc.cli.common import (
    Arch,
    Constraint,
    Mode,
    Units,
    app,
    check_interrupt,
    check_output,
    console,
    err_console,
    friendly_errors,
    progress_steps,
)

# the shared objects stay importable from here, where scripts and docs have always found them
__all__ = [
    "app",
    "check_interrupt",
    "check_output",
    "console",
    "err_console",
    "friendly_errors",
    "main",
    "progress_steps",
]

#: Fewer point logs than this make a poor model (one gives ~77 mm): train warns.
FEW_POINT_LOGS = 10
#: Largest simulated recording the command line makes, bytes of float32 frames.
MAX_SIM_BYTES = 4 * 2**30


def _check_size(points: int, samples: int, sensors: int = 64) -> None:
    """Refuse a simulated session whose frames would not fit in memory or on a disk."""
    size = points * samples * sensors * 4
    if size > MAX_SIM_BYTES:
        raise ValueError(
            f"{points} point logs x {samples} frames x {sensors} sensors is "
            f"{size / 2**30:.0f} GiB of frames; the limit is {MAX_SIM_BYTES / 2**30:.0f} GiB: "
            "ask for fewer --points or --samples"
        )


def _read_all(paths: list[Path]) -> list:
    from skinloc.data.recording import read_recording

    return [read_recording(p) for p in paths]


def _print_json(obj: Any) -> None:
    sys.stdout.write(json.dumps(obj, indent=2, default=float) + "\n")


# ------------------------------------------------------------------------------------ demo
@app.command()
@friendly_errors
def demo(
    out: Annotated[Path, typer.Option(help="Report folder to write.")] = Path("skinloc-demo"),
    points: Annotated[int, typer.Option(min=2, help="Calibration point logs.")] = 80,
    validation: Annotated[int, typer.Option(min=1, help="Fresh validation touches.")] = 20,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the simulated skin and session.")] = 0,
    arch: Annotated[Arch, typer.Option(help="Localiser configuration.")] = Arch.default,
    force: Annotated[
        bool, typer.Option("--force", help="Replace the recordings and model of an earlier demo.")
    ] = False,
    skins: Annotated[
        int, typer.Option(min=1, max=20, help="Simulated skins the expected error is taken over.")
    ] = 3,
) -> None:
    """Simulate the paper's skin, calibrate with 80 touches, train, validate, report.

    The headline is the error over several simulated skins (mean and spread) beside the real
    skin's figure. Example: skinloc demo --out skinloc-demo
    """
    from skinloc.evaluation.demo import REAL_SKIN_ERROR_MM, DemoConfig, run_demo

    check_output(out, option="--out", folder=True)
    earlier = [out / n for n in ("calibration.h5", "validation.h5", "model.h5")]
    if not force and any(p.exists() for p in earlier):
        raise ValueError(
            f"{out} holds an earlier demo's recordings and model: pass --force to replace "
            "them, or choose another --out"
        )
    _check_size(points + validation, 50)
    out.mkdir(exist_ok=True)

    cfg = DemoConfig(
        out_dir=out,
        n_points=points,
        n_validation=validation,
        random_state=seed,
        arch=arch.value,
        curve_sizes=tuple(n for n in (10, 20, 40, 80) if n < points) + (points,),
        n_skins=skins,
    )
    with progress_steps() as step:
        res = run_demo(cfg, step)
    mean, spread, n_skins = res.headline()
    real = REAL_SKIN_ERROR_MM.get(arch.value, {}).get(points)
    console.print(
        f"Simulated paper skin ({n_skins} skins), {points} calibration touches, "
        f"{validation} validation touches on the first skin, {cfg.n_validation_extra} on others"
    )
    console.print(
        f"Expected error: [bold]{mean:.1f} +- {spread:.1f} mm[/] (mean +- std over "
        f"{n_skins} simulated skins)"
        + (f"; on the real skin: {real:.1f} mm (docs/benchmarks.md)" if real else "")
    )
    console.print(
        f"This skin: {res.stats.mean_mm:.1f} +- {res.stats.std_mm:.1f} mm "
        f"(median {res.stats.median_mm:.1f} mm, p95 {res.stats.p95_mm:.1f} mm)"
    )
    console.print(f"Mean SNR (paper Eq. 1): {res.mean_snr_db:.1f} dB")
    console.print(f"Model trained in {res.fit_time_s:.1f} s")
    console.print(f"Report: {res.report}")


# ------------------------------------------------------------------------------------ simulate
@app.command()
@friendly_errors
def simulate(
    out: Annotated[Path, typer.Option(help="Recording to write (.h5, or .mat for MATLAB).")],
    points: Annotated[int, typer.Option(min=1, help="Point logs to record.")] = 80,
    mode: Annotated[Mode, typer.Option(help="Target sampling.")] = Mode.even,
    samples: Annotated[int, typer.Option(min=1, help="Frames per touch.")] = 50,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the session (targets, touches).")] = 0,
    skin_seed: Annotated[int, typer.Option(min=0, help="Seed of the skin (wiring, gains).")] = 0,
    mesh: Annotated[
        Path | None, typer.Option(help="Skin mesh (OBJ/STL/PLY); default: the paper's cone.")
    ] = None,
    units: Annotated[Units, typer.Option(help="Units of --mesh.")] = Units.auto,
    tx: Annotated[int, typer.Option(min=1, max=21, help="TX lines.")] = 8,
    rx: Annotated[int, typer.Option(min=1, max=12, help="RX lines.")] = 8,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --out.")] = False,
) -> None:
    """Record a whole calibration session from the simulated skin.

    Point logs go to a side file (OUT's name with .partial.h5) renamed over --out when the
    session is complete; Ctrl-C keeps the complete point logs there.

    Example: skinloc simulate --points 80 --mode even --samples 50 --seed 0 --out cal.h5
    """
    import tempfile

    from skinloc.calibration.session import SessionConfig, simulate_session
    from skinloc.data.recording import read_recording, write_mat
    from skinloc.geometry.mesh import cone_skin, load_mesh
    from skinloc.sim.skin import SimulatedSkin

    if out.suffix.lower() not in (".h5", ".hdf5", ".mat"):
        raise ValueError(f"--out must name an .h5 or .mat file, got {out}")
    check_output(out, option="--out", inputs=[mesh], force=force)
    _check_size(points, samples, tx * rx)
    surface = cone_skin() if mesh is None else load_mesh(mesh, units.value)
    skin = SimulatedSkin(surface, n_tx=tx, n_rx=rx, random_state=skin_seed)
    skin.reseed(seed)
    cfg = SessionConfig(
        n_points=points,
        mode=mode.value,
        samples_per_touch=samples,
        random_state=seed,
        description=f"simulated skin (skin seed {skin_seed})",
    )
    as_mat = out.suffix.lower() == ".mat"
    with progress_steps() as step, tempfile.TemporaryDirectory() as tmp:
        target = Path(tmp) / "session.h5" if as_mat else out
        rec = simulate_session(
            skin,
            surface,
            target,
            cfg,
            progress=lambda d, t: step("simulating touches", d, t),
            partial=out,  # an interrupted .mat session is kept next to --out, as an .h5
        )
        if as_mat:
            write_mat(read_recording(target), out)
    console.print(
        f"Wrote {out}: {rec.n_point_logs} point logs x {rec.samples_per_touch} frames, "
        f"{rec.n_tx} TX x {rec.n_rx} RX"
    )


# ------------------------------------------------------------------------------------ train
@app.command()
@friendly_errors
def train(
    data: Annotated[list[Path], typer.Argument(help="Recordings (.h5 or the paper's .mat).")],
    out: Annotated[Path, typer.Option(help="Model file to write.")],
    arch: Annotated[
        Arch, typer.Option(help="'paper' is the paper's 64-32-3 network.")
    ] = Arch.default,
    constraint: Annotated[Constraint, typer.Option(help="Output constraint.")] = Constraint.snap,
    seed: Annotated[int, typer.Option(min=0, help="Training seed.")] = 0,
    mesh: Annotated[Path | None, typer.Option(help="Skin mesh; default: the recording's.")] = None,
    units: Annotated[Units, typer.Option(help="Units of --mesh.")] = Units.auto,
    epochs: Annotated[int | None, typer.Option(min=1, help="Override the training epochs.")] = None,
    init: Annotated[
        Path | None,
        typer.Option(
            help="Recalibrate this model to DATA (a new session: fresh baseline, a few touches) "
            "instead of training from scratch."
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --out.")] = False,
    select: Annotated[
        int | None,
        typer.Option(min=1, help="Train on only this many point logs, chosen by --strategy."),
    ] = None,
    strategy: Annotated[
        str, typer.Option(help="How --select chooses: active, random or even (seeded by --seed).")
    ] = "active",
) -> None:
    """Train a localiser on one or more calibration recordings, or recalibrate one.

    Examples: skinloc train cal.h5 --out model.h5;
    skinloc train today.h5 --init model.h5 --out model-today.h5;
    skinloc train a.h5 b.h5 --select 20 --strategy active --out model-20.h5
    """
    from skinloc.evaluation.scoring import recalibrate_localizer, train_localizer
    from skinloc.geometry.mesh import load_mesh
    from skinloc.models.localizer import ContactLocalizer

    check_output(out, option="--out", inputs=[*data, init, mesh], force=force)
    recs = _read_all(data)
    if select is not None:
        recs = _select_point_logs(recs, select, strategy, seed)
    n_logs = sum(r.n_point_logs for r in recs)
    if n_logs == 0:
        raise ValueError("the recordings hold no point logs: record a calibration session first")
    if n_logs < FEW_POINT_LOGS and init is None:
        err_console.print(
            f"[bold yellow]warning:[/] training on {n_logs} point log(s) only: expect a poor "
            f"model (the paper uses 20 to 100)",
            highlight=False,
            soft_wrap=True,
        )
    if init is not None:
        old = ContactLocalizer.load(init)
        with progress_steps() as step:
            model = recalibrate_localizer(
                old, recs, progress=lambda d, t: step("recalibrating", d, t)
            )
        model.save(out)
        n = sum(r.n_point_logs for r in recs)
        console.print(
            f"Recalibrated {init} with {n} point logs in {model.fit_time_s_:.1f} s; wrote {out}"
        )
        return
    surface = load_mesh(mesh, units.value) if mesh is not None else None
    overrides = {"epochs": epochs} if epochs is not None else {}
    with progress_steps() as step:
        model = train_localizer(
            recs,
            arch=arch.value,
            constraint=constraint.value,
            random_state=seed,
            mesh=surface,
            progress=lambda d, t: step("training", d, t),
            **overrides,
        )
    model.save(out)
    n = sum(r.n_point_logs for r in recs)
    console.print(
        f"Trained '{arch.value}' on {n} point logs from {len(recs)} recording(s) "
        f"in {model.fit_time_s_:.1f} s; wrote {out}"
    )


def _select_point_logs(recs: list, n: int, strategy: str, seed: int) -> list:
    """``train --select``: the point logs a strategy asks for (skinloc.calibration.active)."""
    from skinloc.calibration.active import select_point_logs, subset_recordings

    with progress_steps() as step:
        picks = select_point_logs(
            recs, n, strategy, seed, progress=lambda d, t: step(f"choosing ({strategy})", d, t)
        )
    console.print(f"Chose {len(picks)} point logs ({strategy}, seed {seed})")
    return subset_recordings(recs, picks)


# ------------------------------------------------------------------------------------ evaluate
@app.command()
@friendly_errors
def evaluate(
    model: Annotated[Path, typer.Argument(help="Model file from 'skinloc train'.")],
    data: Annotated[list[Path], typer.Argument(help="Recordings to score.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    per_frame: Annotated[
        bool, typer.Option("--per-frame", help="Score every frame, not touch means.")
    ] = False,
) -> None:
    """Score a model on recordings: mean, std, median and p95 error in mm.

    Example: skinloc evaluate model.h5 validation.h5 --json
    """
    from skinloc.evaluation.scoring import evaluate as run
    from skinloc.models.localizer import ContactLocalizer

    loc = ContactLocalizer.load(model)
    ev = run(loc, _read_all(data), per_frame=per_frame)
    result = {
        **ev.as_dict(),
        "per": "frame" if per_frame else "touch",
        "model": str(model),
        "data": [str(d) for d in data],
    }
    if as_json:
        _print_json(result)
        return
    table = Table(title=f"{model.name} on {len(data)} recording(s), per {result['per']}")
    for k in ("n", "mean_mm", "std_mm", "median_mm", "p95_mm", "max_mm", "uncertainty_spearman"):
        v = result[k]
        table.add_row(k, f"{v}" if isinstance(v, int) else f"{v:.2f}")
    console.print(table)


# ------------------------------------------------------------------------------------ snr
@app.command()
@friendly_errors
def snr(
    data: Annotated[list[Path], typer.Argument(help="Recordings.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Per-sensor SNR (the paper's Eq. 1) and its mean, for each recording.

    Example: skinloc snr cal.h5 --json
    """
    import numpy as np

    from skinloc.evaluation.metrics import snr_db

    results = []
    for path, rec in zip(data, _read_all(data), strict=True):
        s = snr_db(rec.touch_means, rec.baseline_frames)
        results.append(
            {
                "file": str(path),
                "mean_snr_db": float(np.nanmean(s)),
                "min_snr_db": float(np.nanmin(s)),
                "max_snr_db": float(np.nanmax(s)),
                "per_sensor_db": [None if not np.isfinite(v) else round(float(v), 2) for v in s],
                "tx": rec.n_tx,
                "rx": rec.n_rx,
            }
        )
    if as_json:
        _print_json(results[0] if len(results) == 1 else results)
        return
    for r in results:
        console.print(
            f"[bold]{r['file']}[/]: mean SNR {r['mean_snr_db']:.1f} dB "
            f"(range {r['min_snr_db']:.1f} to {r['max_snr_db']:.1f})"
        )
        grid = Table("TX \\ RX", *[str(j) for j in range(r["rx"])], title="SNR per sensor (dB)")
        for i in range(r["tx"]):
            vals = r["per_sensor_db"][i * r["rx"] : (i + 1) * r["rx"]]
            grid.add_row(str(i), *["-" if v is None else f"{v:.0f}" for v in vals])
        console.print(grid)


# ------------------------------------------------------------------------------------ info
@app.command()
@friendly_errors
def info(
    data: Annotated[Path, typer.Argument(help="A recording.")],
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
) -> None:
    """Describe a recording: grid, point logs, frames, baseline, noise, SNR.

    Example: skinloc info cal.h5 --json
    """
    import numpy as np

    from skinloc.evaluation.metrics import mean_snr_db
    from skinloc.sources.replay import stream_summary

    (rec,) = _read_all([data])
    summary = {
        "file": str(data),
        "tx": rec.n_tx,
        "rx": rec.n_rx,
        "n_sensors": rec.n_sensors,
        "n_point_logs": rec.n_point_logs,
        "samples_per_touch": rec.samples_per_touch,
        "n_frames": int(rec.n_point_logs * rec.samples_per_touch),
        "n_baseline_frames": len(rec.baseline_frames),
        "n_planned": None if rec.planned_targets is None else len(rec.planned_targets),
        "baseline_counts_min": float(rec.baseline.min()),
        "baseline_counts_max": float(rec.baseline.max()),
        "noise_counts_median": float(np.median(rec.noise)),
        "mean_snr_db": mean_snr_db(rec.touch_means, rec.baseline_frames)
        if rec.n_point_logs
        else None,
        "mesh_vertices": len(rec.vertices),
        "mesh_faces": len(rec.faces),
        **(stream_summary(data) or {}),  # a `skinloc record` file: its raw stream too
        "meta": {k: v for k, v in rec.meta.items() if k not in _TRUTH_KEYS},
        **_truth_layout(rec),
    }
    if as_json:
        _print_json(summary)
        return
    table = Table(title=str(data), show_header=False)
    for k, v in summary.items():
        if k == "truth_sensor_positions_m":
            table.add_row(k, f"{len(v)} true crossings (simulated skin)")
        elif k != "meta":
            table.add_row(k, f"{v:.1f}" if isinstance(v, float) else str(v))
    for k, v in summary["meta"].items():
        table.add_row(f"meta.{k}", str(v))
    console.print(table)


_TRUTH_KEYS = ("true_contacts", "truth_sensor_positions_m")


def _truth_layout(rec) -> dict[str, Any]:
    """A simulated recording's true crossings (``skinloc simulate`` stores them), else nothing."""
    truth = rec.meta.get("truth_sensor_positions_m")
    return {} if truth is None else {"truth_sensor_positions_m": truth}


# ------------------------------------------------------------------------------------ convert
@app.command()
@friendly_errors
def convert(
    src: Annotated[Path, typer.Argument(help="Recording to read (.h5 or .mat).")],
    dst: Annotated[Path, typer.Argument(help="File to write: .mat (MATLAB touchData) or .h5.")],
    force: Annotated[bool, typer.Option("--force", help="Replace an existing DST.")] = False,
) -> None:
    """Convert between skinloc HDF5 and the paper's MATLAB touchData layout.

    Example: skinloc convert cal.h5 cal.mat
    """
    from skinloc.data.recording import write_mat, write_recording

    suffix = dst.suffix.lower()
    if suffix not in (".mat", ".h5", ".hdf5"):
        raise ValueError(f"cannot tell the format of {dst}: name it .mat or .h5")
    check_output(dst, option="DST", inputs=[src], force=force)
    (rec,) = _read_all([src])
    if suffix == ".mat":
        write_mat(rec, dst)
    else:
        write_recording(rec, dst)
    console.print(f"Wrote {dst} ({rec.n_point_logs} point logs)")


# ------------------------------------------------------------------------------------ bench
@app.command()
@friendly_errors
def bench(
    sim: Annotated[
        bool, typer.Option("--sim/--no-sim", help="The paper's experiment on simulated skins.")
    ] = True,
    real: Annotated[
        Path | None,
        typer.Option(help="Folder of the real recordings: run the cross-recording splits."),
    ] = None,
    timing: Annotated[
        bool, typer.Option("--timing", help="Training time and prediction latency.")
    ] = False,
    seeds: Annotated[int, typer.Option(min=1, help="Simulated skins (seeds) per size.")] = 3,
    sizes: Annotated[str, typer.Option(help="Comma-separated point-log counts.")] = "20,50,80,100",
    out: Annotated[Path, typer.Option(help="Folder for figures and JSON results.")] = Path(
        "skinloc-bench"
    ),
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON results.")] = False,
    online: Annotated[
        bool, typer.Option("--online", help="Only the live path: latency, throughput, 100 skins.")
    ] = False,
) -> None:
    """The paper's experiment: train on 20, 50, 80, 100 point logs, validate on 20 touches.

    Example: skinloc bench --seeds 3 --real ../shared/data/hiro-cone-skin --timing
    """
    check_output(out, option="--out", folder=True)
    if online:  # skinloc.cli.live: the live pipeline's figures (docs/benchmarks.md)
        return __import__("skinloc.cli.live", fromlist=["bench_online"]).bench_online(out, as_json)
    import numpy as np

    from skinloc.evaluation import paper_bench as B
    from skinloc.evaluation.report import plot_paper_fig3

    try:
        size_list = [int(s) for s in sizes.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"--sizes must be comma-separated integers, got {sizes!r}") from None
    if not size_list or min(size_list) < 2:
        raise ValueError(f"--sizes must list point-log counts of at least 2, got {sizes!r}")
    if real is not None and not real.is_dir():
        raise ValueError(f"--real {real} is not a folder of recordings")
    out.mkdir(exist_ok=True)
    results: dict[str, Any] = {}
    with progress_steps() as step:
        if sim:
            rows = B.paper_experiment(sizes=size_list, seeds=range(seeds), step=step)
            results["sim"] = rows
        if real is not None:
            results["real"] = [r.__dict__ for r in B.real_splits(real, step=step)]
        if timing:
            results["timing"] = B.timing(step=step)
    (out / "results.json").write_text(json.dumps(results, indent=2, default=float))

    if "sim" in results:
        rows = results["sim"]
        table = Table(title=f"Simulated paper skin: validation on 20 random touches, {seeds} skins")
        table.add_column("point logs")
        table.add_column("mean SNR (dB)")
        archs = sorted({r["arch"] for r in rows})
        for a in archs:
            table.add_column(f"{a}: error (mm)")
        for n in size_list:
            sel = [r for r in rows if r["n_points"] == n]
            snrs = [r["snr_db"] for r in sel if r["arch"] == archs[0]]
            cells = []
            for a in archs:
                m = [r["mean_mm"] for r in sel if r["arch"] == a]
                s = [r["std_mm"] for r in sel if r["arch"] == a]
                cells.append(f"{np.mean(m):.1f} +- {np.mean(s):.1f}")
            table.add_row(str(n), f"{np.mean(snrs):.1f}", *cells)
        if not as_json:
            console.print(table)
        for a in archs:
            sel = [[r for r in rows if r["n_points"] == n and r["arch"] == a] for n in size_list]
            plot_paper_fig3(
                size_list,
                [np.mean([r["snr_db"] for r in s]) for s in sel],
                [np.std([r["snr_db"] for r in s]) for s in sel],
                [np.mean([r["mean_mm"] for r in s]) for s in sel],
                [np.mean([r["std_mm"] for r in s]) for s in sel],
                out / f"fig3_{a}.png",
                title=f"Simulated paper skin, '{a}' model",
            )
    if "real" in results and not as_json:
        table = Table(title="Real recordings (2023-12-10)")
        for c in (
            "protocol",
            "arch",
            "train",
            "test",
            "per",
            "n",
            "mean_mm",
            "std_mm",
            "median_mm",
        ):
            table.add_column(c)
        for r in results["real"]:
            table.add_row(
                *[
                    f"{r[c]:.1f}" if isinstance(r[c], float) else str(r[c])
                    for c in (
                        "protocol",
                        "arch",
                        "train",
                        "test",
                        "per",
                        "n",
                        "mean_mm",
                        "std_mm",
                        "median_mm",
                    )
                ]
            )
        console.print(table)
    if "timing" in results and not as_json:
        t = results["timing"]
        console.print(
            f"Training on {t['n_points']} point logs x {t['samples_per_touch']} frames: "
            f"{t['fit_s']:.2f} s"
        )
        console.print(
            f"Single-frame latency: median {t['latency_median_us']:.0f} us, p99 "
            f"{t['latency_p99_us']:.0f} us (baseline {t['baseline_latency_median_us']:.0f} "
            f"/ {t['baseline_latency_p99_us']:.0f} us, x{t['latency_speedup']:.1f})"
        )
        console.print(
            f"Batch throughput: {t['batch_frames_per_s']:.0f} frames/s (baseline "
            f"{t['baseline_batch_frames_per_s']:.0f}, x{t['batch_speedup']:.1f})"
        )
    if as_json:
        _print_json(results)
    else:
        console.print(f"Results and figures in {out}/")


def main() -> None:
    """Console-script entry point."""
    app()


def _register_groups() -> None:
    # Each group lives in its own module to keep this one about the data path; registered
    # after this module's commands so that ``skinloc --help`` lists them in this order.
    cli_hardware.register(app)  # ports, record, calibrate, virtual-skin, ...
    app_cli.register(app)  # skinloc app
    cli_live.register(app)  # skinloc run, export
    cli_skin.register(app)  # skinloc sensors, coverage
    cli_predict.register(app)  # skinloc predict


_register_groups()
