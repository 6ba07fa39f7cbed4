"""Sessions: listing, creating, opening and importing them, and what the pages show of one."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from skinloc.app.device import DeviceLink
from skinloc.app.store import SessionFolder
from skinloc.app.workspace.state import (
    ActiveSession,
    Mode,
    WorkspaceState,
    app_meta,
    left_out_touches,
    same_mesh,
    touch_numbers,
)
from skinloc.calibration.session import CalibrationSession, SessionConfig
from skinloc.data.recording import read_recording, write_recording
from skinloc.errors import RecordingError, SkinlocError
from skinloc.geometry.mesh import SamplingMode, mesh_from_arrays, nearest_on_surface


class SessionActions(WorkspaceState):
    """Part of ``Workspace``: the session folders and the open session.

    Attributes
    ----------
    _coverage_cache : tuple or None
        ``(model, its coverage map)``: the last map computed (about a second each).
    """

    _coverage_cache: tuple[Any, dict[str, Any]] | None = None

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
            targets = self._plan_targets(mesh, cfg)
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
    def _plan_targets(mesh: trimesh.Trimesh, cfg: SessionConfig) -> np.ndarray:
        """The targets a sampling mode plans, ``(n, 3)`` m.

        An active session starts from an even plan and replaces all but its first targets,
        one after each touch (``_choose_next``).
        """
        from skinloc.geometry.mesh import sample_targets

        plan = "even" if cfg.mode == "active" else SamplingMode(cfg.mode).value
        return sample_targets(mesh, cfg.n_points, plan, random_state=cfg.random_state)

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
                active = ActiveSession(
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
            self._shape_simulated_skin(active.mesh)
            self._update_session_snr()
            self._publish_state()

    def _shape_simulated_skin(self, mesh: trimesh.Trimesh) -> None:
        """Give the simulated skin, if that is what is connected, the shape ``mesh``."""
        device = self.device
        if device is None or not device.is_sim or same_mesh(device.mesh, mesh):
            return
        options = device.options
        self._stop_device(self._detach_device())
        link = DeviceLink(options, self.on_frame, mesh=mesh, on_link=self.on_link)
        link.start()
        self.device = link

    def close_session(self) -> None:
        """Close the open session (everything is already saved)."""
        with self._lock:
            self._close_session()
            self._publish_state()

    def _close_session(self) -> None:
        self._stop_recording()  # it is written into the session's folder
        self._stop_using_frames()
        self.mode = Mode.IDLE
        # The scripted finger is switched on for one session: the next one must not start
        # touching its targets by itself.
        self.finger_on = False
        if self.active is not None:
            SessionFolder.unlock(self.active.lock_fd)
            self.active = None
        if self.device is not None:
            self.device.monitor.session_snr = None
            self.device.monitor.set_session_map(None)

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

    def _need_session(self) -> ActiveSession:
        if self.active is None:
            raise ValueError("no session open: open one on the Sessions page or start a new one")
        return self.active

    def coverage(self, n_points: int = 300) -> dict[str, Any]:
        """The trained model's expected localisation error over the skin, for the 3D view.

        ``points`` ``(E, 3)`` m and ``expected_mm`` ``(E,)`` mm (``skinloc.sensors.coverage``), plus
        the summary of ``skinloc coverage``, the colour scale's range (the map's 5th to 95th
        percentile), mm, and ``measured``: the session's cross-validated and validation errors,
        mm, to compare with. Computed once per model (about a second), outside the lock.
        """
        from skinloc.sensors.coverage import coverage_map

        with self._lock:
            a = self._need_session()
            model = a.model
            cached = self._coverage_cache
        if model is None:
            raise ValueError("train a model first: the coverage map comes from the trained model")
        if getattr(model, "map_", None) is None:
            raise ValueError("the coverage map needs a response-map model (the default)")
        if cached is not None and cached[0] is model:
            return cached[1]
        temperature = float(getattr(model, "meta_", {}).get("coverage_temperature", 1.0))
        cov = coverage_map(model.map_, None, n_points=n_points, temperature=temperature)
        out = {k: v for k, v in cov.as_dict().items() if k != "blind_spots_m"}
        e = cov.expected_mm
        # The colours span the map's own spread (5th to 95th percentile, to 0.1 mm), so a
        # map of nearly one value still shows where it is better and worse.
        lo, hi = np.floor(10 * np.percentile(e, 5)) / 10, np.ceil(10 * np.percentile(e, 95)) / 10
        out.update(
            points=np.round(cov.points_m, 6),
            expected_mm=np.round(e, 2),
            unit="mm",
            scale_mm=[float(lo), float(max(hi, lo + 0.1))],
        )
        self._coverage_cache = (model, out)
        return {**out, "measured": self._measured_errors()}

    def _measured_errors(self) -> dict[str, Any]:
        """The errors measured on touches, to set the coverage map beside.

        The training's (cross-validated: its ``how`` says so) and the validation's.
        """
        with self._lock:
            info = self.active.info if self.active is not None else {}
        keys = ("n", "mean_mm", "median_mm", "p95_mm", "how", "ci95_mm")
        return {
            k: {key: v[key] for key in keys if key in v}
            for k, v in (("holdout", info.get("holdout")), ("validation", info.get("validation")))
            if v and v.get("mean_mm") is not None
        }

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
                "numbers": [],
                "left_out": [],
                "peaks": [],
                "predicted": [],
                "errors_mm": [],
                "skipped": [],
                "baseline_checks": [],
                "taken_back": [],
                "started": False,
            }
        meta = app_meta(rec)
        return {
            "planned": rec.planned_targets if rec.planned_targets is not None else rec.targets,
            "done": rec.targets,
            "flags": meta.get("flags", [[] for _ in range(rec.n_point_logs)]),
            # each touch's target number for life, its attempt, and whether it is left out
            "numbers": [[k, t] for k, t in touch_numbers(rec)],
            "left_out": left_out_touches(rec),
            "peaks": meta.get("peaks", []),
            "predicted": meta.get("predicted", []),
            "errors_mm": meta.get("errors_mm", []),
            "skipped": meta.get("skipped", []),
            "baseline_checks": meta.get("baseline_checks", []),
            "taken_back": meta.get("taken_back", []),
            "started": True,
        }
