"""What every ``skinloc`` command group shares: the Typer ``app``, consoles, option types, errors.

A leaf of the command line: ``skinloc.cli.main`` and each group module (``cli_hardware``,
``cli_live``, ``cli_skin``, ``skinloc.cli.webapp``) import it, and ``skinloc.cli.main`` imports the
groups to register their commands, so no group imports ``skinloc.cli.main``.
"""

from __future__ import annotations

import functools
import json
import logging
import sys
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console
from rich.markup import escape

from skinloc._lazy import EXTRAS, missing_extra_message
from skinloc.errors import RecordingError, SkinlocError
from skinloc.files import os_error_line


def _flags_read_as_flags() -> None:
    """Show no value type after a flag in ``--help`` (``--force``, not ``--force <bool>``).

    Typer 0.29's rich help prints every option's ``display_type_rich`` (``<bool>`` for a flag)
    although a flag takes no value; its plain help already leaves the type out for flags and
    counters, and this makes the rich help agree. Older Typer has no such method and shows no
    type for flags: nothing to do there.
    """
    from typer import core

    option = getattr(core, "TyperOption", None)
    shown = getattr(option, "display_type_rich", None)
    if shown is None or getattr(shown, "_flags_read_as_flags", False):
        return

    def display_type_rich(self: Any, ctx: Any) -> str | None:
        return None if self.is_flag or self.count else shown(self, ctx)

    display_type_rich._flags_read_as_flags = True  # type: ignore[attr-defined]
    option.display_type_rich = display_type_rich


_flags_read_as_flags()

app = typer.Typer(
    name="skinloc",
    help="Contact localisation on 3D tactile skin: calibrate, simulate, train, evaluate.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
# soft_wrap: a message is one line however long its paths are (a log or a script reads it
# whole); tables still fit the width below.
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)
log = logging.getLogger("skinloc")

F = TypeVar("F", bound=Callable[..., Any])


class Arch(StrEnum):
    """Localiser configurations."""

    default = "default"
    mlp = "mlp"
    paper = "paper"


class Constraint(StrEnum):
    """Output constraints."""

    snap = "snap"
    project = "project"
    none = "none"


class Mode(StrEnum):
    """Target sampling modes."""

    even = "even"
    random = "random"
    edge = "edge"


class Change(StrEnum):
    """Session changes of the simulated skin (``skinloc.sim.session_change``)."""

    none = "none"
    mild = "mild"
    real = "real"


class Units(StrEnum):
    """Mesh file units."""

    auto = "auto"
    m = "m"
    mm = "mm"


class WireChoice(StrEnum):
    """Wire format of a serial port."""

    auto = "auto"
    text = "text"
    binary = "binary"


# ------------------------------------------------------------------------ signals and errors
#: Signals received during the current command (SIGINT, SIGTERM), newest last.
_signals: list[int] = []


def _on_signal(signum: int, frame: Any) -> None:
    """Ctrl-C and SIGTERM both become ``KeyboardInterrupt``, so both take the clean path.

    An exception raised here can still be lost: inside a weakref callback (h5py frees its
    objects through a WeakValueDictionary many times per write) Python prints "Exception
    ignored" and drops it, so there the signal is only recorded; and C code that clears errors
    (optional attribute lookups, destructors) drops it silently. Either way the signal stays
    recorded, and the next ``check_interrupt`` (every progress step) raises it again.
    """
    _signals.append(signum)
    if frame is not None and frame.f_code.co_filename.endswith("weakref.py"):
        return
    raise KeyboardInterrupt


def check_interrupt() -> None:
    """Raise ``KeyboardInterrupt`` once if a signal arrived since the last time.

    Called from every progress update, so a long job stops within one step even when the
    exception raised by the handler was lost. A job that handles the interruption itself
    (``record`` keeps the stream so far) calls no progress step afterwards.
    """
    if _signals and _signals[-1] != 0:
        _signals.append(0)  # delivered: later checks stay quiet while the job unwinds
        raise KeyboardInterrupt


