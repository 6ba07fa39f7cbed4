"""``skinloc bench``: the paper's experiment on simulated skins, the real splits, timing."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from skinloc.cli.common import (
    check_output,
    console,
    err_console,
    friendly_errors,
    print_json,
    progress_steps,
)

#: Columns of the real-recordings table.
_REAL_COLUMNS = ("protocol", "arch", "train", "test", "per", "n", "mean_mm", "std_mm", "median_mm")


def installed_archs(archs: tuple[str, ...]) -> tuple[tuple[str, ...], list[str]]:
    """The architectures of ``archs`` this install can train, and what was left out, and why.

    Networks train in PyTorch (the ``nets`` extra); a benchmark without it measures the rest
    and says so.
    """
    from skinloc._lazy import extra_installed, missing_extra_message
    from skinloc.models.localizer import architecture_kind

    if extra_installed("torch"):
        return archs, []
    nets = [a for a in archs if architecture_kind(a).train_extra == "torch"]
    if not nets:
        return archs, []
    names = " and ".join(repr(a) for a in nets)
    what = f"training the {names} network{'s' if len(nets) > 1 else ''}"
    kept = tuple(a for a in archs if a not in nets)
    return kept, [missing_extra_message("torch", what)]


def register(app: typer.Typer) -> None:
    """Add ``skinloc bench`` to ``app``."""

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
        sizes: Annotated[
            str, typer.Option(help="Comma-separated point-log counts.")
        ] = "20,50,80,100",
        out: Annotated[Path, typer.Option(help="Folder for figures and JSON results.")] = Path(
            "skinloc-bench"
        ),
        as_json: Annotated[bool, typer.Option("--json", help="Print JSON results.")] = False,
        online: Annotated[
            bool,
            typer.Option("--online", help="Only the live path: latency, throughput, 100 skins."),
        ] = False,
    ) -> None:
        """The paper's experiment: train on 20, 50, 80, 100 point logs, validate on 20 touches.

        Example: skinloc bench --seeds 3 --real ../shared/data/hiro-cone-skin --timing
        """
        check_output(out, option="--out", folder=True)
        if online:  # skinloc.cli.live: the live pipeline's figures (docs/benchmarks.md)
            archs, left_out = installed_archs(("default", "mlp", "paper"))
            return __import__("skinloc.cli.live", fromlist=["bench_online"]).bench_online(
                out, as_json, archs, left_out
            )
        import numpy as np

        from skinloc.bench import paper as B
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
        sim_archs, _ = installed_archs(("paper", "default"))
        real_archs, _ = installed_archs(("default", "mlp", "paper"))
        asked = (("paper",) if sim else ()) + (("mlp", "paper") if real is not None else ())
        _, left_out = installed_archs(tuple(dict.fromkeys(asked)))
        results: dict[str, Any] = {"left_out": left_out}
        for why in results["left_out"]:
            err_console.print(f"left out: {why}", highlight=False, soft_wrap=True)
        with progress_steps() as step:
            if sim:
                rows = B.paper_experiment(
                    sizes=size_list, seeds=range(seeds), archs=sim_archs, step=step
                )
                results["sim"] = rows
            if real is not None:
                splits = B.real_splits(real, archs=real_archs, step=step)
                results["real"] = [r.__dict__ for r in splits]
            if timing:
                results["timing"] = B.timing(step=step)
        (out / "results.json").write_text(json.dumps(results, indent=2, default=float))

        if "sim" in results:
            rows = results["sim"]
            table = Table(
                title=f"Simulated paper skin: validation on 20 random touches, {seeds} skins"
            )
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
                sel = [
                    [r for r in rows if r["n_points"] == n and r["arch"] == a] for n in size_list
                ]
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
            for c in _REAL_COLUMNS:
                table.add_column(c)
            for r in results["real"]:
                table.add_row(
                    *[
                        f"{r[c]:.1f}" if isinstance(r[c], float) else str(r[c])
                        for c in _REAL_COLUMNS
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
            print_json(results)
        else:
            console.print(f"Results and figures in {out}/")
