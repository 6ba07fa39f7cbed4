"""Commands for the live path: ``run`` (the pipeline) and ``export`` (ONNX, C header)."""

from __future__ import annotations

import json
import logging
import signal
import sys
import time
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer

from skinloc.cli.board_setup import GainOpt, LinesOpt
from skinloc.cli.common import WireChoice
from skinloc.live.sinks.base import SINK_SPECS

log = logging.getLogger(__name__)


class FilterChoice(StrEnum):
    """Temporal filter of the position."""

    one_euro = "one-euro"
    none = "none"


def _served_urls(runner: Any) -> list[str]:
    """``ws://host:port`` of every server sink of ``runner`` (after ``open``: ports bound)."""
    sinks = [*runner.global_sinks, *(s for per_skin in runner.skin_sinks for s in per_skin)]
    return [url for url in (getattr(s, "url", None) for s in sinks) if url]


def _stop_on_signals(runner: Any) -> dict[int, Any]:
    """Make the first Ctrl-C or SIGTERM stop ``runner``'s loop; a second one interrupts.

    The handler only asks the loop to stop (it ends within one turn) instead of raising
    ``KeyboardInterrupt`` wherever the main thread happens to be: an exception raised inside a
    destructor or a weakref callback is dropped by Python, and on a loaded machine the main
    thread is often in the middle of a frame rather than waiting in ``select``, so a raised
    Ctrl-C could be lost and the run go on. Returns the previous handlers, to restore.
    """
    received: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        received.append(signum)
        if len(received) > 1:  # the stop hangs (a sink that will not close): interrupt it
            raise KeyboardInterrupt
        runner.stop()

    old: dict[int, Any] = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            if signal.getsignal(sig) is signal.SIG_IGN:  # a script's background job: keep it
                continue
            old[sig] = signal.signal(sig, handler)
        except ValueError:  # not the main thread (an embedding program, tests)
            break
    return old


def _check_sources(skin_cfgs: list[Any], allow_url: bool, wait: bool) -> None:
    """Refuse, before the models load, a source whose extra is missing or a bad serial port.

    A serial port is refused when it is a pyserial URL (without ``--allow-url``) or not a
    serial device.

    A port that does not exist yet is let through to the runner, which waits for it, unless
    ``--no-wait`` (``wait`` False) or the skin's own ``wait = false`` says to fail at once;
    every skin leaves with ``wait`` set.
    """
    from skinloc.hardware.ports import PortMissingError, check_source
    from skinloc.sources.base import SourceKind, check_source_extras, source_kind

    for skin_cfg in skin_cfgs:
        skin_cfg.wait = wait and skin_cfg.wait is not False
        src = skin_cfg.source
        if isinstance(src, str):
            check_source_extras(src)
        if isinstance(src, str) and source_kind(src) is SourceKind.SERIAL:
            try:
                check_source(src, allow_urls=allow_url, allow_sim=False, opt_in="pass --allow-url")
            except PortMissingError:
                if not skin_cfg.wait:
                    raise


def _sink_files(sink: str) -> list[Path]:
    """Files a ``--sink`` writes (``jsonl:F``, ``...?mcap=F``): the sink registry says."""
    from skinloc.live.sinks.base import sink_files

    return [Path(f) for f in sink_files(sink)]


def _prepare_board(
    source: str,
    baud: int | None,
    gain: int | None,
    lines: str | None,
    tx: int | None,
    rx: int | None,
    allow_url: bool,
) -> tuple[int, int | None, int | None]:
    """The baud and grid of ``source`` when it is a serial port (asked, set up); else as given."""
    from skinloc.cli.board_setup import prepare_port
    from skinloc.cli.common import err_console
    from skinloc.sources.base import SourceKind, source_kind

    serial_port = source_kind(source) is SourceKind.SERIAL
    if not serial_port or ("://" in source and not allow_url):
        if gain is not None or lines is not None:
            raise ValueError("--gain and --lines set a board: give its serial port as --source")
        return baud or 115200, tx, rx
    ready = prepare_port(source, baud=baud, gain=gain, lines=lines, n_tx=tx, n_rx=rx)
    if ready.description:
        err_console.print(f"{source}: {ready.description}", highlight=False)
    return ready.baud, ready.n_tx, ready.n_rx


