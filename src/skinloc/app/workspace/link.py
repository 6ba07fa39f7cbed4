"""The skin's link: connecting, the frame path from the reader thread, the link's state."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.app.capture import CapturePhase
from skinloc.app.device import DeviceLink, SensorMonitor
from skinloc.app.hub import Hub
from skinloc.app.workspace.state import CAPTURED, GUIDED_MODES, AppConfig, Mode, WorkspaceState
from skinloc.data.recording import read_recording
from skinloc.errors import RecordingError
from skinloc.geometry.mesh import nearest_on_surface
from skinloc.sources.base import Frame, SourceKind, SourceOptions

log = logging.getLogger(__name__)


class PageClock:
    """The page's event times mapped onto this machine's ``time.monotonic`` clock.

    A path starts ``delay_s`` after its first piece arrives; later pieces keep the page's
    spacing. A piece that arrives after its time (the machine was busy) shifts the rest of the
    path by its lateness, a pause instead of a jump, and the delay of the next paths grows to
    1.5 x that lateness (at most ``max_delay_s``): a jitter buffer, as audio streams keep one.

    Parameters
    ----------
    delay_s, max_delay_s : float
        The first and the largest delay, s.
    """

    def __init__(self, delay_s: float = 0.02, max_delay_s: float = 0.5) -> None:
        self.delay_s = float(delay_s)
        self.max_delay_s = float(max_delay_s)
        self._offset: float | None = None
        self._open = False  # a path is under way (its last piece did not lift the finger)

    def to_monotonic(self, times: list[float], now: float, lifted: bool) -> list[float]:
        """``times`` (page s, in order) on the monotonic clock; ``lifted``: the path ends."""
        if not times:
            return []
        ahead = self._offset is not None and times[0] + self._offset > now + self.max_delay_s
        if not self._open or self._offset is None or ahead:  # a new path (or a new page)
            self._offset = now - times[0] + self.delay_s
        late = now - (times[0] + self._offset)
        if late > 0:
            self._offset += late
            self.delay_s = min(self.max_delay_s, max(self.delay_s, 1.5 * late))
        self._open = not lifted
        return [t + self._offset for t in times]


class LinkActions(WorkspaceState):
    """Part of ``Workspace``: the device, and every frame the reader thread hands over.

    Attributes
    ----------
    _page_clock : PageClock
        The mouse's path on the simulated skin, on this machine's clock.
    _last_push, _last_report : float
        When a heat map and a sensor report last went to the tabs, monotonic s.
    """

    _page_clock: PageClock
    _last_push: float
    _last_report: float

    def __init__(self, config: AppConfig, hub: Hub) -> None:
        super().__init__(config, hub)
        self._page_clock = PageClock()
        self._last_push = 0.0
        self._last_report = 0.0

    def connect(self, options: SourceOptions) -> None:
        """Open the skin ``options`` name (closing the one before)."""
        with self._lock:
            stopped = self._what_stops()
            self._stop_device(self._detach_device())
            mesh = self.active.mesh if self.active is not None else self.default_mesh
            is_sim = options.kind is SourceKind.SIM
            link = DeviceLink(
                options, self.on_frame, mesh=mesh if is_sim else None, on_link=self.on_link
            )
            link.start()
            self.device = link
            self._update_session_snr()
            self.message = f"connected to {link.name}" + (f"; {stopped}" if stopped else "")
            self._publish_state()

    def disconnect(self) -> None:
        """Close the skin; the message says what that stopped and what was kept."""
        with self._lock:
            stopped = self._what_stops()
            old = self._detach_device()
            self.message = "disconnected" + (f": {stopped}" if stopped else "")
            self._publish_state()
        self._stop_device(old)

    def _what_stops(self) -> str:
        """What closing the skin now stops, and what of it is kept (for the message)."""
        parts = []
        if self.mode in GUIDED_MODES and self.active is not None:
            what = CAPTURED[self.mode]
            sess = self._session_of(self.mode)
            n = sess.n_done
            parts.append(
                f"{what} paused at target {n + 1} of {len(sess.targets)} ({n} touch"
                f"{'' if n == 1 else 'es'} kept; the one under way is not); connect and "
                f"start the {what} again to go on"
            )
        elif self.mode is Mode.LIVE:
            parts.append("the live view stopped")
        elif self.mode is Mode.BASELINE:
            parts.append("the baseline capture was cancelled; capture it again once connected")
        if self.recorder is not None:
            parts.append(f"the recording {self.recorder.path.name} ended with every frame so far")
        return "; ".join(parts)

    def _detach_device(self) -> DeviceLink | None:
        """Forget the device (its reader keeps running until ``_stop_device``)."""
        device, self.device = self.device, None
        if device is not None:
            self._stop_recording()  # the file ends here, with every frame so far
            self._stop_using_frames()
            self.mode = Mode.IDLE
            device.detached = True
        return device

    def _stop_device(self, device: DeviceLink | None) -> None:
        """Stop a detached device's reader; its frames are ignored from detaching on."""
        if device is not None:
            device.stop()

    def _need_device(self) -> DeviceLink:
        if self.device is None:
            raise ValueError("no skin connected: connect the simulated skin or a port first")
        return self.device

    def rezero(self) -> None:
        """Measure the heat map's zero level again."""
        with self._lock:
            self._need_device().monitor.rezero()

    def sim_touch(self, point: list[float] | None) -> None:
        """Press the simulated skin at ``point`` (m; snapped onto the skin) or lift (None), now.

        Without the workspace's lock: the reader thread holds it for every frame and, behind on
        a loaded machine, takes it back at once, so a touch waiting for it reached the skin
        late. The simulated finger is the skin's own state, replaced whole by each call and read
        whole by its frame thread.
        """
        skin = self._sim_skin()
        if point is None:
            skin.release()
        elif skin.contact is not None:
            # A drag: the finger slides, pressing as it landed (a new pressure at every mouse
            # move would make its image flicker and its track split).
            skin.slide(self._on_skin(skin, point))
        else:
            # A mouse press is meant: never one of the light touches the skin may not feel
            # (which of them comes would depend on how many frames the noise drew before).
            skin.press(self._on_skin(skin, point), weak=False)

    def sim_path(self, path: list[tuple[float, list[float] | None]]) -> None:
        """Move the simulated finger along a mouse path at the mouse's pace.

        ``path`` is ``(t, point)`` in time order: ``t`` the page's event time, s (any origin),
        ``point`` m (snapped onto the skin) or None for the mouse's release. The page sends the
        path in pieces, one request at a time, and a loaded machine answers late: the points
        are played on this machine's clock (``PageClock``), never bunched into a jump, so a
        quick stroke stays a quick stroke.
        """
        skin = self._sim_skin()
        times = [float(t) for t, _ in path]
        if not np.all(np.isfinite(times)) or np.any(np.diff(times) < 0):
            raise ValueError("path times must be finite and in order")
        points = [None if p is None else self._on_skin(skin, p) for _, p in path]
        wall = self._page_clock.to_monotonic(times, time.monotonic(), lifted=points[-1] is None)
        skin.follow(list(zip(wall, points, strict=True)))

    def _sim_skin(self) -> Any:
        device = self._need_device()  # one read: a device detached meanwhile is pressed unseen
        if not device.is_sim:
            raise ValueError("touching with the mouse works on the simulated skin only")
        return device.source

    @staticmethod
    def _on_skin(skin: Any, point: list[float]) -> np.ndarray:
        """``point`` (m) snapped onto the skin's surface, ``(3,)``."""
        p = np.asarray(point, dtype=np.float64).reshape(-1)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ValueError(f"point must be 3 finite coordinates in m, got {point!r}")
        return nearest_on_surface(skin.mesh, p)[0][0]

    @contextmanager
    def _locked_for(self, device: DeviceLink | None) -> Iterator[bool]:
        """The lock, for the reader thread of ``device``: gives up once that is detached.

        Whoever detaches a device then stops it, which waits for its reader thread: a reader
        blocked on the lock would hold that up.
        """
        while not self._lock.acquire(timeout=0.05):
            if device is not None and device.detached:
                yield False
                return
        try:
            yield device is None or device is self.device
        finally:
            self._lock.release()

    def on_frame(self, frame: Frame, device: DeviceLink | None = None) -> None:
        """Handle one frame (reader thread): capture, live prediction, messages."""
        with self._locked_for(device) as ok:
            if not ok:
                return  # a detached device's last frames
            now = time.monotonic()
            mode = self.mode
            event = None
            if mode in GUIDED_MODES and self.capture is not None:
                event = self._guided_frame(frame, now)
            elif mode is Mode.LIVE:
                self._live_frame(frame)
            elif mode is Mode.BASELINE:
                self._baseline_frame()
            self.record_frame(frame)
            self.keep_recent(frame)
            if now - self._last_push >= 1.0 / self.config.frame_push_hz or event:
                self._last_push = now
                self._push_frame(frame)
            if now - self._last_report >= 1.0:
                self._last_report = now
                self._push_report()

    def on_link(self, up: bool, device: DeviceLink) -> None:
        """Tell every tab that the link changed (reader thread).

        It went down, came back, or, while down, gives a new reason (``device.error``).
        """
        with self._locked_for(device) as ok:
            if not ok:
                return
            if up:
                self.message = f"link back: {device.name} is streaming again"
            else:
                self._drop_capture_in_progress()
                self.message = (
                    f"link lost: no frame from {device.name}; waiting for it to come back "
                    "(everything recorded is kept)"
                )
            self._publish_state()

    def _drop_capture_in_progress(self) -> None:
        """Restart a capture cut by a gap (frames on both sides are not one steady touch)."""
        if self.capture is not None and self.capture.phase is CapturePhase.CAPTURING:
            self.capture.restart(touched_now=True)
        self._stop_capture_finger()
        self._setup_finger()

    def link_status(self) -> dict[str, Any]:
        """The heartbeat the server sends each tab when nothing else goes to it (no lock).

        ``link_up`` is the reader's verdict (``DeviceLink.link_up``), the one that counts the
        link's losses and pushes a state when it changes: a reader late with its frames (a
        busy machine) is not a lost link, so the heartbeat never says so on its own.
        """
        device = self.device
        if device is None:
            return {"type": "heartbeat", "device": False, "link_up": False}
        return {
            "type": "heartbeat",
            "device": True,
            "link_up": device.link_up,
            "frame_age_s": round(device.frame_age_s, 2),
        }

    def _reference(self) -> np.ndarray | None:
        """The no-touch level the heat maps show counts above, ``(n_sensors,)`` counts.

        The live view's baseline while it runs, the guided capture's during one, else the
        monitor's zero level; None before one is known.
        """
        if self.mode is Mode.LIVE and self._live_base is not None:
            return self._live_base
        if self.detector is not None and self.mode in GUIDED_MODES:
            return self.detector.baseline
        return None if self.device is None else self.device.monitor.zero

    def _push_frame(self, frame: Frame) -> None:
        device = self.device
        if device is None:
            return
        ref = self._reference()
        delta = None if ref is None else np.round(frame.values - ref, 1)
        msg: dict[str, Any] = {
            "type": "frame",
            "index": frame.index,
            "tx": device.source.n_tx,
            "rx": device.source.n_rx,
            "delta": delta,
            "stats": device.stats(),
        }
        if self.detector is not None and self.mode is not Mode.IDLE:
            msg["touched"] = self.detector.is_touched(frame.values)
            msg["n_active"] = self.detector.n_active(frame.values)
        if self.capture is not None:
            msg["capture"] = {
                "phase": self.capture.phase.value,
                "n": self.capture.n_captured,
                "of": self.capture.samples,
                "settle": self.capture.run if self.capture.phase is CapturePhase.WAIT_TOUCH else 0,
            }
        self.hub.publish(msg)

    def _push_report(self) -> None:
        if self.device is not None and self.device.monitor.n_frames >= 5:
            self.hub.publish({"type": "sensors", **self.device.monitor.report()})

    def _update_session_snr(self) -> None:
        """Give the monitor the SNR and the sensor map of the open session's touches.

        The map (its gains make the weak and dead lines) is of the calibration's touches as
        they are, whether the calibration was finished in an earlier run or in this one, and
        whatever monitor asks (a skin connected again gets it at once): the same touches give
        the same lines. It is fitted again (on a thread) once the touches changed and no
        calibration is capturing; the last one stays meanwhile, and with fewer than 15
        touches no new one is fitted, the last of this session staying.
        """
        if self.device is None:
            return
        a = self.active
        rec = a.cal.recording if a is not None and a.cal is not None else None
        if rec is None and a is not None and a.folder.calibration.is_file():
            try:
                rec = read_recording(a.folder.calibration)
            except RecordingError:
                rec = None
        monitor = self.device.monitor
        if a is None or rec is None or rec.n_sensors != self.device.source.n_sensors:
            monitor.session_snr = None
            monitor.set_session_map(None)
            return
        path = a.folder.calibration
        if rec.n_point_logs < 15:
            monitor.session_snr = None
            if not monitor.has_map_of(path):
                monitor.set_session_map(None)
            return
        from skinloc.evaluation.metrics import snr_db

        monitor.session_snr = snr_db(rec.touch_means, rec.baseline_frames)
        if path.is_file():  # judged as `skinloc sensors` judges it; no fit while capturing
            session_sensor_map(path, rec, monitor, fit=self.mode is not Mode.CALIBRATE)


