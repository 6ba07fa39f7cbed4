"""Commands for a skin on a serial port: monitor, record, virtual-skin (ports: ``cli.board``)."""

from __future__ import annotations

import logging
import signal
import sys
import time
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from skinloc.cli.board_setup import GainOpt, LinesOpt
from skinloc.cli.common import (
    Units,
    WireChoice,
    check_output,
    console,
    err_console,
    friendly_errors,
    progress_steps,
)

log = logging.getLogger(__name__)


class SourceChoice(StrEnum):
    """Where frames come from."""

    serial = "serial"
    sim = "sim"


class DeviceFormat(StrEnum):
    """Wire format the virtual skin speaks."""

    text = "text"
    binary = "binary"


class ModeChoice(StrEnum):
    """Target sampling modes."""

    even = "even"
    random = "random"
    edge = "edge"
    active = "active"


# Options shared by every command that reads a skin.
PortOpt = Annotated[
    str | None,
    typer.Option(
        "--port", "-p", help="Serial port (see 'skinloc ports'); a pyserial URL needs --allow-url."
    ),
]
AllowUrlOpt = Annotated[
    bool,
    typer.Option(
        "--allow-url",
        help="Let --port be a pyserial URL (socket://, rfc2217://, loop://, spy://...); these "
        "reach the network or files, not only a skin.",
    ),
]
SourceOpt = Annotated[
    SourceChoice, typer.Option("--source", help="'sim' reads the simulated skin instead.")
]
BaudOpt = Annotated[
    int | None,
    typer.Option(
        min=50,
        help="Baud rate; default: found by asking the board (skinloc's firmware 1000000, the "
        "paper's text firmware 115200).",
    ),
]
FormatOpt = Annotated[WireChoice, typer.Option("--format", help="Wire format of the port.")]
TxOpt = Annotated[
    int | None,
    typer.Option(min=1, max=21, help="TX lines the device sends (default: the board's, or 8)."),
]
RxOpt = Annotated[
    int | None,
    typer.Option(min=1, max=12, help="RX lines the device sends (default: the board's, or 8)."),
]
TxMaskOpt = Annotated[
    str | None, typer.Option(help="TX lines to keep, e.g. 11111111000 (default: all).")
]
RxMaskOpt = Annotated[str | None, typer.Option(help="RX lines to keep, e.g. 111111110000.")]
SeedOpt = Annotated[int, typer.Option(min=0, help="Seed of the simulated skin (--source sim).")]
ForceOpt = Annotated[bool, typer.Option("--force", help="Replace an existing --out.")]


@dataclass(frozen=True)
class SourceArgs:
    """The source options every command that reads a skin declares (``PortOpt`` and the rest).

    Each field is the value of the option of its name (``fmt``: ``--format``); a command
    without an option passes its default.
    """

    port: str | None = None
    source: SourceChoice = SourceChoice.serial
    baud: int | None = None
    fmt: WireChoice = WireChoice.auto
    tx: int | None = None
    rx: int | None = None
    tx_mask: str | None = None
    rx_mask: str | None = None
    seed: int = 0
    gain: int | None = None
    lines: str | None = None
    allow_url: bool = False


def open_cli_source(args: SourceArgs, *, realtime: bool = False, mesh: Any = None):
    """Build (not connect) the frame source a command's options name.

    A serial port's board is asked first (``cli.board_setup.prepare_port``): its baud and grid
    unless given, its controller, and ``gain`` / ``lines`` set. The source is built by the one
    factory, ``skinloc.sources.base.make_source``; ``mesh`` is the simulated skin's surface.
    """
    from skinloc.sources.base import SourceOptions, make_source

    port, source, gain, lines = args.port, args.source, args.gain, args.lines
    n_tx, n_rx, baud = args.tx, args.rx, args.baud
    if source is SourceChoice.sim:
        if port is not None:
            raise ValueError("give either --port or --source sim, not both")
        if gain is not None or lines is not None:
            raise ValueError("--gain and --lines set a board: give --port, not --source sim")
        port = "sim"
    elif port is None:
        raise ValueError(
            "give --port (a serial port: see 'skinloc ports') or --source sim for the simulator"
        )
    else:
        from skinloc.cli.board_setup import prepare_port
        from skinloc.hardware.ports import check_source

        check_source(
            port,
            allow_urls=args.allow_url,
            allow_sim=False,
            opt_in="pass --allow-url",
        )
        ready = prepare_port(port, baud=baud, gain=gain, lines=lines, n_tx=n_tx, n_rx=n_rx)
        if ready.description:
            err_console.print(f"{port}: {ready.description}", highlight=False)
        baud, n_tx, n_rx = ready.baud, ready.n_tx, ready.n_rx
    options = SourceOptions(
        port,
        n_tx=n_tx or 8,
        n_rx=n_rx or 8,
        baud=baud or 115200,
        format=args.fmt.value,
        tx_mask=args.tx_mask,
        rx_mask=args.rx_mask,
        seed=args.seed,
        realtime=realtime,
    )
    return make_source(options, mesh=mesh)


