"""``skinloc.files.atomic_write``: the old file or the new one, never a half, never litter."""

from __future__ import annotations

import os
import stat

import pytest

from skinloc import files


def test_a_write_replaces_the_file_with_normal_permissions(tmp_path):
    out = tmp_path / "a.txt"
    out.write_text("old")
    files.atomic_write(out, lambda p: p.write_text("new"))
    assert out.read_text() == "new" and [p.name for p in tmp_path.iterdir()] == ["a.txt"]
    mask = os.umask(0o022)
    os.umask(mask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o666 & ~mask  # not mkstemp's 0600


@pytest.mark.parametrize("where", ["writing", "just after the temporary file was made"])
def test_an_interruption_keeps_the_old_file_and_leaves_no_temporary_one(
    tmp_path, monkeypatch, where
):
    out = tmp_path / "a.txt"
    out.write_text("old")

    def write(p):
        p.write_text("half")
        raise KeyboardInterrupt

    if where != "writing":  # the Ctrl-C arrives as soon as the file exists
        close = os.close

        def close_then_interrupt(fd: int) -> None:
            close(fd)
            raise KeyboardInterrupt

        monkeypatch.setattr(files.os, "close", close_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        files.atomic_write(out, write)
    monkeypatch.undo()
    assert out.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["a.txt"]


# ------------------------------------------------------------------ one output, one writer
def _hold_claim_in_another_process(path):
    """A child process that claims ``path`` and holds it until its stdin closes."""
    import subprocess
    import sys

    code = (
        "import sys; from skinloc.files import claim_output; c = claim_output(sys.argv[1]); "
        "print('held', flush=True); sys.stdin.read(); c.release()"
    )
    env = {**os.environ, "PYTHONPATH": str(files.__file__).rsplit("/skinloc/", 1)[0]}
    proc = subprocess.Popen(
        [sys.executable, "-c", code, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_claimed_output_is_refused_to_a_second_writer_and_free_after(tmp_path):
    out = tmp_path / "cal.h5"
    holder = _hold_claim_in_another_process(out)
    try:
        with pytest.raises(files.OutputBusyError, match=rf"pid {holder.pid}\) is writing"):
            files.claim_output(out)
    finally:
        holder.stdin.close()
        holder.wait(timeout=60)
    claim = files.claim_output(out)  # released: free again
    claim.release()
    claim.release()  # idempotent
    assert list(tmp_path.iterdir()) == []  # no lock file left behind


def test_a_claim_dies_with_its_process(tmp_path):
    out = tmp_path / "cal.h5"
    holder = _hold_claim_in_another_process(out)
    holder.kill()
    holder.wait(timeout=60)
    files.claim_output(out).release()  # the kernel dropped the lock of the killed process
