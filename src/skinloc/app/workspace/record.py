"""Recording the live stream from the page: raw frames, contacts and gestures, HDF5 or MCAP.

One recording at a time, into the open session's folder, with the package's own writers:

- ``h5``: ``StreamAppender``, the layout of ``skinloc record`` (a no-touch baseline, then the
  group ``stream``: every raw frame, its time and counter), so ``skinloc info`` and ``skinloc run
  --source FILE.h5`` read it; the live pipeline's contacts and gestures go beside the frames into
  the group ``live`` of the same file, one JSON line each (the ``jsonl`` sink's lines:
  ``live/contacts``, ``live/gestures``). It is written under ``live-...partial.h5`` and renamed
  when it ends; what was flushed (every second) survives a crash.
- ``mcap``: ``Ros2BagSink`` (``skinloc run --sink mcap-ros2:FILE``), a ROS 2 bag that Foxglove
  opens and ``skinloc run --source FILE.mcap`` replays: raw frames, contacts, markers, gestures.

The frames come from the reader thread (``record_frame``); contacts and gestures from the live
pipeline when it runs, through ``RecordTee``, one of its sinks. Stopping, disconnecting, closing
the session and closing the app end the file (``stop_recording``).
"""

from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.app.hub import Hub
from skinloc.app.workspace.state import AppConfig, WorkspaceState
from skinloc.h5layout import create_live_events, read_live_events  # re-exported: its reader
from skinloc.live.sinks.base import Sink, SkinInfo, gesture_json
from skinloc.sources.base import Frame

log = logging.getLogger(__name__)

__all__ = ["FORMATS", "LiveRecorder", "LiveRecording", "RecordTee", "read_live_events"]

#: What ``start_recording`` writes, by format.
FORMATS = {"h5": "HDF5 (skinloc info, replay)", "mcap": "MCAP (Foxglove, ROS 2 bag)"}


@functools.cache
def missing_format(fmt: str) -> str | None:
    """Why ``fmt`` cannot be recorded in this install (the extra to install), None when it can."""
    if fmt != "mcap":
        return None
    from skinloc.errors import MissingExtraError
    from skinloc.live.sinks.ros2.bag import bag_requirements

    try:
        bag_requirements()
    except MissingExtraError as exc:
        return str(exc)
    return None


def offered_formats() -> dict[str, str]:
    """The formats the page offers: those this install can write."""
    return {k: v for k, v in FORMATS.items() if missing_format(k) is None}


#: Frames kept in memory before they are appended to an HDF5 recording (also at least once a s).
CHUNK = 64


