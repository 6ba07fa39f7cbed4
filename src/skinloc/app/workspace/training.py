"""Training jobs: the held-out check and the final model, on a background thread."""

from __future__ import annotations

import logging
import os
import threading
import time

import numpy as np

from skinloc.app.workspace.state import ActiveSession
from skinloc.data.recording import Recording, read_recording

log = logging.getLogger(__name__)


class TrainingJobs:
    """Part of ``Workspace``: training the session's localiser."""

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

    def _train(self, a: ActiveSession, rec: Recording) -> None:
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

    def _fit(self, a: ActiveSession, rec: Recording) -> None:
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