#: Longest wait for a board's first frame, s: opening the port resets an Uno (DTR), and its
#: bootloader and the controller's start-up take a second or two before frames flow.
FIRST_FRAME_S = 5.0


#: Frames appended to a recording at a time by ``skinloc record`` (also at least once a second).
_STREAM_CHUNK = 64


def first_frame(src, timeout_s: float):
    """The first frame after connecting, waited for at least ``FIRST_FRAME_S``."""
    return src.read(max(timeout_s, FIRST_FRAME_S))


def load_surface(mesh: Path | None, units: Units):
    """The skin's mesh from ``--mesh`` (in ``units``), the paper's cone without it."""
    from skinloc.geometry.mesh import cone_skin, load_mesh

    return cone_skin() if mesh is None else load_mesh(mesh, units.value)


def stats_line(src) -> str:
    """One line of a source's link counters after a session (the simulator: no faults)."""
    stats = getattr(src, "stats", None)
    if stats is None:
        return f"{src.name}: simulated, no link faults"
    s = stats()
    return (
        f"{s.port} [{s.format}] {s.rate_hz:5.1f} Hz | received {s.n_received} | "
        f"dropped {s.n_dropped} | corrupted {s.n_corrupted} | lost {s.n_lost} | "
        f"overflow {s.n_overflow} | reconnects {s.n_reconnects}"
        + ("" if s.link_up else " | LINK DOWN")
    )


# -------------------------------------------------------------------------------- monitor
@friendly_errors
def monitor(
    port: PortOpt = None,
    source: SourceOpt = SourceChoice.serial,
    baud: BaudOpt = None,
    fmt: FormatOpt = WireChoice.auto,
    tx: TxOpt = None,
    rx: RxOpt = None,
    gain: GainOpt = None,
    lines: LinesOpt = None,
    tx_mask: TxMaskOpt = None,
    rx_mask: RxMaskOpt = None,
    seconds: Annotated[
        float | None, typer.Option(min=0.0, help="Stop after this long (default: Ctrl-C).")
    ] = None,
    raw: Annotated[bool, typer.Option("--raw", help="Show raw counts, not deltas.")] = False,
    timeout: Annotated[float, typer.Option(min=0.01, help="Longest wait for a frame, s.")] = 2,
    seed: SeedOpt = 0,
    allow_url: AllowUrlOpt = False,
) -> None:
    """Live view of the sensor image, the frame rate and the drop counts.

    The image shows counts above the median of the first 30 frames (--raw: raw counts).

    Example: skinloc monitor --port /dev/ttyACM0
    """
    from rich.live import Live
    from rich.table import Table

    src = open_cli_source(
        SourceArgs(port, source, baud, fmt, tx, rx, tx_mask, rx_mask, seed, gain, lines, allow_url),
        realtime=True,
    )

    def render(values: np.ndarray, baseline: np.ndarray | None, n: int) -> Table:
        img = values if raw or baseline is None else values - baseline
        grid = img.reshape(src.n_tx, src.n_rx)
        what = "raw counts" if raw or baseline is None else "counts above baseline"
        table = Table(
            "TX\\RX",
            *[str(j) for j in range(src.n_rx)],
            title=f"{src.name}: frame {n}, {what}",
            caption=stats_line(src),
        )
        scale = max(float(np.abs(grid).max()), 1.0) if not raw else 1.0
        for i in range(src.n_tx):
            cells = []
            for v in grid[i]:
                level = min(abs(v) / scale, 1.0) if baseline is not None and not raw else 0
                style = "bold red" if level > 0.6 else "yellow" if level > 0.25 else ""
                cells.append(f"[{style}]{v:.0f}[/]" if style else f"{v:.0f}")
            table.add_row(str(i), *cells)
        return table

    with src:
        first = first_frame(src, timeout)
        warm = [first.values]
        baseline = None
        start = time.monotonic()
        n = 1
        with Live(
            render(first.values, None, n),
            console=console,
            auto_refresh=False,
            transient=False,
        ) as live:
            last_draw = 0.0
            while seconds is None or time.monotonic() - start < seconds:
                frame = src.read(timeout)
                n += 1
                if baseline is None:
                    warm.append(frame.values)
                    if len(warm) >= 30:
                        baseline = np.median(np.stack(warm), axis=0)
                now = time.monotonic()
                if now - last_draw > 0.05:
                    live.update(render(frame.values, baseline, n), refresh=True)
                    last_draw = now
            live.update(render(frame.values if n > 1 else first.values, baseline, n), refresh=True)