class LiveRecorder(Sink):
    """One recording of the live stream, written as it comes (``h5`` or ``mcap``).

    Parameters
    ----------
    path : Path
        The file it ends as (it must not exist).
    fmt : {"h5", "mcap"}
        Format.
    skin : SkinInfo
        Name, mesh and grid of the skin.
    mesh : trimesh.Trimesh
        Skin surface, m (the HDF5 header).
    baseline_frames : (m, n_tx * n_rx) float
        No-touch frames, raw counts (the HDF5 header's baseline).
    meta : dict
        Stored with an HDF5 recording.
    """

    name = "app-record"

    def __init__(
        self,
        path: Path,
        fmt: str,
        skin: SkinInfo,
        mesh: Any,
        baseline_frames: np.ndarray,
        meta: dict[str, Any],
    ) -> None:
        from skinloc.files import side_path

        self.path, self.fmt, self.skin = Path(path), fmt, skin
        self.started = time.monotonic()
        self.n_frames = self.n_contacts = self.n_gestures = 0
        self.t0: float | None = None
        self.t_last = 0.0
        self._lock = threading.Lock()
        self._frames: list[tuple[np.ndarray, float, int]] = []
        self._contacts: list[str] = []
        self._gestures: list[str] = []
        self._flushed = time.monotonic()
        self.closed = False
        if fmt == "mcap":
            from skinloc.live.sinks.ros2.bag import Ros2BagSink

            self.writer: Any = Ros2BagSink(self.path)
            self.writer.open([skin])
            self.side = None
        elif fmt == "h5":
            from skinloc.data.appender import StreamAppender

            self.side = side_path(self.path, "partial")
            self.writer = StreamAppender(
                self.side,
                n_tx=int(skin.n_tx),
                n_rx=int(skin.n_rx),
                mesh=mesh,
                baseline_frames=baseline_frames,
                meta=meta,
                chunk=CHUNK,
            )
            self._events = create_live_events(self.writer.file, CHUNK)
        else:
            raise ValueError(f"record to {' or '.join(FORMATS)}, not {fmt[:20]!r}")

    # ------------------------------------------------------------------ the stream
    def frame(self, frame: Frame) -> None:
        """One raw frame (the reader thread)."""
        if self.t0 is None:
            self.t0 = frame.timestamp_s
        self.t_last = frame.timestamp_s - self.t0
        with self._lock:
            if self.closed:
                return
            self.n_frames += 1
            if self.fmt == "mcap":
                self.writer.emit_frame(self.skin.name, frame.values, frame.timestamp_s, frame.index)
                return
            values = np.asarray(frame.values, dtype=np.float32)
            self._frames.append((values, self.t_last, frame.index))
            if len(self._frames) >= CHUNK or time.monotonic() - self._flushed >= 1.0:
                self._flush()

    def emit(self, contact: Any) -> None:
        """One contact (a single-contact pipeline)."""
        self.emit_contacts(contact.skin, contact.timestamp_s, [contact])

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Any]) -> None:
        """A frame's contacts (the pipeline's thread)."""
        with self._lock:
            if self.closed:
                return
            self.n_contacts += len(contacts)
            if self.fmt == "mcap":
                self.writer.emit_contacts(skin, timestamp_s, contacts)
            else:
                self._contacts.extend(c.to_json() for c in contacts)

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """A gesture (the pipeline's thread)."""
        with self._lock:
            if self.closed:
                return
            self.n_gestures += 1
            if self.fmt == "mcap":
                self.writer.emit_gesture(skin, timestamp_s, event)
            else:
                self._gestures.append(gesture_json(skin, event))

    def _flush(self) -> None:
        """Append what is waiting to an HDF5 recording (under ``_lock``).

        The frames first (``StreamAppender.append`` refuses a disk too full for them, keeping
        the file whole), then the contacts and gestures.
        """
        frames, self._frames = self._frames, []
        events = {"contacts": self._contacts, "gestures": self._gestures}
        self._contacts, self._gestures = [], []
        self._flushed = time.monotonic()
        if frames:
            self.writer.append(
                np.stack([f[0] for f in frames]),
                np.asarray([f[1] for f in frames]),
                np.asarray([f[2] for f in frames], dtype=np.int64),
            )
        for name, lines in events.items():
            if lines:
                ds = self._events[name]
                n = len(ds)
                ds.resize(n + len(lines), axis=0)
                ds[n:] = lines
        if any(events.values()):
            self.writer.file.flush()

    # ------------------------------------------------------------------ what it is, its end
    @property
    def n_bytes(self) -> int:
        """The file's size so far, bytes."""
        if self.fmt == "mcap":
            return self.writer.n_bytes
        try:
            return self.side.stat().st_size
        except OSError:
            return 0

    def status(self) -> dict[str, Any]:
        """What the page shows while it runs."""
        return {
            "running": True,
            "format": self.fmt,
            "name": self.path.name,
            "bytes": self.n_bytes,
            "seconds": round(self.t_last, 2),
            "frames": self.n_frames,
            "contacts": self.n_contacts,
            "gestures": self.n_gestures,
        }

    def close(self) -> None:
        """Write what is left, finish the file and give it its name."""
        import os

        with self._lock:
            if self.closed:
                return
            self.closed = True
            if self.fmt == "mcap":
                self.writer.close()
                return
            try:
                self._flush()
            finally:
                self.writer.close()
        if self.path.exists():  # never over a file (the name has the time: only by accident)
            raise FileExistsError(f"{self.path} appeared while recording; kept as {self.side}")
        os.replace(self.side, self.path)


class RecordTee(Sink):
    """The live pipeline's sink that hands contacts and gestures to the recording, if one runs."""

    name = "app-record-tee"

    def __init__(self) -> None:
        self.target: LiveRecorder | None = None

    def emit(self, contact: Any) -> None:
        """One contact."""
        if self.target is not None:
            self.target.emit(contact)

    def emit_contacts(self, skin: str, timestamp_s: float, contacts: Sequence[Any]) -> None:
        """A frame's contacts."""
        target = self.target
        if target is not None:
            target.emit_contacts(skin, timestamp_s, contacts)

    def emit_gesture(self, skin: str, timestamp_s: float, event: dict[str, Any]) -> None:
        """A gesture."""
        target = self.target
        if target is not None:
            target.emit_gesture(skin, timestamp_s, event)


