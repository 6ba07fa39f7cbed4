"""``skinloc predict``: the contacts of every row of an array or of a recording's frames."""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path
from typing import Annotated, Any, TextIO

import numpy as np
import typer

__all__ = ["read_input", "register", "write_contacts"]

_ARRAYS = (".npy", ".csv")
_RECORDINGS = (".h5", ".hdf5", ".mat")


def read_input(path: Path, n_sensors: int) -> np.ndarray:
    """The baseline-subtracted images of ``path``, ``(n, n_sensors)`` float32 counts.

    ``.npy`` and ``.csv``: an array ``(n, n_sensors)`` of baseline-subtracted counts (a CSV may
    have one header line); ``.h5``, ``.hdf5``, ``.mat``: a recording's frames minus its baseline,
    in order (point log by point log).

    Raises
    ------
    ValueError
        Naming the file and what is wrong with it.
    """
    suffix = path.suffix.lower()
    if not path.is_file():
        raise ValueError(f"input not found: {path}")
    if suffix in _RECORDINGS:
        from skinloc.data.recording import read_recording

        rec = read_recording(path)
        X = rec.deltas.reshape(-1, rec.n_sensors)
        what = f"{path} has {rec.n_sensors} sensors"
    elif suffix == ".npy":
        try:
            X = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise ValueError(f"cannot read {path} as a NumPy array: {exc}") from None
        what = f"{path} holds an array of shape {X.shape}"
    elif suffix == ".csv":
        X = _read_csv(path)
        what = f"{path} has rows of {X.shape[1]} values"
    else:
        raise ValueError(
            f"cannot tell what {path} holds: give a .npy or .csv array (n, {n_sensors}) of "
            "baseline-subtracted counts, or a recording (.h5, .mat)"
        )
    if X.ndim == 1 and suffix == ".npy":
        X = X[None, :]
    if X.ndim != 2 or X.shape[1] != n_sensors:
        raise ValueError(f"{what}; the model takes rows of {n_sensors} sensors: (n, {n_sensors})")
    if not np.issubdtype(X.dtype, np.number) or np.issubdtype(X.dtype, np.complexfloating):
        raise ValueError(f"{path} does not hold real numbers (dtype {X.dtype})")
    X = np.ascontiguousarray(X, dtype=np.float32)
    bad = ~np.isfinite(X).all(axis=1)
    if bad.any():
        raise ValueError(f"{path}: row {int(np.argmax(bad))} holds NaN or infinite values")
    return X


def _read_csv(path: Path) -> np.ndarray:
    for skip in (0, 1):  # a header line, if any
        try:
            X = np.loadtxt(path, delimiter=",", ndmin=2, skiprows=skip, dtype=np.float64)
        except ValueError:
            continue
        except OSError as exc:
            raise ValueError(f"cannot read {path}: {exc}") from None
        return X
    raise ValueError(f"cannot read {path} as comma-separated numbers")


def write_contacts(engine: Any, X: np.ndarray, max_contacts: int, fh: TextIO) -> int:
    """One JSON object per row of ``X`` into ``fh``; returns the rows written."""
    for x in X:
        cs = engine.contacts(x, max_contacts)
        fh.write(json.dumps({"contacts": cs.to_json()}) + "\n")
    return len(X)


def register(app: typer.Typer) -> None:
    """Add ``predict`` to the main ``skinloc`` app."""
    from skinloc.cli.common import check_output, console, friendly_errors

    @app.command()
    @friendly_errors
    def predict(
        model: Annotated[Path, typer.Argument(help="Model file from 'skinloc train'.")],
        data: Annotated[
            Path,
            typer.Argument(
                metavar="INPUT",
                help="A .npy or .csv array (n, n_sensors) of baseline-subtracted counts, or a "
                "recording (.h5, .mat) whose frames are taken minus its baseline.",
            ),
        ],
        max_contacts: Annotated[
            int, typer.Option(min=1, max=3, help="Most contacts per row (1: single contact).")
        ] = 3,
        out: Annotated[
            Path | None, typer.Option(help="JSON-lines file to write (default: stdout).")
        ] = None,
        force: Annotated[bool, typer.Option("--force", help="Replace an existing --out.")] = False,
    ) -> None:
        """Localise the contacts of every row of INPUT: one JSON object per row.

        Each line is {"contacts": [{"position_m": [x, y, z], "uncertainty_mm": u,
        "strength": s}, ...]}, strongest first, [] when nothing touches.

        Example: skinloc predict model.h5 frames.npy --max-contacts 3 --out contacts.jsonl
        """
        from skinloc.models.localizer import ContactLocalizer

        if out is not None:
            check_output(out, option="--out", inputs=[model, data], force=force)
        loc = ContactLocalizer.load(model)
        X = read_input(data, loc.n_features_in_)  # before the kernels compile: bad input at once
        engine = loc.engine().warm_up()
        if out is None:
            write_contacts(engine, X, max_contacts, sys.stdout)
            return
        fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=f".{out.name}.", suffix=".partial")
        try:
            with os.fdopen(fd, "w") as fh:
                n = write_contacts(engine, X, max_contacts, fh)
            os.replace(tmp, out)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        console.print(f"Wrote {out}: {n} rows", highlight=False)