# -------------------------------------------------------------------------------- record
@friendly_errors
def record(
    out: Annotated[Path, typer.Option(help="Recording to write (.h5).")],
    port: PortOpt = None,
    source: SourceOpt = SourceChoice.serial,
    seconds: Annotated[float, typer.Option(min=0.0, help="Length of the raw stream, s.")] = 10,
    baseline_frames: Annotated[
        int, typer.Option(min=2, help="No-touch frames captured first.")
    ] = 50,
    baud: BaudOpt = None,
    fmt: FormatOpt = WireChoice.auto,
    tx: TxOpt = None,
    rx: RxOpt = None,
    gain: GainOpt = None,
    lines: LinesOpt = None,
    tx_mask: TxMaskOpt = None,
    rx_mask: RxMaskOpt = None,
    mesh: Annotated[Path | None, typer.Option(help="Skin mesh; default: the paper's cone.")] = None,
    units: Annotated[Units, typer.Option(help="Units of --mesh.")] = Units.auto,
    timeout: Annotated[float, typer.Option(min=0.01, help="Longest wait for a frame, s.")] = 2,
    seed: SeedOpt = 0,
    allow_url: AllowUrlOpt = False,
    force: ForceOpt = False,
) -> None:
    """Record a no-touch baseline, then the raw stream for --seconds, to an HDF5 recording.

    The stream goes to the group 'stream' (frames, times_s, index) next to the usual
    recording layout (docs/hardware.md); 'skinloc info' reads the file. It is written as it
    comes, to OUT's name with .partial.h5, renamed over --out at the end: Ctrl-C, SIGTERM
    or a full disk keep the frames so far.

    Example: skinloc record --port /dev/ttyACM0 --seconds 30 --out stream.h5
    """
    import os

    from skinloc.data.appender import StreamAppender
    from skinloc.errors import RecordingError, SkinlocError
    from skinloc.files import cannot_write, os_error_line, os_error_reason, side_path

    if out.suffix.lower() not in (".h5", ".hdf5"):
        raise ValueError(f"--out must be an .h5 file, got {out}")
    check_output(out, option="--out", inputs=[mesh], force=force)
    surface = load_surface(mesh, units)
    src = open_cli_source(
        SourceArgs(port, source, baud, fmt, tx, rx, tx_mask, rx_mask, seed, gain, lines, allow_url),
        mesh=surface if source is SourceChoice.sim else None,
    )
    side = side_path(out, "partial")
    buf: list[tuple[np.ndarray, float, int]] = []  # frames not yet on disk
    t_end = 0.0  # stream time of the last frame on disk, s
    with src, progress_steps() as step:
        first_frame(src, timeout)
        base, _ = src.read_many(baseline_frames, timeout)
        step("baseline", baseline_frames, baseline_frames)
        try:
            writer = StreamAppender(
                side,
                n_tx=src.n_tx,
                n_rx=src.n_rx,
                mesh=surface,
                baseline_frames=base,
                meta={"source": src.name, "description": f"raw stream of {seconds:g} s"},
                chunk=_STREAM_CHUNK,
            )
        except OSError as exc:
            raise cannot_write(out, exc) from None

        def save() -> OSError | None:
            """Append ``buf`` to the file; the disk's refusal is returned, not raised."""
            nonlocal t_end
            if not buf:
                return None
            try:  # the appender refuses a disk too full for them, keeping the file whole
                writer.append(
                    np.asarray([b[0] for b in buf], dtype=np.float32),
                    np.asarray([b[1] for b in buf]),
                    np.asarray([b[2] for b in buf], dtype=np.int64),
                )
            except OSError as exc:
                return exc
            t_end = buf[-1][1]
            buf.clear()
            return None

        t0 = None
        interrupted = False
        refused: OSError | None = None  # the disk's refusal
        failed: Exception | None = None  # the source's (a timeout, an unplugged port)
        try:
            try:
                while True:
                    f = src.read(timeout)
                    t0 = f.timestamp_s if t0 is None else t0
                    if f.timestamp_s - t0 > seconds:
                        break
                    buf.append((f.values, f.timestamp_s - t0, f.index))
                    if len(buf) >= _STREAM_CHUNK or f.timestamp_s - t0 - t_end >= 1.0:
                        refused = save()
                        if refused is not None:
                            break
                    if (writer.n_frames + len(buf)) % 25 == 0:
                        step("streaming (s)", int(f.timestamp_s - t0), int(np.ceil(seconds)))
            except KeyboardInterrupt:  # Ctrl-C or SIGTERM ends the stream early: keep it
                interrupted = True
            except (SkinlocError, OSError) as exc:
                failed = exc
            refused = refused or save()
        finally:
            try:
                writer.close()
            except OSError as exc:
                refused = refused or exc
        summary = stats_line(src)
    os.replace(side, out)
    n_kept = writer.n_frames
    held = f"{out} holds the first {n_kept} stream frames ({t_end:.1f} s of {seconds:g} s)"
    if refused is not None:
        raise OSError(f"cannot write {out}: {os_error_reason(refused)}; {held}")
    if failed is not None:
        text = os_error_line(failed) if isinstance(failed, OSError) else str(failed)
        raise RecordingError(f"{text}; {held}")
    console.print(
        f"Wrote {out}: {baseline_frames} baseline frames + {writer.n_frames} stream "
        f"frames, {src.n_tx} TX x {src.n_rx} RX"
    )
    err_console.print(summary, highlight=False)
    if interrupted:
        from skinloc.errors import Interrupted

        raise Interrupted(f"the stream was cut short; {out} holds the frames up to then")


