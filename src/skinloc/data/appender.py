"""Recordings written as they are made: point log by point log, or frame by frame.

A crash, a signal or a full disk keeps what was written before it.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._typing import Points
from skinloc.data.recording import Recording, utc_now, write_h5
from skinloc.errors import RecordingError
from skinloc.files import cannot_write
from skinloc.h5layout import create_stream

__all__ = ["DISK_RESERVE", "RecordingAppender", "StreamAppender"]

#: Bytes an appender leaves free on the disk beyond what it writes, for HDF5's bookkeeping. An
#: HDF5 file that meets a full disk is left broken (h5py may even crash on it), so an appender
#: refuses to write before that happens, and the file keeps everything appended so far.
DISK_RESERVE = 32 * 1024


def _ensure_room(path: Path, nbytes: int) -> None:
    """Raise ``OSError`` (ENOSPC) unless ``path``'s disk has room for ``nbytes`` and more."""
    if shutil.disk_usage(path.parent).free < nbytes + DISK_RESERVE:
        exc = OSError(f"cannot write {path}: {os.strerror(errno.ENOSPC).lower()}")
        exc.errno = errno.ENOSPC
        raise exc


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
        self.meta = {"created": utc_now(), **rec.meta, "skinloc_version": __version__}
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
            write_h5(self._file, rec, self.meta, appendable=True)
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
        _ensure_room(self.path, frames.nbytes + 16 * len(frames) + 24)
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
        self.update_meta(modified=utc_now())

    def update_meta(self, **values: Any) -> None:
        """Merge ``values`` into the stored meta and flush."""
        meta = json.dumps({**self.meta, **values})
        _ensure_room(self.path, len(meta))
        self.meta.update(values)
        self._file.attrs["meta"] = meta
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


class StreamAppender:
    """A raw-stream recording (``skinloc record``) written as the frames come.

    Creates the recording's layout without point logs (header: grid, mesh, the no-touch
    baseline capture, meta) and the group ``stream``: ``frames (n, k)`` float32 raw counts,
    ``times_s (n,)`` s since the first frame, ``index (n,)`` the device's frame counter. Every
    ``append`` grows them and flushes, so the file on disk always holds the frames so far and
    stays readable (``skinloc.sources.replay.read_stream``): a crash, a signal or a full disk
    keeps what was appended before it.

    Parameters
    ----------
    path : str or Path
        File to create; it must not exist unless ``exclusive`` is False.
    n_tx, n_rx : int
        Grid.
    mesh : trimesh.Trimesh
        Skin surface, m.
    baseline_frames : (m, n_tx * n_rx) float
        No-touch capture, raw counts.
    meta : dict, optional
        Stored with the recording.
    chunk : int
        Frames per HDF5 chunk: append about this many at a time (a partly filled compressed
        chunk is rewritten, and the file grows, each time it is appended to).
    columns : dict, optional
        More per-frame datasets, ``{"group/name": (shape of one frame's value, dtype)}``,
        filled through ``append``'s keyword arguments.
    exclusive : bool
        Refuse an existing ``path`` (False: replace it, for a temporary file).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        n_tx: int,
        n_rx: int,
        mesh: Any,
        baseline_frames: np.ndarray,
        meta: dict[str, Any] | None = None,
        chunk: int = 64,
        columns: dict[str, tuple[tuple[int, ...], Any]] | None = None,
        exclusive: bool = True,
    ) -> None:
        import h5py

        from skinloc import __version__
        from skinloc.geometry.mesh import surface_points

        k = n_tx * n_rx
        header = Recording(
            n_tx=n_tx,
            n_rx=n_rx,
            vertices=mesh.vertices,
            faces=mesh.faces,
            surface_points=surface_points(mesh),
            baseline_frames=baseline_frames,
            targets=np.zeros((0, 3)),
            frames=np.zeros((0, 1, k), dtype=np.float32),
            meta={"sampling_mode": "none", "samples_per_touch": 0, **(meta or {})},
        )
        header.validate()
        self.path = Path(path)
        self.n_frames = 0
        try:
            self.file = h5py.File(self.path, "x" if exclusive else "w")
        except OSError as exc:
            raise cannot_write(self.path, exc) from None
        try:
            write_h5(
                self.file,
                header,
                {"created": utc_now(), **header.meta, "skinloc_version": __version__},
            )
            self._data = create_stream(self.file, k, chunk)
            for name, (shape, dtype) in (columns or {}).items():
                self._data[name] = self.file.create_dataset(
                    name, (0, *shape), dtype, maxshape=(None, *shape), chunks=(chunk, *shape)
                )
            self.file.flush()
        except BaseException as exc:
            with contextlib.suppress(OSError):  # a full disk refuses the close's flush too
                self.file.close()
            self.path.unlink(missing_ok=True)
            if isinstance(exc, OSError):
                raise cannot_write(self.path, exc) from None
            raise

    def append(
        self, frames: np.ndarray, times_s: np.ndarray, index: np.ndarray, **columns: np.ndarray
    ) -> None:
        """Add frames ``(n, k)`` raw counts, their times ``(n,)`` s and counters ``(n,)``.

        ``columns`` give the ``columns`` datasets' values, ``(n, ...)`` each. The frames are
        flushed to disk; on any error (a full disk, Ctrl-C) none of them stays in the file.
        """
        values = {"frames": frames, "times_s": times_s, "index": index, **columns}
        if set(values) != set(self._data):
            raise ValueError(f"append needs exactly {sorted(self._data)}, got {sorted(values)}")
        n = len(frames)
        if any(len(v) != n for v in values.values()):
            raise ValueError("append needs as many values of each dataset as frames")
        if not n:
            return
        _ensure_room(self.path, sum(np.asarray(v).nbytes for v in values.values()))
        i = self.n_frames
        try:
            for name, ds in self._data.items():
                ds.resize(i + n, axis=0)
                ds[i:] = values[name]
            self.file.flush()
        except BaseException:
            with contextlib.suppress(OSError):  # a full disk may refuse this too
                self.truncate(i)
            raise
        self.n_frames = i + n

    def truncate(self, n: int) -> None:
        """Keep the first ``n`` frames only (and flush)."""
        for ds in self._data.values():
            ds.resize(n, axis=0)
        self.n_frames = n
        self.file.flush()

    def close(self) -> None:
        """Flush, sync to disk and close (idempotent)."""
        if self.file.id.valid:
            self.file.flush()
            self.file.close()
            with open(self.path, "rb") as fh:
                os.fsync(fh.fileno())

    def __enter__(self) -> StreamAppender:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
