"""The command line with bad input: one clear line, a non-zero exit, and no file damaged.

The full table of cases is ``bench/cli_bad_input.py`` (docs/reliability.md); these are the
cases that once lost data or printed a traceback, plus Ctrl-C and SIGTERM in a subprocess.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from skinloc.calibration.session import SessionConfig, simulate_session
from skinloc.data.appender import RecordingAppender
from skinloc.data.recording import read_recording, write_recording
from skinloc.errors import Interrupted
from skinloc.sim.skin import SimulatedSkin
from tests._helpers import Lines, one_line_error, start_skinloc, stop_and_wait
from tests.conftest import make_recording

runner = CliRunner()
posix_only = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")


def run(*args: object):
    return runner.invoke(app_(), [str(a) for a in args])


def app_():
    from skinloc.cli.main import app

    return app


def digest(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


@pytest.fixture
def files(tmp_path):
    """A recording and a model trained on it."""
    cal, model = tmp_path / "cal.h5", tmp_path / "model.h5"
    write_recording(make_recording(12, 4), cal)
    res = run("train", cal, "--out", model, "--arch", "paper", "--epochs", "3")
    assert res.exit_code == 0, res.output
    return cal, model


# ------------------------------------------------------------------------ outputs over inputs
def test_train_refuses_to_write_over_its_recording(files):
    cal, _ = files
    before = digest(cal)
    one_line_error(run("train", cal, "--out", cal), "is also an input")
    # Another spelling of the same file, and --force does not change that.
    other = cal.parent / "." / cal.name
    one_line_error(run("train", cal, "--out", other, "--force"), "is also an input")
    assert digest(cal) == before and read_recording(cal).n_point_logs == 12


@posix_only
def test_train_refuses_a_hard_link_of_its_input(files):
    cal, _ = files
    link = cal.parent / "link.h5"
    os.link(cal, link)
    one_line_error(run("train", cal, "--out", link, "--force"), "is also an input")


def test_recalibration_refuses_to_replace_its_model(files):
    cal, model = files
    before = digest(model)
    one_line_error(run("train", cal, "--init", model, "--out", model), "is also an input")
    assert digest(model) == before


def test_existing_output_needs_force(files, tmp_path):
    cal, model = files
    other = tmp_path / "other.h5"
    write_recording(make_recording(3, 4), other)
    before = digest(other)
    err = one_line_error(run("train", cal, "--out", other, "--arch", "paper"), "--force")
    assert str(other) in err and digest(other) == before
    res = run("train", cal, "--out", other, "--arch", "paper", "--epochs", "3", "--force")
    assert res.exit_code == 0, res.output
    assert digest(other) != before


def test_convert_and_export_refuse_their_input(files):
    cal, model = files
    one_line_error(run("convert", cal, cal), "is also an input")
    one_line_error(run("export", model, "--onnx", model), "is also an input")
    one_line_error(run("convert", cal, model), "exists", "--force")


def test_run_refuses_a_sink_file_over_the_model(files):
    _, model = files
    before = digest(model)
    one_line_error(run("run", "--model", model, "--sink", f"jsonl:{model}"), "is also an input")
    assert digest(model) == before


# ------------------------------------------------------------------------ where outputs go
def test_missing_folder_is_not_created(files, tmp_path):
    cal, _ = files
    out = tmp_path / "missing" / "deeper" / "m.h5"
    err = one_line_error(run("train", cal, "--out", out), "does not exist")
    assert str(out) in err and not (tmp_path / "missing").exists()


@pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs /proc")
def test_unwritable_folder_names_the_users_path(files):
    cal, _ = files
    err = one_line_error(run("convert", cal, "/proc/x.mat"), "cannot write /proc/x.mat")
    assert ".tmp" not in err and "partial" not in err


@posix_only
def test_written_files_follow_the_umask(tmp_path):
    old = os.umask(0o022)
    try:
        path = tmp_path / "r.h5"
        write_recording(make_recording(2, 3), path)
    finally:
        os.umask(old)
    assert path.stat().st_mode & 0o777 == 0o644
    assert not list(tmp_path.glob(".*.tmp"))


# ------------------------------------------------------------------------ bad values
def test_info_on_a_folder(tmp_path):
    one_line_error(run("info", tmp_path), "is a folder")


def test_nan_error_names_the_file(tmp_path):
    path = tmp_path / "nan.h5"
    write_recording(make_recording(3, 4), path)
    with h5py.File(path, "a") as f:
        frames = f["point_logs/frames"][()]
        frames[1, 2, 3] = np.inf
        f["point_logs/frames"][...] = frames
    one_line_error(run("info", path), str(path), "NaN or infinite")


def test_negative_seed_names_the_option(tmp_path):
    res = run("simulate", "--seed", "-1", "--out", tmp_path / "x.h5")
    assert res.exit_code == 2 and "--seed" in res.output


def test_absurd_point_count_is_refused_before_any_work(tmp_path):
    err = one_line_error(
        run("simulate", "--points", "100000000", "--out", tmp_path / "x.h5"), "GiB"
    )
    assert "--points" in err and not list(tmp_path.iterdir())


def test_zero_area_mesh(tmp_path):
    mesh = tmp_path / "flat.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    one_line_error(run("simulate", "--mesh", mesh, "--out", tmp_path / "x.h5"), "zero area")


def test_training_on_one_point_log_warns(tmp_path):
    one = tmp_path / "one.h5"
    write_recording(make_recording(1, 4), one)
    res = run("train", one, "--out", tmp_path / "m.h5", "--arch", "paper", "--epochs", "2")
    assert res.exit_code == 0, res.output
    assert "warning: training on 1 point log" in res.output


def test_collect_new_over_a_recording_needs_force(files):
    cal, _ = files
    before = digest(cal)
    one_line_error(run("collect", "--source", "sim", "--new", "--out", cal), "--force")
    assert digest(cal) == before


# ------------------------------------------------------------------------ appending
def test_appender_writes_what_write_recording_writes(tmp_path):
    rec = make_recording(5, 4)
    head = rec.subset(slice(0, 0))
    with RecordingAppender(head, tmp_path / "a.h5") as app:
        for i in range(rec.n_point_logs):
            app.append(rec.targets[i], rec.frames[i], np.arange(4) * 0.01 + i)
            # Readable at every step: the file always holds the complete point logs.
            assert read_recording(tmp_path / "a.h5").n_point_logs == i + 1
    got = read_recording(tmp_path / "a.h5")
    np.testing.assert_allclose(got.frames, rec.frames)
    np.testing.assert_allclose(got.targets, rec.targets)
    assert got.frame_times.shape == (5, 4)
    with pytest.raises(OSError, match="cannot write"):  # never replaces a file
        RecordingAppender(head, tmp_path / "a.h5")


def test_appender_drops_a_point_log_cut_by_ctrl_c(tmp_path, monkeypatch):
    rec = make_recording(3, 4)
    app = RecordingAppender(rec.subset(slice(0, 2)), tmp_path / "a.h5")
    original = h5py.Dataset.__setitem__

    def interrupted(self, key, value):
        if self.name.endswith("frames"):
            raise KeyboardInterrupt
        original(self, key, value)

    monkeypatch.setattr(h5py.Dataset, "__setitem__", interrupted)
    with pytest.raises(KeyboardInterrupt):
        app.append(rec.targets[2], rec.frames[2])
    monkeypatch.undo()
    app.close()
    assert read_recording(tmp_path / "a.h5").n_point_logs == 2


def test_interrupted_simulation_keeps_the_old_file_and_the_complete_part(tmp_path, cone):
    out = tmp_path / "keep.h5"
    out.write_bytes(b"an earlier recording")

    def stop_at_3(done: int, total: int) -> None:
        if done == 3:
            raise KeyboardInterrupt

    skin = SimulatedSkin(cone, random_state=0)
    cfg = SessionConfig(n_points=6, samples_per_touch=5, n_baseline_frames=10)
    with pytest.raises(Interrupted, match="keep.partial.h5") as info:
        simulate_session(skin, cone, out, cfg, progress=stop_at_3)
    assert "3 complete point logs" in str(info.value) and "unchanged" in str(info.value)
    assert out.read_bytes() == b"an earlier recording"
    part = read_recording(tmp_path / "keep.partial.h5")
    assert part.n_point_logs == 3 and len(part.meta["true_contacts"]) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.h5", "keep.partial.h5"]
    # A second interrupted run does not overwrite the first one's partial file.
    with pytest.raises(Interrupted, match="keep.partial-2.h5"):
        simulate_session(SimulatedSkin(cone, random_state=0), cone, out, cfg, progress=stop_at_3)


def test_signal_in_a_weakref_callback_is_raised_at_the_next_step():
    from skinloc.cli import common as cli

    class Code:
        co_filename = "/usr/lib/python3.11/weakref.py"

    class Frame:
        f_code = Code()

    cli._signals.clear()
    cli._on_signal(signal.SIGINT, Frame())  # swallowed there: only recorded
    with pytest.raises(KeyboardInterrupt):
        cli.check_interrupt()
    cli.check_interrupt()  # raised once, not again while the job unwinds
    cli._signals.clear()


# ------------------------------------------------------------------------ signals, for real
SIMULATE_LONG = ["simulate", "--points", "3000", "--samples", "40", "--mode", "random"]


@posix_only
@pytest.mark.parametrize(
    ("argv", "sig", "code", "says"),
    [
        # --mode random: spreading 3000 targets evenly takes ~10 CPU-s before the job starts
        (SIMULATE_LONG, signal.SIGINT, 130, "partial"),
        (SIMULATE_LONG, signal.SIGTERM, 143, "partial"),
        (
            ["collect", "--source", "sim", "--points", "1000", "--samples", "20"],
            signal.SIGINT,
            130,
            "resume",
        ),
    ],
)
@pytest.mark.slow  # a long job stopped by a signal
def test_one_signal_stops_a_long_job_cleanly(tmp_path, argv, sig, code, says):
    """The signal is sent once the job says it is under way (its first progress line), and the
    job is sized so that it is still far from its end then, whatever the machine's load."""
    out = tmp_path / "out.h5"
    extra = ["--force"] if argv[0] == "simulate" else []
    if argv[0] == "simulate":
        out.write_bytes(b"keep me")
    proc = start_skinloc(
        *argv, "--out", out, *extra, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
    )
    try:
        err = Lines(proc.stderr)
        # Off a terminal the first progress line comes after 2 s of the job's main phase.
        total = argv[argv.index("--points") + 1]
        err.wait_for(f"/{total} (", "its first progress line", timeout_s=180.0)
        stop_and_wait(proc, sig, argv[0])
        text = err.rest()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == code, text
    assert "Traceback" not in text and "Exception ignored" not in text, text
    assert "interrupted" in text and says in text, text
    assert f"{total}/{total}" not in text, text  # stopped in the phase under test
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    if argv[0] == "simulate":
        assert out.read_bytes() == b"keep me"
        assert 1 <= read_recording(tmp_path / "out.partial.h5").n_point_logs < int(total)
    else:
        assert 1 <= read_recording(out).n_point_logs < int(total)