def _summary(counters: list[dict[str, Any]], elapsed: float, as_json: bool) -> None:
    """The run's per-skin summary lines on stderr, and ``--stats``'s JSON line."""
    from skinloc.cli.common import err_console

    for c in counters:
        if c.get("lost"):
            err_console.print(
                f"{c['skin']}: no statistics (worker {c['worker']} did not stop)", highlight=False
            )
            continue
        err_console.print(
            f"{c['skin']}: {c['frames']} frames, {c['touches']} touches, "
            f"{c['contacts']} contacts, {c.get('gestures', 0)} gestures in {elapsed:.1f} s"
            + (f", {c['reconnects']} reconnects" if "reconnects" in c else "")
            + (f", {c['errors']} frames dropped by errors" if c["errors"] else "")
            + (f", {c['sink_errors']} sink errors" if c["sink_errors"] else "")
            + (
                f", worker restarted {c['worker_restarts']} time(s)"
                if c.get("worker_restarts")
                else ""
            ),
            highlight=False,
        )
    if as_json:
        sys.stderr.write(json.dumps(counters, default=str) + "\n")


def _run_workers(
    skin_cfgs: list[Any], sinks: list[str], workers: int, duration: float | None, stats: bool
) -> None:
    """``run --workers N``: the skins over N processes (``skinloc.live.workers``)."""
    from skinloc.cli.common import err_console
    from skinloc.live.workers import WorkerError, WorkerPool

    def report(line: str) -> None:
        err_console.print(line, highlight=False)

    pool = WorkerPool(skin_cfgs, sinks, workers, report=report)
    report(
        f"running {len(skin_cfgs)} skin(s) on {workers} workers: "
        + ", ".join(f"{s.name} <- {s.source}" for s in skin_cfgs)
    )
    previous = _stop_on_signals(pool)
    try:
        counters = pool.run(duration)
    except WorkerError as exc:
        raise ValueError(str(exc)) from None
    except KeyboardInterrupt:  # a second signal: the workers were killed
        counters = pool.stats()
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
    _summary(counters, pool.elapsed(), stats)


def _us(value: float | None) -> str:
    """A time in us as ``1234 us``, or ``n/a`` (no contact came)."""
    return "n/a" if value is None else f"{value:.0f} us"


