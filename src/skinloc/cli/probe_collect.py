"""``skinloc collect --probe sim|ros2``: a calibration session pressed by a robot's probe.

``sim`` is a simulated arm on a simulated skin of its own; ``ros2`` an arm answering the ROS 2
topics of ``calibration.probe_ros2`` on the skin of ``--port`` (or ``--source``).

The session is the terminal's (``cli.collect``): the recording at ``--out`` is written touch by
touch with ``RecordingAppender`` and a rerun of the same command resumes it. The probe's plan
comes from the mesh (``calibration.probe_plan``), each touch is ``calibration.probe``'s
``record_probe_point``; the settings of the probe, its plan and the skin go to the recording's
``meta["probe"]``, from which a resumed session takes them.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.cli.common import console, progress_steps

__all__ = ["ProbeChoice", "ProbeOptions", "collect_with_probe", "press_levels"]


class ProbeChoice(StrEnum):
    """Probes ``skinloc collect --probe`` drives."""

    sim = "sim"
    ros2 = "ros2"


@dataclass
class ProbeOptions:
    """The command line's probe options, in the units it takes them (mm, N, s, degrees)."""

    probe: ProbeChoice
    error_mm: float = 0.5
    depth_mm: str | float | None = "2"
    force_n: str | float | None = None
    max_depth_mm: float = 5.0
    max_force_n: float = 10.0
    clearance_mm: float = 10.0
    dwell_s: float = 0.2
    max_tilt_deg: float = 90.0
    rim_mm: float = 5.0
    arm_direction: str = "0,0,-1"
    skins: Path | None = None
    skin: str | None = None
    skin_seed: int = 0
    dry_run: bool = False
    timeout_s: float = 30.0


