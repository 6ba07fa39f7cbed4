"""Replay recorded frames as a frame source, and the raw-stream part of a recording.

``skinloc record`` writes a normal recording (mesh, baseline) plus a group ``stream`` holding
the raw frames in arrival order: ``frames (n, n_sensors) float32``, ``times_s (n,)`` and
``index (n,)`` (the device's frame counter). ``ReplaySource`` plays that stream back, or, for a
recording without one, the baseline followed by every point log.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.errors import FrameTimeoutError
from skinloc.files import atomic_write
from skinloc.h5layout import read_stream, stream_summary  # re-exported: the stream's readers
from skinloc.sources.base import Frame, FrameSource, SourceOptions

log = logging.getLogger(__name__)

__all__ = [
    "ArrayReplaySource",
    "ReplaySource",
    "read_stream",
    "stream_summary",
    "write_stream_recording",
]


def write_stream_recording(
    path: str | Path,
    *,
    n_tx: int,
    n_rx: int,
    mesh,
    baseline_frames: np.ndarray,
    frames: np.ndarray,
    times_s: np.ndarray,
    index: np.ndarray,
    meta: dict[str, Any] | None = None,
) -> None:
    """Write a recording with no point logs and the raw stream, atomically.

    Parameters
    ----------
    path : str or Path
        HDF5 file to write.
    n_tx, n_rx : int
        Grid.
    mesh : trimesh.Trimesh
        Skin surface, m.
    baseline_frames : (m, n_tx * n_rx) float
        No-touch capture, raw counts.
    frames : (n, n_tx * n_rx) float
        The stream, raw counts.
    times_s : (n,) float
        Arrival time of each frame since the first, s.
    index : (n,) int
        Frame counter of each frame (gaps are lost frames).
    meta : dict, optional
        Stored with the recording.
    """
    from skinloc.data.appender import StreamAppender

    n = n_tx * n_rx
    frames = np.asarray(frames, dtype=np.float32).reshape(-1, n)
    times_s = np.asarray(times_s, dtype=np.float64).reshape(-1)
    index = np.asarray(index, dtype=np.int64).reshape(-1)
    if not len(frames) == len(times_s) == len(index):
        raise ValueError(
            f"stream lengths differ: {len(frames)} frames, {len(times_s)} times, "
            f"{len(index)} indices"
        )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    header = dict(n_tx=n_tx, n_rx=n_rx, mesh=mesh, baseline_frames=baseline_frames, meta=meta)

    def write(tmp: Path) -> None:
        with StreamAppender(tmp, **header, chunk=4096, exclusive=False) as out:
            out.append(frames, times_s, index)

    atomic_write(path, write)


class ArrayReplaySource(FrameSource):
    """Play back frames held in memory, in order: what every file replay shares.

    Subclasses fill ``_frames (n, n_sensors) float32`` (raw counts), ``_times (n,)`` (s),
    ``_index (n,)`` (frame counters), ``n_tx``, ``n_rx`` and ``loop`` in their ``__init__``.
    ``read`` returns the next frame (a copy), starts again at the end when ``loop`` is set, and
    raises ``FrameTimeoutError`` at the end otherwise (and always for an empty file). Each pass
    of a loop goes on in time: its timestamps are the recorded ones shifted by the passes
    before (one frame period after the last frame), so time never runs back and a replay paced
    by its timestamps keeps the recorded rate on every pass; the indices repeat.
    """

    #: a file, not a live device: the runner paces it by its timestamps (or runs it ``--fast``)
    is_replay = True
    #: what the frames come from, for the end-of-file message
    _what = "recording"
    _frames: np.ndarray
    _times: np.ndarray
    _index: np.ndarray
    loop: bool = False
    _pos: int = 0
    _connected: bool = False
    _t_shift: float = 0.0  # s added to the recorded times: the passes of a loop before this one

    @property
    def is_connected(self) -> bool:
        """Whether ``read`` may be called."""
        return self._connected

    def _connect(self) -> None:
        self._connected = True

    def _disconnect(self) -> None:
        self._connected = False

    def _read(self, timeout_s: float) -> Frame:
        if self._pos >= len(self._frames):
            if not self.loop or not len(self._frames):
                raise FrameTimeoutError(f"{self.name}: the {self._what} has no more frames")
            self._pos = 0
            self._t_shift += self._pass_s()
        k = self._pos
        self._pos += 1
        return Frame(
            values=np.array(self._frames[k], dtype=np.float32),
            timestamp_s=float(self._times[k]) + self._t_shift,
            index=int(self._index[k]),
        )

    def _pass_s(self) -> float:
        """How long one pass lasts, s: first frame to last plus one mean frame period.

        A single frame's pass lasts 0.01 s.
        """
        t = self._times
        n = len(t)
        span = float(t[-1] - t[0]) if n > 1 else 0.0
        period = span / (n - 1) if n > 1 and span > 0 else 0.01
        return span + period


class ReplaySource(ArrayReplaySource):
    """Play back the frames of a recording.

    Parameters
    ----------
    path : str or Path
        A recording (``skinloc record`` stream, or any calibration recording).
    loop : bool, default=False
        Start again at the end instead of timing out.

    Examples
    --------
    >>> src = ReplaySource("stream.h5")  # doctest: +SKIP
    """

    def __init__(self, path: str | Path, *, loop: bool = False) -> None:
        from skinloc.data.recording import read_recording

        self.path = Path(path)
        rec = read_recording(self.path)
        self.n_tx, self.n_rx = rec.n_tx, rec.n_rx
        stream = read_stream(self.path) if self.path.suffix.lower() in (".h5", ".hdf5") else None
        if stream is not None:
            self._frames, self._times, self._index = stream
        else:
            frames = np.concatenate(
                [rec.baseline_frames, rec.frames.reshape(-1, rec.n_sensors)]
            ).astype(np.float32)
            self._frames = frames
            self._times = np.arange(len(frames)) / 100.0
            self._index = np.arange(len(frames))
        self.loop = loop
        self._pos = 0
        self._connected = False

    @classmethod
    def from_options(cls, options: SourceOptions, mesh: Any = None) -> ReplaySource:
        """The recording ``options`` name (``skinloc.sources.base.make_source``)."""
        return cls(options.source, loop=options.loop)

    @property
    def name(self) -> str:
        """The file."""
        return str(self.path)
