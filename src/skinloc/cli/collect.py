"""``skinloc collect``: a calibration session on a skin in the terminal, resumable after a crash."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from skinloc.cli.board_setup import GainOpt, LinesOpt
from skinloc.cli.common import (
    Units,
    WireChoice,
    check_output,
    console,
    err_console,
    friendly_errors,
    progress_steps,
)
from skinloc.cli.hardware import (
    AllowUrlOpt,
    BaudOpt,
    FormatOpt,
    ModeChoice,
    PortOpt,
    RxMaskOpt,
    RxOpt,
    SourceArgs,
    SourceChoice,
    SourceOpt,
    TxMaskOpt,
    TxOpt,
    first_frame,
    load_surface,
    open_cli_source,
    stats_line,
)
from skinloc.cli.probe_collect import ProbeChoice, ProbeOptions, collect_with_probe

log = logging.getLogger(__name__)


class TerminalProber:
    """Prompt a person in the terminal; optionally drive a scripted finger over the port.

    With ``finger`` (a ``SerialSource`` on ``skinloc virtual-skin``), each prompt is also sent
    as ``touch x y z`` (m) and each capture as ``lift``, so a session runs unattended.
    """

    def __init__(self, console, n_targets: int, finger=None) -> None:
        self.console = console
        self.n_targets = n_targets
        self.finger = finger

    def prompt(self, index: int, target: np.ndarray) -> None:
        """Name target ``index`` by its coordinates in mm."""
        x, y, z = (np.asarray(target) * 1e3).tolist()
        self.console.print(
            f"[bold]Touch target {index + 1}/{self.n_targets}[/] at "
            f"x={x:.1f} y={y:.1f} z={z:.1f} mm and hold still"
        )
        if self.finger is not None:
            tx, ty, tz = np.asarray(target, dtype=float).tolist()
            self.finger.write(f"touch {tx:.6f} {ty:.6f} {tz:.6f}\n".encode())

    def captured(self, index: int) -> None:
        """Tell the person to lift."""
        self.console.print(f"  captured point log {index + 1}: lift your finger")
        if self.finger is not None:
            self.finger.write(b"lift\n")


def _opener(args: SourceArgs):
    """Opens the source ``args`` (the command's options) name, for the skin's mesh."""

    def open_source(mesh):
        if args.source is SourceChoice.sim:
            return open_cli_source(dataclasses.replace(args, port=None), mesh=mesh)
        return open_cli_source(args)

    return open_source


def register(app: typer.Typer) -> None:
    """Add ``skinloc collect`` to the main ``skinloc`` app."""

    # -------------------------------------------------------------------------------- collect
    @app.command()
    @friendly_errors
    def collect(
        out: Annotated[Path, typer.Option(help="Recording to write; an unfinished one resumes.")],
        port: PortOpt = None,
        source: SourceOpt = SourceChoice.serial,
        mesh: Annotated[
            Path | None, typer.Option(help="Skin mesh; default: the paper's cone.")
        ] = None,
        units: Annotated[Units, typer.Option(help="Units of --mesh.")] = Units.auto,
        points: Annotated[int, typer.Option(min=1, help="Point logs to record.")] = 80,
        mode: Annotated[
            ModeChoice,
            typer.Option(
                help="Target sampling; 'active' chooses each next target from the touches "
                "recorded so far (after a few evenly spread ones)."
            ),
        ] = ModeChoice.even,
        samples: Annotated[int, typer.Option(min=1, help="Frames per touch.")] = 50,
        baseline_frames: Annotated[int, typer.Option(min=2, help="No-touch frames first.")] = 50,
        touch_timeout: Annotated[
            float, typer.Option(min=0.1, help="Longest wait for a touch or a release, s.")
        ] = 60.0,
        max_touches: Annotated[
            int | None, typer.Option(min=1, help="Stop after this many new point logs.")
        ] = None,
        new: Annotated[
            bool, typer.Option("--new", help="Start over even if --out exists.")
        ] = False,
        scripted_finger: Annotated[
            bool,
            typer.Option(
                "--scripted-finger",
                help="Send 'touch x y z'/'lift' to the port (for 'skinloc virtual-skin').",
            ),
        ] = False,
        baud: BaudOpt = None,
        fmt: FormatOpt = WireChoice.auto,
        tx: TxOpt = None,
        rx: RxOpt = None,
        gain: GainOpt = None,
        lines: LinesOpt = None,
        tx_mask: TxMaskOpt = None,
        rx_mask: RxMaskOpt = None,
        allow_url: AllowUrlOpt = False,
        seed: Annotated[
            int, typer.Option(min=0, help="Seed of the targets (and of --source sim).")
        ] = 0,
        force: Annotated[
            bool, typer.Option("--force", help="With --new: replace an existing --out.")
        ] = False,
        probe: Annotated[
            ProbeChoice | None,
            typer.Option(
                help="A robot's probe presses the targets instead of a person: 'sim' is a "
                "simulated arm on the simulated skin, 'ros2' an arm over ROS 2 topics "
                "(/skinloc/probe/*) on the skin of --port (docs/hardware.md, 4b-4d)."
            ),
        ] = None,
        probe_timeout: Annotated[
            float,
            typer.Option(
                min=0.1, help="--probe ros2: longest wait for the arm to appear or answer, s."
            ),
        ] = 30.0,
        probe_error_mm: Annotated[
            float, typer.Option(min=0, help="--probe sim: the tip's position error per axis, mm.")
        ] = 0.5,
        press_depth_mm: Annotated[
            str,
            typer.Option(
                help="--probe: press depth past the surface, mm; several (0.5,1,2): each "
                "target pressed at each, every press its own touch."
            ),
        ] = "2",
        press_force_n: Annotated[
            str | None,
            typer.Option(
                help="--probe: press to this force, N, instead of a depth; several (1,2,4) "
                "as for --press-depth-mm."
            ),
        ] = None,
        max_depth_mm: Annotated[
            float, typer.Option(min=0.01, help="--probe: deepest press allowed, mm.")
        ] = 5.0,
        max_force_n: Annotated[
            float, typer.Option(min=0.01, help="--probe: strongest press allowed, N.")
        ] = 10.0,
        clearance_mm: Annotated[
            float, typer.Option(min=0.1, help="--probe: height above a target before a press, mm.")
        ] = 10.0,
        dwell: Annotated[
            float, typer.Option(min=0, help="--probe: hold after reaching the depth, s.")
        ] = 0.2,
        max_tilt_deg: Annotated[
            float,
            typer.Option(
                min=1, max=180, help="--probe: largest angle of a press from --arm-direction."
            ),
        ] = 90.0,
        rim_mm: Annotated[
            float, typer.Option(min=0, help="--probe: leave out targets this near the rim, mm.")
        ] = 5.0,
        arm_direction: Annotated[
            str, typer.Option(help="--probe: the way the probe points, x,y,z in the base frame.")
        ] = "0,0,-1",
        skins: Annotated[
            Path | None,
            typer.Option(help="--probe: skins file giving the skin's pose on the robot."),
        ] = None,
        skin: Annotated[str | None, typer.Option(help="--probe: the skin of --skins.")] = None,
        skin_seed: Annotated[
            int, typer.Option(min=0, help="--probe sim: seed of the simulated skin.")
        ] = 0,
        dry_run: Annotated[
            bool,
            typer.Option("--dry-run", help="--probe: only move above every target; no file."),
        ] = False,
    ) -> None:
        """Record a calibration session on the skin, resumable after a crash.

        The terminal names each target by its index and coordinates; the recording is saved
        after every touch, and rerunning the same command resumes it.

        With --probe sim a simulated robot arm presses a plan made from the mesh (targets it
        cannot reach left out) on the simulated skin of --skin-seed, and each touch keeps the
        tip's reported position and press depth. With --probe ros2 an arm answering the
        /skinloc/probe topics presses the skin of --port (docs/hardware.md, 4c).

        Example: skinloc collect --port /dev/ttyACM0 --points 80 --mode even --out cal.h5
        """
        from skinloc.calibration.session import CalibrationSession, ScriptedFinger, SessionConfig

        if out.suffix.lower() not in (".h5", ".hdf5"):
            raise ValueError(f"--out must be an .h5 file, got {out}")
        resume = out.exists() and not new
        if new and out.exists() and not force:
            raise ValueError(
                f"{out} exists: --new would replace it; pass --force too, or choose another --out"
            )
        # Resuming appends to --out on purpose; anything else must not clobber a file.
        check_output(out, option="--out", inputs=[mesh], force=resume or force)
        surface = None if resume else load_surface(mesh, units)
        if resume and mesh is not None:
            raise ValueError(
                f"{out} exists and is resumed with its own mesh: drop --mesh or "
                "pass --new to start over"
            )
        args = SourceArgs(
            port, source, baud, fmt, tx, rx, tx_mask, rx_mask, seed, gain, lines, allow_url
        )
        if probe is not None:
            if scripted_finger:
                raise ValueError("--probe presses the targets itself: drop --scripted-finger")
            if probe is ProbeChoice.sim and (port is not None or source is not SourceChoice.serial):
                raise ValueError(
                    "--probe sim presses the simulated skin it reads: drop --port, --source "
                    "and --scripted-finger"
                )
            if mode.value not in ("even", "random"):
                raise ValueError(
                    "--probe plans its targets up front: --mode must be even or random"
                )
            collect_with_probe(
                ProbeOptions(
                    probe,
                    error_mm=probe_error_mm,
                    depth_mm=press_depth_mm,
                    force_n=press_force_n,
                    max_depth_mm=max_depth_mm,
                    max_force_n=max_force_n,
                    clearance_mm=clearance_mm,
                    dwell_s=dwell,
                    max_tilt_deg=max_tilt_deg,
                    rim_mm=rim_mm,
                    arm_direction=arm_direction,
                    skins=skins,
                    skin=skin,
                    skin_seed=skin_seed,
                    dry_run=dry_run,
                    timeout_s=probe_timeout,
                ),
                out=out,
                resume=resume,
                surface=surface,
                cfg_args={
                    "samples_per_touch": samples,
                    "n_baseline_frames": baseline_frames,
                    "touch_timeout_s": touch_timeout,
                },
                n_points=points,
                mode=mode.value,
                seed=seed,
                tx=tx,
                rx=rx,
                max_touches=max_touches,
                open_source=_opener(args),
            )
            return
        if source is SourceChoice.sim:
            from skinloc.data.recording import read_recording

            sim_mesh = read_recording(out).mesh if resume else surface
            src = open_cli_source(dataclasses.replace(args, port=None), mesh=sim_mesh)
        else:
            src = open_cli_source(args)
        with src:
            first_frame(src, 1.0)
            if resume:
                session = CalibrationSession.resume(src, out)
                if session.finished:
                    raise ValueError(
                        f"{out} is already complete ({session.n_done} point logs); "
                        "pass --new to record it again"
                    )
                console.print(
                    f"Resuming {out} at point log {session.n_done + 1}/{len(session.targets)}"
                )
            else:
                cfg = SessionConfig(
                    n_points=points,
                    mode=mode.value,
                    samples_per_touch=samples,
                    n_baseline_frames=baseline_frames,
                    touch_timeout_s=touch_timeout,
                    random_state=seed,
                    description=f"collected on {src.name}",
                )
                session = CalibrationSession(src, surface, out, cfg)
            n_targets = len(session.targets)
            if source is SourceChoice.sim:
                prober: Any = ScriptedFinger(
                    src, random_state=seed + 1 + session.n_done, move_time_s=1.0
                )
            else:
                prober = TerminalProber(console, n_targets, finger=src if scripted_finger else None)
            if session.recording is None:
                console.print(
                    f"Keep the skin untouched: capturing {baseline_frames} baseline frames"
                )
                session.capture_baseline()
            stop_at = (
                n_targets if max_touches is None else min(n_targets, session.n_done + max_touches)
            )
            try:
                with progress_steps() as step:
                    while session.n_done < stop_at:
                        session.record_point(session.n_done, prober)
                        step("point logs", session.n_done, n_targets)
            except KeyboardInterrupt:
                from skinloc.errors import Interrupted

                raise Interrupted(
                    f"{session.n_done}/{n_targets} point logs are saved in {out}; rerun the "
                    "same command to resume"
                ) from None
            summary = stats_line(src)
        done = session.n_done
        state = "complete" if done >= n_targets else "saved; rerun the same command to resume"
        console.print(f"Wrote {out}: {done}/{n_targets} point logs ({state})")
        err_console.print(summary, highlight=False)
