"""The app's state and actions: the device, the open session, guided capture, training, live.

One ``Workspace`` serves every tab of one app process. The reader thread calls ``on_frame``;
HTTP handlers call the actions; both hold ``_lock``. Control belongs to one tab at a time (the
lease): another tab that tries to change anything is told the session is busy, and may take
over explicitly. Every touch is saved before anything else happens with it.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from skinloc.app.capture import (
    CapturePhase,
    TouchCapture,
    baseline_drift_sigma,
    off_target,
    touch_flags,
)
from skinloc.app.device import DeviceLink, SourceSpec
from skinloc.app.hub import Hub
from skinloc.app.store import SessionFolder, SessionStore
from skinloc.calibration.session import (
    CalibrationSession,
    ScriptedFinger,
    SessionConfig,
    TouchDetector,
)
from skinloc.data.recording import Recording, read_recording, write_recording
from skinloc.errors import RecordingError, SkinlocError
from skinloc.geometry.mesh import SamplingMode, cone_skin, mesh_from_arrays, nearest_on_surface
from skinloc.sources.base import Frame

log = logging.getLogger(__name__)

__all__ = ["AppConfig", "BusyError", "Mode", "Workspace"]


class BusyError(SkinlocError):
    """Another tab (or process) has control of the skin."""


class Mode(StrEnum):
    """What the frames are used for."""

    IDLE = "idle"
    BASELINE = "baseline"  # a baseline capture is running
    CALIBRATE = "calibrate"
    VALIDATE = "validate"
    LIVE = "live"


@dataclass
class AppConfig:
    """Settings of one app process.

    Attributes
    ----------
    data_dir : Path
        Folder of sessions and recordings.
    mesh : trimesh.Trimesh or None
        Skin of new sessions; the paper's semi-cone when None.
    mesh_name : str
        How the UI names that mesh.
    train_options : dict
        Overrides passed to ``train_localizer`` (none: its defaults).
    finger_delay_s : float
        Pause of the scripted finger before each touch, s.
    frame_push_hz : float
        Heat-map updates sent to the tabs per second.
    holdout_fraction : float
        Share of the point logs held out to measure the error when training.
    """

    data_dir: Path = Path("skinloc-sessions")
    mesh: Any = None
    mesh_name: str = "paper semi-cone (built in)"
    train_options: dict[str, Any] = field(default_factory=dict)
    finger_delay_s: float = 0.4
    frame_push_hz: float = 25.0
    holdout_fraction: float = 0.2


class _SerialFinger:
    """The scripted finger of ``skinloc virtual-skin``, driven over its port."""

    def __init__(self, source) -> None:
        self.source = source

    def prompt(self, index: int, target: np.ndarray) -> None:
        x, y, z = np.asarray(target, dtype=float).tolist()
        self.source.write(f"touch {x:.6f} {y:.6f} {z:.6f}\n".encode())

    def captured(self, index: int) -> None:
        self.source.write(b"lift\n")


@dataclass
class _Active:
    """The open session."""

    folder: SessionFolder
    lock_fd: int
    info: dict[str, Any]
    mesh: trimesh.Trimesh
    targets: np.ndarray
    cal: CalibrationSession | None = None
    val: CalibrationSession | None = None
    model: Any = None


def _app_meta(rec: Recording) -> dict[str, Any]:
    return rec.meta.setdefault("app", {})


_PER_POINT = ("touch_flags", "flags", "peaks", "predicted", "uncertainty_mm", "errors_mm")


def _pop_point_log(rec: Recording, i: int) -> dict[str, Any]:
    """Remove point log ``i`` (and its per-touch metadata); returns what was removed."""
    keep = np.arange(rec.n_point_logs) != i
    removed = {
        "target": rec.targets[i].copy(),
        "frames": rec.frames[i].copy(),
        "times": None if rec.frame_times is None else rec.frame_times[i].copy(),
    }
    rec.targets, rec.frames = rec.targets[keep], rec.frames[keep]
    if rec.frame_times is not None:
        rec.frame_times = rec.frame_times[keep]
    meta = _app_meta(rec)
    removed["meta"] = {}
    for key in _PER_POINT:
        if key in meta and len(meta[key]) > i:
            removed["meta"][key] = meta[key].pop(i)
    return removed


class Workspace:
    """Everything one app process knows and does.

    Parameters
    ----------
    config : AppConfig
        Settings.
    hub : Hub
        Where messages to the tabs go.
    """

    def __init__(self, config: AppConfig, hub: Hub) -> None:
        self.config = config
        self.hub = hub
        self.store = SessionStore(config.data_dir)
        self.default_mesh = config.mesh if config.mesh is not None else cone_skin()
        self._lock = threading.RLock()
        self.device: DeviceLink | None = None
        self.active: _Active | None = None
        self.mode = Mode.IDLE
        self.lease: str | None = None
        self.capture: TouchCapture | None = None
        self.detector: TouchDetector | None = None
        self.finger_on = False
        self._finger: Any = None
        self._finger_due: float | None = None
        self._finger_down = False
        self._quiet: list[np.ndarray] = []
        self._last_push = 0.0
        self._last_report = 0.0
        self._live_base: np.ndarray | None = None
        self.training: dict[str, Any] | None = None
        self.message = ""

    # ================================================================== lease
    def require(self, client: str | None) -> None:
        """Give ``client`` control if nobody has it; raise ``BusyError`` if another tab has."""
        client = client or "anonymous"
        with self._lock:
            if self.lease is None or self.lease not in self.hub.client_ids + [client]:
                # Free, or held by a tab that is gone: take it.
                self._set_lease(client)
            elif self.lease != client:
                raise BusyError(
                    "busy: this skin and session are in use in another tab; "
                    "close that tab or take over here"
                )

    def take_over(self, client: str) -> None:
        """Give ``client`` control, whoever had it (the other tab is told)."""
        with self._lock:
            self._set_lease(client)

    def release(self, client: str) -> None:
        """A tab went away: free control if it had it and no tab of it remains."""
        with self._lock:
            if self.lease == client and client not in self.hub.client_ids:
                self.lease = None
                self._publish_state()

    def _set_lease(self, client: str) -> None:
        if self.lease != client:
            self.lease = client
            self._publish_state()

    # ================================================================== device
    def connect(self, spec: SourceSpec) -> None:
        """Open the skin ``spec`` names (closing the one before)."""
        with self._lock:
            self._stop_device(self._detach_device())
            mesh = self.active.mesh if self.active is not None else self.default_mesh
            link = DeviceLink(
                spec, self.on_frame, mesh=mesh if spec.is_sim else None, on_link=self.on_link
            )
            link.start()
            self.device = link
            self._update_session_snr()
            self.message = f"connected to {link.name}"
            self._publish_state()

    def disconnect(self) -> None:
        """Close the skin."""
        with self._lock:
            old = self._detach_device()
            self._publish_state()
        self._stop_device(old)

    def _detach_device(self) -> DeviceLink | None:
        """Forget the device (its reader keeps running until ``_stop_device``)."""
        device, self.device = self.device, None
        if device is not None:
            self._stop_capture()
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
        """Press the simulated skin at ``point`` (m; snapped onto the skin) or lift (None)."""
        with self._lock:
            device = self._need_device()
            if not device.spec.is_sim:
                raise ValueError("touching with the mouse works on the simulated skin only")
            skin = device.source
            if point is None:
                skin.release()
                return
            p = np.asarray(point, dtype=np.float64).reshape(-1)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise ValueError(f"point must be 3 finite coordinates in m, got {point!r}")
            skin.press(nearest_on_surface(skin.mesh, p)[0][0])

    # ================================================================== sessions
    def sessions(self) -> dict[str, Any]:
        """Sessions and loose recordings for the first page."""
        out = []
        for folder in self.store.sessions():
            try:
                out.append(folder.summary())
            except SkinlocError as exc:
                out.append({"id": folder.id, "name": folder.id, "error": str(exc)})
        return {
            "sessions": out,
            "recordings": self.store.recordings(),
            "root": str(self.store.root),
        }

    def create_session(
        self,
        name: str,
        n_points: int = 80,
        mode: str = "even",
        samples: int = 50,
        baseline_frames: int = 50,
        seed: int = 0,
        mesh_file: str | None = None,
        targets_csv: str | None = None,
        n_validation: int = 20,
    ) -> str:
        """Make and open a new session; returns its id."""
        cfg = SessionConfig(
            n_points=int(n_points),
            mode=mode if mode != "list" else "even",
            samples_per_touch=int(samples),
            n_baseline_frames=int(baseline_frames),
            random_state=int(seed),
            description=name,
        )
        if mesh_file:
            from skinloc.geometry.mesh import load_mesh

            path = self.mesh_dir / Path(mesh_file).name
            mesh, mesh_name = load_mesh(path), path.name
        else:
            mesh, mesh_name = self.default_mesh, self.config.mesh_name
        if mode == "list":
            targets = self._parse_targets(targets_csv or "", mesh)
            cfg.n_points = len(targets)
        else:
            from skinloc.geometry.mesh import sample_targets

            # An active session starts from an even plan and replaces all but its first
            # targets, one after each touch (``_choose_next``).
            plan = "even" if cfg.mode == "active" else SamplingMode(cfg.mode).value
            targets = sample_targets(mesh, cfg.n_points, plan, random_state=cfg.random_state)
        info = {
            "config": asdict(cfg),
            "sampling": mode,
            "mesh": mesh_name,
            "n_validation": int(n_validation),
        }
        folder = self.store.create(name or "session", mesh.vertices, mesh.faces, targets, info)
        self.open_session(folder.id)
        return folder.id

    @property
    def mesh_dir(self) -> Path:
        """Where uploaded meshes are kept."""
        return self.store.root / "meshes"

    @staticmethod
    def _parse_targets(text: str, mesh: trimesh.Trimesh) -> np.ndarray:
        rows = []
        for k, line in enumerate(text.splitlines(), 1):
            line = line.split("#")[0].strip()
            if not line:
                continue
            parts = [p for p in line.replace(";", ",").replace("\t", ",").split(",") if p.strip()]
            try:
                rows.append([float(p) for p in parts[:3]])
            except ValueError:
                if not rows:  # a header line
                    continue
                raise ValueError(
                    f"targets line {k}: expected x, y, z numbers, got {line!r}"
                ) from None
            if len(parts) < 3:
                raise ValueError(f"targets line {k}: expected x, y, z, got {line!r}")
        if not rows:
            raise ValueError("the list of targets is empty: give one 'x, y, z' line per target")
        pts = np.asarray(rows, dtype=np.float64)
        if np.abs(pts).max() > 5.0:  # millimetres, as the UI and the sheets show them
            pts = pts * 1e-3
        closest, dist, _ = nearest_on_surface(mesh, pts)
        if dist.max() > 0.005:
            k = int(np.argmax(dist))
            raise ValueError(
                f"target {k + 1} lies {dist[k] * 1e3:.1f} mm off the skin: give points on its "
                "surface (in mm or m, in the mesh's frame)"
            )
        return closest

    def open_session(self, session_id: str) -> None:
        """Open a session (lock it, load its recordings and model)."""
        with self._lock:
            folder = self.store.get(session_id)
            if self.active is not None and self.active.folder.id == folder.id:
                return
            self._close_session()
            fd = folder.lock()
            try:
                vertices, faces, targets = folder.read_plan()
                active = _Active(
                    folder, fd, folder.read_info(), mesh_from_arrays(vertices, faces), targets
                )
                if folder.model.is_file():
                    from skinloc.models.localizer import ContactLocalizer

                    active.model = ContactLocalizer.load(folder.model)
            except BaseException:
                SessionFolder.unlock(fd)
                raise
            self.active = active
            self.message = f"opened session {active.info.get('name', folder.id)}"
            device = self.device
            if (
                device is not None
                and device.spec.is_sim
                and not _same_mesh(device.mesh, active.mesh)
            ):
                # The simulated skin takes the session's shape.
                spec = device.spec
                self._stop_device(self._detach_device())
                link = DeviceLink(spec, self.on_frame, mesh=active.mesh, on_link=self.on_link)
                link.start()
                self.device = link
            self._update_session_snr()
            self._publish_state()

    def close_session(self) -> None:
        """Close the open session (everything is already saved)."""
        with self._lock:
            self._close_session()
            self._publish_state()

    def _close_session(self) -> None:
        self._stop_capture()
        self.mode = Mode.IDLE
        if self.active is not None:
            SessionFolder.unlock(self.active.lock_fd)
            self.active = None
        if self.device is not None:
            self.device.monitor.session_snr = None

    def import_recording(self, path: str) -> str:
        """Make a session from a loose recording (copied in as its finished calibration)."""
        rec = read_recording(self._recording_path(path))
        n = rec.n_point_logs
        cfg = SessionConfig(
            n_points=max(n, 1),
            samples_per_touch=max(rec.samples_per_touch, 1),
            n_baseline_frames=max(len(rec.baseline_frames), 2),
            description=f"imported {Path(path).name}",
        )
        info = {
            "config": asdict(cfg),
            "sampling": rec.meta.get("sampling_mode", "?"),
            "mesh": f"from {Path(path).name}",
            "n_validation": 20,
            "imported_from": str(path),
        }
        folder = self.store.create(Path(path).stem, rec.vertices, rec.faces, rec.targets, info)
        rec.planned_targets = rec.targets.copy()
        rec.meta.setdefault("session", asdict(cfg))
        write_recording(rec, folder.calibration)
        self.open_session(folder.id)
        return folder.id

    def _recording_path(self, path: str) -> Path:
        p = Path(path).resolve()
        root = self.store.root.resolve()
        if root not in p.parents:
            raise ValueError(f"{path} is not a recording in {root}")
        return p

    def _need_session(self) -> _Active:
        if self.active is None:
            raise ValueError("no session open: open one on the Sessions page or start a new one")
        return self.active

    def coverage(self, n_points: int = 300) -> dict[str, Any]:
        """The trained model's expected localisation error over the skin, for the 3D view.

        ``points`` ``(E, 3)`` m and ``expected_mm`` ``(E,)`` mm (``skinloc.sensors.coverage``), plus
        the summary of ``skinloc coverage`` and the colour scale's range, mm. Computed once
        per model (about a second), outside the lock.
        """
        from skinloc.sensors.coverage import coverage_map

        with self._lock:
            a = self._need_session()
            model = a.model
            cached = getattr(self, "_coverage_cache", None)
        if model is None:
            raise ValueError("train a model first: the coverage map comes from the trained model")
        if getattr(model, "map_", None) is None:
            raise ValueError("the coverage map needs a response-map model (the default)")
        if cached is not None and cached[0] is model:
            return cached[1]
        temperature = float(getattr(model, "meta_", {}).get("coverage_temperature", 1.0))
        cov = coverage_map(model.map_, None, n_points=n_points, temperature=temperature)
        out = {k: v for k, v in cov.as_dict().items() if k != "blind_spots_m"}
        out.update(
            points=np.round(cov.points_m, 6),
            expected_mm=np.round(cov.expected_mm, 2),
            unit="mm",
            scale_mm=[0.0, 20.0],  # the colours of the validation errors: green, yellow, red
        )
        self._coverage_cache = (model, out)
        return out

    def session_mesh(self) -> dict[str, Any] | None:
        """The open session's skin mesh (m), for the 3D view."""
        with self._lock:
            a = self.active
            if a is None:
                return None
            return {"id": a.folder.id, "vertices": a.mesh.vertices, "faces": a.mesh.faces}

    def session_detail(self) -> dict[str, Any] | None:
        """The open session: targets, point logs and their flags, model, validation."""
        with self._lock:
            a = self.active
            if a is None:
                return None
            out: dict[str, Any] = {
                "id": a.folder.id,
                "name": a.info.get("name"),
                "info": a.info,
                "history": a.folder.history_count(),
            }
            out["calibration"] = self._rec_detail(a.cal, a.folder.calibration, a.targets)
            out["validation"] = self._rec_detail(a.val, a.folder.validation, None)
            return out

    def _rec_detail(self, sess: CalibrationSession | None, path: Path, plan) -> dict[str, Any]:
        rec = sess.recording if sess is not None else None
        if rec is None and path.is_file():
            try:
                rec = read_recording(path)
            except RecordingError as exc:
                return {"error": str(exc)}
        if rec is None:
            return {
                "planned": plan if plan is not None else np.zeros((0, 3)),
                "done": np.zeros((0, 3)),
                "flags": [],
                "peaks": [],
                "predicted": [],
                "errors_mm": [],
                "skipped": [],
                "baseline_checks": [],
                "taken_back": [],
                "started": False,
            }
        meta = _app_meta(rec)
        return {
            "planned": rec.planned_targets if rec.planned_targets is not None else rec.targets,
            "done": rec.targets,
            "flags": meta.get("flags", [[] for _ in range(rec.n_point_logs)]),
            "peaks": meta.get("peaks", []),
            "predicted": meta.get("predicted", []),
            "errors_mm": meta.get("errors_mm", []),
            "skipped": meta.get("skipped", []),
            "baseline_checks": meta.get("baseline_checks", []),
            "taken_back": meta.get("taken_back", []),
            "started": True,
        }

    # ================================================================== calibration & validation
    def start_calibration(self) -> None:
        """Resume the session's calibration, or capture its baseline and start it."""
        with self._lock:
            a = self._need_session()
            device = self._need_device()
            resumed = a.cal is None and a.folder.calibration.is_file()
            if resumed:
                a.cal = CalibrationSession.resume(device.source, a.folder.calibration)
            if a.cal is not None and a.cal.recording is None:
                # The baseline capture did not finish: take it again.
                self._capture_baseline(a.cal, Mode.CALIBRATE)
                return
            if a.cal is not None:
                if a.cal.recording.n_sensors != device.source.n_sensors:
                    raise RecordingError(
                        f"the session has {a.cal.recording.n_sensors} sensors but the skin "
                        f"has {device.source.n_sensors}"
                    )
                if resumed:
                    self._choose_next(a.cal)
                self._begin(Mode.CALIBRATE, a.cal)
                return
            cfg_fields = SessionConfig.__dataclass_fields__
            cfg = SessionConfig(**{k: v for k, v in a.info["config"].items() if k in cfg_fields})
            a.cal = CalibrationSession(
                device.source,
                a.mesh,
                a.folder.calibration,
                cfg,
                targets=a.targets,
                source_name=device.name,
            )
            self._capture_baseline(a.cal, Mode.CALIBRATE)

    def start_validation(self, n_points: int | None = None) -> None:
        """Resume the validation, or start one: fresh baseline, random targets."""
        with self._lock:
            a = self._need_session()
            device = self._need_device()
            if a.model is None:
                raise ValueError("train a model first: validation scores the trained model")
            if a.val is None and a.folder.validation.is_file():
                a.val = CalibrationSession.resume(device.source, a.folder.validation)
            if (
                a.val is not None
                and a.val.recording is not None
                and not a.val.finished
                and n_points in (None, len(a.val.targets))
            ):
                self._begin(Mode.VALIDATE, a.val)  # carry on where it stopped
                return
            n = int(n_points or a.info.get("n_validation", 20))
            if n < 1:
                raise ValueError(f"validation needs at least 1 touch, got {n}")
            if a.val is not None and a.folder.validation.is_file():
                # Starting again: the old validation is kept, renamed.
                stamp = time.strftime("%Y%m%d-%H%M%S")
                kept = f"validation-{stamp}.h5"
                a.folder.validation.rename(a.folder.path / kept)
                # Its result is the previous one now, said so, not the new run's.
                old = a.info.pop("validation", None)
                if old:
                    a.info["validation_previous"] = {**old, "file": kept}
                a.folder.write_info(a.info)
            base = a.info["config"]
            cfg = SessionConfig(
                n_points=n,
                mode="random",
                samples_per_touch=base["samples_per_touch"],
                n_baseline_frames=base["n_baseline_frames"],
                random_state=int(base.get("random_state", 0)) + 1000 + int(time.time()) % 1000,
                description=f"validation of {a.info.get('name')}",
            )
            a.val = CalibrationSession(
                device.source, a.mesh, a.folder.validation, cfg, source_name=device.name
            )
            a.info["n_validation"] = n
            self._capture_baseline(a.val, Mode.VALIDATE)

    def _capture_baseline(self, sess: CalibrationSession, then: Mode) -> None:
        """Capture the session's baseline (it writes the recording), then start guided capture."""

        def read(source) -> None:
            sess.source = source  # the skin may have been reconnected since
            sess.capture_baseline()

        self._baseline(read, lambda _: self._begin(then, sess))

    def _baseline(self, read: Callable[[Any], Any], then: Callable[[Any], None]) -> None:
        """Run ``read(source)`` on the reader thread while the skin is untouched; then ``then``.

        The mode is ``BASELINE`` meanwhile; a failure is reported and ends in ``IDLE``.
        """
        device = self._need_device()
        self._stop_capture()
        self.mode = Mode.BASELINE
        self.message = "keep the skin untouched: capturing the baseline"
        self._publish_state()

        def job(source) -> Any:
            clear = getattr(source, "clear", None)
            if callable(clear):  # drop frames buffered before the request
                clear()
            return read(source)

        def done(f) -> None:
            with self._locked_for(device) as ok:
                if not ok or self.mode is not Mode.BASELINE:
                    return
                if f.cancelled() or f.exception() is not None:
                    self.mode = Mode.IDLE
                    self.message = f"baseline capture failed: {f.exception() or 'cancelled'}"
                else:
                    then(f.result())
                self._publish_state()

        device.run_exclusive(job).add_done_callback(done)

    def _begin(self, mode: Mode, sess: CalibrationSession) -> None:
        rec = sess.recording
        assert rec is not None and sess.detector is not None
        self._stop_capture()
        self.detector = sess.detector
        cfg = sess.config
        self.capture = TouchCapture(
            sess.detector,
            cfg.samples_per_touch,
            settle_frames=cfg.settle_frames,
        )
        self.capture.phase = CapturePhase.WAIT_RELEASE
        self.mode = mode
        self._quiet = []
        self._setup_finger()
        if sess.finished:
            self._finish(mode)
        else:
            self.message = f"touch target {sess.n_done + 1} of {len(sess.targets)}"
        self._publish_state()

    def _session_of(self, mode: Mode) -> CalibrationSession:
        a = self._need_session()
        sess = a.cal if mode is Mode.CALIBRATE else a.val
        if sess is None or sess.recording is None:
            raise ValueError("nothing to capture: start calibrating or validating first")
        return sess

    def _guided(self) -> CalibrationSession:
        if self.mode not in (Mode.CALIBRATE, Mode.VALIDATE):
            raise ValueError("not calibrating or validating now")
        return self._session_of(self.mode)

    def _finish(self, mode: Mode) -> None:
        self.mode = Mode.IDLE
        self._stop_capture()
        what = "calibration" if mode is Mode.CALIBRATE else "validation"
        self.message = f"{what} complete"
        if mode is Mode.VALIDATE:
            self._summarise_validation()

    def stop(self) -> None:
        """Pause guided capture or live view (everything recorded is saved)."""
        with self._lock:
            self._stop_capture()
            self.mode = Mode.IDLE
            self.message = "paused"
            self._publish_state()

    def _stop_capture(self) -> None:
        self._stop_capture_finger()
        self.capture = None

    def set_finger(self, on: bool) -> None:
        """Let the scripted finger touch each target (simulated or virtual skin)."""
        with self._lock:
            self.finger_on = bool(on)
            if not on:
                self._stop_capture_finger()
            elif self.capture is not None:
                self._setup_finger()
            self._publish_state()

    def _stop_capture_finger(self) -> None:
        """Lift the scripted finger if it is down, and forget it."""
        if self._finger_down and self._finger is not None:
            try:
                self._finger.captured(-1)
            except (SkinlocError, OSError):  # the port may be gone already
                pass
        self._finger, self._finger_due, self._finger_down = None, None, False

    def _setup_finger(self) -> None:
        if not self.finger_on or self.device is None:
            self._finger = None
            return
        source = self.device.source
        if self.device.spec.is_sim:
            # The calibration module's scripted finger, without its simulated travel time
            # (the app's clock is the wall clock; finger_delay_s plays that part).
            self._finger = ScriptedFinger(source, random_state=int(time.time()), move_time_s=0.0)
        else:
            self._finger = _SerialFinger(source)

    def capture_now(self) -> None:
        """Start capturing now, touch detected or not (the key fallback)."""
        with self._lock:
            self._guided()
            if self.capture is not None:
                self.capture.force()
                self._publish_state()

    def undo(self) -> None:
        """Take back the last touch (kept in history.h5) and prompt its target again."""
        with self._lock:
            sess = self._guided() if self.mode in (Mode.CALIBRATE, Mode.VALIDATE) else None
            if sess is None:
                sess = self._session_of(Mode.CALIBRATE)
            rec = sess.recording
            if rec.n_point_logs == 0:
                raise ValueError("nothing to undo: no touch recorded yet")
            self._take_back(sess, rec.n_point_logs - 1, "undo")

    def retake(self, index: int, which: str = "calibration") -> None:
        """Take back touch ``index`` (kept in history.h5) and prompt its target next."""
        with self._lock:
            sess = self._session_of(Mode.CALIBRATE if which == "calibration" else Mode.VALIDATE)
            rec = sess.recording
            if not 0 <= index < rec.n_point_logs:
                raise ValueError(f"no touch {index + 1}: {rec.n_point_logs} recorded")
            self._take_back(sess, index, "retake")
            mode = Mode.CALIBRATE if which == "calibration" else Mode.VALIDATE
            if self.mode is not mode:
                self._begin(mode, sess)

    def _take_back(self, sess: CalibrationSession, index: int, reason: str) -> None:
        a = self._need_session()
        rec = sess.recording
        n = rec.n_point_logs
        arrays = {"target": rec.targets[index], "frames": rec.frames[index]}
        if rec.frame_times is not None:
            arrays["frame_times"] = rec.frame_times[index]
        which = "validation" if sess is a.val else "calibration"
        # The history first: the touch must exist somewhere at every instant.
        a.folder.archive("touch", arrays, {"reason": reason, "recording": which, "index": index})
        removed = _pop_point_log(rec, index)
        if which == "validation":
            # A validation touch taken back is still an attempt: the result keeps it, so
            # retaking the worst touches cannot quietly improve the reported error.
            err = removed["meta"].get("errors_mm")
            _app_meta(rec).setdefault("taken_back", []).append(
                {
                    "index": int(index),
                    "reason": reason,
                    "target": removed["target"].tolist(),
                    "predicted": removed["meta"].get("predicted"),
                    "error_mm": None if err is None else round(float(err), 3),
                    "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
                }
            )
        planned = rec.planned_targets if rec.planned_targets is not None else rec.targets
        rec.planned_targets = np.concatenate([rec.targets, removed["target"][None], planned[n:]])
        sess.targets = rec.planned_targets
        self._refresh_flags(rec)
        write_recording(rec, sess.path)
        if self.capture is not None:
            self.capture.restart(touched_now=True)
        self._stop_capture_finger()
        self._setup_finger()
        if which == "validation":
            self._summarise_validation()
        self.message = f"{reason}: touch target {rec.n_point_logs + 1} again"
        self._update_session_snr()
        self._publish_state()

    def skip(self) -> None:
        """Drop the current target from the plan (noted in the recording) and go on."""
        with self._lock:
            sess = self._guided()
            rec = sess.recording
            n = rec.n_point_logs
            if sess.finished:
                raise ValueError("no target left to skip")
            target = sess.targets[n]
            _app_meta(rec).setdefault("skipped", []).append(target.tolist())
            rec.planned_targets = np.delete(sess.targets, n, axis=0)
            sess.targets = rec.planned_targets
            write_recording(rec, sess.path)
            if self.capture is not None:
                self.capture.restart(touched_now=True)
            self._stop_capture_finger()
            self._setup_finger()
            if sess.finished:
                self._finish(self.mode)
            else:
                self.message = f"skipped; touch target {n + 1} of {len(sess.targets)}"
            self._publish_state()

    # ------------------------------------------------------------------ the frame path
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
            values = frame.values
            mode = self.mode
            event = None
            if mode in (Mode.CALIBRATE, Mode.VALIDATE) and self.capture is not None:
                event = self._guided_frame(frame, now)
            elif mode is Mode.LIVE:
                self._live_frame(values)
            if now - self._last_push >= 1.0 / self.config.frame_push_hz or event:
                self._last_push = now
                self._push_frame(frame)
            if now - self._last_report >= 1.0:
                self._last_report = now
                self._push_report()

    def on_link(self, up: bool, device: DeviceLink) -> None:
        """The link went down or came back (reader thread): tell every tab at once."""
        with self._locked_for(device) as ok:
            if not ok:
                return
            if not up:
                if self.capture is not None and self.capture.phase is CapturePhase.CAPTURING:
                    # Frames from before and after a gap are not one steady touch.
                    self.capture.restart(touched_now=True)
                self._stop_capture_finger()
                self._setup_finger()
                self.message = (
                    f"link lost: no frame from {device.name}; waiting for it to come back "
                    "(everything recorded is kept)"
                )
            else:
                self.message = f"link back: {device.name} is streaming again"
            self._publish_state()

    def link_status(self) -> dict[str, Any]:
        """The heartbeat the server sends each tab when nothing else goes to it (no lock)."""
        device = self.device
        if device is None:
            return {"type": "heartbeat", "device": False, "link_up": False}
        return {
            "type": "heartbeat",
            "device": True,
            "link_up": device.link_up and device.link_now(),
            "frame_age_s": round(device.frame_age_s, 2),
        }

    def _guided_frame(self, frame: Frame, now: float) -> bool:
        cap = self.capture
        sess = self._session_of(self.mode)
        if cap.phase is CapturePhase.WAIT_TOUCH and not self.detector.is_touched(frame.values):
            self._quiet.append(frame.values)
            del self._quiet[:-100]
        if (
            self._finger is not None
            and cap.phase is CapturePhase.WAIT_TOUCH
            and not self._finger_down
            and not sess.finished
        ):
            if self._finger_due is None:
                self._finger_due = now + self.config.finger_delay_s
            elif now >= self._finger_due:
                self._finger.prompt(sess.n_done, sess.targets[sess.n_done])
                self._finger_down, self._finger_due = True, None
        before = cap.phase
        touch = cap.feed(frame.values, frame.timestamp_s)
        if touch is None:
            if cap.phase is not before:
                self._publish_state()
                return True
            return False
        self._store_touch(sess, touch)
        return True

    def _store_touch(self, sess: CalibrationSession, touch) -> None:
        rec = sess.recording
        meta = _app_meta(rec)
        index = rec.n_point_logs
        target = sess.targets[index]
        peaks = meta.setdefault("peaks", [])
        ref = float(np.median(peaks)) if len(peaks) >= 3 else None
        flags, peak = touch_flags(touch, rec.baseline, self.detector, ref)
        if touch.forced:
            flags.append("forced")
        rec.append(target, touch.frames, touch.times)
        meta.setdefault("touch_flags", []).append(flags)
        peaks.append(peak)
        if len(self._quiet) >= 20:
            drift = baseline_drift_sigma(np.stack(self._quiet), rec.baseline, rec.noise)
            meta.setdefault("baseline_checks", []).append(
                {"after": index, "drift_sigma": round(drift, 2)}
            )
            if drift > 2.0:
                self.message = (
                    f"the baseline has drifted by {drift:.1f} sigma since the session began: "
                    "finish soon or start a new session"
                )
        self._quiet = []
        if self.mode is Mode.VALIDATE:
            self._score_touch(rec, index)
        self._refresh_flags(rec)
        write_recording(rec, sess.path)  # autosave: the touch is on disk before anything else
        if self._finger is not None and self._finger_down:
            self._finger.captured(index)
            self._finger_down = False
        what = "validation" if self.mode is Mode.VALIDATE else "calibration"
        self.hub.publish({"type": "touch", "recording": what, "index": index, "flags": flags})
        if self.mode is Mode.CALIBRATE:
            self._update_session_snr()
            self._choose_next(sess)
        if sess.finished:
            self._finish(self.mode)
        elif "drifted" not in self.message:
            self.message = f"touch target {sess.n_done + 1} of {len(sess.targets)}"
        self._publish_state()

    def _choose_next(self, sess: CalibrationSession) -> None:
        """In an ``active`` session, choose the next target from the touches recorded so far.

        Runs once after each stored touch and on resuming (not after an undo, a retake or a
        skip: the target they put next stays). The plan in the recording shows the choice.
        Takes about a second (a map refit), under the lock: the next touch waits for it anyway.
        """
        rec = sess.recording
        if sess.config.mode != "active" or sess.finished or rec is None:
            return
        sess.target_for(sess.n_done)
        rec.planned_targets = sess.targets
        write_recording(rec, sess.path)

    def _refresh_flags(self, rec: Recording) -> None:
        meta = _app_meta(rec)
        own = meta.setdefault("touch_flags", [])
        # Touches recorded elsewhere (skinloc collect on the same file) have no flags of their own.
        own.extend([] for _ in range(rec.n_point_logs - len(own)))
        del own[rec.n_point_logs :]
        bad, _ = off_target(rec.targets, rec.touch_means)
        meta["flags"] = [
            list(f) + (["off-target"] if b else []) for f, b in zip(own, bad, strict=True)
        ]

    def _score_touch(self, rec: Recording, index: int) -> None:
        model = self.active.model
        pred = model.predict_full(rec.touch_means[index][None])
        meta = _app_meta(rec)
        err = float(1e3 * np.linalg.norm(pred.points[0] - rec.targets[index]))
        meta.setdefault("predicted", []).append(pred.points[0].tolist())
        meta.setdefault("uncertainty_mm", []).append(float(pred.uncertainty_mm[0]))
        meta.setdefault("errors_mm", []).append(err)

    def _summarise_validation(self) -> None:
        a = self.active
        if a is None or a.val is None or a.val.recording is None:
            return
        rec = a.val.recording
        meta = _app_meta(rec)
        errors = meta.get("errors_mm", [])
        taken_back = meta.get("taken_back", [])
        if not errors and not taken_back:
            return
        from skinloc.evaluation.metrics import error_stats

        stats: dict[str, Any] = (
            error_stats(np.asarray(errors)).as_dict() if errors else {"n": 0, "mean_mm": None}
        )
        every = list(errors) + [t["error_mm"] for t in taken_back if t.get("error_mm") is not None]
        planned = rec.planned_targets if rec.planned_targets is not None else rec.targets
        stats.update(
            complete=rec.n_point_logs >= len(planned),
            n_planned=len(planned),
            retaken=len(taken_back),
            skipped=len(meta.get("skipped", [])),
            n_attempts=len(errors) + len(taken_back),
            # Every attempt, the ones taken back included: the honest figure next to the mean.
            all_attempts=error_stats(np.asarray(every)).as_dict() if every else None,
            taken_back=[
                {"index": t["index"], "reason": t["reason"], "error_mm": t.get("error_mm")}
                for t in taken_back
            ],
        )
        a.info["validation"] = stats
        a.folder.write_info(a.info)
        if not errors:
            return
        k = len(taken_back)
        note = f"; {k} touch{'es' if k > 1 else ''} retaken" if k else ""
        self.message = (
            f"validation: {stats['mean_mm']:.1f} +- {stats['std_mm']:.1f} mm over {stats['n']} "
            f"touches{note}"
        )

    def _update_session_snr(self) -> None:
        if self.device is None:
            return
        a = self.active
        rec = a.cal.recording if a is not None and a.cal is not None else None
        if rec is None and a is not None and a.folder.calibration.is_file():
            try:
                rec = read_recording(a.folder.calibration)
            except RecordingError:
                rec = None
        if rec is None or rec.n_point_logs < 15 or rec.n_sensors != self.device.source.n_sensors:
            self.device.monitor.session_snr = None
            return
        from skinloc.evaluation.metrics import snr_db

        self.device.monitor.session_snr = snr_db(rec.touch_means, rec.baseline_frames)

    # ------------------------------------------------------------------ live
    def start_live(self) -> None:
        """Capture a fresh baseline, then localise every frame."""
        with self._lock:
            a = self._need_session()
            device = self._need_device()
            if a.model is None:
                raise ValueError("train a model first: the live view needs one")
            if a.model.n_features_in_ != device.source.n_sensors:
                raise ValueError(
                    f"the model expects {a.model.n_features_in_} sensors but the skin has "
                    f"{device.source.n_sensors}"
                )
            cfg = a.info["config"]
            n = int(cfg.get("n_baseline_frames", 50))

            def read(source) -> tuple[np.ndarray, np.ndarray]:
                frames, _ = source.read_many(n)
                return frames.mean(axis=0), frames.std(axis=0)

            def then(result: tuple[np.ndarray, np.ndarray]) -> None:
                base, noise = result
                self._live_base = base
                self.detector = TouchDetector(
                    base, noise, cfg.get("threshold_sigma", 5.0), cfg.get("min_active", 2)
                )
                self.mode = Mode.LIVE
                self.message = "live: touch the skin"

            self._baseline(read, then)

    def _live_frame(self, values: np.ndarray) -> None:
        delta = values - self._live_base
        touched = self.detector.is_touched(values)
        msg: dict[str, Any] = {"type": "live", "touched": touched}
        if touched:
            pred = self.active.model.predict_full(delta[None])
            unc = float(pred.uncertainty_mm[0])
            msg.update(
                point=pred.points[0],
                uncertainty_mm=unc,
                confidence=float(np.clip(1.0 - unc / 15.0, 0.0, 1.0)) if np.isfinite(unc) else None,
                n_active=self.detector.n_active(values),
            )
        self.hub.publish(msg)

    # ------------------------------------------------------------------ training
    def train(self) -> None:
        """Train on the calibration in the background: held-out error first, then all of it."""
        with self._lock:
            a = self._need_session()
            if self.training is not None and self.training.get("running"):
                raise ValueError("training is already running")
            if a.cal is not None and a.cal.recording is not None:
                rec = a.cal.recording
            elif a.folder.calibration.is_file():
                rec = read_recording(a.folder.calibration)
            else:
                raise ValueError("calibrate first: there are no touches to train on")
            if rec.n_point_logs < 4:
                raise ValueError(
                    f"need at least 4 touches to train and hold some out, have {rec.n_point_logs}"
                )
            rec = rec.subset(slice(None))  # a copy: capture may go on meanwhile
            self.training = {"running": True, "phase": "held-out check", "done": 0, "total": 1}
            self._publish_state()
        threading.Thread(
            target=self._train, args=(a, rec), name="skinloc-train", daemon=True
        ).start()

    def _train(self, a: _Active, rec: Recording) -> None:
        from skinloc.errors import MissingExtraError
        from skinloc.models.localizer import ARCHITECTURES
        from skinloc.models.network_training import import_torch

        arch = self.config.train_options.get("arch", "default")
        torch = None
        if ARCHITECTURES.get(arch, {}).get("kind") == "network":  # a map needs no PyTorch
            try:
                torch = import_torch(f"training the {arch!r} network")
            except MissingExtraError:
                pass  # _fit fails on it and reports it to the tabs
        if torch is None:
            self._fit(a, rec)
            return
        # Leave a core to the reader thread (training would otherwise starve the live stream).
        threads = torch.get_num_threads()
        torch.set_num_threads(max(1, (os.cpu_count() or 2) - 1))
        try:
            self._fit(a, rec)
        finally:
            torch.set_num_threads(threads)

    def _fit(self, a: _Active, rec: Recording) -> None:
        from skinloc.evaluation.scoring import evaluate, train_localizer

        opts = self.config.train_options
        n = rec.n_point_logs
        rng = np.random.default_rng(0)
        order = rng.permutation(n)
        n_test = max(1, int(round(self.config.holdout_fraction * n)))
        test, fit = np.sort(order[:n_test]), np.sort(order[n_test:])
        t0 = time.perf_counter()

        def progress(phase: str):
            def cb(done: int, total: int) -> None:
                self.training.update(phase=phase, done=done, total=total)
                self.hub.publish({"type": "train", **self.training})

            return cb

        try:
            check = train_localizer(
                [rec.subset(fit)], mesh=a.mesh, progress=progress("held-out check"), **opts
            )
            ev = evaluate(check, [rec.subset(test)])
            model = train_localizer([rec], mesh=a.mesh, progress=progress("final model"), **opts)
            holdout = {
                **ev.stats.as_dict(),
                "n_train": int(len(fit)),
                "n_test": int(n_test),
                "n_point_logs": int(n),
                "train_s": round(time.perf_counter() - t0, 2),
            }
            model.save(a.folder.model, extra_meta={"holdout": holdout, "session": a.folder.id})
        except Exception as exc:  # reported to the tabs; the session itself is untouched
            log.exception("training failed")
            with self._lock:
                self.training = {"running": False, "error": str(exc)}
                self.message = f"training failed: {exc}"
                self._publish_state()
            return
        with self._lock:
            if self.active is a:
                a.model = model
                a.info["holdout"] = holdout
                a.folder.write_info(a.info)
            self.training = {"running": False, "result": holdout}
            self.message = (
                f"trained: held-out error {holdout['mean_mm']:.1f} +- {holdout['std_mm']:.1f} mm"
            )
            self._publish_state()

    # ================================================================== messages
    def snapshot(self) -> dict[str, Any]:
        """Everything the tabs show, except the stream."""
        with self._lock:
            a = self.active
            guided = None
            if self.mode in (Mode.CALIBRATE, Mode.VALIDATE) and a is not None:
                sess = self._session_of(self.mode)
                guided = {
                    "index": sess.n_done,
                    "total": len(sess.targets),
                    "target": None if sess.finished else sess.targets[sess.n_done],
                    "phase": self.capture.phase.value if self.capture else None,
                }
            return {
                "type": "state",
                "mode": self.mode.value,
                "message": self.message,
                "lease": self.lease,
                "finger": self.finger_on,
                "device": None
                if self.device is None
                else {**self.device.stats(), "spec": asdict(self.device.spec)},
                "session": None
                if a is None
                else {
                    "id": a.folder.id,
                    "name": a.info.get("name"),
                    "has_model": a.model is not None,
                    "holdout": a.info.get("holdout"),
                    "validation": a.info.get("validation"),
                    "validation_previous": a.info.get("validation_previous"),
                    "n_validation": a.info.get("n_validation", 20),
                    "mesh": a.info.get("mesh"),
                },
                "guided": guided,
                "training": self.training,
                "data_dir": str(self.store.root),
                "default_mesh": self.config.mesh_name,
            }

    def _publish_state(self) -> None:
        self.hub.publish(self.snapshot())

    def _push_frame(self, frame: Frame) -> None:
        device = self.device
        if device is None:
            return
        if self.mode is Mode.LIVE and self._live_base is not None:
            ref = self._live_base
        elif self.detector is not None and self.mode in (Mode.CALIBRATE, Mode.VALIDATE):
            ref = self.detector.baseline
        else:
            ref = device.monitor.zero
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

    def shutdown(self) -> None:
        """Stop the reader and release the session (on server exit)."""
        with self._lock:
            old = self._detach_device()
            self._close_session()
        self._stop_device(old)


def _same_mesh(a: Any, b: Any) -> bool:
    if a is None or b is None:
        return a is b
    return a.vertices.shape == b.vertices.shape and np.allclose(a.vertices, b.vertices)