def register(app: typer.Typer) -> None:
    """Add ``run`` and ``export`` to the main ``skinloc`` app."""
    from skinloc.cli.common import check_output, err_console, friendly_errors

    @app.command()
    @friendly_errors
    def run(
        model: Annotated[
            Path | None, typer.Option("--model", "-m", help="Model file ('skinloc train').")
        ] = None,
        source: Annotated[
            str | None,
            typer.Option(
                "--source",
                "-s",
                help="A serial port, a recording (.h5/.mat/.mcap) to replay, or 'sim' (the "
                "simulated skin, a scripted finger); a pyserial URL needs --allow-url.",
            ),
        ] = None,
        sink: Annotated[
            list[str] | None,
            typer.Option(
                "--sink",
                help="Where contacts go, repeatable: "
                + ", ".join(form.split(" (")[0] for form in SINK_SPECS)
                + ". Default: jsonl (stdout).",
            ),
        ] = None,
        config: Annotated[
            Path | None,
            typer.Option("--config", help="Skins file (TOML) for many skins; see docs/live.md."),
        ] = None,
        fast: Annotated[
            bool,
            typer.Option(
                "--fast", help="Replay recordings as fast as possible (every skin of --config)."
            ),
        ] = False,
        loop: Annotated[
            bool,
            typer.Option("--loop", help="Replay recordings forever (every skin of --config)."),
        ] = False,
        baud: Annotated[
            int | None,
            typer.Option(
                min=50,
                help="Baud rate of a serial port; default: found by asking the board "
                "(1000000 when it is not plugged in yet).",
            ),
        ] = None,
        gain: GainOpt = None,
        lines: LinesOpt = None,
        wire_format: Annotated[
            WireChoice, typer.Option("--format", help="Wire format of a serial port.")
        ] = WireChoice.auto,
        tx: Annotated[int | None, typer.Option(min=1, max=21, help="TX lines sent.")] = None,
        rx: Annotated[int | None, typer.Option(min=1, max=12, help="RX lines sent.")] = None,
        name: Annotated[str, typer.Option(help="Skin name carried by the contacts.")] = "skin",
        duration: Annotated[
            float | None, typer.Option(min=0.0, help="Stop after this many seconds.")
        ] = None,
        drift: Annotated[
            bool, typer.Option("--drift/--no-drift", help="Track baseline drift while untouched.")
        ] = True,
        filter_: Annotated[
            FilterChoice, typer.Option("--filter", help="Temporal filter on the surface.")
        ] = FilterChoice.one_euro,
        on_z: Annotated[
            float, typer.Option(help="Touch starts above this signal (noise std).")
        ] = 8.0,
        off_z: Annotated[
            float, typer.Option(help="Touch ends below this signal (noise std).")
        ] = 4.0,
        baseline: Annotated[
            Path | None,
            typer.Option(help="Take the baseline from this recording instead of capturing it."),
        ] = None,
        emit_idle: Annotated[
            bool, typer.Option("--emit-idle", help="Also output untouched frames.")
        ] = False,
        max_contacts: Annotated[
            int,
            typer.Option(
                "--max-contacts",
                min=1,
                max=10,
                help="Contacts (fingers, tracks) per frame at most; 1: one contact per touch, "
                "as before multi-touch.",
            ),
        ] = 3,
        gestures: Annotated[
            bool,
            typer.Option(
                "--gestures/--no-gestures",
                help="Recognise taps, double taps, long presses, swipes, two-finger taps.",
            ),
        ] = True,
        stats: Annotated[
            bool, typer.Option("--stats", help="Print per-skin counters as JSON on stderr at exit.")
        ] = False,
        allow_url: Annotated[
            bool,
            typer.Option(
                "--allow-url",
                help="Let a source be a pyserial URL (socket://, rfc2217://, loop://, spy://...); "
                "these reach the network or files, not only a skin.",
            ),
        ] = False,
        wait: Annotated[
            bool,
            typer.Option(
                "--wait/--no-wait",
                help="Wait for a serial port that is not plugged in yet (retried every 0.1 s, "
                "Ctrl-C stops); --no-wait fails at once with exit code 1, for scripts.",
            ),
        ] = True,
        workers: Annotated[
            int,
            typer.Option(
                "--workers",
                min=1,
                help="Spread the skins of --config over this many processes (one loop and, "
                "with --sink ros2, one node NODE_<i> each); sinks: jsonl, udp, ros2.",
            ),
        ] = 1,
    ) -> None:
        """Run the live pipeline: frames -> baseline -> touch -> localiser -> surface -> sinks.

        Example: skinloc run --model model.h5 --source /dev/ttyACM0 --sink jsonl --sink ws://127.0.0.1:8767
        """
        from skinloc.live.sinks.base import check_sink

        sinks = list(sink) if sink else ["jsonl"]
        inputs = [model, baseline, config, *([Path(source)] if source else [])]
        for spec_text in sinks:
            check_sink(spec_text)  # before the pipeline's imports: a bad sink fails at once
            for path in _sink_files(spec_text):
                # Sink files are logs that may be appended to; only an input is off limits.
                check_output(path, option="--sink", inputs=inputs, force=True)
        from skinloc.live.core import PipelineConfig
        from skinloc.live.runner import Runner, SkinConfig

        if config is not None:
            from skinloc.live.skins_file import load_skins

            if model is not None:
                raise ValueError("give either --config (many skins) or --model, not both")
            if gain is not None or lines is not None:
                raise ValueError("--gain and --lines set one board: use them without --config")
            if source is not None:
                raise ValueError("--source is one skin's: give each skin's source in --config")
            skin_cfgs, global_sinks = load_skins(config)
            for skin_cfg in skin_cfgs:  # the replay options apply to every skin of the file
                skin_cfg.realtime = skin_cfg.realtime and not fast
                skin_cfg.loop = skin_cfg.loop or loop
            _check_sources(skin_cfgs, allow_url, wait)
            all_sinks = [*global_sinks, *(sink or [])] or ["jsonl"]
            if workers > 1:
                _run_workers(skin_cfgs, all_sinks, workers, duration, stats)
                return
            runner = Runner(skin_cfgs, sinks=all_sinks)
        else:
            if workers > 1:
                raise ValueError("--workers spreads the skins of --config: give a skins file")
            if model is None:
                raise ValueError("give --model MODEL (from 'skinloc train') or --config SKINS.toml")
            if not model.is_file():
                raise ValueError(f"model not found: {model}")
            if source is None:
                raise ValueError(
                    "give --source: a serial port (see 'skinloc ports'), a recording, or "
                    "--source sim for the simulated skin"
                )
            cfg = PipelineConfig(
                drift_tracking=drift,
                filter=filter_.value,
                touch_on_z=on_z,
                touch_off_z=off_z,
                emit_idle=emit_idle,
                max_contacts=max_contacts,
                gestures=gestures,
            )
            skin_cfg = SkinConfig(
                model=model,
                source=source,
                name=name,
                config=cfg,
                baud=baud or 115200,
                wire_format=wire_format.value,
                n_tx=tx,
                n_rx=rx,
                realtime=not fast,
                loop=loop,
                baseline=baseline,
            )
            _check_sources([skin_cfg], allow_url, wait)
            skin_cfg.baud, skin_cfg.n_tx, skin_cfg.n_rx = _prepare_board(
                source, baud, gain, lines, tx, rx, allow_url
            )
            runner = Runner([skin_cfg], sinks=sinks)
        t0 = time.monotonic()
        # Until the loop runs (opening sources and sinks), a signal interrupts as in every
        # command; while it runs, one stops it cleanly and the summary is printed.
        with runner:
            err_console.print(
                f"running {len(runner.skins)} skin(s): "
                + ", ".join(f"{s.name} <- {s.source}" for s in runner.skins),
                highlight=False,
            )
            # Servers asked for port 0 got a free one: say which.
            for url in _served_urls(runner):
                err_console.print(f"serving contacts on {url}", highlight=False)
            for skin, port in runner.waiting:
                err_console.print(
                    f"waiting for {port} (skin {skin}): not present; plug it in or press Ctrl-C",
                    highlight=False,
                )
            previous = _stop_on_signals(runner)
            try:
                runner.run(duration)
            except KeyboardInterrupt:  # a second signal: the stop did not end the loop
                pass
            except BrokenPipeError:  # stdout closed by the reader (| head): stop quietly
                import os

                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            finally:
                for sig, old in previous.items():
                    signal.signal(sig, old)
            counters = runner.stats()
        _summary(counters, time.monotonic() - t0, stats)

    @app.command()
    @friendly_errors
    def export(
        model: Annotated[Path, typer.Argument(help="Model file ('skinloc train').")],
        onnx: Annotated[Path | None, typer.Option("--onnx", help="Write an ONNX file.")] = None,
        c_header: Annotated[
            Path | None, typer.Option("--c-header", help="Write a C header for a microcontroller.")
        ] = None,
        surface: Annotated[
            bool,
            typer.Option("--surface/--no-surface", help="Include the snap to the surface points."),
        ] = True,
        prefix: Annotated[str, typer.Option(help="Prefix of the C names.")] = "skinloc",
        force: Annotated[bool, typer.Option("--force", help="Replace existing files.")] = False,
    ) -> None:
        """Export a model to ONNX (robot computer) or a C header (Arduino, ESP32).

        Example: skinloc export model.h5 --onnx model.onnx --c-header skinloc_model.h
        """
        from skinloc.files import atomic_write
        from skinloc.models.engine import ModelSpec
        from skinloc.models.export import export_c_header, export_onnx

        if onnx is None and c_header is None:
            raise ValueError("nothing to do: give --onnx FILE and/or --c-header FILE")
        if not model.is_file():
            raise ValueError(f"model not found: {model}")
        if onnx is not None and c_header is not None and onnx.resolve() == c_header.resolve():
            raise ValueError("--onnx and --c-header name the same file")
        if onnx is not None:
            check_output(onnx, option="--onnx", inputs=[model], force=force)
        if c_header is not None:
            check_output(c_header, option="--c-header", inputs=[model], force=force)
        model_spec = ModelSpec.load(model)
        if onnx is not None:
            atomic_write(onnx, lambda tmp: export_onnx(model_spec, tmp, include_surface=surface))
            err_console.print(f"wrote {onnx}", highlight=False)
        if c_header is not None:
            atomic_write(
                c_header,
                lambda tmp: export_c_header(
                    model_spec, tmp, include_surface=surface, prefix=prefix
                ),
            )
            size = c_header.stat().st_size
            err_console.print(
                f"wrote {c_header} ({size / 1024:.0f} KiB of source)", highlight=False
            )


