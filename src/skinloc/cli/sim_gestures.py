"""``skinloc simulate --gestures N``: a raw stream of a scripted hand making gestures."""

from __future__ import annotations

from pathlib import Path

from skinloc.cli.common import check_output, check_skin_covers, console, progress_steps

#: Largest gesture stream the command line makes, bytes of float32 frames (as ``simulate``).
MAX_STREAM_BYTES = 4 * 2**30


def simulate_gestures(
    out: Path,
    *,
    n_gestures: int,
    other_touches: int | None,
    seed: int,
    skin_seed: int,
    mesh: Path | None,
    units: str,
    tx: int,
    rx: int,
    force: bool,
) -> None:
    """Record the stream (see ``skinloc.sim.gesture_stream``) and print one line about it."""
    from skinloc.calibration.session import truth_layout
    from skinloc.geometry.mesh import cone_skin, load_mesh
    from skinloc.sim.gesture_stream import record_gestures
    from skinloc.sim.gestures import GESTURE_KINDS, GestureScript
    from skinloc.sim.skin import SimulatedSkin

    if n_gestures < 1:
        raise ValueError(f"--gestures must be >= 1, got {n_gestures}")
    if other_touches is not None and other_touches < 0:
        raise ValueError(f"--other-touches must be >= 0, got {other_touches}")
    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise ValueError(f"--gestures writes a raw stream: --out must name an .h5 file, got {out}")
    check_output(out, option="--out", inputs=[mesh], force=force)
    surface = cone_skin() if mesh is None else load_mesh(mesh, units)
    # The same skin as every `skinloc simulate --skin-seed K`: wiring from the skin seed,
    # noise, drift and touches from --seed.
    skin = SimulatedSkin(surface, n_tx=tx, n_rx=rx, random_state=skin_seed)
    if mesh is not None:
        check_skin_covers(skin, mesh)
    skin.reseed(seed)
    script = GestureScript(
        surface,
        n_gestures,
        n_touches=other_touches,
        random_state=seed,
        draw_touch=lambda rng: skin.draw_touch(rng, weak=False),
    )
    size = script.max_duration_s() * skin.rate_hz * (skin.n_sensors * 4 + 32)
    if size > MAX_STREAM_BYTES:
        raise ValueError(
            f"{n_gestures} gestures may need {size / 2**30:.1f} GiB of frames; the limit is "
            f"{MAX_STREAM_BYTES / 2**30:.0f} GiB: ask for fewer --gestures"
        )
    meta = {
        "description": f"simulated gestures (skin seed {skin_seed}, seed {seed})",
        "source": "sim",
        "gesture_script": {
            "n_gestures": n_gestures,
            "n_other_touches": script.n_touches,
            "seed": seed,
            "skin_seed": skin_seed,
            "kinds": list(GESTURE_KINDS),
            "skin_up": script.up.tolist(),
            "skin_right": script.right.tolist(),
            "timing": script.timing.as_dict(),
        },
        **truth_layout(skin),
    }
    with progress_steps() as step:
        res = record_gestures(
            skin,
            out,
            script,
            meta=meta,
            progress=lambda d, t: step("simulating gestures", d, t),
        )
    console.print(
        f"Wrote {out}: {res['n_frames']} frames ({res['seconds']:.1f} s), "
        f"{len(res['truth_gestures'])} gestures and {len(res['truth_touches'])} other touches"
    )
