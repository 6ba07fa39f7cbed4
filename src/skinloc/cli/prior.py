"""``skinloc prior build`` and ``skinloc prior show``: the response map's prior."""

from __future__ import annotations

from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer

__all__ = ["register"]


class Backend(StrEnum):
    """joblib backends the build can run on."""

    loky = "loky"
    dask = "dask"


def register(app: typer.Typer) -> None:
    """Add the ``prior`` group (``build``, ``show``) to the main ``skinloc`` app."""
    from skinloc.cli.common import check_output, console, friendly_errors, print_json

    group = typer.Typer(
        help="The response map's prior, learned from simulated skins (docs/accuracy.md).",
        no_args_is_help=True,
    )
    app.add_typer(group, name="prior")

    @group.command()
    @friendly_errors
    def build(
        out: Annotated[Path, typer.Option(help="Prior file to write (JSON).")],
        skins: Annotated[
            int, typer.Option(min=2, help="Simulated skins for the hyperparameters.")
        ] = 24,
        eval_skins: Annotated[
            int, typer.Option(min=1, help="Further skins that choose its strength.")
        ] = 40,
        touches: Annotated[int, typer.Option(min=40, help="Calibration touches per skin.")] = 80,
        seed: Annotated[int, typer.Option(min=0, help="Seed of the first skin.")] = 1000,
        jobs: Annotated[int, typer.Option(help="joblib workers (-1: every core).")] = -1,
        backend: Annotated[
            Backend,
            typer.Option(
                help="joblib backend: 'dask' runs the skins on the Dask cluster of a "
                "distributed.Client made from --scheduler (needs dask[distributed])."
            ),
        ] = Backend.loky,
        scheduler: Annotated[
            str | None, typer.Option(help="Dask scheduler address, e.g. tcp://host:8786.")
        ] = None,
        force: Annotated[bool, typer.Option("--force", help="Replace an existing --out.")] = False,
    ) -> None:
        """Simulate skins and learn the prior; the package's own was made with the defaults.

        Example: skinloc prior build --out src/skinloc/models/map_prior.json --force
        """
        from joblib import parallel_config

        from skinloc.sim.prior_build import build_prior

        check_output(out, option="--out", inputs=[], force=force)
        client = None
        if backend is Backend.dask:
            from skinloc._lazy import require_extra

            distributed = require_extra("distributed", "skinloc prior build --backend dask")
            client = distributed.Client(scheduler)
        try:
            with parallel_config(backend=backend.value, n_jobs=jobs):
                report = build_prior(skins, eval_skins, touches, jobs, seed, progress=console.print)
        finally:
            if client is not None:
                client.close()
        report.prior.save(out)
        curve = report.curve
        sizes = " / ".join(str(n) for n in curve["none"])
        fmt = " / ".join
        console.print(
            f"Simulated {skins + eval_skins} skins in {report.seconds:.0f} s "
            f"({report.skins_per_minute:.0f} skins per minute); wrote {out}\n"
            f"On {eval_skins} skins the first stage never saw, error at {sizes} touches: "
            f"{fmt(f'{v:.1f}' for v in curve['prior'].values())} mm with the prior, "
            f"{fmt(f'{v:.1f}' for v in curve['none'].values())} mm without; "
            f"applied up to {report.prior.max_touches} touches",
            highlight=False,
        )

    @group.command()
    @friendly_errors
    def show(
        path: Annotated[
            Path | None, typer.Argument(help="Prior file; default: the package's.")
        ] = None,
        as_json: Annotated[bool, typer.Option("--json", help="Print JSON.")] = False,
    ) -> None:
        """Print a prior: its hyperpriors, strength and how it was built."""
        from dataclasses import asdict

        from skinloc.models.map_prior import load_prior

        prior = load_prior(path)
        if as_json:
            print_json(asdict(prior))
            return
        t = prior.typical
        console.print(
            f"map prior v{prior.version}: length scale {t['length_scale_mm']:.1f} mm, "
            f"amplitude {t['amplitude']:.2g}, noise {t['noise']:.2g} (log stds "
            f"{', '.join(f'{v:.2f}' for v in prior.log_std)}); mean shrunk by "
            f"{prior.mean_pseudo_touches:g} pseudo-touches; applied up to "
            f"{prior.max_touches} touches\nbuilt by: {prior.provenance.get('command', '?')}",
            highlight=False,
        )
