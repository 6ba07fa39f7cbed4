"""A full disk: ``record`` keeps the frames that fit, and every command says so in one line.

Each test mounts a small tmpfs (root only; skipped elsewhere), so the disk really fills.
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from typer.testing import CliRunner

from skinloc.data.recording import read_recording
from skinloc.sources.replay import read_stream

#: A progress line off a terminal (a slow machine prints them after 2 s): not part of the error.
PROGRESS = re.compile(r"^[^:]+: \d+/\d+ \(\d+ s\)$")


def one_line_error(res, *needles: str) -> str:
    """The one ``error:`` line of a failed command (progress lines aside)."""
    assert res.exit_code not in (0, None), res.output
    assert "Traceback" not in res.output
    lines = [ln for ln in res.output.strip().splitlines() if not PROGRESS.match(ln)]
    assert len(lines) == 1 and lines[0].startswith("error:"), res.output
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


pytestmark = pytest.mark.skipif(
    sys.platform != "linux" or os.geteuid() != 0, reason="mounts a tmpfs: Linux, as root"
)


@contextlib.contextmanager
def small_disk(folder: Path, kib: int) -> Iterator[Path]:
    """``folder`` as a tmpfs of ``kib`` KiB for the block."""
    folder.mkdir()
    res = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={kib}k", "tmpfs", str(folder)],
        capture_output=True,
        text=True,
    )
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", str(folder)], check=True)


def run(*args: object):
    from skinloc.cli.main import app

    return CliRunner().invoke(app, [str(a) for a in args])


def test_record_keeps_what_fit_on_a_full_disk_and_says_so(tmp_path):
    # the header alone (mesh, surface points, baseline) takes most of a stream this short
    probe = tmp_path / "probe.h5"
    assert run("record", "--source", "sim", "--seconds", "0.5", "--out", probe).exit_code == 0
    room = probe.stat().st_size // 1024 + 100  # the header and about 100 KiB of stream
    with small_disk(tmp_path / "disk", room) as disk:
        out = disk / "stream.h5"
        err = one_line_error(
            run("record", "--source", "sim", "--seconds", "30", "--out", out),
            "no space left on device",
            f"{out} holds the first",
        )
        frames, times, index = read_stream(out)
        assert 100 < len(frames) < 3000 and f"the first {len(frames)} stream frames" in err
        assert len(times) == len(index) == len(frames)
        assert read_recording(out).baseline_frames.shape == (50, 64)
        assert sorted(p.name for p in disk.iterdir()) == ["stream.h5"]


@pytest.mark.parametrize(
    "args",
    [
        ["record", "--source", "sim", "--seconds", "5"],
        ["simulate", "--points", "40"],
        ["train", "{rec}"],
    ],
    ids=["record", "simulate", "train"],
)
def test_a_disk_too_small_is_one_line_and_leaves_nothing(tmp_path, args):
    from skinloc.data.recording import write_recording
    from tests.conftest import make_recording

    rec = tmp_path / "cal.h5"
    write_recording(make_recording(12, 4), rec)
    with small_disk(tmp_path / "disk", 200) as disk:
        out = disk / "out.h5"
        argv = [a.format(rec=rec) for a in args]
        one_line_error(run(*argv, "--out", out), f"cannot write {out}: no space left on device")
        assert list(disk.iterdir()) == []