# ---------------------------------------------------------------------------- virtual-skin
@friendly_errors
def virtual_skin(
    fmt: Annotated[
        DeviceFormat, typer.Option("--format", help="Wire format.")
    ] = DeviceFormat.binary,
    rate: Annotated[float, typer.Option(min=0.1, max=2000, help="Frames per second.")] = 100,
    faults: Annotated[
        bool, typer.Option("--faults", help="Inject garbage, drops, splits, merges, unplugs.")
    ] = False,
    disconnect_every: Annotated[
        float, typer.Option(min=0, help="With --faults: mean s between unplugs (0: none).")
    ] = 30.0,
    tx: TxOpt = 8,
    rx: RxOpt = 8,
    seed: Annotated[int, typer.Option(help="Seed of the skin and of the faults.")] = 0,
    seconds: Annotated[
        float | None, typer.Option(min=0, help="Stop after this long (default: Ctrl-C).")
    ] = None,
    truth: Annotated[
        Path | None, typer.Option(help="On exit, save the ground truth per frame (.npz).")
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing --truth.")] = False,
) -> None:
    """Expose the simulated skin as a serial port; prints the port's path first.

    The pseudo-terminal streams in real time in the chosen format and answers the firmware's
    commands; 'touch x y z' (m) and 'lift' over the port move a scripted finger (collect
    --scripted-finger sends them).

    Example: skinloc virtual-skin --format text --rate 100 --faults
    """
    if sys.platform == "win32":
        raise ValueError("virtual-skin needs a POSIX pseudo-terminal (Linux or macOS)")
    from skinloc.sim.skin import SimulatedSkin
    from skinloc.sim.virtual_device import FaultConfig, VirtualSkin

    if truth is not None:
        if truth.suffix.lower() != ".npz":
            raise ValueError(f"--truth must name an .npz file, got {truth}")
        check_output(truth, option="--truth", force=force)
    skin = SimulatedSkin(n_tx=tx, n_rx=rx, random_state=seed, rate_hz=rate)
    fault_cfg = (
        FaultConfig(disconnect_every_s=disconnect_every, random_state=seed + 1) if faults else None
    )
    dev = VirtualSkin(
        skin, fmt=fmt.value, rate_hz=rate, faults=fault_cfg, keep_truth=truth is not None
    )
    stopping = []

    def on_signal(signum, _frame) -> None:
        stopping.append(signum)

    # Handle SIGINT too: a device started in the background inherits it ignored, and
    # scripts (bench/soak.py) stop it with either signal.
    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        path = dev.start()
        sys.stdout.write(path + "\n")
        sys.stdout.flush()
        err_console.print(
            f"virtual skin {tx} x {rx}, {fmt.value}, {rate:g} Hz"
            + (", faults on" if faults else "")
            + f" on {path}; Ctrl-C stops",
            highlight=False,
        )
        start = time.monotonic()
        while not stopping and (seconds is None or time.monotonic() - start < seconds):
            time.sleep(0.05)
    finally:
        dev.stop()
        for sig, handler in old.items():
            signal.signal(sig, handler)
    if truth is not None:
        from skinloc.files import atomic_write

        data = dev.truth()

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as fh:  # a file object: numpy adds no second .npz
                np.savez_compressed(fh, **data)

        atomic_write(truth, write)
    c = dev.counts
    err_console.print(
        f"frames sent intact {c['sent']}, destroyed by faults {c['destroyed']}, "
        f"unheard {c['unheard']}, disconnects {c['disconnects']}",
        highlight=False,
    )


def register(app: typer.Typer) -> None:
    """Add the hardware commands to the main ``skinloc`` app."""
    app.command()(monitor)
    app.command()(record)
    app.command("virtual-skin")(virtual_skin)
