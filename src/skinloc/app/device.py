"""The skin the app reads: a frame source on a reader thread, with live sensor statistics.

``DeviceLink`` opens a source (the simulated skin or a serial port), reads it on one thread and
hands every frame to a callback. Work that needs the stream to itself (a baseline capture) runs
on that same thread between frames through ``run_exclusive``. ``SensorMonitor`` keeps the
numbers the Connect page shows: frame rate, per-sensor noise and SNR, dead or noisy lines.
"""

from __future__ import annotations

import collections
import concurrent.futures
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from skinloc.calibration.session import TouchDetector
from skinloc.errors import FrameTimeoutError, SourceNotConnectedError
from skinloc.sources.base import Frame, FrameSource, make_source

log = logging.getLogger(__name__)

__all__ = ["LINK_TIMEOUT_S", "DeviceLink", "SensorMonitor", "SourceSpec"]

#: Seconds without a frame after which the link counts as down (the tabs say so within 1 s).
LINK_TIMEOUT_S = 0.8


@dataclass
class SourceSpec:
    """Which skin to read.

    Attributes
    ----------
    source : str
        ``sim`` for the simulated skin, else a serial port (a pyserial URL is refused: see
        ``skinloc.hardware.ports.check_source``).
    tx, rx : int
        Grid the device sends.
    baud : int
        Serial baud rate.
    format : str
        Serial wire format: ``auto``, ``text`` or ``binary``.
    seed : int
        Seed of the simulated skin.
    rate_hz : float
        Frame rate of the simulated skin.
    """

    source: str = "sim"
    tx: int = 8
    rx: int = 8
    baud: int = 115200
    format: str = "auto"
    seed: int = 0
    rate_hz: float = 100.0

    @property
    def is_sim(self) -> bool:
        """Whether this is the simulated skin."""
        return self.source == "sim"

    def check(self) -> None:
        """Raise ``ValueError`` unless the source is ``sim`` or a serial device (no URL)."""
        from skinloc.hardware.ports import check_source

        check_source(self.source)

    def build(self, mesh: Any = None) -> FrameSource:
        """The (unconnected) frame source; ``mesh`` is the simulated skin's surface."""
        self.check()
        if self.is_sim:
            return make_source(
                "sim",
                mesh=mesh,
                n_tx=self.tx,
                n_rx=self.rx,
                random_state=self.seed,
                rate_hz=self.rate_hz,
                realtime=True,
            )
        return make_source(
            "serial",
            port=self.source,
            baud=self.baud,
            n_tx=self.tx,
            n_rx=self.rx,
            format=self.format,
        )


