"""Recordings written as they are made: point log by point log, or frame by frame.

A crash, a signal or a full disk keeps what was written before it.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from skinloc._typing import Points
from skinloc.data.recording import (
    Recording,
    file_meta,
    read_recording,
    utc_now,
    write_h5,
    write_planned_targets,
)
from skinloc.errors import RecordingError
from skinloc.files import atomic_write, cannot_write
from skinloc.h5layout import create_stream

__all__ = ["DISK_RESERVE", "RecordingAppender", "StreamAppender"]

#: Bytes an appender leaves free on the disk beyond what it writes, for HDF5's bookkeeping. An
#: HDF5 file that meets a full disk is left broken (h5py may even crash on it), so an appender
#: refuses to write before that happens, and the file keeps everything appended so far.
DISK_RESERVE = 32 * 1024
#: Longest wait, s, for a reader of a calibration file (HDF5 locks a file while it is read) to
#: let the appender write its next change.
LOCK_WAIT_S = 10.0


def _ensure_room(path: Path, nbytes: int) -> None:
    """Raise ``OSError`` (ENOSPC) unless ``path``'s disk has room for ``nbytes`` and more."""
    if shutil.disk_usage(path.parent).free < nbytes + DISK_RESERVE:
        exc = OSError(f"cannot write {path}: {os.strerror(errno.ENOSPC).lower()}")
        exc.errno = errno.ENOSPC
        raise exc


