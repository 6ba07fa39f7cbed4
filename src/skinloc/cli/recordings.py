"""Commands about recordings themselves: ``skinloc check``, ``snr``, ``info`` and ``convert``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from skinloc.cli.common import (
    check_output,
    console,
    friendly_errors,
    print_json,
    read_recordings,
)

#: Meta keys ``info`` shows in their own fields, not under ``meta``.
_TRUTH_KEYS = ("true_contacts", "truth_sensor_positions_m")


def _probe_touches(meta: dict[str, Any]) -> dict[str, Any]:
    """A probed session's touches: reported tip (mm, mesh frame), depth (mm), force (N)."""
    tips = meta.get("probe_tips_m")
    if not isinstance(tips, list):
        return {}
    depths = meta.get("probe_depths_m") or [None] * len(tips)
    forces = meta.get("probe_forces_n") or [None] * len(tips)
    return {
        "probe_touches": [
            {
                "tip_mm": [round(1e3 * float(v), 3) for v in tip],
                "depth_mm": None if d is None else round(1e3 * float(d), 3),
                "force_n": f,
            }
            for tip, d, f in zip(tips, depths, forces, strict=False)
        ]
    }


def _probe_line(touches: list[dict[str, Any]]) -> str:
    """One line about a probed session's touches, for the table."""
    depths = [t["depth_mm"] for t in touches if t["depth_mm"] is not None]
    forces = [t["force_n"] for t in touches if t["force_n"] is not None]
    what = [f"{len(touches)} with the probe's reported tip"]
    for name, vals, unit in (("depth", depths, "mm"), ("force", forces, "N")):
        if vals:
            lo, hi = min(vals), max(vals)
            what.append(f"{name} {lo:g} {unit}" if lo == hi else f"{name} {lo:g}-{hi:g} {unit}")
    return ", ".join(what) + " (each in --json)"


def _truth_layout(rec) -> dict[str, Any]:
    """A simulated recording's true crossings (``skinloc simulate`` stores them), else nothing."""
    truth = rec.meta.get("truth_sensor_positions_m")
    return {} if truth is None else {"truth_sensor_positions_m": truth}


def _finite_round(value: float, ndigits: int = 2) -> float | None:
    """``value`` rounded for JSON, or None when it is not finite (too few touches)."""
    import math

    return round(float(value), ndigits) if math.isfinite(value) else None


def _show(
    summary: dict[str, Any],
    as_json: bool,
    skip: tuple[str, ...] = (),
    rows: Any = None,
) -> None:
    """Print ``summary`` as JSON, or as a two-column table: nested dicts flattened a level."""
    if as_json:
        print_json(summary)
        return
    table = Table(title=summary["file"], show_header=False)
    for k, v in summary.items():
        if k in skip and isinstance(v, dict):
            for kk, vv in v.items():
                table.add_row(f"{k}.{kk}", str(vv))
        elif k not in skip:
            table.add_row(k, f"{v:.3f}" if isinstance(v, float) else str(v))
    console.print(table)
    if rows is not None:
        console.print(rows(summary))


def _channel_rows(summary: dict[str, Any]) -> Table:
    """An MCAP file's channels as a table."""
    table = Table("topic", "schema", "encoding", "messages", title="channels")
    for ch in summary["channels"]:
        table.add_row(ch["topic"], str(ch["schema"]), ch["encoding"], str(ch["n_messages"]))
    return table


def _history_info(path: Path, history: list, as_json: bool) -> None:
    """``info`` of an app session's ``history.h5``: each touch taken back or baseline replaced."""
    from skinloc.h5layout import HISTORY

    entries = []
    for name, arrays, attrs in history:
        e: dict[str, Any] = {"entry": name, "kind": name.rsplit("_", 1)[0], **attrs}
        if "target" in arrays:
            e["target_mm"] = [round(1e3 * float(v), 2) for v in arrays["target"]]
        if "frames" in arrays:
            e["n_frames"] = int(len(arrays["frames"]))
        entries.append(e)
    if as_json:
        print_json({"file": str(path), "format": HISTORY, "entries": entries})
        return
    table = Table(title=f"{path}: an app session's history (kept, never used for training)")
    for col in ("entry", "time", "reason", "recording", "index", "target (mm)", "frames"):
        table.add_column(col)
    for e in entries:
        target = e.get("target_mm")
        table.add_row(
            e["entry"],
            str(e.get("time", "")),
            str(e.get("reason", "")),
            str(e.get("recording", "")),
            str(e.get("index", "")),
            "" if target is None else ", ".join(f"{v:.1f}" for v in target),
            str(e.get("n_frames", "")),
        )
    console.print(table)


