"""Commands about the skin itself: ``skinloc sensors`` and ``skinloc coverage``."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from skinloc.files import atomic_write, cannot_write

__all__ = ["register", "load_skin_input"]


def load_skin_input(paths: list[Path]) -> tuple[str, Any]:
    """Read recordings of one skin, or one model file.

    Returns ``("recordings", [Recording, ...])`` or ``("model", ContactLocalizer)``.

    Raises
    ------
    ValueError
        For a model given with other files.
    """
    from skinloc.cli.common import read_recordings
    from skinloc.h5layout import MODEL, is_kind
    from skinloc.models.localizer import ContactLocalizer

    models = [p for p in paths if p.is_file() and is_kind(p, MODEL)]
    if models:
        if len(paths) > 1:
            raise ValueError("give one model file, or one or more recordings, not both")
        return "model", ContactLocalizer.load(models[0])
    return "recordings", read_recordings(paths, calibration=True)


def _check_out(out: Path, inputs: list[Path], names: tuple[str, ...]) -> None:
    """Refuse a report folder that is, or would overwrite, an input."""
    res = out.resolve()
    for p in inputs:
        if p.resolve() == res or p.resolve().parent == res and p.name in names:
            raise ValueError(f"--out {out} would overwrite the input {p}")
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")


def _report(
    data: list[Path],
    out: Path | None,
    name: str,
    build: Callable[[str, Any], tuple[dict, Callable[[Path], None]]],
    as_json: bool,
) -> dict | None:
    """The steps ``sensors`` and ``coverage`` share: inputs, report folder, JSON.

    Checks ``--out`` before any work (it must not overwrite an input), reads the inputs,
    ``build(kind, obj) -> (result, plot)``, writes ``NAME.json`` atomically and
    ``plot(NAME.png)`` into ``out``, and prints the JSON when asked. Returns the result for a
    human summary, or None when the JSON was printed.
    """
    names = (f"{name}.json", f"{name}.png")
    if out is not None:
        _check_out(out, data, names)
    kind, obj = load_skin_input(data)
    result, plot = build(kind, obj)
    result["source"] = [str(p) for p in data]
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        text = json.dumps(result, indent=1) + "\n"
        atomic_write(out / names[0], lambda tmp: tmp.write_text(text))
        try:
            plot(out / names[1])
        except OSError as exc:  # a full disk: name the figure
            raise cannot_write(out / names[1], exc) from None
    if as_json:
        sys.stdout.write(json.dumps(result, indent=1) + "\n")
        return None
    return result


def sensors_result(
    kind: str, obj: Any, n_boot: int, seed: int, fields: bool = False
) -> tuple[dict, Any, Any, Any]:
    """The sensor map as JSON, with a truth comparison when the recording knows its layout.

    ``fields`` opts in to the separable line-field model (``estimate_sensor_map(fields=True)``);
    it needs touches, so a model file with ``fields`` is refused.

    Returns ``(result, SensorMap, mesh, truth or None)``.

    Raises
    ------
    ValueError
        For ``fields`` with a model file.
    """
    import numpy as np

    from skinloc.geometry.mesh import mesh_from_arrays
    from skinloc.sensors import sensor_map as S

    if kind == "model":
        if fields:
            raise ValueError(
                "--fields fits the line fields to calibration touches: give recordings, "
                "not a model file (a model keeps no touches)"
            )
        smap = S.sensor_map_from_model(obj)
        mesh = (
            mesh_from_arrays(obj.mesh_vertices_, obj.mesh_faces_)
            if getattr(obj, "mesh_vertices_", None) is not None
            else None
        )
        truth = None
    else:
        smap = S.sensor_map_from_recordings(obj, n_boot=n_boot, random_state=seed, fields=fields)
        mesh = obj[0].mesh
        truth = S.truth_sensor_positions(obj[0].meta)
    result = smap.as_dict()
    if kind != "model" and len(obj) == 1:
        from skinloc.evaluation.repeatability import session_repeatability

        rep = session_repeatability(obj[0])
        if rep is not None:
            result["probing_repeatability_mm"] = round(rep["rms_mm"], 2)
            result["n_repeated_targets"] = rep["n_pairs"]
    if truth is not None and truth.shape == smap.positions_m.shape:
        err = S.position_errors_mm(smap.positions_m, truth)
        alive = smap.status != "dead"
        result["truth"] = {
            "median_mm": round(float(np.median(err[alive])), 2),
            "p90_mm": round(float(np.percentile(err[alive], 90)), 2),
            "max_mm": round(float(err[alive].max()), 2),
            "n_scored": int(alive.sum()),
            "note": "against the simulator's true crossings, sensors not flagged dead",
        }
    result["two_point"] = two_point_result(obj if kind == "model" else None, obj)
    return result, smap, mesh, truth


def two_point_result(model: Any, recordings: Any = None) -> dict:
    """The skin's two-point threshold as JSON, with the sentence a person reads (``text``).

    From ``model``'s contact rule; with no model, from the default model fitted on
    ``recordings`` (unknown when none can be fitted).
    """
    from skinloc.models.multi_contact.two_point import SHARE, WITHIN_MM, describe, two_point_of

    if model is None and recordings is not None:
        from skinloc.evaluation.scoring import train_localizer

        try:
            model = train_localizer(recordings)
        except ValueError:
            model = None  # e.g. a recording without its skin's mesh: nothing to measure on
    tp = two_point_of(getattr(model, "contact_rule_", None))
    return {
        "measured": tp is not None,
        "counted_two_mm": None if tp is None else tp["counted_two_mm"],
        "threshold_mm": None if tp is None else tp["threshold_mm"],
        "within_mm": WITHIN_MM,
        "share": SHARE,
        "bins": None if tp is None else tp["bins"],
        "text": describe(tp),
    }


#: Options both commands take.
_JsonFlag = Annotated[bool, typer.Option("--json", help="Print one JSON object.")]
_ReportDir = Annotated[
    Path | None,
    typer.Option(help="Report folder: <command>.json and <command>.png (the skin)."),
]


def register(app: typer.Typer) -> None:
    """Add ``sensors`` and ``coverage`` to the main ``skinloc`` app."""
    from skinloc.cli.common import console, friendly_errors

    @app.command()
    @friendly_errors
    def sensors(
        data: Annotated[
            list[Path],
            typer.Argument(help="Calibration recordings of one skin, or one model file."),
        ],
        as_json: _JsonFlag = False,
        out: _ReportDir = None,
        boot: Annotated[
            int, typer.Option(min=0, max=100, help="Bootstrap resamples for the uncertainty.")
        ] = 8,
        seed: Annotated[int, typer.Option(help="Seed of the bootstrap.")] = 0,
        fields: Annotated[
            bool,
            typer.Option(
                "--fields",
                help="Opt in to the separable line-field model (one smooth field per TX and "
                "RX line; docs/sensors.md): where the whole-image model is not kept, it is "
                "used when it predicts held-out touches better than the per-crossing fit. "
                "It places the crossings worse (real cone: recordings agree to 13.9 mm, "
                "median, against 8.3 mm without it), so leave it off for a map of the "
                "crossings; recordings only.",
            ),
        ] = False,
    ) -> None:
        """Locate every TX x RX crossing and wire on the surface; flag dead, weak, noisy lines.

        Example: skinloc sensors cal.h5 --json --out sensors-report/
        """

        def build(kind: str, obj: Any) -> tuple[dict, Any]:
            result, smap, mesh, truth = sensors_result(kind, obj, boot, seed, fields)

            def plot(path: Path) -> None:
                from skinloc.sensors.figures import plot_sensor_map

                if mesh is not None:
                    plot_sensor_map(mesh, smap, path, truth)

            return result, plot

        result = _report(data, out, "sensors", build, as_json)
        if result is None:
            return
        _print_summary(console, result)
        if out is not None:
            console.print(f"Report in {out}/")

    @app.command()
    @friendly_errors
    def coverage(
        data: Annotated[
            list[Path],
            typer.Argument(help="A model file, or calibration recordings (a map is fitted)."),
        ],
        as_json: _JsonFlag = False,
        out: _ReportDir = None,
        points: Annotated[
            int, typer.Option(min=20, max=3000, help="Evaluation points on the surface.")
        ] = 400,
    ) -> None:
        """Expected localisation error over the skin, and its blind spots.

        Example: skinloc coverage model.h5 --json --out coverage-report/
        """

        def build(kind: str, obj: Any) -> tuple[dict, Any]:
            result, cov, mesh = coverage_result(kind, obj, points)

            def plot(path: Path) -> None:
                from skinloc.sensors.figures import plot_coverage

                if mesh is not None:
                    plot_coverage(mesh, cov.points_m, cov.expected_mm, path, cov.blind_m)

            return result, plot

        result = _report(data, out, "coverage", build, as_json)
        if result is None:
            return
        e = result["expected_error_mm"]
        console.print(
            f"expected error: mean {e['mean']} mm, median {e['median']} mm, p90 {e['p90']} mm; "
            f"blind (> {result['blind_threshold_mm']:.0f} mm): "
            f"{100 * result['blind_fraction']:.0f}% of the skin"
        )
        console.print(result["two_point"]["text"])


def coverage_result(kind: str, obj: Any, n_points: int) -> tuple[dict, Any, Any]:
    """Coverage of a model, or of a default map trained on the recordings.

    Returns ``(result, Coverage, mesh or None)``.
    """
    from skinloc.geometry.mesh import mesh_from_arrays
    from skinloc.sensors.coverage import calibrate_temperature, coverage_map

    temperature = float(getattr(obj, "meta_", {}).get("coverage_temperature", 1.0))
    if kind == "model":
        model, F = obj, None
        mesh = (
            mesh_from_arrays(model.mesh_vertices_, model.mesh_faces_)
            if getattr(model, "mesh_vertices_", None) is not None
            else None
        )
    else:
        import numpy as np

        from skinloc.evaluation.scoring import train_localizer
        from skinloc.models.response_map import shape_features

        model = train_localizer(obj)
        F = shape_features(np.concatenate([r.touch_means for r in obj]))
        targets = np.concatenate([r.targets for r in obj])
        temperature = calibrate_temperature(targets, F, model.map_.candidates)
        mesh = obj[0].mesh
    if getattr(model, "map_", None) is None:
        raise ValueError("coverage needs a response-map model (arch 'default'), or recordings")
    cov = coverage_map(model.map_, F, n_points=n_points, temperature=temperature)
    return {**cov.as_dict(), "two_point": two_point_result(model)}, cov, mesh


def _print_summary(console: Any, result: dict) -> None:
    from rich.table import Table

    n_rx = result["n_rx"]
    grid = Table("TX \\ RX", *[str(j) for j in range(n_rx)], title="sensor status / gain")
    rows: dict[int, list[str]] = {}
    for s in result["sensors"]:
        mark = "" if s["status"] == "ok" else f" {s['status']}"
        rows.setdefault(s["tx"], []).append(f"{s['gain']:.2f}{mark}")
    for i, cells in rows.items():
        grid.add_row(str(i), *cells)
    console.print(grid)
    bad = [f"{ln['kind'].upper()} {ln['index']}: {ln['status']}" for ln in result["lines"]]
    bad = [b for b in bad if not b.endswith(": ok")]
    console.print("lines flagged: " + (", ".join(bad) if bad else "none"))
    if "method" in result:
        console.print(f"positions: {result['method']} fit (docs/sensors.md)")
    if "heldout" in result:
        h = result["heldout"]
        console.print(
            f"held-out misfit: per-crossing {h['per_crossing']:.2f}, line fields "
            f"{min(h['fields'].values()):.2f} (n = {h['best_centres']}; lower is better)"
        )
    unc = [s["uncertainty_mm"] for s in result["sensors"] if s["uncertainty_mm"] is not None]
    if unc:
        unc.sort()
        console.print(f"position uncertainty: median {unc[len(unc) // 2]:.1f} mm")
    if "probing_repeatability_mm" in result:
        console.print(
            f"your probing repeatability: {result['probing_repeatability_mm']:.1f} mm "
            f"({result['n_repeated_targets']} repeated targets): no accuracy figure of this "
            "session can be trusted below it"
        )
    if "truth" in result:
        t = result["truth"]
        console.print(
            f"against the true crossings: median {t['median_mm']} mm, 90th pct {t['p90_mm']} mm"
        )
    if "two_point" in result:
        console.print(result["two_point"]["text"])
