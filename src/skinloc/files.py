"""Writing files so that nothing a user has is ever lost: atomic replacement, free side names.

Every file skinloc writes goes through ``atomic_write`` (a temporary file in the same folder,
synced, then renamed over the target), so a crash or a Ctrl-C leaves the old file or the new one,
never half of one.
"""

from __future__ import annotations

import errno
import os
import re
import secrets
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from skinloc.errors import Interrupted, SkinlocError

__all__ = [
    "OutputBusyError",
    "atomic_write",
    "claim_output",
    "cannot_write",
    "os_error_line",
    "os_error_reason",
    "side_path",
    "written_through_side",
]


#: ``errno`` values that mean the disk refused a write (full, over quota, read-only, failing).
_DISK_ERRORS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO})


def os_error_reason(exc: OSError) -> str:
    """Why ``exc`` happened, in a few words on one line (``no space left on device``).

    HDF5's errors are many lines holding the system's ``errno = N``; an error that already
    names its file (``cannot write X: why``) gives its own reason.
    """
    errno = exc.errno or _errno_of(exc)
    if errno:
        why = os.strerror(errno)
    else:
        why = (exc.strerror or str(exc) or type(exc).__name__).strip().splitlines()[0]
        why = why.rpartition(": ")[2] if why.startswith("cannot write ") else why
    return why[:1].lower() + why[1:]


def os_error_line(exc: OSError) -> str:
    """``exc`` as one line: its message when it is one line, else its file and reason."""
    text = str(exc)
    if "\n" not in text and not text.startswith("[Errno"):
        return text
    found = re.search(r"filename = '([^']*)'", text)
    name = exc.filename or (found.group(1) if found else None)
    return f"{name}: {os_error_reason(exc)}" if name else os_error_reason(exc)


def cannot_write(path: Path, exc: OSError) -> OSError:
    """``exc`` reworded to name the file the user asked for, not a temporary one.

    The result keeps ``exc``'s ``errno`` (a full disk stays recognisable).
    """
    out = OSError(f"cannot write {path}: {os_error_reason(exc)}")
    out.errno = exc.errno or _errno_of(exc)
    return out


def _errno_of(exc: OSError) -> int | None:
    found = re.search(r"errno = (\d+)", str(exc))
    return int(found.group(1)) if found else None


def atomic_write(path: str | Path, write: Callable[[Path], object]) -> None:
    """Write through a temporary file in the same folder, then rename over ``path``.

    The folder must exist (a typo in a path should not create folders). The result gets the
    permissions of a normally created file (0666 minus the umask), not ``mkstemp``'s 0600.
    Errors name ``path``; an interruption (Ctrl-C, SIGTERM turned into ``KeyboardInterrupt``)
    removes the temporary file and leaves any old ``path`` as it was.
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: folder {path.parent} does not exist")
    # Named before it is made, not by mkstemp: a Ctrl-C landing just after the file was
    # created (inside mkstemp, or before the next line) would leave it behind.
    tmp = path.parent / f".{path.name}.{secrets.token_hex(6)}.tmp"
    try:
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))  # minus the umask
    except OSError as exc:  # FileExistsError included: that file is not ours to remove
        raise cannot_write(path, exc) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:
        write(tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise cannot_write(path, exc) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def side_path(path: str | Path, tag: str) -> Path:
    """A free file name next to ``path`` saying what it holds: ``cal.partial.h5``.

    If that exists, ``cal.partial-2.h5`` and so on.
    """
    path = Path(path)
    suffix = path.suffix if path.suffix.lower() in (".h5", ".hdf5") else ".h5"
    for k in range(1, 10_000):
        candidate = path.with_name(f"{path.stem}.{tag}{'' if k == 1 else f'-{k}'}{suffix}")
        if not candidate.exists():
            return candidate
    raise OSError(f"no free file name for the {tag} side file of {path}")


@contextmanager
def written_through_side(
    side: Path, path: Path, kept: Callable[[], tuple[int, int]], what: str, one: str
) -> Iterator[None]:
    """Write into ``side``; rename it over ``path`` only when the block completes.

    Ctrl-C (``KeyboardInterrupt``) keeps ``side`` with what is complete in it and raises
    ``Interrupted`` naming it (nothing complete: ``side`` is removed); any other error removes
    ``side``. ``path`` is never half replaced.

    Parameters
    ----------
    side, path : Path
        The side file the block writes, and the file it becomes.
    kept : callable
        ``() -> (complete items in side, items planned)``, asked on an interruption.
    what, one : str
        The items' name in messages, plural and singular (``"point logs"``, ``"point log"``).
    """
    try:
        yield
    except KeyboardInterrupt:
        n, total = kept()
        target = f"{path} is unchanged" if path.exists() else f"{path} was not written"
        if n == 0:
            side.unlink(missing_ok=True)
            raise Interrupted(f"no {one} was complete; {target}") from None
        raise Interrupted(
            f"kept the {n} complete {what} (of {total}) in {side}; {target}"
        ) from None
    except OSError as exc:
        side.unlink(missing_ok=True)
        if exc.errno in _DISK_ERRORS:  # a full disk: name the file the user asked for
            raise cannot_write(path, exc) from None
        raise
    except BaseException:
        side.unlink(missing_ok=True)
        raise
    os.replace(side, path)


class OutputBusyError(SkinlocError):
    """Another process is writing the same output file (its claim is held)."""


def _lock_path(path: Path) -> Path:
    return path.parent / f".{path.name}.lock"


class OutputClaim:
    """An exclusive claim on an output path, held by this process until ``release``.

    The claim is an advisory ``flock`` on a hidden file next to the output
    (``.NAME.lock``), removed on release. Two skinloc processes asked to write one file can
    therefore never both run: the second is refused before it reads, checks or writes
    anything, so neither can delete the other's side file or silently replace its result.
    Where ``fcntl`` does not exist (Windows) the claim is a no-op.
    """

    def __init__(self, path: Path, fd: int | None) -> None:
        self.path = path
        self._fd = fd

    def release(self) -> None:
        """Give the claim up (idempotent); the lock file is removed first, then unlocked."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            _lock_path(self.path).unlink(missing_ok=True)
        except OSError:
            pass
        os.close(fd)  # closing the descriptor drops the flock


def claim_output(path: str | Path) -> OutputClaim:
    """Claim ``path`` for writing by this process, or raise ``OutputBusyError``.

    Parameters
    ----------
    path : str or Path
        The file (or folder) a command is about to write. Its folder must exist.

    Returns
    -------
    OutputClaim
        Held until ``release()`` (or the process ends: the kernel drops the lock).

    Raises
    ------
    OutputBusyError
        Another process holds the claim; the message names it and its process id.
    """
    path = Path(path)
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return OutputClaim(path, None)
    lock = _lock_path(path)
    while True:
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise cannot_write(path, exc) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.read(fd, 32).decode(errors="replace").strip() or "unknown"
            finally:
                os.close(fd)
            raise OutputBusyError(
                f"another process (pid {holder}) is writing {path}: wait for it to end, or "
                f"choose another output"
            ) from None
        # The holder before us may have removed the file between our open and our lock: a
        # lock on a removed inode guards nothing, so take the one the path names now.
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            same = False
        if same:
            os.ftruncate(fd, 0)
            os.pwrite(fd, str(os.getpid()).encode(), 0)
            return OutputClaim(path, fd)
        os.close(fd)
