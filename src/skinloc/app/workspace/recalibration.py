"""Recalibration: a model of an earlier session brought to today's skin with k guided touches.

The flow: pick a model (the open session's, another session's of this workspace, or a model
file uploaded to ``models/``), plan ``k`` targets where its map and the new skin most likely
disagree (``calibration.active.recalibration_targets``; random ones for a network), capture a
fresh baseline and the k touches through the guided capture (``guided``: the one capture path,
in ``Mode.RECALIBRATE``), then ``evaluation.recalibration.recalibrate`` (the one entry point,
as ``skinloc train --init``) on a background thread. Its report (what was kept, the old model
untouched against the recalibrated one, mm) is the session's ``info["recalibration"]``; the
model is saved beside the old one, never over it (``model-recalibrated-STAMP.h5``).
"""

from __future__ import annotations

import logging
import re
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from skinloc.app.workspace.state import ActiveSession, Mode, WorkspaceState
from skinloc.calibration.session import CalibrationSession, SessionConfig

log = logging.getLogger(__name__)

#: Most touches a recalibration asks for (the recalibration's choice settles by about 20).
MAX_TOUCHES = 50
#: Targets the plan chooses from: evenly spread points of the session's skin.
POOL_SIZE = 200
#: The name of an uploaded model file.
MODEL_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,120}\.h5$")


