"""Training jobs: the held-out check and the final model, on a background thread."""

from __future__ import annotations

import logging
import os
import threading
import time
from typing import Any

import numpy as np

from skinloc.app.workspace.state import ActiveSession, WorkspaceState, app_meta
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
        """Train on the calibration in the background: held-out error, final model, influence.

        ``exclude`` are touches (0-based) left out of the model, e.g. the ones the capture
        flagged; the result names them.
        """
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
            n = rec.n_point_logs
            left_out = sorted({int(i) for i in exclude or []})
            bad = [i + 1 for i in left_out if not 0 <= i < n]
            if bad:
                raise ValueError(f"no touch {bad[0]} to leave out: {n} recorded")
            kept = np.array([i for i in range(n) if i not in left_out], dtype=int)
            if len(kept) < 4:
                raise ValueError(
                    f"need at least 4 touches to train and hold some out, have {len(kept)}"
                    + (f" ({len(left_out)} left out)" if left_out else "")
                )
            flags = app_meta(rec).get("flags", [])
            inputs = {
                "n_recorded": int(n),
                "kept": kept.tolist(),
                "left_out": [
                    {"index": i, "flags": list(flags[i]) if i < len(flags) else []}
                    for i in left_out
                ],
                "flagged_kept": [
                    {"index": int(i), "flags": list(flags[i])}
                    for i in kept
                    if i < len(flags) and flags[i]
                ],
            }
            rec = rec.subset(kept)  # a copy: capture may go on meanwhile
            self.training = {
                "running": True,
                "phase": "held-out check",
                "done": 0,
                "total": 1,
                "session": a.folder.id,
            }
            self._publish_state()
        threading.Thread(
            target=self._train, args=(a, rec, inputs), name="skinloc-train", daemon=True
        ).start()

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
        """Held-out check, final model, then which touch hurts the held-out error most.

        ``rec`` holds the touches trained on; ``inputs["kept"]`` maps them to the session's.
        """
        from skinloc.evaluation.influence import touch_influence
        from skinloc.evaluation.scoring import evaluate, prior_curve, train_localizer

        opts = self.config.train_options
        n = rec.n_point_logs
        rng = np.random.default_rng(0)
        order = rng.permutation(n)
        n_test = max(1, int(round(self.config.holdout_fraction * n)))
        test, fit = np.sort(order[:n_test]), np.sort(order[n_test:])
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

        try:
            check = train_localizer(
                [rec.subset(fit)], mesh=a.mesh, progress=progress("held-out check"), **opts
            )
            ev = evaluate(check, [rec.subset(test)])
            # The Train page's curve: this session's held-out error against calibration
            # touches, with the map prior and without (a few map fits: seconds).
            curve = None
            if check.map_prior() is not None:  # a response map's (no other kind has one)
                progress("with and without the map prior")(0, 1)
                curve = prior_curve(rec.subset(fit), [rec.subset(test)], mesh=a.mesh, **opts)
            model = train_localizer([rec], mesh=a.mesh, progress=progress("final model"), **opts)
            holdout = {
                **ev.stats.as_dict(),
                "n_train": int(len(fit)),
                "n_test": int(n_test),
                "n_point_logs": int(n),
                **inputs,
            }
            influence = None
            # Ten more fits: seconds for a response map, far too long for a network.
            if self.config.influence_suspects > 0 and model.kind.quick_fit:
                where = {int(k): j for j, k in enumerate(kept)}
                flagged = [where[f["index"]] for f in inputs["flagged_kept"]]
                infl = touch_influence(
                    rec,
                    lambda r: train_localizer([r], mesh=a.mesh, **opts),
                    suspects=flagged,
                    max_suspects=self.config.influence_suspects,
                    progress=progress("which touch hurts most"),
                )
                influence = infl.as_dict()
                for s in influence["suspects"]:  # the session's numbering, not the subset's
                    s["index"] = int(kept[s["index"]])
            holdout["influence"] = influence
            # whether the map prior from simulated skins was used (few touches: models.map_prior)
            holdout["map_prior"] = bool(getattr(model, "prior_used_", False))
            # Each touch's error predicted by a model that did not see it, for the Train page's
            # map and histogram: all of them when the cross-validation ran, else the held-out.
            if influence is not None:
                how = f"{influence['n_folds']}-fold cross-validation"
                touched, errs = kept.tolist(), influence["cv_errors_mm"]
            else:
                how = "held out"
                touched, errs = kept[test].tolist(), np.round(ev.errors_mm, 2).tolist()
            holdout["touch_errors"] = {"how": how, "index": touched, "error_mm": errs}
            holdout["prior_curve"] = curve
            holdout["train_s"] = round(time.perf_counter() - t0, 2)
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
            (mine or a).folder.write_info((mine or a).info)
            if mine is not None:
                prior = " (with the map prior: few touches)" if holdout["map_prior"] else ""
                self.message = (
                    f"trained{prior}: held-out error {holdout['mean_mm']:.1f} +- "
                    f"{holdout['std_mm']:.1f} mm; next: validate on fresh touches, or go live"
                )
            self.training = {"running": False, "result": holdout, "session": session}
            self._publish_state()