def bench_online(out: Path, as_json: bool, archs: tuple[str, ...], left_out: list[str]) -> None:
    """``skinloc bench --online``: the live path's figures, written to ``out/online.json``.

    ``archs`` are the models to measure; ``left_out`` says what was left out before (networks
    without PyTorch), and what the benchmark leaves out itself is added to it.
    """
    from skinloc.bench.online import online_bench
    from skinloc.cli.common import console, err_console, print_json, progress_steps

    out.mkdir(parents=True, exist_ok=True)
    with progress_steps() as step:
        res = online_bench(out=out, step=step, archs=archs)
    res["left_out"] = [*left_out, *res["left_out"]]
    (out / "online.json").write_text(json.dumps(res, indent=2, default=float))
    for why in res["left_out"]:
        err_console.print(f"left out: {why}", highlight=False, soft_wrap=True)
    if as_json:
        print_json(res)
        return
    for r in res["single_stream"]:
        console.print(
            f"[bold]{r['arch']}[/] ({r['kind']}): bytes in -> contact out median "
            f"{r['latency_touched_median_us']:.1f} us, p99 {r['latency_touched_p99_us']:.0f} us; "
            f"baseline {r['baseline_median_us']:.0f} us (x{r['speedup_median']:.1f}); "
            f"stream {r['stream_frames_per_s']:.0f} frames/s; "
            f"batched {r['batch_frames_per_s']:.0f} frames/s"
        )
    for key in (
        "many_skins",
        "many_skins_one_process",
        "many_skins_ros2",
        "many_skins_ros2_loaded",
    ):
        m = res.get(key)
        if m is None:
            continue
        sink = f"ROS 2 sink ({m['ros2_backend']})" if m["ros2_backend"] else "no sink"
        load = "/".join(f"{x:.2f}" for x in m["load_average_before"])
        console.print(
            f"{m['skins']} skins at {m['rate_hz']:g} Hz, K = {m['max_contacts']}, "
            f"{m['workers']} worker(s), {sink}, {m['cpu_heavy_processes_beside']} CPU-heavy "
            f"process(es) beside, load average {load} before: end to end p99 "
            f"{_us(m['end_to_end_p99_us'])} (median {_us(m['end_to_end_median_us'])}), "
            f"{m['frames_dropped']} frames dropped of {m['frames_sent']}, "
            f"{m['sink_frames_dropped']} by the sink; loop CPU {m['loop_cpu_us_per_frame']:.1f} "
            f"us/frame, single-contact NumPy baseline {m['baseline_cpu_us_per_frame']:.1f} "
            f"us/frame (x{m['loop_cpu_over_baseline']:.2f})",
            soft_wrap=True,
        )
    console.print(f"Results in {out}/online.json")
