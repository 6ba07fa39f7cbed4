"""The ``skinloc`` command line: simulate, train, evaluate, inspect, convert, benchmark, demo.

The shared objects (``app``, consoles, ``friendly_errors``, ``check_output``, ``progress_steps``,
option types) live in ``skinloc.cli.common``; the command groups in their own modules register
themselves on ``app`` at the end of this one.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from skinloc.cli import bench as cli_bench
from skinloc.cli import board as cli_board
from skinloc.cli import collect as cli_collect
from skinloc.cli import hardware as cli_hardware
from skinloc.cli import live as cli_live
from skinloc.cli import predict as cli_predict
from skinloc.cli import prior as cli_prior
from skinloc.cli import recordings as cli_recordings
from skinloc.cli import skin as cli_skin
from skinloc.cli import webapp as app_cli
from skinloc.cli.common import (
    Arch,
    Change,
    Constraint,
    Mode,
    Units,
    app,
    check_interrupt,
    check_output,
    check_skin_covers,
    console,
    err_console,
    friendly_errors,
    print_json,
    progress_steps,
    read_recordings,
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
    from skinloc.experiments.demo import REAL_SKIN_ERROR_MM, DemoConfig, run_demo

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
        curve_sizes=tuple(n for n in (5, 10, 20, 40, 80) if n < points) + (points,),
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
    for line in res.prior_lines():  # the map prior matters with few touches
        console.print(f"With {line}", highlight=False)
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
    gestures: Annotated[
        int | None,
        typer.Option(help="Instead of a session: a raw stream of N scripted gestures (.h5)."),
    ] = None,
    other_touches: Annotated[
        int | None,
        typer.Option(help="With --gestures: touches that are not gestures (default N/4)."),
    ] = None,
    session_change: Annotated[
        Change,
        typer.Option(
            help="Record a later session of the skin: 'real' changes it as much as the real "
            "skin changed in five months, 'mild' a little (docs/simulator.md)."
        ),
    ] = Change.none,
    change_seed: Annotated[
        int, typer.Option(min=0, help="Seed of the --session-change draws.")
    ] = 0,
) -> None:
    """Record a whole calibration session from the simulated skin.

    Point logs go to a side file (OUT's name with .partial.h5) renamed over --out when the
    session is complete; Ctrl-C keeps the complete point logs there.

    With --gestures N it records instead a raw stream in which a scripted hand performs N
    gestures and some other touches, with the truth in the file (docs/multitouch.md).

    With --session-change real|mild the skin of --skin-seed is recorded as in a later session
    (gains, footprint and crossings moved; the same wiring), to test recalibration
    (skinloc train LATER --init MODEL).

    Example: skinloc simulate --points 80 --mode even --samples 50 --seed 0 --out cal.h5
    """
    import tempfile

    if gestures is not None or other_touches is not None:
        from skinloc.cli.sim_gestures import simulate_gestures

        if gestures is None:
            raise ValueError("--other-touches needs --gestures N")
        if session_change is not Change.none:
            raise ValueError("--session-change records a calibration session, not --gestures")
        simulate_gestures(
            out,
            n_gestures=gestures,
            other_touches=other_touches,
            seed=seed,
            skin_seed=skin_seed,
            mesh=mesh,
            units=units.value,
            tx=tx,
            rx=rx,
            force=force,
        )
        return

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
    if mesh is not None:
        check_skin_covers(skin, mesh)
    description = f"simulated skin (skin seed {skin_seed})"
    if session_change is not Change.none:
        from skinloc.sim.session_change import later_session

        skin = later_session(skin, session_change.value, change_seed)
        description += f", later session ({session_change.value} change, seed {change_seed})"
    skin.reseed(seed)
    cfg = SessionConfig(
        n_points=points,
        mode=mode.value,
        samples_per_touch=samples,
        random_state=seed,
        description=description,
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
            help="Recalibrate this model to DATA (a new session: fresh baseline, a few touches; "
            "a baseline capture alone keeps it): cross-validation over the new touches chooses "
            "the old map, corrected, blended or replaced by the new touches alone."
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --out.")] = False,
    select: Annotated[
        int | None,
        typer.Option(min=1, help="Train on only this many point logs, chosen by --strategy."),
    ] = None,
    strategy: Annotated[
        str,
        typer.Option(
            help="How --select chooses: active, random or even (seeded by --seed); with --init, "
            "active asks where the old model's map needs new touches most, from it alone."
        ),
    ] = "active",
    no_prior: Annotated[
        bool,
        typer.Option(
            "--no-prior",
            help="Fit the response map without the prior learned from simulated skins "
            "(by default it is used for the few-touch calibrations where it helps).",
        ),
    ] = False,
    prior: Annotated[
        Path | None,
        typer.Option(help="A prior file of `skinloc prior build` instead of the package's."),
    ] = None,
) -> None:
    """Train a localiser on one or more calibration recordings, or recalibrate one.

    Examples: skinloc train cal.h5 --out model.h5;
    skinloc train today.h5 --init model.h5 --out model-today.h5;
    skinloc train a.h5 b.h5 --select 20 --strategy active --out model-20.h5
    """
    from skinloc.evaluation.recalibration import recalibrate
    from skinloc.evaluation.scoring import train_localizer
    from skinloc.geometry.mesh import load_mesh
    from skinloc.models.localizer import ContactLocalizer

    check_output(out, option="--out", inputs=[*data, init, mesh, prior], force=force)
    if (no_prior or prior is not None) and (arch is not Arch.default or init is not None):
        raise ValueError(
            "--no-prior and --prior apply to training the default model (a response map) "
            "from scratch"
        )
    if no_prior and prior is not None:
        raise ValueError("give --no-prior or --prior, not both")
    if prior is not None:
        from skinloc.models.map_prior import load_prior

        load_prior(prior)  # a bad file fails here, in one line, before anything else
    recs = read_recordings(data, calibration=init is None)  # --init: a baseline capture will do
    if select is not None and init is not None:
        recs = _select_recalibration(recs, select, strategy, seed, ContactLocalizer.load(init))
    elif select is not None:
        choose_with = "none" if no_prior else ("package" if prior is None else str(prior))
        recs = _select_point_logs(recs, select, strategy, seed, choose_with)
    n_logs = sum(r.n_point_logs for r in recs)
    if n_logs == 0 and init is None:
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
            done = recalibrate(old, recs, progress=lambda d, t: step("recalibrating", d, t))
        model = done.model
        model.save(out)
        console.print(
            f"Recalibrated {init} with {n_logs} point logs in {model.fit_time_s_:.1f} s; "
            f"wrote {out}"
        )
        for line in done.report.lines():
            console.print(line, highlight=False)
        return
    surface = load_mesh(mesh, units.value) if mesh is not None else None
    overrides: dict = {"epochs": epochs} if epochs is not None else {}
    if no_prior:
        overrides["prior"] = "none"
    elif prior is not None:
        overrides["prior"] = str(prior)
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
    if arch is Arch.default:
        console.print(_prior_note(model, no_prior), highlight=False)


def _prior_note(model, no_prior: bool) -> str:
    """What ``train`` says about the map prior it used or not."""
    if no_prior:
        return "Without the map prior (--no-prior)."
    p = model.map_prior()
    if getattr(model, "prior_used_", False):
        return (
            f"Used the map prior learned from {p.provenance.get('skins', '?')} simulated skins "
            f"(it helps up to {p.max_touches} touches; --no-prior to fit without it)."
        )
    return (
        f"The map prior was not needed: it helps up to {p.max_touches} touches and "
        "this calibration has more."
    )


def _select_point_logs(recs: list, n: int, strategy: str, seed: int, prior: str) -> list:
    """``train --select``: the point logs a strategy asks for (skinloc.calibration.active).

    ``prior`` is the map prior the active strategy fits its maps with (as the model's).
    """
    from skinloc.calibration.active import select_point_logs, subset_recordings

    with progress_steps() as step:
        picks = select_point_logs(
            recs,
            n,
            strategy,
            seed,
            progress=lambda d, t: step(f"choosing ({strategy})", d, t),
            prior=prior,
        )
    console.print(f"Chose {len(picks)} point logs ({strategy}, seed {seed})")
    return subset_recordings(recs, picks)


def _select_recalibration(recs: list, n: int, strategy: str, seed: int, old) -> list:
    """``train --select --init``: the point logs ``recalibration_targets`` asks for.

    Chosen from the old model's map and the recordings' targets only (not their images), as a
    later session would be asked for them.
    """
    import numpy as np

    from skinloc.calibration.active import recalibration_targets, subset_recordings

    rmap = getattr(old, "map_", None)
    if strategy == "active" and rmap is None:
        raise ValueError(
            "--strategy active with --init chooses from the old model's response map; this "
            "model has none: use --strategy random"
        )
    owners = [(r, i) for r, rec in enumerate(recs) for i in range(rec.n_point_logs)]
    where = np.concatenate([rec.targets for rec in recs]) if owners else np.zeros((0, 3))
    try:
        idx = recalibration_targets(rmap, n, where, strategy=strategy, random_state=seed)
    except ValueError as e:
        raise ValueError(f"--select / --strategy: {e}") from None
    console.print(f"Chose {len(idx)} point logs ({strategy} for recalibration, seed {seed})")
    return subset_recordings(recs, [owners[i] for i in idx])


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
    ev = run(loc, read_recordings(data, calibration=True), per_frame=per_frame)
    result = {
        **ev.as_dict(),
        "per": "frame" if per_frame else "touch",
        "model": str(model),
        "data": [str(d) for d in data],
    }
    if as_json:
        print_json(result)
        return
    table = Table(title=f"{model.name} on {len(data)} recording(s), per {result['per']}")
    for k in ("n", "mean_mm", "std_mm", "median_mm", "p95_mm", "max_mm", "uncertainty_spearman"):
        v = result[k]
        table.add_row(k, f"{v}" if isinstance(v, int) else f"{v:.2f}")
    console.print(table)


def main() -> None:
    """Console-script entry point."""
    app()


def _register_groups() -> None:
    # Each group lives in its own module to keep this one about the data path; registered
    # after this module's commands so that ``skinloc --help`` lists them in this order.
    cli_recordings.register(app)  # snr, info, convert
    cli_bench.register(app)  # skinloc bench
    cli_hardware.register(app)  # monitor, record, virtual-skin
    cli_collect.register(app)  # collect
    cli_board.register(app)  # ports, doctor
    app_cli.register(app)  # skinloc app
    cli_live.register(app)  # skinloc run, export
    cli_skin.register(app)  # skinloc sensors, coverage
    cli_predict.register(app)  # skinloc predict
    cli_prior.register(app)  # skinloc prior build, show


_register_groups()