class SensorMonitor:
    """Rolling statistics of the stream: rate, noise, SNR, flagged sensors and lines.

    Noise is the robust spread (1.4826 x MAD) of each sensor over the last ``window`` untouched
    frames: a frame the touch detector (5 sigma of the zero frames' noise, 2 sensors) calls a
    touch, and the ``settle`` frames after one, are left out, so a finger held down never makes
    its sensors look noisy. The zero level is the median of the first frames after
    ``rezero``; SNR is the largest rise above it relative to the noise (the paper's Eq. 1 with
    the running peak), unless a session supplies per-sensor SNR from its point logs.
    """

    def __init__(self, n_tx: int, n_rx: int, window: int = 100, settle: int = 10) -> None:
        self.n_tx, self.n_rx = n_tx, n_rx
        self.window = window
        self.settle = settle
        self._detector: TouchDetector | None = None
        self._after_touch = 0
        self._frames: collections.deque[np.ndarray] = collections.deque(maxlen=window)
        self._times: collections.deque[float] = collections.deque(maxlen=window)
        self.zero: np.ndarray | None = None
        self._zero_frames: list[np.ndarray] = []
        self.peak = np.zeros(n_tx * n_rx)
        self.n_frames = 0
        self.session_snr: np.ndarray | None = None

    def rezero(self) -> None:
        """Measure the zero level again from the next 30 frames."""
        self.zero, self._zero_frames = None, []
        self._detector = None
        self.peak = np.zeros(self.n_tx * self.n_rx)

    def restart_rate(self) -> None:
        """Measure the frame rate afresh (after a gap in the stream)."""
        last = self._times[-1] if self._times else None
        self._times.clear()
        if last is not None:
            self._times.append(last)

    def add(self, values: np.ndarray, wall_s: float) -> None:
        """Take one frame of raw counts."""
        self.n_frames += 1
        self._times.append(wall_s)
        if self.zero is None:
            self._frames.append(values)
            self._zero_frames.append(values)
            if len(self._zero_frames) >= 30:
                Z = np.stack(self._zero_frames).astype(np.float64)
                self.zero = np.median(Z, axis=0)
                spread = 1.4826 * np.median(np.abs(Z - self.zero), axis=0)
                self._detector = TouchDetector(self.zero, spread)
                self._zero_frames = []
            return
        self.peak = np.maximum(self.peak, values - self.zero)
        # Only untouched frames measure the noise: a touch is signal, not noise.
        if self._detector is not None and self._detector.is_touched(values):
            self._after_touch = self.settle
        elif self._after_touch > 0:
            self._after_touch -= 1
        else:
            self._frames.append(values)

    @property
    def rate_hz(self) -> float:
        """Frames per second over the window (wall clock)."""
        t = self._times
        if len(t) < 2 or t[-1] <= t[0]:
            return 0.0
        return (len(t) - 1) / (t[-1] - t[0])

    def noise(self) -> np.ndarray:
        """Per-sensor noise, counts (robust std over the window)."""
        if len(self._frames) < 5:
            return np.full(self.n_tx * self.n_rx, np.nan)
        F = np.stack(self._frames).astype(np.float64)
        mad = np.median(np.abs(F - np.median(F, axis=0)), axis=0)
        return 1.4826 * mad

    def report(self) -> dict[str, Any]:
        """Noise, SNR and flags for the Connect page."""
        noise = self.noise()
        n = self.n_tx * self.n_rx
        if self.session_snr is not None and len(self.session_snr) == n:
            snr, snr_from = self.session_snr, "session"
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = self.peak / np.maximum(noise, 1.0)
                snr = np.where(ratio > 1, 20 * np.log10(np.where(ratio > 1, ratio, 1.0)), np.nan)
            snr_from = "peak since zero"
        status = np.array(["ok"] * n, dtype=object)
        if np.isfinite(noise).all():
            med = float(np.median(noise))
            last = self._frames[-1]
            frames = np.stack(self._frames)
            stuck = (np.ptp(frames, axis=0) == 0) & (len(frames) >= 20)
            status[noise > max(3.0 * med, med + 2.0)] = "noisy"
            status[stuck | (last <= 0) | (last >= 65535)] = "dead"
        if np.isfinite(snr).sum() > n // 2:
            weak = np.isfinite(snr) & (snr < np.nanmedian(snr) - 6.0) & (status == "ok")
            if snr_from == "session":
                status[weak] = "weak"
        grid = status.reshape(self.n_tx, self.n_rx)

        def lines(axis: int) -> list[dict[str, Any]]:
            out = []
            for i in range(grid.shape[1 - axis]):
                cells = grid[i, :] if axis == 1 else grid[:, i]
                bad = [s for s in cells if s != "ok"]
                if len(bad) * 2 >= len(cells):
                    out.append({"index": i, "status": max(set(bad), key=bad.count)})
            return out

        return {
            "noise": noise,
            "snr_db": snr,
            "snr_from": snr_from,
            "mean_snr_db": float(np.nanmean(snr)) if np.isfinite(snr).any() else None,
            "status": status.tolist(),
            "tx_lines": lines(1),
            "rx_lines": lines(0),
        }


