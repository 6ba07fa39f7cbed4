"""Training jobs: the cross-validated error and the final model, on a background thread.

Which touches go in: every one but those left out by hand (``leave_out``), until put back.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import uuid
from typing import Any

import numpy as np

from skinloc.app.workspace.state import (
    ActiveSession,
    WorkspaceState,
    app_meta,
    fill_per_touch,
    left_out_touches,
    ordinal,
    touch_numbers,
)
from skinloc.data.appender import RecordingAppender
from skinloc.data.recording import Recording, read_recording

log = logging.getLogger(__name__)


class TrainingJobs(WorkspaceState):
    """Part of ``Workspace``: training the session's localiser.

    Attributes
    ----------
    training : dict or None
        The last training job: ``running``, its ``phase`` and progress, then its ``result``
        or ``error``, and the ``session`` it trains.
    """

    training: dict[str, Any] | None = None

    def train(self, exclude: list[int] | None = None) -> None:
        """Train on the calibration in the background: cross-validated error, final model.

        The touches left out by hand (``leave_out``) stay out; ``exclude`` (0-based) leaves
        these out too, as ``leave_out`` would (they stay out until put back). The result
        lists every touch that went in and every one left out, with its flags.
        """
        with self._lock:
            a = self._need_session()
            if self.training is not None and self.training.get("running"):
                raise ValueError("training is already running")
            rec, save = self._calibration_to_edit(a)
            n = rec.n_point_logs
            asked = sorted({int(i) for i in exclude or []})
            bad = [i + 1 for i in asked if not 0 <= i < n]
            if bad:
                raise ValueError(f"no touch {bad[0]} to leave out: {n} recorded")
            fill_per_touch(rec)
            if asked:
                for i in asked:
                    app_meta(rec)["left_out"][i] = True
                save()
            left = left_out_touches(rec)
            kept = np.array([i for i in range(n) if not left[i]], dtype=int)
            if len(kept) < 4:
                raise ValueError(
                    f"need at least 4 touches to train and cross-validate, have {len(kept)}"
                    + (f" ({n - len(kept)} left out)" if n > len(kept) else "")
                )
            touches = self.touch_entries(rec)
            inputs = {
                "n_recorded": int(n),
                "kept": kept.tolist(),
                "went_in": [touches[i] for i in kept],
                "left_out": [
                    {**touches[i], "why": "left out by hand"} for i in range(n) if left[i]
                ],
                "flagged_kept": [touches[i] for i in kept if touches[i]["flags"]],
            }
            rec = rec.subset(kept)  # a copy: capture may go on meanwhile
            self.training = {
                "running": True,
                "phase": "cross-validation",
                "done": 0,
                "total": 1,
                "session": a.folder.id,
            }
            self._publish_state()
        threading.Thread(
            target=self._train, args=(a, rec, inputs), name="skinloc-train", daemon=True
        ).start()

    @staticmethod
    def touch_entries(rec: Recording) -> list[dict[str, Any]]:
        """Each touch as the Train page names it.

        ``index`` (0-based), ``number``, ``attempt`` and the gate's ``flags`` (the words of
        ``skinloc check``).
        """
        flags = app_meta(rec).get("flags", [])
        return [
            {
                "index": i,
                "number": number,
                "attempt": attempt,
                "flags": list(flags[i]) if i < len(flags) else [],
            }
            for i, (number, attempt) in enumerate(touch_numbers(rec))
        ]

    def leave_out(self, index: int, out: bool = True) -> None:
        """Leave touch ``index`` (0-based) out of every training, or put it back (``out``).

        It stays out until put back; a retake of it is a new touch, which goes in.
        """
        with self._lock:
            a = self._need_session()
            rec, save = self._calibration_to_edit(a)
            if not 0 <= index < rec.n_point_logs:
                raise ValueError(f"no touch {index + 1}: {rec.n_point_logs} recorded")
            fill_per_touch(rec)
            app_meta(rec)["left_out"][index] = bool(out)
            save()
            t = self.touch_entries(rec)[index]
            name = f"#{t['number']}" + (f" ({ordinal(t['attempt'])})" if t["attempt"] > 1 else "")
            self.message = (
                f"touch {name} left out of training until put back; train again to use it"
                if out
                else f"touch {name} put back: the next training uses it"
            )
            self._publish_state()

    @staticmethod
    def _calibration_to_edit(a: ActiveSession) -> tuple[Recording, Any]:
        """The session's calibration and how to store a change of its meta.

        The recording of the running capture when there is one, else the file's, written
        back with ``RecordingAppender`` (no device needed).
        """
        if a.cal is not None and a.cal.recording is not None:
            return a.cal.recording, a.cal.save_plan_and_meta
        path = a.folder.calibration
        if not path.is_file():
            raise ValueError("calibrate first: there are no touches to train on")
        rec = read_recording(path)

        def save() -> None:
            with RecordingAppender.reopen(path, rec) as w:
                w.set_meta(rec.meta)

        return rec, save

    def _train(self, a: ActiveSession, rec: Recording, inputs: dict[str, Any]) -> None:
        from skinloc.errors import MissingExtraError
        from skinloc.models.localizer import architecture_kind
        from skinloc.models.network_training import import_torch

        arch = self.config.train_options.get("arch", "default")
        kind = architecture_kind(arch)
        torch = None
        if kind is not None and kind.train_extra == "torch":  # a map needs no PyTorch
            try:
                torch = import_torch(f"training the {arch!r} network")
            except MissingExtraError:
                pass  # _fit fails on it and reports it to the tabs
        if torch is None:
            self._fit(a, rec, inputs)
            return
        # Leave a core to the reader thread (training would otherwise starve the live stream).
        threads = torch.get_num_threads()
        torch.set_num_threads(max(1, (os.cpu_count() or 2) - 1))
        try:
            self._fit(a, rec, inputs)
        finally:
            torch.set_num_threads(threads)

    def _fit(self, a: ActiveSession, rec: Recording, inputs: dict[str, Any]) -> None:
        """Cross-validated error over every touch, the final model, which touch hurts most.

        ``rec`` holds the touches trained on; ``inputs["kept"]`` maps them to the session's.
        """
        from skinloc.evaluation.influence import cross_validated_errors, fold_of, touch_influence
        from skinloc.evaluation.metrics import error_stats, mean_interval
        from skinloc.evaluation.scoring import prior_curve, train_localizer
        from skinloc.models.localizer import architecture_kind

        opts = self.config.train_options
        n = rec.n_point_logs
        kept = np.asarray(inputs["kept"], dtype=int)
        session = a.folder.id
        t0 = time.perf_counter()

        def progress(phase: str):
            def cb(done: int, total: int) -> None:
                self.training.update(phase=phase, done=done, total=total)
                # Another session's tabs are not told of this one.
                if self.active is not None and self.active.folder.id == session:
                    self.hub.publish({"type": "train", **self.training})

            return cb

        def fit(r: Recording):  # a fold's model: scored on single touches, never kept
            return train_localizer([r], mesh=a.mesh, count_rule=False, **opts)

        try:
            # Every touch predicted by a model that did not see it: k folds over all touches.
            # Ten more fits for the influence: seconds for a response map, too long for a
            # network.
            kind = architecture_kind(opts.get("arch", "default"))
            folds = fold_of(n, self.config.cv_folds, 0)
            influence = None
            if self.config.influence_suspects > 0 and (kind is None or kind.quick_fit):
                where = {int(k): j for j, k in enumerate(kept)}
                flagged = [where[f["index"]] for f in inputs["flagged_kept"]]
                infl = touch_influence(
                    rec,
                    fit,
                    suspects=flagged,
                    max_suspects=self.config.influence_suspects,
                    n_folds=self.config.cv_folds,
                    progress=progress("cross-validation"),
                )
                errors = infl.errors_mm
                influence = infl.as_dict()
                for s in influence["suspects"]:  # the session's numbering, not the subset's
                    s["index"] = int(kept[s["index"]])
            else:
                step = progress("cross-validation")
                k_folds = int(folds.max()) + 1
                done = iter(range(1, k_folds + 1))
                errors = cross_validated_errors(
                    rec, fit, folds=folds, progress=lambda: step(next(done), k_folds)
                )
            k_folds = int(folds.max()) + 1
            low, high = mean_interval(errors)
            # The Train page's curve: the error against calibration touches, with the map
            # prior and without, scored on one fold (a few map fits: seconds).
            curve = None
            model = train_localizer([rec], mesh=a.mesh, progress=progress("final model"), **opts)
            if model.config_["kind"] == "map" and model.map_prior() is not None:
                progress("with and without the map prior")(0, 1)
                test = np.flatnonzero(folds == 0)
                train_part = rec.subset(np.flatnonzero(folds != 0))
                curve = prior_curve(train_part, [rec.subset(test)], mesh=a.mesh, **opts)
            holdout = {
                **error_stats(errors).as_dict(),
                "ci95_mm": [round(low, 2), round(high, 2)],
                "how": f"{k_folds}-fold cross-validation",
                "n_folds": k_folds,
                "n_point_logs": int(n),
                **inputs,
            }
            holdout["influence"] = influence
            # whether the map prior from simulated skins was used (few touches: models.map_prior)
            holdout["map_prior"] = bool(getattr(model, "prior_used_", False))
            # Each touch's error predicted by a model that did not see it, for the Train
            # page's map and histogram, with the touch's number.
            numbers = {t["index"]: t for t in inputs["went_in"]}
            holdout["touch_errors"] = {
                "how": holdout["how"],
                "index": kept.tolist(),
                "number": [numbers[int(i)]["number"] for i in kept],
                "attempt": [numbers[int(i)]["attempt"] for i in kept],
                "error_mm": np.round(errors, 2).tolist(),
            }
            holdout["prior_curve"] = curve
            holdout["train_s"] = round(time.perf_counter() - t0, 2)
            holdout["model_id"] = uuid.uuid4().hex[:12]
            model.save(a.folder.model, extra_meta={"holdout": holdout, "session": session})
        except Exception as exc:  # reported to the tabs; the session itself is untouched
            log.exception("training failed")
            with self._lock:
                self.training = {"running": False, "error": str(exc), "session": session}
                if self.active is a:
                    self.message = f"training failed: {exc}"
                self._publish_state()
            return
        with self._lock:
            # The session's own result, also when it was closed (or opened again) meanwhile.
            mine = self.active if self.active and self.active.folder.id == session else None
            for held in (a, mine):
                if held is not None:
                    held.model = model
                    held.info["holdout"] = holdout
                    # A validation scored the model before this one: it is no result of this
                    # model (shown as an earlier model's until this one is validated).
                    old = held.info.pop("validation", None)
                    if old:
                        held.info["validation_previous"] = {**old, "earlier_model": True}
            (mine or a).folder.write_info((mine or a).info)
            if mine is not None:
                prior = " (with the map prior: few touches)" if holdout["map_prior"] else ""
                self.message = (
                    f"trained{prior}: cross-validated error {holdout['mean_mm']:.1f} mm "
                    f"(95 % interval of the mean {low:.1f} to {high:.1f} mm); next: validate "
                    "on fresh touches, or go live"
                )
            self.training = {"running": False, "result": holdout, "session": session}
            self._publish_state()
        self.warm_live(model)  # its engine built now: the Live page starts at once