#: Sensor maps of finished calibrations, by (file, modification time): a map takes seconds.
_SENSOR_MAPS: dict[tuple[str, int], Any] = {}
_SENSOR_MAPS_LOCK = threading.Lock()


def session_sensor_map(
    path: Path, rec: Any, monitor: SensorMonitor, wait: bool = False, fit: bool = True
) -> None:
    """Give ``monitor`` the sensor map of the calibration ``rec`` (the file ``path``).

    The Connect page then flags sensors and lines as ``skinloc sensors`` flags that recording
    (``skinloc.sensors.health``). A map fitted before for the file as it is now is given at
    once; otherwise it is fitted on a thread (seconds), the monitor keeping the map it has
    meanwhile (with none, it flags from the live stream alone). ``wait``: fit it on this
    thread. ``fit=False`` (touches being captured): fit nothing, give the last map fitted for
    ``path`` if the monitor has none of it.
    """
    key = (str(path), path.stat().st_mtime_ns if path.is_file() else 0)
    if monitor.session_map_key == key and monitor.session_gain is not None:
        return  # it has this very map
    # A snapshot, without the lock a fit holds for seconds (the caller may hold the
    # workspace's lock, which the frames wait for).
    fitted = dict(_SENSOR_MAPS)
    known = fitted.get(key)
    if known is None and not fit and not monitor.has_map_of(path):
        older = [k for k in fitted if k[0] == str(path)]
        if older:
            key = max(older, key=lambda k: k[1])
            known = fitted[key]
    if known is not None:  # fitted before (another monitor, a session opened again): at once
        monitor.session_map_key = key
        monitor.set_session_map(known)
        return
    if not fit:
        return
    monitor.session_map_key = key  # a map of an older session arriving late is ignored

    def compute() -> None:
        with _SENSOR_MAPS_LOCK:
            smap = _SENSOR_MAPS.get(key)
            if smap is None:
                from skinloc.sensors.sensor_map import sensor_map_from_recordings

                try:
                    smap = _SENSOR_MAPS[key] = sensor_map_from_recordings([rec], n_boot=0)
                except (ValueError, RecordingError) as exc:
                    log.warning("no sensor map of %s: %s", path, exc)
                    return
        if monitor.session_map_key == key:
            monitor.set_session_map(smap)

    if wait:
        compute()
    else:
        threading.Thread(target=compute, name="skinloc-sensor-map", daemon=True).start()
