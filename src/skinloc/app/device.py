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
from dataclasses import replace
from typing import Any

import numpy as np

from skinloc.calibration.session import TouchDetector
from skinloc.errors import FrameTimeoutError, SourceNotConnectedError
from skinloc.sensors.health import STEADY_CONFIRM, SteadyHealth, classify_sensors
from skinloc.sources.base import Frame, FrameSource, SourceKind, SourceOptions, make_source

log = logging.getLogger(__name__)

__all__ = ["LINK_TIMEOUT_S", "DeviceLink", "SensorMonitor"]

#: Seconds without a frame after which the link counts as down (the tabs say so within 1 s).
LINK_TIMEOUT_S = 0.8


class SensorMonitor:
    """Rolling statistics of the stream: rate, noise, SNR, flagged sensors and lines.

    Noise is the robust spread (1.4826 x MAD) of each sensor over the last ``window`` untouched
    frames: a frame the touch detector (5 sigma of the zero frames' noise, 2 sensors) calls a
    touch, and the ``settle`` frames after one, are left out, so a finger held down never makes
    its sensors look noisy. The zero level is the median of the first frames after
    ``rezero``; SNR is the largest rise above it relative to the noise (the paper's Eq. 1 with
    the running peak), unless a session supplies per-sensor SNR from its point logs.

    The flags are ``skinloc.sensors.health``'s, shown steady (``SteadyHealth``): once the
    window holds ``min_frames`` untouched frames, a sensor's or line's flag shows, changes or
    clears only after ``steady`` reports in a row (one a second) say so, so a touch the
    detector misses, swaying one window, does not make a line's flag come and go.
    """

    def __init__(
        self,
        n_tx: int,
        n_rx: int,
        window: int = 100,
        settle: int = 10,
        steady: int = STEADY_CONFIRM,
        min_frames: int = 20,
    ) -> None:
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
        #: Gains and no-touch noise of the session's calibration (its ``skinloc sensors`` map),
        #: once known: sensors and lines are then judged on them, as that command judges them.
        self.session_gain: np.ndarray | None = None
        self.session_noise: np.ndarray | None = None
        self.session_map_key: Any = None
        self.min_frames = min_frames
        self._steady = SteadyHealth(steady)

    def quiet_frames(self) -> np.ndarray:
        """The last untouched frames ``(m, n_tx * n_rx)`` raw counts (m: up to ``window``)."""
        if not self._frames:
            return np.zeros((0, self.n_tx * self.n_rx))
        return np.stack(list(self._frames))

    def rezero(self) -> None:
        """Measure the zero level again from the next 30 frames."""
        self.zero, self._zero_frames = None, []
        self._detector = None
        self.peak = np.zeros(self.n_tx * self.n_rx)
        self._steady.reset()

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

    def has_map_of(self, path: Any) -> bool:
        """Whether the sensor map it judges on is of the calibration file ``path``."""
        key = self.session_map_key
        return self.session_gain is not None and key is not None and key[0] == str(path)

    def set_session_map(self, smap: Any) -> None:
        """Judge the sensors on a ``SensorMap``'s gains and noise from now on (None: stop)."""
        ok = smap is not None and len(smap.gain) == self.n_tx * self.n_rx
        if smap is None:
            self.session_map_key = None
        self.session_gain = np.asarray(smap.gain) if ok else None
        self.session_noise = np.asarray(smap.noise_counts) if ok else None

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
        stuck = None
        if np.isfinite(noise).all():
            frames = np.stack(self._frames)
            last = frames[-1]
            stuck = ((np.ptp(frames, axis=0) == 0) & (len(frames) >= 20)) | (last <= 0)
            stuck |= last >= 65535
        gain, judged = self.session_gain, noise
        if gain is not None and self.session_noise is not None:
            judged = self.session_noise
        health = classify_sensors(
            self.n_tx, self.n_rx, gain=gain, noise=judged, stuck=stuck, shown=self._steady.lines
        )
        if len(self._frames) >= self.min_frames:  # enough evidence to hold the flags to
            health = self._steady.update(health)
        return {
            "noise": noise,
            "snr_db": snr,
            "snr_from": snr_from,
            "mean_snr_db": float(np.nanmean(snr)) if np.isfinite(snr).any() else None,
            "status": health.status.tolist(),
            "tx_lines": health.bad_lines("tx"),
            "rx_lines": health.bad_lines("rx"),
        }


class DeviceLink:
    """A connected frame source read on its own thread.

    Parameters
    ----------
    options : SourceOptions
        What to open: ``sim`` or a serial device (``skinloc.hardware.ports.check_source``:
        no pyserial URL), read on the wall clock.
    on_frame : callable(Frame, DeviceLink)
        Called on the reader thread for every frame, with this link.
    mesh : trimesh.Trimesh, optional
        Surface of the simulated skin.
    on_link : callable(bool, DeviceLink), optional
        Called on the reader thread when the link goes down (no frame for ``LINK_TIMEOUT_S``,
        or the port lost), again while it is down whenever the reason it gives (``error``)
        changes, and when frames come again.
    """

    def __init__(
        self,
        options: SourceOptions,
        on_frame: Callable[[Frame, DeviceLink], None],
        mesh: Any = None,
        on_link: Callable[[bool, DeviceLink], None] | None = None,
    ):
        from skinloc.hardware.ports import check_source

        check_source(options.source)
        self.options = replace(options, realtime=True)
        self.mesh = mesh
        self.source = make_source(self.options, mesh=mesh if self.is_sim else None)
        self.on_frame = on_frame
        self.on_link = on_link
        self.last_frame_s = time.monotonic()
        self.link_up = True
        self.link_losses = 0
        self._in_job = False
        self.monitor = SensorMonitor(self.source.n_tx, self.source.n_rx)
        self.error = ""
        self._error_told = ""  # the reason the last down link was told with
        self.detached = False
        self._jobs: collections.deque = collections.deque()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def is_sim(self) -> bool:
        """Whether the link reads the simulated skin."""
        return self.options.kind is SourceKind.SIM

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
            # The port can be found lost while buffered frames are still read (the verdict
            # then goes out with no reason); the reason read after it must reach the tabs too.
            if not up and self.error != self._error_told:
                self._tell(up)
            return
        self.link_up = up
        if up:
            self.monitor.restart_rate()  # the gap is not part of the frame rate
        else:
            self.link_losses += 1
            log.warning("%s: no frame for %.1f s", self.name, self.frame_age_s)
        self._tell(up)

    def _tell(self, up: bool) -> None:
        self._error_told = self.error
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
            "sim": self.is_sim,
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
                # The reader's verdict alone (it also follows the port: ``link_now``), so
                # every message the tabs get says what the counted losses say.
                link_up=self.link_up,
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
                    alive = True
                    try:
                        fut.set_result(fn(self.source))
                    except (FrameTimeoutError, SourceNotConnectedError) as exc:
                        alive = False  # it waited for frames that did not come
                        fut.set_exception(exc)
                    except BaseException as exc:  # handed to whoever waits on the future
                        fut.set_exception(exc)
                    finally:
                        # The job read the stream: its frames count as signs of life.
                        self._in_job = False
                        if alive:
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