@contextmanager
def _signal_handlers() -> Iterator[None]:
    import signal

    _signals.clear()
    old: dict[int, Any] = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            current = signal.getsignal(sig)
            if current is signal.SIG_IGN:  # started with nohup or in the background: keep it
                continue
            old[sig] = signal.signal(sig, _on_signal)
    except ValueError:  # not the main thread (an embedding app, some tests): leave them alone
        pass
    try:
        yield
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _exit_code_of_interrupt() -> int:
    import signal

    received = [s for s in _signals if s]
    return 128 + (received[0] if received else signal.SIGINT)


def friendly_errors(fn: F) -> F:
    """Turn expected failures (bad files, bad values) into one line on stderr and exit 1.

    Ctrl-C and SIGTERM end the command through ``KeyboardInterrupt`` (temporary files are
    removed on the way out) with exit code 130 or 143; an ``Interrupted`` says what was kept.
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with _signal_handlers(), _claims_released():
            try:
                return fn(*args, **kwargs)
            except (SkinlocError, ValueError, OSError) as exc:
                # HDF5's errors (a full disk) are many lines: one line, file and reason
                text = os_error_line(exc) if isinstance(exc, OSError) else str(exc)
                # escaped: a message may hold brackets (pip install 'skinloc[nets]', paths)
                err_console.print(
                    f"[bold red]error:[/] {escape(text)}", highlight=False, soft_wrap=True
                )
                raise typer.Exit(1) from None
            except ModuleNotFoundError as exc:
                # every optional import goes through require_extra (MissingExtraError, above);
                # one that does not is still one line when it is an extra's
                top = (exc.name or "").partition(".")[0]
                if top not in EXTRAS:
                    raise
                msg = missing_extra_message(top, "this command", exc)
                err_console.print(f"[bold red]error:[/] {escape(msg)}", highlight=False)
                raise typer.Exit(1) from None
            except MemoryError:
                err_console.print(
                    "[bold red]error:[/] out of memory: ask for less (fewer points, frames or "
                    "files)",
                    highlight=False,
                    soft_wrap=True,
                )
                raise typer.Exit(1) from None
            except KeyboardInterrupt as exc:
                msg = f"interrupted: {exc}" if str(exc) else "interrupted"
                err_console.print(msg, highlight=False, soft_wrap=True)
                raise typer.Exit(_exit_code_of_interrupt()) from None

    return wrapper  # type: ignore[return-value]


# ------------------------------------------------------------------------ output paths
#: Outputs this process has claimed (``skinloc.files.claim_output``), by resolved path.
_claims: dict[Path, Any] = {}


@contextmanager
def _claims_released() -> Iterator[None]:
    """Release the output claims a command made when it ends, however it ends."""
    before = set(_claims)
    try:
        yield
    finally:
        for key in [k for k in _claims if k not in before]:
            _claims.pop(key).release()


def _claim(path: Path) -> None:
    from skinloc.files import claim_output

    key = path.resolve()
    if key not in _claims:
        _claims[key] = claim_output(path)


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file (same resolved path, or hard links of one)."""
    import os

    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def check_output(
    path: Path,
    *,
    option: str,
    inputs: Iterable[Path | None] = (),
    force: bool = False,
    folder: bool = False,
) -> None:
    """Refuse an output path before any work is done; every command that writes calls this.

    Parameters
    ----------
    path : Path
        What the user asked to write.
    option : str
        How the user named it (``--out``, ``DST``), for the message.
    inputs : iterable of Path or None
        Files the command reads: writing over one of them is refused, with or without
        ``--force``.
    force : bool
        Allow replacing an existing file (the replacement is atomic).
    folder : bool
        ``path`` is a folder the command fills (created if missing, its parent must exist).

    Raises
    ------
    ValueError
        Naming ``path`` and what to do.
    OutputBusyError
        Another process is writing ``path`` (claimed until this command ends).
    """
    import tempfile

    for src in inputs:
        if src is not None and _same_file(path, src):
            raise ValueError(f"{option} {path} is also an input ({src}): write to another file")
    if folder:
        if path.exists() and not path.is_dir():
            raise ValueError(f"{option} {path} is a file, not a folder")
        parent = path if path.is_dir() else path.parent
        if parent.is_dir():
            _claim(path)
    else:
        if path.is_dir():
            raise ValueError(f"{option} {path} is a folder: give a file name")
        if path.parent.is_dir():
            # One output, one writer: claimed before the existence check, so two commands
            # started together cannot both find it free (OutputBusyError for the second).
            _claim(path)
        if path.exists() and not force:
            raise ValueError(
                f"{path} exists: pass --force to replace it, or choose another {option}"
            )
        parent = path.parent
    if not parent.exists():
        raise ValueError(f"cannot write {path}: folder {parent} does not exist")
    if not parent.is_dir():
        raise ValueError(f"cannot write {path}: {parent} is not a folder")
    # Try it: permission bits do not tell root about read-only or virtual file systems.
    try:
        with tempfile.NamedTemporaryFile(dir=parent, prefix=f".{path.name}.", suffix=".probe"):
            pass
    except OSError as exc:
        why = (exc.strerror or str(exc)).lower()
        raise ValueError(f"cannot write {path}: folder {parent} is not writable ({why})") from None


