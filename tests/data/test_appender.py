"""The calibration appender changes a recording in place: it never rewrites the whole file."""

from __future__ import annotations

import numpy as np
import pytest

from skinloc.data.appender import RecordingAppender
from skinloc.data.recording import read_recording, write_recording
from skinloc.errors import RecordingError
from tests.conftest import make_recording


def test_every_change_is_made_in_place_and_read_back(tmp_path):
    rec = make_recording(5, 4)
    path = tmp_path / "a.h5"
    head = rec.subset(slice(0, 0))
    head.planned_targets = rec.targets.copy()
    app = RecordingAppender(head, path)
    inode = path.stat().st_ino  # a rewrite (a temporary file renamed over it) changes it
    times = np.arange(20.0).reshape(5, 4)
    for i in range(5):
        app.append(rec.targets[i], rec.frames[i], times[i])
    app.remove(1)
    keep = [0, 2, 3, 4]
    plan = rec.targets[[0, 2, 3, 4, 1]]
    app.set_planned_targets(plan)
    app.set_meta({**rec.meta, "app": {"flags": [[], ["weak"], [], []]}})
    app.close()
    assert path.stat().st_ino == inode
    got = read_recording(path)
    np.testing.assert_array_equal(got.frames, rec.frames[keep])
    np.testing.assert_array_equal(got.targets, rec.targets[keep])
    np.testing.assert_array_equal(got.frame_times, times[keep])
    np.testing.assert_array_equal(got.planned_targets, plan)
    assert got.meta["app"] == {"flags": [[], ["weak"], [], []]}
    assert "created" in got.meta and "modified" in got.meta
    # A shorter plan, then none.
    app = RecordingAppender.reopen(path)
    app.set_planned_targets(plan[:2])
    np.testing.assert_array_equal(read_recording(path).planned_targets, plan[:2])
    app.set_planned_targets(None)
    assert read_recording(path).planned_targets is None
    assert path.stat().st_ino == inode


def test_an_append_merges_its_meta_in_the_same_write(tmp_path):
    rec = make_recording(2, 4)
    path = tmp_path / "a.h5"
    head = rec.subset(slice(0, 0))
    app = RecordingAppender(head, path)
    created = read_recording(path).meta["created"]
    app.append(rec.targets[0], rec.frames[0], meta={"probe_depths_m": [0.002]})
    assert read_recording(path).meta["probe_depths_m"] == [0.002]
    app.append(rec.targets[1], rec.frames[1], meta={"probe_depths_m": [0.002, 0.003]})
    app.append(rec.targets[1], rec.frames[1])  # no meta: what is there stays
    got = read_recording(path)
    assert got.meta["probe_depths_m"] == [0.002, 0.003] and got.meta["created"] == created


def test_a_file_written_whole_is_converted_once_then_appended_to(tmp_path):
    rec = make_recording(3, 4)
    rec.planned_targets = np.concatenate([rec.targets, rec.targets[:1]])
    path = tmp_path / "old.h5"
    write_recording(rec, path)  # as an older session or an imported recording
    app = RecordingAppender.reopen(path)
    inode = path.stat().st_ino
    assert app.n_point_logs == 3
    app.append(rec.targets[0], rec.frames[0])
    app.remove(0)
    assert path.stat().st_ino == inode
    got = read_recording(path)
    np.testing.assert_array_equal(got.frames, rec.frames[[1, 2, 0]])
    np.testing.assert_array_equal(got.planned_targets, rec.planned_targets)
    assert got.meta["created"] == read_recording(path).meta["created"]


def test_bad_changes_are_refused(tmp_path):
    rec = make_recording(2, 4)
    app = RecordingAppender(rec, tmp_path / "a.h5")
    with pytest.raises(IndexError, match="no point log 2"):
        app.remove(2)
    with pytest.raises(RecordingError, match="shape"):
        app.append(rec.targets[0], rec.frames[0][:3])
    app.close()
    with pytest.raises(RecordingError, match="closed"):
        app.append(rec.targets[0], rec.frames[0])
    assert read_recording(tmp_path / "a.h5").n_point_logs == 2


def test_replace_swaps_an_existing_file_for_the_new_header(tmp_path):
    path = tmp_path / "a.h5"
    write_recording(make_recording(4, 4), path)
    head = make_recording(1, 4, random_state=3).subset(slice(0, 0))
    RecordingAppender(head, path, replace=True)
    assert read_recording(path).n_point_logs == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.h5"]  # no temporary file left


def test_a_change_waits_for_a_reader_that_holds_the_file(tmp_path):
    """HDF5 locks a file while another process reads it; the appender waits, not fails."""
    import subprocess
    import sys

    rec = make_recording(2, 4)
    path = tmp_path / "a.h5"
    app = RecordingAppender(rec.subset(slice(0, 1)), path)
    reader = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import h5py, sys, time\n"
            f"f = h5py.File({str(path)!r}, 'r')\n"
            "print('open', flush=True)\n"
            "time.sleep(0.5)\n"
            "f.close()\n",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert reader.stdout.readline().strip() == "open"
        app.append(rec.targets[1], rec.frames[1])  # refused at once before the wait
    finally:
        reader.wait()
    assert read_recording(path).n_point_logs == 2