class DeviceLink:
    """A connected frame source read on its own thread.

    Parameters
    ----------
    spec : SourceSpec
        What to open.
    on_frame : callable(Frame, DeviceLink)
        Called on the reader thread for every frame, with this link.
    mesh : trimesh.Trimesh, optional
        Surface of the simulated skin.
    on_link : callable(bool, DeviceLink), optional
        Called on the reader thread when the link goes down (no frame for ``LINK_TIMEOUT_S``,
        or the port lost) and when frames come again.
    """

    def __init__(
        self,
        spec: SourceSpec,
        on_frame: Callable[[Frame, DeviceLink], None],
        mesh: Any = None,
        on_link: Callable[[bool, DeviceLink], None] | None = None,
    ):
        self.spec = spec
        self.mesh = mesh
        self.source = spec.build(mesh)
        self.on_frame = on_frame
        self.on_link = on_link
        self.last_frame_s = time.monotonic()
        self.link_up = True
        self.link_losses = 0
        self._in_job = False
        self.monitor = SensorMonitor(self.source.n_tx, self.source.n_rx)
        self.error = ""
        self.detached = False
        self._jobs: collections.deque = collections.deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def name(self) -> str:
        """The source's name."""
        return self.source.name

    def start(self) -> None:
        """Connect the source (errors propagate, one line) and start reading."""
        self.source.connect()
        self._thread = threading.Thread(target=self._run, name="skinloc-app-reader", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop reading and disconnect."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self.source.is_connected:
            self.source.disconnect()
        while self._jobs:
            _, fut = self._jobs.popleft()
            fut.cancel()

    def run_exclusive(self, fn: Callable[[FrameSource], Any]) -> concurrent.futures.Future:
        """Run ``fn(source)`` on the reader thread between frames; returns a future."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._jobs.append((fn, fut))
        return fut

    @property
    def frame_age_s(self) -> float:
        """Seconds since the last frame (0 while an exclusive job reads the stream)."""
        return 0.0 if self._in_job else max(0.0, time.monotonic() - self.last_frame_s)

    def _source_link_up(self) -> bool:
        link_stats = getattr(self.source, "stats", None)
        return bool(link_stats().link_up) if callable(link_stats) else True

    def link_now(self) -> bool:
        """Whether the link is up now: the port is open and frames keep coming."""
        return self._source_link_up() and self.frame_age_s < LINK_TIMEOUT_S

    def _check_link(self) -> None:
        """Tell ``on_link`` when the link goes down or comes back (reader thread)."""
        up = self.link_now()
        if up == self.link_up:
            return
        self.link_up = up
        if up:
            self.monitor.restart_rate()  # the gap is not part of the frame rate
        else:
            self.link_losses += 1
            log.warning("%s: no frame for %.1f s", self.name, self.frame_age_s)
        if self.on_link is not None and not self.detached:
            try:
                self.on_link(up, self)
            except Exception:  # a bug in a handler must not stop the stream
                log.exception("link handler failed")

    def stats(self) -> dict[str, Any]:
        """Frame rate and link counters (drops, corruption, reconnects) for the UI."""
        out: dict[str, Any] = {
            "name": self.name,
            "tx": self.source.n_tx,
            "rx": self.source.n_rx,
            # A stalled link streams nothing: no stale rate from the frames before it stopped.
            "rate_hz": round(self.monitor.rate_hz, 1) if self.link_now() else 0.0,
            "frames": self.monitor.n_frames,
            "error": self.error,
            "sim": self.spec.is_sim,
        }
        link_stats = getattr(self.source, "stats", None)
        if callable(link_stats):
            s = link_stats().as_dict()
            out.update(
                received=s["n_received"],
                dropped=s["n_dropped"],
                corrupted=s["n_corrupted"],
                lost=s["n_lost"],
                overflow=s["n_overflow"],
                reconnects=s["n_reconnects"],
                link_up=s["link_up"] and self.link_up,
                format=s["format"],
            )
        else:
            out.update(
                received=self.monitor.n_frames,
                dropped=0,
                corrupted=0,
                lost=0,
                overflow=0,
                reconnects=0,
                link_up=self.link_up,
                format="sim",
            )
        out["link_losses"] = self.link_losses
        out["frame_age_s"] = round(self.frame_age_s, 2)
        return out

    def _run(self) -> None:
        while not self._stop.is_set():
            while self._jobs:
                fn, fut = self._jobs.popleft()
                if fut.set_running_or_notify_cancel():
                    self._in_job = True
                    try:
                        fut.set_result(fn(self.source))
                    except BaseException as exc:  # handed to whoever waits on the future
                        fut.set_exception(exc)
                    finally:
                        # The job read the stream: its frames count as signs of life.
                        self._in_job = False
                        self.last_frame_s = time.monotonic()
            try:
                # A short wait, so a stalled link is noticed well within a second.
                frame = self.source.read(timeout_s=0.2)
            except FrameTimeoutError as exc:
                self.error = str(exc)
                self._check_link()
                continue
            except SourceNotConnectedError as exc:
                self.error = str(exc)
                self._check_link()
                if not self.source.is_connected:
                    return
                time.sleep(0.1)
                continue
            self.error = ""
            self.last_frame_s = time.monotonic()
            self._check_link()
            self.monitor.add(frame.values, time.monotonic())
            try:
                self.on_frame(frame, self)
            except Exception:  # a bug in a handler must not stop the stream
                log.exception("frame handler failed")
