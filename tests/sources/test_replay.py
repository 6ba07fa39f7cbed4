"""Replaying a recording: a ``skinloc record`` stream as it came, a calibration as frames."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.data.recording import write_recording
from skinloc.errors import FrameTimeoutError
from skinloc.geometry.mesh import cone_skin
from skinloc.sources.replay import ReplaySource, read_stream, stream_summary, write_stream_recording
from tests.conftest import make_recording


def _stream(path, n: int = 6, lost: int = 0):
    frames = 8000.0 + np.arange(n * 4, dtype=float).reshape(n, 4)
    index = np.arange(n) + np.where(np.arange(n) >= n // 2, lost, 0)  # a gap in the counter
    write_stream_recording(path, n_tx=2, n_rx=2, mesh=cone_skin(), baseline_frames=frames[:3],
                           frames=frames, times_s=np.arange(n) / 100.0, index=index)  # fmt: skip
    return frames, index


def test_a_stream_replays_frame_by_frame_with_its_times_and_counters(tmp_path):
    path = tmp_path / "s.h5"
    frames, index = _stream(path)
    got = read_stream(path)
    assert got is not None and np.array_equal(got[0], frames) and np.array_equal(got[2], index)
    with ReplaySource(path) as src:
        assert (src.n_tx, src.n_rx) == (2, 2)
        out = [src.read(1.0) for _ in range(6)]
        with pytest.raises(FrameTimeoutError, match="no more frames"):
            src.read(1.0)  # the end of a replay without --loop
    assert [f.index for f in out] == index.tolist()
    assert [f.timestamp_s for f in out] == pytest.approx(np.arange(6) / 100.0)
    assert np.array_equal(np.stack([f.values for f in out]), frames)


def test_loop_starts_again_at_the_end(tmp_path):
    path = tmp_path / "s.h5"
    _stream(path, n=3)
    with ReplaySource(path, loop=True) as src:
        assert [src.read(1.0).index for _ in range(7)] == [0, 1, 2, 0, 1, 2, 0]


def test_the_summary_counts_the_frames_the_counter_says_were_lost(tmp_path):
    path = tmp_path / "s.h5"
    _stream(path, n=6, lost=2)
    s = stream_summary(path)
    assert s["stream_frames"] == 6 and s["stream_lost_frames"] == 2
    assert s["stream_seconds"] == pytest.approx(0.05) and s["stream_rate_hz"] == pytest.approx(100)


def test_a_calibration_recording_replays_its_baseline_then_its_touches(tmp_path):
    path = tmp_path / "cal.h5"
    rec = make_recording(n_points=3, samples=2)
    write_recording(rec, path)
    assert read_stream(path) is None and stream_summary(path) is None  # no raw stream
    with ReplaySource(path) as src:
        n = len(rec.baseline_frames) + 3 * 2
        got = np.stack([src.read(1.0).values for _ in range(n)])
    assert got[: len(rec.baseline_frames)] == pytest.approx(rec.baseline_frames)
    assert got[len(rec.baseline_frames) :] == pytest.approx(rec.frames.reshape(6, -1))