class LiveRecording(WorkspaceState):
    """Part of ``Workspace``: the Record button.

    Attributes
    ----------
    recorder : LiveRecorder or None
        The recording running.
    record_tee : RecordTee
        The live pipeline's sink that hands its contacts and gestures to ``recorder``.
    last_recording : dict or None
        The summary of the last recording made.
    """

    recorder: LiveRecorder | None = None
    record_tee: RecordTee
    last_recording: dict[str, Any] | None = None

    def __init__(self, config: AppConfig, hub: Hub) -> None:
        super().__init__(config, hub)
        self.record_tee = RecordTee()

    def start_recording(self, fmt: str) -> dict[str, Any]:
        """Record the stream (and the live view's contacts and gestures) to ``fmt``."""
        if fmt not in FORMATS:
            raise ValueError(f"record to {' or '.join(FORMATS)}, not {fmt[:20]!r}")
        why = missing_format(fmt)
        if why is not None:
            raise ValueError(why)
        with self._lock:
            a = self._need_session()
            device = self._need_device()
            if self.recorder is not None:
                raise ValueError(f"already recording to {self.recorder.path.name}: stop it first")
            base = device.monitor.quiet_frames()
            if len(base) < 2:
                raise ValueError("the skin has sent too few untouched frames yet: try again")
            stamp = time.strftime("%Y%m%d-%H%M%S")
            path, k = a.folder.path / f"live-{stamp}.{fmt}", 1
            while path.exists():
                k += 1
                path = a.folder.path / f"live-{stamp}-{k}.{fmt}"
            src = device.source
            skin = SkinInfo(
                name="skin",
                vertices=np.asarray(a.mesh.vertices),
                faces=np.asarray(a.mesh.faces),
                n_tx=src.n_tx,
                n_rx=src.n_rx,
            )
            meta = {
                "source": device.name,
                "description": f"live stream recorded in the app, session {a.folder.id}",
            }
            self.recorder = LiveRecorder(path, fmt, skin, a.mesh, base, meta)
            self.record_tee.target = self.recorder
            self.last_recording = None
            self.message = f"recording to {path.name}"
            self._publish_state()
            return self.recorder.status()

    def record_frame(self, frame: Frame) -> None:
        """Hand a frame to the recording (the reader thread, under the lock)."""
        rec = self.recorder
        if rec is None:
            return
        try:
            rec.frame(frame)
        except OSError as exc:  # a full disk: end the file with what it holds
            log.warning("recording stopped: %s", exc)
            self._stop_recording(f"recording stopped: {exc}")
            self._publish_state()

    def recording_status(self) -> dict[str, Any]:
        """The recording running (size, duration, counts), or the last one made."""
        with self._lock:
            if self.recorder is not None:
                return self.recorder.status()
            return {"running": False, "last": self.last_recording, "formats": offered_formats()}

    def stop_recording(self) -> dict[str, Any]:
        """End the recording (nothing recorded is lost); its summary."""
        with self._lock:
            if self.recorder is None:
                raise ValueError("not recording")
            self._stop_recording()
            self._publish_state()
            return {"running": False, "last": self.last_recording}

    def _stop_recording(self, why: str | None = None) -> None:
        """Finish the recording, if one runs (on stop, disconnect, session close, exit)."""
        rec, self.recorder = self.recorder, None
        if rec is None:
            return
        self.record_tee.target = None
        summary = rec.status()
        summary["running"] = False
        try:
            rec.close()
        except OSError as exc:
            summary["error"] = str(exc)
            self.message = f"recording ended with an error: {exc}"
        else:
            summary["bytes"] = rec.path.stat().st_size
            counts = ", ".join(
                f"{summary[k]} {k[:-1] if summary[k] == 1 else k}"
                for k in ("frames", "contacts", "gestures")
            )
            self.message = (
                why or f"recorded {summary['seconds']:.1f} s to {rec.path.name} ({counts})"
            )
        self.last_recording = summary
