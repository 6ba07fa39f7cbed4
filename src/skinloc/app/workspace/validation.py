"""Validation: the paper's check of a trained model on fresh random targets, and its result."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from skinloc.app.workspace.state import ActiveSession, Mode, WorkspaceState, app_meta
from skinloc.calibration.session import CalibrationSession, SessionConfig
from skinloc.data.recording import Recording


class ValidationActions(WorkspaceState):
    """Part of ``Workspace``: validation runs, each touch scored, the result summed up."""

    def start_validation(self, n_points: int | None = None) -> None:
        """Resume the validation, or start one: fresh baseline, random targets."""
        with self._lock:
            a = self._need_session()
            device = self._need_device()
            if a.model is None:
                raise ValueError("train a model first: validation scores the trained model")
            if a.val is None and a.folder.validation.is_file():
                a.val = CalibrationSession.resume(device.source, a.folder.validation)
            model_id = (a.info.get("holdout") or {}).get("model_id")
            if (
                a.val is not None
                and a.val.recording is not None
                and not a.val.finished
                and n_points in (None, len(a.val.targets))
                # a validation belongs to the model it scored: a retrained one starts anew
                and app_meta(a.val.recording).get("model_id", model_id) == model_id
            ):
                self._begin(Mode.VALIDATE, a.val)  # carry on where it stopped
                return
            n = int(n_points or a.info.get("n_validation", 20))
            if n < 1:
                raise ValueError(f"validation needs at least 1 touch, got {n}")
            if a.val is not None and a.folder.validation.is_file():
                self._keep_old_validation(a)
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

    @staticmethod
    def _keep_old_validation(a: ActiveSession) -> None:
        """Rename the session's validation file (its result becomes the previous one)."""
        stamp = time.strftime("%Y%m%d-%H%M%S")
        kept = f"validation-{stamp}.h5"
        a.folder.validation.rename(a.folder.path / kept)
        # Said to be the previous result, never shown as the new run's.
        old = a.info.pop("validation", None)
        if old is None and "file" not in a.info.get("validation_previous", {"file": None}):
            old = a.info["validation_previous"]  # an earlier model's, moved by training
        if old:
            a.info["validation_previous"] = {**old, "file": kept}
        a.folder.write_info(a.info)

    @staticmethod
    def _keep_attempt(rec: Recording, index: int, reason: str, removed: dict[str, Any]) -> None:
        """Note a validation touch taken back (``removed``, from ``pop_point_log``).

        It is still an attempt: the result keeps it, so retaking the worst touches cannot
        quietly improve the reported error.
        """
        err = removed["meta"].get("errors_mm")
        app_meta(rec).setdefault("taken_back", []).append(
            {
                "index": int(index),
                "reason": reason,
                "target": removed["target"].tolist(),
                "predicted": removed["meta"].get("predicted"),
                "error_mm": None if err is None else round(float(err), 3),
                "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
            }
        )

    def _score_touch(self, rec: Recording, index: int) -> None:
        model = self.active.model
        pred = model.predict_full(rec.touch_means[index][None])
        meta = app_meta(rec)
        meta.setdefault("model_id", (self.active.info.get("holdout") or {}).get("model_id"))
        err = float(1e3 * np.linalg.norm(pred.points[0] - rec.targets[index]))
        meta.setdefault("predicted", []).append(pred.points[0].tolist())
        meta.setdefault("uncertainty_mm", []).append(float(pred.uncertainty_mm[0]))
        meta.setdefault("errors_mm", []).append(err)

    def _summarise_validation(self) -> None:
        a = self.active
        if a is None or a.val is None or a.val.recording is None:
            return
        rec = a.val.recording
        meta = app_meta(rec)
        errors = meta.get("errors_mm", [])
        taken_back = meta.get("taken_back", [])
        if not errors and not taken_back:
            return
        if meta.get("model_id") != (a.info.get("holdout") or {}).get("model_id"):
            return  # an earlier model's validation: never shown as this model's
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
            model_id=meta.get("model_id"),
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
