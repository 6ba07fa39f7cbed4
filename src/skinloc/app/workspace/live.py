"""The live view: every frame localised and sent to the tabs."""

from __future__ import annotations

from typing import Any

import numpy as np

from skinloc.app.workspace.state import Mode
from skinloc.calibration.session import TouchDetector


class LiveView:
    """Part of ``Workspace``: the live view."""

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
