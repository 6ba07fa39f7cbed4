"""Recordings written point log by point log, for sessions that must survive a crash."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._typing import Points
from skinloc.data.recording import Recording, _now, _write_h5
from skinloc.errors import RecordingError
from skinloc.files import cannot_write

__all__ = ["RecordingAppender"]


class RecordingAppender:
    """A recording written point log by point log into one open HDF5 file.

    Rewriting a whole recording after every point log (``write_recording``) costs time
    quadratic in the session's length; this appends each point log to resizable datasets and
    flushes, so the file on disk always holds the complete point logs so far and stays
    readable by ``read_recording`` (same layout, docs/formats.md).

    The file is created exclusively: it never replaces an existing one. Callers write it under
    a side name and rename it over the target when the session is complete.

    Parameters
    ----------
    rec : Recording
        The header (grid, mesh, baseline, planned targets, meta) and any point logs so far.
    path : str or Path
        File to create.
    """

    def __init__(self, rec: Recording, path: str | Path) -> None:
        import h5py

        from skinloc import __version__

        rec.validate()
        self.path = Path(path)
        self.meta = {"created": _now(), **rec.meta, "skinloc_version": __version__}
        self.n_point_logs = rec.n_point_logs
        self._shape = (rec.frames.shape[1] or int(rec.meta.get("samples_per_touch", 0)),)
        self._shape += (rec.n_sensors,)
        if rec.n_point_logs == 0:  # size the empty datasets for the frames to come
            rec = Recording(**{**rec.__dict__, "frames": np.zeros((0, *self._shape), np.float32)})
        try:
            self._file = h5py.File(self.path, "x")
        except OSError as exc:
            raise cannot_write(self.path, exc) from None
        try:
            _write_h5(self._file, rec, self.meta, appendable=True)
            self._file.flush()
        except BaseException:
            self._file.close()
            self.path.unlink(missing_ok=True)
            raise

    def append(self, target: Points, frames: np.ndarray, times: np.ndarray | None = None) -> None:
        """Add one point log and flush it to disk.

        ``target (3,)`` m, ``frames (s, n_sensors)`` raw counts, ``times (s,)`` s (optional).
        """
        frames = np.asarray(frames, dtype=np.float32)
        if frames.shape != self._shape:
            raise RecordingError(
                f"point log frames must have shape {self._shape}, got {frames.shape}"
            )
        if not np.all(np.isfinite(frames)):
            raise RecordingError("point log frames have NaN or infinite values")
        g = self._file["point_logs"]
        i = self.n_point_logs
        names = ("targets", "frames", "frame_times")
        try:
            for name in names:
                g[name].resize(i + 1, axis=0)
            g["targets"][i] = np.asarray(target, dtype=np.float64).reshape(3)
            g["frames"][i] = frames
            g["frame_times"][i] = np.full(self._shape[0], np.nan) if times is None else times
        except BaseException:  # Ctrl-C mid-write: no half-written point log stays in the file
            for name in names:
                g[name].resize(i, axis=0)
            raise
        self.n_point_logs = i + 1
        self.update_meta(modified=_now())

    def update_meta(self, **values: Any) -> None:
        """Merge ``values`` into the stored meta and flush."""
        self.meta.update(values)
        self._file.attrs["meta"] = json.dumps(self.meta)
        self._file.flush()

    def close(self) -> None:
        """Flush, sync to disk and close (idempotent)."""
        if self._file.id.valid:
            self._file.flush()
            self._file.close()
            with open(self.path, "rb") as fh:
                os.fsync(fh.fileno())

    def __enter__(self) -> RecordingAppender:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