def register(app: typer.Typer) -> None:
    """Add ``skinloc snr``, ``info`` and ``convert`` to ``app``."""

    # ------------------------------------------------------------------------------------ snr
    @app.command()
    @friendly_errors
    def check(
        data: Annotated[Path, typer.Argument(help="A calibration recording (.h5 or .mat).")],
        as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    ) -> None:
        """Every touch's flags, as the app's gate gives them: off_target, weak, short, saturated.

        off_target: the map of the other touches (of the images' square roots) puts the
        touch's image more than 30 mm from its target, fits it there better than at the target
        and badly at the target, by more than the session's own spread (docs/app.md, "Touch
        quality"). Retake such a touch, or leave it out in the app (skinloc app).

        Example: skinloc check cal.h5 --json
        """
        from skinloc.calibration.touch_check import check_recording

        (rec,) = read_recordings([data], calibration=True)
        flags, off = check_recording(rec)
        touches = [
            {
                "index": i,
                "flags": f,
                "located_mm": _finite_round(off.distance_mm[i]),
                "gain": _finite_round(off.gain[i]),
                "score": _finite_round(off.score[i]),
            }
            for i, f in enumerate(flags)
        ]
        result = {
            "file": str(data),
            "n_touches": len(touches),
            "n_flagged": sum(bool(t["flags"]) for t in touches),
            "off_target_score_threshold": _finite_round(off.threshold),
            "touches": touches,
        }
        if as_json:
            print_json(result)
            return
        table = Table(
            "touch", "flags", "located from target (mm)", "gain", "score", title=str(data)
        )
        for t in touches:
            if t["flags"]:
                table.add_row(
                    str(t["index"]),
                    ", ".join(t["flags"]),
                    "-" if t["located_mm"] is None else f"{t['located_mm']:.0f}",
                    "-" if t["gain"] is None else f"{t['gain']:.2f}",
                    "-" if t["score"] is None else f"{t['score']:.2f}",
                )
        if result["n_flagged"]:
            console.print(table)
        console.print(
            f"{result['n_flagged']} of {result['n_touches']} touches flagged "
            f"(touch numbers from 0, in the file's order)"
        )

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
        for path, rec in zip(data, read_recordings(data, calibration=True), strict=True):
            s = snr_db(rec.touch_means, rec.baseline_frames)
            results.append(
                {
                    "file": str(path),
                    "mean_snr_db": float(np.nanmean(s)),
                    "min_snr_db": float(np.nanmin(s)),
                    "max_snr_db": float(np.nanmax(s)),
                    "per_sensor_db": [
                        None if not np.isfinite(v) else round(float(v), 2) for v in s
                    ],
                    "tx": rec.n_tx,
                    "rx": rec.n_rx,
                }
            )
        if as_json:
            print_json(results[0] if len(results) == 1 else results)
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
        """Describe a file skinloc wrote: a recording, a model, a session history, an MCAP bag.

        A recording: grid, point logs, frames, baseline, noise, SNR (and its raw stream, live
        output and truth when it has them). A model: kind, sensors, what it was trained on.
        An MCAP file ('run --sink mcap:' or foxglove's): topics, schemas, counts, duration.

        Example: skinloc info cal.h5 --json
        """
        import numpy as np

        from skinloc.data.recording import PER_TOUCH_META
        from skinloc.evaluation.metrics import mean_snr_db
        from skinloc.sim.gesture_stream import read_gesture_truth
        from skinloc.sources.replay import stream_summary

        if data.suffix.lower() == ".mcap" and data.is_file():
            from skinloc.sources.mcap_ros2 import bag_summary

            _show(bag_summary(data), as_json, skip=("channels",), rows=_channel_rows)
            return
        if data.suffix.lower() in (".h5", ".hdf5") and data.is_file():
            from skinloc.h5layout import MODEL, is_kind, read_history

            if is_kind(data, MODEL):
                from skinloc.models.model_file import model_summary

                _show(model_summary(data), as_json, skip=("config", "training", "meta"))
                return
            history = read_history(data)
            if history is not None:  # an app session's history.h5: what was taken back
                _history_info(data, history, as_json)
                return
        (rec,) = read_recordings([data])
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
            "meta": {k: v for k, v in rec.meta.items() if k not in (*_TRUTH_KEYS, *PER_TOUCH_META)},
            **_probe_touches(rec.meta),
            **_truth_layout(rec),
            **(read_gesture_truth(data) or {}),  # a `skinloc simulate --gestures` stream
        }
        if as_json:
            print_json(summary)
            return
        table = Table(title=str(data), show_header=False)
        for k, v in summary.items():
            if k == "truth_sensor_positions_m":
                table.add_row(k, f"{len(v)} true crossings (simulated skin)")
            elif k in ("truth_gestures", "truth_touches"):
                table.add_row(k, f"{len(v)} (see --json)")
            elif k == "probe_touches":
                table.add_row(k, _probe_line(v))
            elif k != "meta":
                table.add_row(k, f"{v:.1f}" if isinstance(v, float) else str(v))
        for k, v in summary["meta"].items():
            if k == "probe" and isinstance(v, dict) and "skipped_m" in v:
                # the targets left out are many numbers: their count here, each in --json
                n = len(v["skipped_m"])
                v = {kk: vv for kk, vv in v.items() if kk not in ("skipped_m", "skipped_reasons")}
                v["skipped"] = f"{n} unreachable targets (each in --json)"
            table.add_row(f"meta.{k}", str(v))
        console.print(table)

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
        (rec,) = read_recordings([src])
        if suffix == ".mat":
            write_mat(rec, dst)
        else:
            write_recording(rec, dst)
        console.print(f"Wrote {dst} ({rec.n_point_logs} point logs)")
