"""Writing files so that nothing a user has is ever lost: atomic replacement, free side names.

Every file skinloc writes goes through ``atomic_write`` (a temporary file in the same folder,
synced, then renamed over the target), so a crash or a Ctrl-C leaves the old file or the new one,
never half of one.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from skinloc.errors import Interrupted

__all__ = ["atomic_write", "cannot_write", "side_path", "written_through_side"]


def cannot_write(path: Path, exc: OSError) -> OSError:
    """``exc`` reworded to name the file the user asked for, not a temporary one."""
    why = (exc.strerror or str(exc)).lower()
    return OSError(f"cannot write {path}: {why}")


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
    except BaseException:
        side.unlink(missing_ok=True)
        raise
    os.replace(side, path)