class RecalibrationFlow(WorkspaceState):
    """Part of ``Workspace``: the Recalibrate page's actions and its running job.

    Attributes
    ----------
    recalibrating : dict or None
        The last recalibration job: ``running``, then its ``result`` (the report, the saved
        model's file) or ``error``, and the ``session`` it belongs to.
    """

    recalibrating: dict[str, Any] | None

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.recalibrating = None

    # ------------------------------------------------------------------ the models offered
    @property
    def model_dir(self) -> Path:
        """Where uploaded model files are kept."""
        return self.store.root / "models"

    def recalibration_models(self) -> list[dict[str, Any]]:
        """The models a recalibration may start from: ``{"kind", "id", "name"}`` each.

        ``kind`` ``session`` (``id``: a session of this workspace with a trained model) or
        ``file`` (``id``: a model file uploaded to ``models/``).
        """
        out = [
            {"kind": "session", "id": f.id, "name": f"session {f.read_info().get('name', f.id)}"}
            for f in self.store.sessions()
            if f.model.is_file()
        ]
        if self.model_dir.is_dir():
            out += [
                {"kind": "file", "id": p.name, "name": f"file {p.name}"}
                for p in sorted(self.model_dir.iterdir())
                if MODEL_NAME.match(p.name) and p.is_file()
            ]
        return out

    def _model_path(self, session: str | None, file: str | None) -> Path:
        if (session is None) == (file is None):
            raise ValueError("model: give a session or a file, not both and not neither")
        if file is not None:
            if not MODEL_NAME.match(file):
                raise ValueError(f"model file must be a name ending in .h5, got {file[:80]!r}")
            path = self.model_dir / file
            if not path.is_file():
                raise ValueError(f"no uploaded model file {file!r}: upload it first")
            return path
        path = self.store.get(str(session)).model
        if not path.is_file():
            raise ValueError(f"session {session!r} has no trained model: train it first")
        return path

    # ------------------------------------------------------------------ the flow
    def start_recalibration(
        self,
        session: str | None = None,
        file: str | None = None,
        k: int = 10,
        strategy: str = "active",
    ) -> None:
        """Plan ``k`` targets for the chosen model, capture a fresh baseline, then prompt them.

        Parameters
        ----------
        session, file : str, optional
            The model: a session's of this workspace (its id), or an uploaded file's name.
        k : int, default=10
            Touches to ask for, ``0..MAX_TOUCHES`` (0: the fresh baseline only).
        strategy : {"active", "random"}
            ``active``: where the old map and the new skin most likely disagree (a model
            without a response map, a network, gets ``random``).

        Raises
        ------
        ValueError
            Naming what is wrong: no session or skin, ``k`` out of range, no such model, a
            model of another skin (sensors or mesh), a recalibration already running.
        """
        from skinloc.calibration.active import recalibration_targets
        from skinloc.geometry.mesh import mesh_from_arrays, same_surface, sample_targets
        from skinloc.models.localizer import ContactLocalizer

        if isinstance(k, bool) or not isinstance(k, int) or not 0 <= k <= MAX_TOUCHES:
            raise ValueError(f"k must be an integer between 0 and {MAX_TOUCHES}, got {k!r}")
        with self._lock:
            a = self._need_session()
            device = self._need_device()
            if self.recalibrating is not None and self.recalibrating.get("running"):
                raise ValueError("a recalibration is already running")
            path = self._model_path(session, file)
            old = ContactLocalizer.load(path)
            if old.n_features_in_ != device.source.n_sensors:
                raise ValueError(
                    f"the model expects {old.n_features_in_} sensors but the skin has "
                    f"{device.source.n_sensors}: pick a model of this skin"
                )
            v, f = getattr(old, "mesh_vertices_", None), getattr(old, "mesh_faces_", None)
            if v is not None and f is not None and not same_surface(mesh_from_arrays(v, f), a.mesh):
                raise ValueError(
                    "the model was trained on another mesh than this session's skin: pick a "
                    "model of this skin"
                )
            rmap = getattr(old, "map_", None)
            used = strategy if rmap is not None else "random"
            seed = int(time.time()) % 100_000
            pool = sample_targets(a.mesh, POOL_SIZE, "even", random_state=seed)
            idx = recalibration_targets(rmap, k, pool, strategy=used, random_state=seed)
            base = a.info["config"]
            cfg = SessionConfig(
                n_points=max(k, 1),  # the targets are given; 0 of them: a baseline capture
                mode="even",  # unused: the targets are given
                samples_per_touch=base["samples_per_touch"],
                n_baseline_frames=base["n_baseline_frames"],
                random_state=seed,
                description=f"recalibration of {path.name} ({used} targets)",
            )
            target = a.folder.path / "recalibration.h5"
            if target.is_file():  # an earlier recalibration's touches are kept, renamed
                target.rename(a.folder.path / f"recalibration-{_stamp(a.folder.path)}.h5")
            a.recal = CalibrationSession(
                device.source, a.mesh, target, cfg, targets=pool[idx], source_name=device.name
            )
            a.recal_from = {
                "model": old,
                "path": str(path),
                "name": f"{'session ' + str(session) if session else 'file ' + str(file)}",
                "strategy": used,
            }
            self.recalibrating = {"running": False, "planned": int(k), "session": a.folder.id}
            self._capture_baseline(a.recal, Mode.RECALIBRATE)

    def _recalibration_done(self) -> None:
        """The k touches are in (or k = 0): recalibrate on a background thread (lock held)."""
        a = self.active
        if a is None or a.recal is None or a.recal_from is None:
            return
        rec = a.recal.recording
        self.recalibrating = {"running": True, "session": a.folder.id}
        self.message = f"recalibrating on {rec.n_point_logs} touches"
        threading.Thread(
            target=self._recalibrate,
            args=(a, rec, dict(a.recal_from)),
            name="skinloc-recalibrate",
            daemon=True,
        ).start()

    def _recalibrate(self, a: ActiveSession, rec: Any, source: dict[str, Any]) -> None:
        from skinloc.evaluation.recalibration import recalibrate
        from skinloc.evaluation.scoring import evaluate

        session = a.folder.id
        try:
            done = recalibrate(source["model"], [rec])
            path = a.folder.path / f"model-recalibrated-{_stamp(a.folder.path)}.h5"
            report = done.report.as_dict()
            done.model.save(
                path,
                extra_meta={"recalibrated_from": source["path"], "session": session},
            )
            errors = (
                np.round(evaluate(source["model"], [rec]).errors_mm, 2).tolist()
                if rec.n_point_logs
                else []
            )
            result = {
                **report,
                "model_file": path.name,
                "from": source["name"],
                "strategy": source["strategy"],
                "before_per_touch_mm": errors,
            }
        except Exception as exc:  # reported to the tabs; the session and old model untouched
            log.exception("recalibration failed")
            with self._lock:
                self.recalibrating = {"running": False, "error": str(exc), "session": session}
                if self.active is a:
                    self.message = f"recalibration failed: {exc}"
                self._publish_state()
            return
        with self._lock:
            a.info["recalibration"] = result
            a.folder.write_info(a.info)
            self.recalibrating = {"running": False, "result": result, "session": session}
            if self.active is a:
                after = "" if result["after_mm"] is None else f", {result['after_mm']:.1f} mm after"
                before = (
                    "" if result["before_mm"] is None else f": {result['before_mm']:.1f} mm before"
                )
                self.message = (
                    f"recalibrated ({result['method']}){before}{after}; saved {path.name}"
                )
            self._publish_state()

    def recalibration_status(self) -> dict[str, Any]:
        """What the Recalibrate page shows: the models, the job, the last result, the guide."""
        with self._lock:
            a = self.active
            job = self.recalibrating
            if a is None or job is None or job.get("session") != a.folder.id:
                job = None
            return {
                "models": self.recalibration_models(),
                "max_touches": MAX_TOUCHES,
                "job": job,
                "result": None if a is None else a.info.get("recalibration"),
                "mode": self.mode.value,
                "message": self.message,
            }


def _stamp(folder: Path) -> str:
    """A time stamp no file of ``folder`` has yet (``YYYYmmdd-HHMMSS``, ``-2``, ...)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    names = {p.name for p in folder.iterdir()}
    k, out = 1, stamp
    while any(out in n for n in names):
        k += 1
        out = f"{stamp}-{k}"
    return out