class RecordingAppender:
    """The one writer of a calibration recording while it is made: each change as it comes.

    Every calibration capture (``skinloc collect``, ``skinloc simulate``, the app's guided
    capture, through ``calibration.session.CalibrationSession``) writes with it. A point log is
    appended to resizable datasets (``write_h5(appendable=True)``); taking one back, a new
    plan of targets or new meta touch only those parts; the whole file is never rewritten
    (rewriting it after every point log costs time quadratic in the session's length). The
    file on disk always holds the complete point logs so far and stays readable by
    ``read_recording`` (same layout, docs/formats.md).

    The file is opened for each change and closed after it, so it is never held open between
    touches: any reader (training, ``skinloc info``, the app's other pages) can open it then,
    and a session dropped without ``close`` leaves nothing open. A change waits (up to
    ``LOCK_WAIT_S``) for a reader that holds the file's lock. Each change is one flush of a
    few milliseconds; a crash inside one can leave HDF5's bookkeeping half written, a risk
    the whole rewrite through a rename did not have, traded for writing a touch, not the
    session, per touch.

    Parameters
    ----------
    rec : Recording
        The header (grid, mesh, baseline, planned targets, meta) and any point logs so far.
    path : str or Path
        File to create.
    replace : bool
        Replace an existing ``path`` atomically with the new header (``skinloc collect
        --new --force``); by default the file is created exclusively and an existing one is
        refused (callers write a side file and rename it when the session is complete).
    """

    _NAMES = ("targets", "frames", "frame_times")

    def __init__(self, rec: Recording, path: str | Path, *, replace: bool = False) -> None:
        import h5py

        rec.validate()
        self.path = Path(path)
        self.meta = file_meta(rec.meta)
        self.n_point_logs = rec.n_point_logs
        self._shape = (rec.frames.shape[1] or int(rec.meta.get("samples_per_touch", 0)),)
        self._shape += (rec.n_sensors,)
        if rec.n_point_logs == 0:  # size the empty datasets for the frames to come
            rec = Recording(**{**rec.__dict__, "frames": np.zeros((0, *self._shape), np.float32)})
        self._open = True
        if replace:
            atomic_write(self.path, lambda tmp: _write_appendable(tmp, rec, self.meta))
            return
        try:
            f = h5py.File(self.path, "x")
        except OSError as exc:
            raise cannot_write(self.path, exc) from None
        try:
            with f:
                write_h5(f, rec, self.meta, appendable=True)
        except BaseException:
            self.path.unlink(missing_ok=True)
            raise

    @classmethod
    def reopen(cls, path: str | Path, rec: Recording | None = None) -> RecordingAppender:
        """Carry on writing the recording in ``path`` (``rec``: it, already read).

        A file written whole (``write_recording``: an imported recording, an older session)
        is rewritten once, atomically, in the appendable layout; after that only changes are
        written.
        """
        path = Path(path)
        if rec is None:
            rec = read_recording(path)
        app = cls.__new__(cls)
        app.path = path
        app.meta = file_meta(rec.meta)
        app.n_point_logs = rec.n_point_logs
        samples = rec.frames.shape[1] if rec.n_point_logs else rec.meta.get("samples_per_touch")
        app._shape = (int(samples or 0), rec.n_sensors)
        app._open = True
        if not _appendable(path):
            if rec.n_point_logs == 0:
                rec = Recording(
                    **{**rec.__dict__, "frames": np.zeros((0, *app._shape), np.float32)}
                )
            atomic_write(path, lambda tmp: _write_appendable(tmp, rec, app.meta))
        return app

    @contextlib.contextmanager
    def _edit(self, nbytes: int) -> Iterator[Any]:
        """The file, open for one change (after a check of the disk's room); then closed."""
        import h5py

        if not self._open:
            raise RecordingError(f"{self.path} is closed for writing")
        _ensure_room(self.path, nbytes)
        deadline = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                f = h5py.File(self.path, "r+")
                break
            except OSError as exc:  # someone reads it now (``skinloc info``, a polling test)
                if "lock" not in str(exc).lower() or time.monotonic() > deadline:
                    raise cannot_write(self.path, exc) from None
                time.sleep(0.01)
        with f:
            yield f
            f.flush()

    def append(
        self,
        target: Points,
        frames: np.ndarray,
        times: np.ndarray | None = None,
        meta: dict[str, Any] | None = None,
    ) -> None:
        """Add one point log and flush it to disk.

        ``target (3,)`` m, ``frames (s, n_sensors)`` raw counts, ``times (s,)`` s (optional);
        ``meta``: keys merged into the file's meta in the same flush (what a robot's probe
        reported of this touch stays with it).
        """
        frames = np.asarray(frames, dtype=np.float32)
        if frames.shape != self._shape:
            raise RecordingError(
                f"point log frames must have shape {self._shape}, got {frames.shape}"
            )
        if not np.all(np.isfinite(frames)):
            raise RecordingError("point log frames have NaN or infinite values")
        i = self.n_point_logs
        meta = {**self.meta, **(meta or {}), "modified": utc_now()}
        text = json.dumps(meta)
        with self._edit(frames.nbytes + 16 * len(frames) + 24 + len(text)) as f:
            g = f["point_logs"]
            try:
                for name in self._NAMES:
                    g[name].resize(i + 1, axis=0)
                g["targets"][i] = np.asarray(target, dtype=np.float64).reshape(3)
                g["frames"][i] = frames
                g["frame_times"][i] = np.full(self._shape[0], np.nan) if times is None else times
                f.attrs["meta"] = text  # in the same flush: one short window per touch
            except BaseException:  # Ctrl-C mid-write: no half-written point log stays
                for name in self._NAMES:
                    g[name].resize(i, axis=0)
                raise
        self.n_point_logs = i + 1
        self.meta = meta

    def remove(self, index: int) -> None:
        """Take point log ``index`` out: the later ones move down by one, the rest stays.

        The point logs are moved one at a time in order, so an interruption leaves at worst
        a later point log twice in the file, never one lost.
        """
        n = self.n_point_logs
        if not 0 <= index < n:
            raise IndexError(f"no point log {index}: the recording has {n}")
        with self._edit(0) as f:
            g = f["point_logs"]
            for j in range(index, n - 1):
                for name in self._NAMES:
                    g[name][j] = g[name][j + 1]
            for name in self._NAMES:
                g[name].resize(n - 1, axis=0)
        self.n_point_logs = n - 1

    def set_planned_targets(self, planned: Points | None) -> None:
        """Store the session's plan of targets, ``(N, 3)`` m (None: remove it)."""
        with self._edit(0 if planned is None else 24 * len(planned)) as f:
            old = f.get("planned_targets")
            if planned is None:
                if old is not None:
                    del f["planned_targets"]
                return
            planned = np.asarray(planned, dtype=np.float64).reshape(-1, 3)
            if old is not None and old.maxshape[0] is None:
                old.resize(len(planned), axis=0)
                old[...] = planned
                return
            if old is not None:
                del f["planned_targets"]
            write_planned_targets(f, planned)

    def set_meta(self, meta: dict[str, Any]) -> None:
        """Store ``meta`` as the recording's meta (its ``created`` and ``modified`` kept)."""
        kept = {k: self.meta[k] for k in ("created", "modified") if k in self.meta}
        self._store_meta({**kept, **file_meta(meta)})

    def update_meta(self, **values: Any) -> None:
        """Merge ``values`` into the stored meta and flush."""
        self._store_meta({**self.meta, **values})

    def _store_meta(self, meta: dict[str, Any]) -> None:
        text = json.dumps(meta)
        with self._edit(len(text)) as f:
            f.attrs["meta"] = text
        self.meta = meta

    def close(self) -> None:
        """Sync the file to disk; no change is written after it (idempotent)."""
        if self._open:
            self._open = False
            with open(self.path, "rb") as fh:
                os.fsync(fh.fileno())

    def __enter__(self) -> RecordingAppender:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _write_appendable(tmp: Path, rec: Recording, meta: dict[str, Any]) -> None:
    import h5py

    with h5py.File(tmp, "w") as f:
        write_h5(f, rec, meta, appendable=True)


def _appendable(path: Path) -> bool:
    """Whether ``path``'s point logs and plan can grow and shrink in place."""
    import h5py

    with h5py.File(path, "r") as f:
        g = f["point_logs"]
        grows = all(n in g and g[n].maxshape[0] is None for n in RecordingAppender._NAMES)
        plan = f.get("planned_targets")
        return grows and (plan is None or plan.maxshape[0] is None)


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
            write_h5(self.file, header, file_meta(header.meta))
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
