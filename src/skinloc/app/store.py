"""Sessions on disk: one folder each, listed on the app's first page.

A session folder holds ``session.json`` (name, settings, the mesh's origin), ``plan.npz`` (the
skin mesh and the planned targets, written when the session is made), ``calibration.h5`` and
``validation.h5`` (skinloc recordings, rewritten atomically after every touch), ``model.h5``,
and ``history.h5``: every touch taken back (undone or retaken) and every replaced baseline, so
nothing recorded is ever lost. A lock file keeps two app processes off the same session.
"""

from __future__ import annotations

import json
import logging
import os
import re
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.data.recording import read_recording, utc_now
from skinloc.errors import RecordingError, SkinlocError
from skinloc.files import atomic_write
from skinloc.h5layout import HISTORY, HISTORY_FILE, read_history, write_history

log = logging.getLogger(__name__)

__all__ = ["HISTORY_FORMAT", "SessionBusyError", "SessionFolder", "SessionStore", "read_history"]

#: The ``format`` attribute of a session's ``history.h5`` (``skinloc.h5layout``).
HISTORY_FORMAT = HISTORY


class SessionBusyError(SkinlocError):
    """The session is open elsewhere (another app process)."""


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")[:40] or "session"


@dataclass
class SessionFolder:
    """The files of one session."""

    path: Path

    @property
    def id(self) -> str:
        """Folder name, unique in the store."""
        return self.path.name

    @property
    def info_path(self) -> Path:
        """``session.json``."""
        return self.path / "session.json"

    @property
    def plan_path(self) -> Path:
        """``plan.npz``: mesh and planned targets."""
        return self.path / "plan.npz"

    @property
    def calibration(self) -> Path:
        """The calibration recording."""
        return self.path / "calibration.h5"

    @property
    def validation(self) -> Path:
        """The validation recording."""
        return self.path / "validation.h5"

    @property
    def model(self) -> Path:
        """The trained localiser."""
        return self.path / "model.h5"

    @property
    def history(self) -> Path:
        """Touches taken back and baselines replaced."""
        return self.path / HISTORY_FILE

    # ------------------------------------------------------------------ metadata
    def read_info(self) -> dict[str, Any]:
        """``session.json`` as a dict."""
        try:
            return json.loads(self.info_path.read_text())
        except (OSError, ValueError) as exc:
            raise RecordingError(f"cannot read {self.info_path}: {exc}") from exc

    def write_info(self, info: dict[str, Any]) -> None:
        """Rewrite ``session.json`` atomically."""
        info = {**info, "modified": utc_now()}
        atomic_write(self.info_path, lambda tmp: tmp.write_text(json.dumps(info, indent=2)))

    def read_plan(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(vertices (V, 3) m, faces (F, 3), targets (n, 3) m)`` of the session."""
        with np.load(self.plan_path) as z:
            return z["vertices"], z["faces"], z["targets"]

    def summary(self) -> dict[str, Any]:
        """What the session list shows: name, progress, model and validation results."""
        info = self.read_info()
        out: dict[str, Any] = {
            "id": self.id,
            "name": info.get("name", self.id),
            "created": info.get("created"),
            "modified": info.get("modified"),
            "n_planned": info.get("config", {}).get("n_points"),
            "n_done": 0,
            "has_model": self.model.is_file(),
            "holdout": info.get("holdout"),
            "validation": info.get("validation"),
            "validation_previous": info.get("validation_previous"),
            "calibration_file": str(self.calibration) if self.calibration.is_file() else None,
        }
        if self.calibration.is_file():
            try:
                rec = read_recording(self.calibration)
                out["n_done"] = rec.n_point_logs
                if rec.planned_targets is not None:
                    out["n_planned"] = len(rec.planned_targets)
            except RecordingError as exc:
                out["error"] = str(exc)
        return out

    # ------------------------------------------------------------------ history
    def archive(self, kind: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> None:
        """Keep ``arrays`` (a touch taken back, a replaced baseline) in ``history.h5``.

        The file is rewritten atomically with the new entry added, so a crash keeps the old one.
        """
        old = read_history(self.history) if self.history.is_file() else []
        if old is None:  # never written over: whatever it holds stays
            raise RecordingError(f"{self.history} is not a session history; move it away first")
        entry = f"{kind}_{len(old)}"
        old.append((entry, arrays, {**attrs, "time": utc_now()}))

        atomic_write(self.history, lambda tmp: write_history(tmp, old))

    def history_count(self) -> int:
        """Entries in ``history.h5``."""
        if not self.history.is_file():
            return 0
        import h5py

        with h5py.File(self.history, "r") as f:
            return len(f)

    # ------------------------------------------------------------------ locking
    def lock(self) -> int:
        """Take the session's lock file; raises ``SessionBusyError`` when another process has it.

        Returns the open file descriptor; ``unlock`` releases it.
        """
        import fcntl

        fd = os.open(self.path / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise SessionBusyError(
                f"session {self.id} is open in another skinloc app process; close it there first"
            ) from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        return fd

    @staticmethod
    def unlock(fd: int) -> None:
        """Release a lock taken by ``lock``."""
        import fcntl

        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)


class SessionStore:
    """The folder of sessions (and of loose recordings) the app works in.

    Parameters
    ----------
    root : str or Path
        Created if missing. Sessions are its subfolders with a ``session.json``; recordings
        (``.h5``, ``.mat``) lying in it or in ``root/recordings`` are listed too.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def sessions(self) -> list[SessionFolder]:
        """All sessions, newest first."""
        found = [SessionFolder(p.parent) for p in self.root.glob("*/session.json")]
        return sorted(found, key=lambda s: s.info_path.stat().st_mtime, reverse=True)

    def get(self, session_id: str) -> SessionFolder:
        """The session ``session_id``; raises ``RecordingError`` if there is none."""
        if not re.fullmatch(r"[A-Za-z0-9_.-]+", session_id or "") or session_id.startswith("."):
            raise RecordingError(f"no session {session_id!r}")
        folder = SessionFolder(self.root / session_id)
        if not folder.info_path.is_file():
            raise RecordingError(f"no session {session_id!r} in {self.root}")
        return folder

    def create(
        self,
        name: str,
        vertices: np.ndarray,
        faces: np.ndarray,
        targets: np.ndarray,
        info: dict[str, Any],
    ) -> SessionFolder:
        """Make a new session folder with its plan (mesh and targets) and ``session.json``."""
        stamp = time.strftime("%Y%m%d-%H%M%S")
        base = f"{stamp}-{_slug(name)}"
        path, k = self.root / base, 1
        while path.exists():
            k += 1
            path = self.root / f"{base}-{k}"
        path.mkdir(parents=True)
        folder = SessionFolder(path)

        def write_plan(tmp: Path) -> None:
            with tmp.open("wb") as fh:
                np.savez(fh, vertices=vertices, faces=faces, targets=targets)

        atomic_write(folder.plan_path, write_plan)
        folder.write_info({"name": name, "created": utc_now(), **info})
        return folder

    def recordings(self) -> list[dict[str, Any]]:
        """Loose recordings in the store (not inside a session), with their size."""
        out = []
        for folder in (self.root, self.root / "recordings"):
            if not folder.is_dir():
                continue
            for p in sorted(folder.iterdir()):
                if p.suffix.lower() not in (".h5", ".hdf5", ".mat") or not p.is_file():
                    continue
                entry: dict[str, Any] = {"path": str(p), "name": p.name}
                try:
                    rec = read_recording(p)
                    entry.update(
                        n_point_logs=rec.n_point_logs,
                        tx=rec.n_tx,
                        rx=rec.n_rx,
                        samples=rec.samples_per_touch,
                    )
                except RecordingError as exc:
                    entry["error"] = str(exc)
                out.append(entry)
        return out