# ------------------------------------------------------------------------ off a terminal
def test_progress_off_a_terminal_prints_plain_lines(monkeypatch, capsys):
    """A long job piped to a file is not silent: a line after 2 s, then every 10 s."""
    from skinloc.cli import common as cli

    clock = iter([0.0, 1.0, 2.5, 5.0, 13.0, 14.0])
    monkeypatch.setattr(time, "monotonic", lambda: next(clock))
    monkeypatch.delenv("SKINLOC_PROGRESS", raising=False)
    cli._signals.clear()
    with cli.progress_steps() as step:
        for done in range(1, 6):
            step("work", done, 5)
    err = capsys.readouterr().err
    assert "work: 2/5 (2 s)" in err and "work: 4/5 (13 s)" in err and "work: 5/5" in err
    assert "work: 3/5" not in err


def test_wide_tables_are_not_cut_off_a_terminal(rec_wide, monkeypatch):
    monkeypatch.delenv("COLUMNS", raising=False)
    res = run("snr", rec_wide)
    assert res.exit_code == 0, res.output
    # At rich's default 80 columns the corner cell of this 21 x 12 grid wraps.
    assert "TX \\ RX" in res.output and "…" not in res.output


@pytest.fixture
def rec_wide(tmp_path):
    path = tmp_path / "wide.h5"
    write_recording(make_recording(3, 4, n_tx=21, n_rx=12), path)
    return path