def check_skin_covers(skin: Any, mesh: Path | None) -> None:
    """Refuse a mesh whose simulated wires leave much of it unfelt (a closed shell).

    ``skinloc simulate`` draws targets over the whole mesh; where no crossing is near, a touch
    is never felt and the session waits for it in vain.
    """
    share = skin.uncovered_share()
    if share > 0.2:
        raise ValueError(
            f"the simulated wires cover only {100 * (1 - share):.0f} % of {mesh}: they lie on "
            f"one side of a mesh that is not a cone or cylinder about y, so give the part the "
            f"skin covers (an open shell such as a hemisphere, or a plate), not a closed one"
        )


# ------------------------------------------------------------------------ progress
@contextmanager
def progress_steps() -> Iterator[Callable[[str, int, int], None]]:
    """A ``step(label, done, total)`` callback drawing one rich progress bar per label.

    Off a terminal (a pipe, a log file) it prints a plain line per label at most every 10 s,
    the first after 2 s, so a long job is never silent. Every call checks for Ctrl-C/SIGTERM.
    """
    import time

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    live = err_console.is_terminal or _force_progress()
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=err_console,
        transient=False,
        disable=not live,
    ) as bar:
        tasks: dict[str, Any] = {}
        started: dict[str, float] = {}
        printed: dict[str, float] = {}

        def step(label: str, done: int, total: int) -> None:
            check_interrupt()
            if label not in tasks:
                tasks[label] = bar.add_task(label, total=total)
                started[label] = printed[label] = time.monotonic()
            bar.update(tasks[label], completed=done, total=total)
            now = time.monotonic()
            gap = 2.0 if printed[label] == started[label] else 10.0
            if not live and (
                now - printed[label] >= gap or (done >= total and printed[label] > started[label])
            ):
                printed[label] = now
                err_console.print(
                    f"{label}: {done}/{total} ({now - started[label]:.0f} s)", highlight=False
                )

        yield step


def _force_progress() -> bool:
    import os

    return os.environ.get("SKINLOC_PROGRESS") == "1"


@app.callback()
def _main(
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Log what happens.")] = False,
) -> None:
    import os

    # Off a terminal rich assumes 80 columns (or COLUMNS) and cuts wide tables (bench, ports
    # with long paths): a pipe or a log has no width, so give them room, every command anew.
    columns = os.environ.get("COLUMNS", "")
    for c in (console, err_console):
        if not c.is_terminal:
            c.width = max(200, int(columns) if columns.isdigit() else 0)
    logging.basicConfig(
        level=logging.INFO if verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )


def print_json(obj: Any) -> None:
    """Write ``obj`` to stdout as indented JSON (numpy scalars as floats)."""
    sys.stdout.write(json.dumps(obj, indent=2, default=float) + "\n")


def read_recordings(paths: Iterable[Path], *, calibration: bool = False) -> list:
    """The recordings at ``paths``, read in order (``Recording`` each).

    With ``calibration``, a recording without point logs (a raw stream from ``skinloc
    record``) is refused with a message naming it and what is expected instead.
    """
    from skinloc.data.recording import read_recording

    recs = []
    for p in paths:
        rec = read_recording(p)
        if calibration and rec.n_point_logs == 0:
            raise RecordingError(
                f"{p} is a raw stream without point logs, not a calibration: give recordings "
                "of touches ('skinloc collect' or 'skinloc simulate')"
            )
        recs.append(rec)
    return recs