def _direction(text: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(math.isfinite(x) for x in v) or not any(v):
        raise ValueError(f"--arm-direction must be 3 numbers x,y,z (not all 0), got {text!r}")
    return v[0], v[1], v[2]


def _pose(opts: ProbeOptions):
    from skinloc.calibration.probe_plan import SkinPose

    if opts.skins is None:
        if opts.skin is not None:
            raise ValueError("--skin names a skin of --skins FILE: give the file too")
        return SkinPose()
    from skinloc.live.skins_file import skin_mount

    frame, translation, rotation = skin_mount(opts.skins, opts.skin)
    return SkinPose(translation, rotation, frame)


def press_levels(text: str | float, option: str) -> tuple[float, ...]:
    """The press levels of ``option``: one number or several separated by commas, each > 0.

    Raises a one-line ``ValueError`` naming ``option`` otherwise (a repeated level too).
    """
    try:
        levels = tuple(float(x) for x in str(text).split(","))
    except ValueError:
        levels = ()
    if not levels or not all(math.isfinite(v) and v > 0 for v in levels):
        raise ValueError(
            f"{option} must be one number > 0 or several separated by commas (0.5,1,2), "
            f"got {text!r}"
        )
    if len(set(levels)) != len(levels):
        raise ValueError(f"{option} names a level twice: {text!r}")
    return levels


def _presses(opts: ProbeOptions) -> list:
    """One ``ProbeSettings`` per press level of a target, each checked against the limits."""
    from skinloc.calibration.probe import ProbeSettings, check_press

    if opts.force_n is not None:
        levels = [{"force_n": f} for f in press_levels(opts.force_n, "--press-force-n")]
    else:
        depths = press_levels(2.0 if opts.depth_mm is None else opts.depth_mm, "--press-depth-mm")
        levels = [{"depth_m": d * 1e-3, "force_n": None} for d in depths]
    presses = []
    for level in levels:
        settings = ProbeSettings(
            **{"depth_m": None, **level},
            max_depth_m=opts.max_depth_mm * 1e-3,
            max_force_n=opts.max_force_n,
            clearance_m=opts.clearance_mm * 1e-3,
        )
        check_press(settings)  # a press beyond the limits is refused before anything moves
        presses.append(settings)
    return presses


def _levels_text(presses: list) -> str:
    """``0.5, 1, 2 mm`` or ``1, 2 N``: a target's press levels, for the plan's line."""
    if presses[0].force_n is not None:
        return ", ".join(f"{p.force_n:g}" for p in presses) + " N"
    return ", ".join(f"{1e3 * p.depth_m:g}" for p in presses) + " mm"


def collect_with_probe(
    opts: ProbeOptions,
    *,
    out: Path,
    resume: bool,
    surface,
    cfg_args: dict[str, Any],
    n_points: int,
    mode: str,
    seed: int,
    tx: int | None,
    rx: int | None,
    max_touches: int | None,
    open_source: Callable[[Any], Any] | None = None,
) -> None:
    """Run (or resume) a probed session into ``out``; see the module and ``skinloc collect``.

    ``cfg_args`` are the ``SessionConfig`` fields the command sets (samples, baseline frames,
    touch timeout); ``surface`` is the mesh (None when resuming: the file's). ``--probe sim``
    presses a simulated skin of its own; ``--probe ros2`` an arm over ROS 2
    (``calibration.probe_ros2``) on the skin ``open_source(mesh)`` opens (``--port``).
    """
    from skinloc.calibration.probe import (
        ProbeSettings,
        SimulatedProbe,
        check_press,
        probe_dry_run,
        record_probe_point,
    )
    from skinloc.calibration.probe_plan import PLAN_MODES, SkinPose, plan_probing
    from skinloc.calibration.session import CalibrationSession, SessionConfig, truth_layout
    from skinloc.data.recording import read_recording
    from skinloc.errors import Interrupted, RecordingError
    from skinloc.sim.skin import SimulatedSkin

    if resume:
        rec = read_recording(out)
        saved = rec.meta.get("probe")
        if not isinstance(saved, dict):
            raise RecordingError(
                f"{out} was not recorded with a probe: resume it without --probe, or pass --new"
            )
        if saved.get("kind", "sim") != opts.probe.value:
            raise ValueError(
                f"{out} was probed with --probe {saved.get('kind', 'sim')}: resume it with that "
                "probe, or pass --new"
            )
        surface = rec.mesh
        pose = SkinPose(
            tuple(saved["pose"]["translation_m"]),
            tuple(saved["pose"]["rotation_xyzw"]),
            saved["pose"]["parent_frame"],
        )
        presses = [ProbeSettings(**p) for p in saved.get("presses", [saved["settings"]])]
        for settings in presses:
            check_press(settings)
        error_m, dwell_s, skin_seed = saved["error_m"], saved["dwell_s"], saved["skin_seed"]
        seed = int(rec.meta.get("session", {}).get("random_state", seed))
        tx, rx = rec.n_tx, rec.n_rx
    else:
        if mode not in PLAN_MODES:
            raise ValueError("--probe plans its targets up front: --mode must be even or random")
        pose, presses = _pose(opts), _presses(opts)
        error_m, dwell_s, skin_seed = opts.error_mm * 1e-3, opts.dwell_s, opts.skin_seed
        if not (math.isfinite(error_m) and error_m >= 0):
            raise ValueError(f"--probe-error-mm must be >= 0, got {opts.error_mm!r}")
    settings = presses[0]  # the first press level: its limits and clearance are every level's
    n_levels = len(presses)
    ros2 = opts.probe is ProbeChoice.ros2
    if ros2:
        if open_source is None:
            raise ValueError("--probe ros2 reads the skin of --port: give --port")
        skin = open_source(surface)
    else:
        skin = SimulatedSkin(surface, n_tx=tx or 8, n_rx=rx or 8, random_state=skin_seed)
    with contextlib.ExitStack() as stack:
        probe: Any = None
        if ros2:  # the arm first: a missing one is told before anything is written
            from skinloc.calibration.probe_ros2 import Ros2Probe

            probe = Ros2Probe(
                pose.parent_frame or "base_link",
                timeout_s=opts.timeout_s,
                connect_timeout_s=opts.timeout_s,
                max_depth_m=settings.max_depth_m,
                max_force_n=settings.max_force_n,
            )
            stack.callback(probe.close)
        stack.enter_context(skin)
        if resume:
            session = CalibrationSession.resume(skin, out)
            if session.finished:
                raise ValueError(
                    f"{out} is already complete ({session.n_done} point logs); "
                    "pass --new to record it again"
                )
            if not ros2:
                skin.reseed(seed + session.n_done)
            console.print(
                f"Resuming {out} at point log {session.n_done + 1}/{len(session.targets)}"
            )
        else:
            if not ros2:
                skin.reseed(seed)
            plan = plan_probing(
                surface,
                n_points,
                mode,
                random_state=seed,
                pose=pose,
                arm_direction=_direction(opts.arm_direction),
                max_tilt_deg=opts.max_tilt_deg,
                rim_clearance_m=opts.rim_mm * 1e-3,
                clearance_m=settings.clearance_m,
                fill=True,
            )
            left = ", ".join(f"{n} {why}" for why, n in plan.skipped_counts().items())
            if not len(plan):
                raise ValueError(
                    f"no target is reachable ({plan.n_drawn} drawn, left out: {left}): check "
                    "--arm-direction, --max-tilt-deg, --rim-mm and the skin's pose (--skins)"
                )
            console.print(
                f"Plan: {len(plan)} of {n_points} targets, drawn from {plan.n_drawn}"
                + (f" (left out as unreachable: {left})" if left else "")
                + f"; path {plan.path_length_m:.2f} m above the skin"
                + (
                    f"; each pressed at {n_levels} levels ({_levels_text(presses)}), "
                    f"{n_levels * len(plan)} touches"
                    if n_levels > 1
                    else ""
                )
            )
            cfg = SessionConfig(
                n_points=n_levels * len(plan),
                mode=mode,
                random_state=seed,
                description=(
                    f"probed by an arm over ROS 2 on {skin.name}"
                    if ros2
                    else f"probed by a simulated arm (skin seed {skin_seed})"
                ),
                **cfg_args,
            )
            session = CalibrationSession(
                skin,
                surface,
                out,
                cfg,
                # each target once per press level, one after the other (no travel between)
                targets=np.repeat(plan.targets_m, n_levels, axis=0),
                source_name=skin.name if ros2 else "sim",
            )
        n_targets = len(session.targets)
        try:
            if not ros2:
                probe = SimulatedProbe(
                    skin,
                    pose=pose,
                    position_error_m=error_m,
                    max_depth_m=settings.max_depth_m,
                    max_force_n=settings.max_force_n,
                    dwell_s=dwell_s,
                    random_state=seed + 1 + session.n_done,
                )
            if opts.dry_run and not resume:
                frames, _ = skin.read_many(session.config.n_baseline_frames)
                from skinloc.calibration.capture import TouchDetector

                session.detector = TouchDetector(
                    frames.mean(axis=0), frames.std(axis=0), session.config.threshold_sigma
                )
                n = probe_dry_run(session, probe, settings, pose) // n_levels
                console.print(f"Dry run: moved above {n} targets, pressed none; nothing written")
                return
            if session.recording is None:
                console.print(
                    f"Keep the skin untouched: capturing {session.config.n_baseline_frames} "
                    "baseline frames"
                )
                session.capture_baseline()
                session.update_meta(
                    probe={
                        "kind": opts.probe.value,
                        # a simulated arm's own figures; an arm over ROS 2 has none
                        "error_m": None if ros2 else error_m,
                        "dwell_s": None if ros2 else dwell_s,
                        "skin_seed": None if ros2 else skin_seed,
                        "settings": settings.as_meta(),
                        # the press levels of each target, in order (touch i: i % len)
                        "presses": [p.as_meta() for p in presses],
                        "pose": {
                            "translation_m": list(pose.translation_m),
                            "rotation_xyzw": list(pose.rotation_xyzw),
                            "parent_frame": pose.parent_frame,
                        },
                        "n_asked": n_points,
                        "n_drawn": plan.n_drawn,
                        "skipped_m": np.round(plan.skipped_m, 7).tolist(),
                        "skipped_reasons": plan.skipped_reasons,
                    },
                    **truth_layout(skin),
                )
            stop_at = (
                n_targets if max_touches is None else min(n_targets, session.n_done + max_touches)
            )
            with progress_steps() as step:
                while session.n_done < stop_at:
                    i = session.n_done
                    record_probe_point(session, i, probe, presses[i % n_levels], pose)
                    step("probed touches", session.n_done, n_targets)
        except KeyboardInterrupt:
            raise Interrupted(
                f"probe stopped; {session.n_done}/{n_targets} point logs are saved in {out}; "
                "rerun the same command to resume"
            ) from None
        finally:
            if probe is not None:
                probe.close()
            session.close()
    done = session.n_done
    state = "complete" if done >= n_targets else "saved; rerun the same command to resume"
    console.print(f"Wrote {out}: {done}/{n_targets} probed point logs ({state})")
