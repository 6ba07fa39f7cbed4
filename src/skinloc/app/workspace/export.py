"""Export: the open session's files, its validation errors as CSV, its error view as PNG and SVG.

Only files directly in the open session's folder whose names ``EXPORTABLE`` accepts are ever
sent: the recordings the app writes (``calibration.h5``, ``validation.h5``, earlier validations,
``history.h5``, the live recordings of ``skinloc.app.workspace.record``) and ``model.h5``.
A name is looked up in that listing, never joined to a path, so no request reaches another file.
"""

from __future__ import annotations

import csv
import io
import re
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.app.workspace.settings import SKINS_FILE
from skinloc.app.workspace.state import ActiveSession, WorkspaceState, app_meta
from skinloc.data.recording import Recording, read_recording
from skinloc.errors import RecordingError

__all__ = ["EXPORTABLE", "ExportFiles", "NoSuchExport", "open_command", "validation_csv"]

#: Names of the session's files that may be downloaded, and what each is.
EXPORTABLE: tuple[tuple[re.Pattern[str], str], ...] = (
    (re.compile(r"calibration\.h5"), "calibration recording"),
    (re.compile(r"validation\.h5"), "validation recording"),
    (re.compile(r"validation-[0-9]{8}-[0-9]{6}\.h5"), "earlier validation recording"),
    (re.compile(r"history\.h5"), "touches taken back and replaced baselines"),
    (re.compile(r"model\.h5"), "trained model"),
    (re.compile(r"skins\.toml"), "live settings: the skins file 'skinloc run --config' reads"),
    (re.compile(r"live-[0-9]{8}-[0-9]{6}(-[0-9]+)?\.(h5|mcap)"), "live recording"),
    # what an HDF5 live recording holds when the app stopped without finishing it (a crash)
    (
        re.compile(r"live-[0-9]{8}-[0-9]{6}(-[0-9]+)?\.partial(-[0-9]+)?\.h5"),
        "live recording, unfinished (the app stopped during it)",
    ),
)

#: Column names of ``validation_csv`` (positions and errors in mm).
CSV_COLUMNS = (
    "touch",
    "status",
    "target_x_mm",
    "target_y_mm",
    "target_z_mm",
    "predicted_x_mm",
    "predicted_y_mm",
    "predicted_z_mm",
    "error_mm",
    "uncertainty_mm",
)

# pyplot keeps global state: one figure at a time.
_PLOT_LOCK = threading.Lock()


class NoSuchExport(RecordingError):
    """A file the open session does not have (or may not be downloaded): HTTP 404."""


def open_command(name: str, session: str, names: set[str]) -> str:
    """A skinloc command that opens the session's file ``name`` once downloaded.

    It names the files as they download (``{session}-{name}``) and runs as printed in the
    folder they were downloaded to: a validation is scored by the model when there is one, the
    skins file runs the live pipeline for 5 s, anything else is described by ``skinloc info``.
    """

    def dl(n: str) -> str:
        return f"{session}-{n}"

    if name == SKINS_FILE:
        return f"skinloc run --config {dl(name)} --duration 5"
    if name.startswith("validation") and "model.h5" in names:
        return f"skinloc evaluate {dl('model.h5')} {dl(name)}"
    return f"skinloc info {dl(name)}"


def _kind(name: str) -> str | None:
    """What the file ``name`` is, or None when it is not one to export."""
    for pattern, kind in EXPORTABLE:
        if pattern.fullmatch(name):
            return kind
    return None


def validation_csv(rec: Recording) -> str:
    """Every validation touch of ``rec`` as CSV: target, prediction, error (mm), one per row.

    Touches taken back (retaken or undone) follow as ``status`` ``taken back``: they were
    attempts and count in the honest figure, so the file keeps them.
    """
    meta = app_meta(rec)
    predicted = meta.get("predicted", [])
    errors = meta.get("errors_mm", [])
    unc = meta.get("uncertainty_mm", [])
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(CSV_COLUMNS)

    def mm(p: Any) -> list[str]:
        return ["", "", ""] if p is None else [f"{1e3 * float(x):.3f}" for x in p]

    def num(x: Any) -> str:
        return "" if x is None else f"{float(x):.3f}"

    for i in range(rec.n_point_logs):
        pred = predicted[i] if i < len(predicted) else None
        err = errors[i] if i < len(errors) else None
        u = unc[i] if i < len(unc) else None
        w.writerow([i + 1, "kept", *mm(rec.targets[i]), *mm(pred), num(err), num(u)])
    for t in meta.get("taken_back", []):
        w.writerow(
            [
                int(t["index"]) + 1,
                f"taken back ({t.get('reason', '')})".replace(" ()", ""),
                *mm(t.get("target")),
                *mm(t.get("predicted")),
                num(t.get("error_mm")),
                "",
            ]
        )
    return out.getvalue()


class ExportFiles(WorkspaceState):
    """Part of ``Workspace``: what the Export page downloads."""

    def export_list(self) -> dict[str, Any]:
        """The open session's files to download and what else is ready.

        Each file: ``name``, ``download`` (the name it downloads as), ``kind`` (what it is),
        ``bytes`` and ``command`` (a skinloc command that opens it, run as printed in the
        folder the files were downloaded to). ``skins.toml`` is offered once there is a model,
        saved or not (the settings the live view would use); it names the downloaded model.
        ``validation`` says whether the CSV and the error view can be made.
        """
        with self._lock:
            a = self._need_session()
            found: dict[str, int] = {}
            recorder = self.recorder
            writing = None if recorder is None else recorder.side  # not until it is finished
            for p in sorted(a.folder.path.iterdir()):
                kind = _kind(p.name)
                if kind is None or p.is_symlink() or not p.is_file() or p == writing:
                    continue
                found[p.name] = p.stat().st_size
            found.pop(SKINS_FILE, None)
            if "model.h5" in found:
                found[SKINS_FILE] = len(self._skins_export(a).encode())
            files = [
                {
                    "name": name,
                    "download": f"{a.folder.id}-{name}",
                    "kind": _kind(name),
                    "bytes": size,
                    "command": open_command(name, a.folder.id, set(found)),
                }
                for name, size in sorted(found.items())
            ]
            rec = self._validation_recording(a)
            scored = rec is not None and bool(app_meta(rec).get("errors_mm"))
            return {"session": a.folder.id, "files": files, "validation": scored}

    def _skins_export(self, a: ActiveSession) -> str:
        """The skins file as downloaded: its model is the downloaded model."""
        return self.skins_text(model=f"{a.folder.id}-model.h5")

    def export_file(self, name: str) -> tuple[str, bytes]:
        """``(download name, content)`` of the session's file ``name`` (one ``export_list`` lists).

        Read whole under the lock, so no touch or recording is half-written into it meanwhile.
        """
        with self._lock:
            a = self._need_session()
            listed = {f["name"] for f in self.export_list()["files"]}
            if name not in listed:
                shown = name if len(name) <= 80 else name[:77] + "..."
                raise NoSuchExport(f"session {a.folder.id} has no file {shown!r} to export")
            if name == SKINS_FILE:
                return f"{a.folder.id}-{name}", self._skins_export(a).encode()
            return f"{a.folder.id}-{name}", (a.folder.path / name).read_bytes()

    def export_validation_csv(self) -> tuple[str, str]:
        """``(download name, CSV text)`` of the validation touches (``validation_csv``)."""
        with self._lock:
            a = self._need_session()
            rec = self._validation_recording(a)
            if rec is None or not app_meta(rec).get("errors_mm"):
                raise ValueError("validate first: there are no validation errors to export")
            return f"{a.folder.id}-validation-errors.csv", validation_csv(rec)

    def export_error_view(self, fmt: str) -> tuple[str, bytes]:
        """``(download name, image)`` of the validation errors on the skin, ``png`` or ``svg``.

        The figure of ``skinloc evaluate``'s report (``plot_predictions_3d``): each target joined
        to its prediction, coloured by error, seen from above and from the side.
        """
        from skinloc.evaluation.report import plot_predictions_3d

        if fmt not in ("png", "svg"):
            raise ValueError(f"the error view comes as png or svg, not {fmt[:20]!r}")
        with self._lock:
            a = self._need_session()
            rec = self._validation_recording(a)
            meta = app_meta(rec) if rec is not None else {}
            predicted = meta.get("predicted", [])
            if not predicted:
                raise ValueError("validate first: the error view shows the validation touches")
            n = min(len(predicted), rec.n_point_logs)
            targets = rec.targets[:n].copy()
            pred = np.asarray(predicted[:n], dtype=float)
            mesh, sid = a.mesh, a.folder.id
        with _PLOT_LOCK, tempfile.TemporaryDirectory(prefix="skinloc-export-") as tmp:
            path = Path(tmp) / "errors.png"
            title = f"Validation of {sid}: targets (o) and predictions (x), {n} touches"
            plot_predictions_3d(mesh, targets, pred, path, title=title)
            data = path.with_suffix(f".{fmt}").read_bytes()
        return f"{sid}-validation-errors.{fmt}", data

    @staticmethod
    def _validation_recording(a: ActiveSession) -> Recording | None:
        """The validation in progress or on disk, or None."""
        if a.val is not None and a.val.recording is not None:
            return a.val.recording
        if a.folder.validation.is_file():
            try:
                return read_recording(a.folder.validation)
            except RecordingError:
                return None
        return None
